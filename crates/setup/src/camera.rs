//! A camera: pose, field of view, resolution, principal point and radial
//! lens distortion. Pixel `(u, v)` has its centre at `(u + 0.5, v + 0.5)`;
//! `u` grows to the right, `v` downward, as in every image format.
//!
//! Distortion is the two-term radial model: a ray with ideal (pinhole)
//! normalised image coordinates `x` is imaged at `x (1 + k1 r^2 + k2 r^4)`,
//! `r = |x|` (Brown 1966; the model of Zhang 2000 and of most calibration
//! tools). A rig file written by hand leaves the principal point centred
//! and the distortion zero; a geometric calibration measures them.

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use crate::geometry::SampleArea;

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraModel {
    pub position_mm: Vec3,
    pub look_at_mm: Vec3,
    /// Roughly up in the image; made orthogonal to the view direction.
    pub up: Vec3,
    pub fov_y_deg: f32,
    pub width: u32,
    pub height: u32,
    /// Offset of the principal point from the image centre, pixels.
    #[serde(default, skip_serializing_if = "is_zero2")]
    pub principal_offset_px: Vec2,
    /// Radial distortion `[k1, k2]`.
    #[serde(default, skip_serializing_if = "is_zero_k")]
    pub radial_k: [f32; 2],
}

fn is_zero2(v: &Vec2) -> bool {
    *v == Vec2::ZERO
}

fn is_zero_k(k: &[f32; 2]) -> bool {
    *k == [0.0, 0.0]
}

/// Orthonormal camera basis: right, down (image v) and forward.
#[derive(Clone, Copy, Debug)]
pub struct CameraBasis {
    pub right: Vec3,
    pub down: Vec3,
    pub forward: Vec3,
    /// Focal length in pixels.
    pub focal_px: f32,
}

impl CameraModel {
    /// A camera `elevation_deg` from the sample normal, on the `-x` side,
    /// `distance_mm` from the sample centre, looking at it.
    pub fn oblique(elevation_deg: f32, distance_mm: f32, fov_y_deg: f32, width: u32, height: u32) -> Self {
        let e = elevation_deg.to_radians();
        Self {
            position_mm: Vec3::new(-distance_mm * e.sin(), 0.0, distance_mm * e.cos()),
            look_at_mm: Vec3::ZERO,
            up: Vec3::Z,
            fov_y_deg,
            width,
            height,
            principal_offset_px: Vec2::ZERO,
            radial_k: [0.0, 0.0],
        }
    }

    /// Pinhole camera at `position_mm` looking at `look_at_mm`, centred
    /// principal point, no distortion.
    pub fn pinhole(position_mm: Vec3, look_at_mm: Vec3, up: Vec3, fov_y_deg: f32, width: u32, height: u32) -> Self {
        Self {
            position_mm,
            look_at_mm,
            up,
            fov_y_deg,
            width,
            height,
            principal_offset_px: Vec2::ZERO,
            radial_k: [0.0, 0.0],
        }
    }

    /// The principal point, pixels.
    pub fn principal_px(&self) -> Vec2 {
        Vec2::new(0.5 * self.width as f32, 0.5 * self.height as f32) + self.principal_offset_px
    }

    /// Distorted normalised coordinates of ideal ones.
    pub fn distort(&self, x: Vec2) -> Vec2 {
        let r2 = x.length_squared();
        x * (1.0 + self.radial_k[0] * r2 + self.radial_k[1] * r2 * r2)
    }

    /// Ideal normalised coordinates of distorted ones: the inverse of
    /// [`CameraModel::distort`] by fixed-point iteration, which converges
    /// while the distortion's derivative stays well below 1 (any lens a
    /// calibration accepts, over its image).
    pub fn undistort(&self, xd: Vec2) -> Vec2 {
        if self.radial_k == [0.0, 0.0] {
            return xd;
        }
        let mut x = xd;
        for _ in 0..20 {
            let r2 = x.length_squared();
            let f = 1.0 + self.radial_k[0] * r2 + self.radial_k[1] * r2 * r2;
            let next = xd / f.max(0.1);
            let done = (next - x).length_squared() < 1e-14;
            x = next;
            if done {
                break;
            }
        }
        x
    }

    pub fn basis(&self) -> CameraBasis {
        let forward = (self.look_at_mm - self.position_mm).normalize();
        let right = forward.cross(self.up).normalize();
        let up = right.cross(forward);
        let focal_px = 0.5 * self.height as f32 / (0.5 * self.fov_y_deg.to_radians()).tan();
        CameraBasis { right, down: -up, forward, focal_px }
    }

    /// Pixel coordinates of a world point, or `None` behind the camera.
    pub fn project(&self, p: Vec3) -> Option<Vec2> {
        let b = self.basis();
        let d = p - self.position_mm;
        let z = d.dot(b.forward);
        if z <= 0.0 {
            return None;
        }
        let x = self.distort(Vec2::new(d.dot(b.right) / z, d.dot(b.down) / z));
        Some(self.principal_px() + b.focal_px * x)
    }

    /// Unit ray direction through continuous pixel coordinates.
    pub fn ray(&self, pixel: Vec2) -> Vec3 {
        let b = self.basis();
        let x = self.undistort((pixel - self.principal_px()) / b.focal_px);
        (b.forward + x.x * b.right + x.y * b.down).normalize()
    }

    /// Where the ray through `pixel` meets the sample plane `z = 0`.
    pub fn pixel_to_plane(&self, pixel: Vec2) -> Option<Vec2> {
        self.pixel_to(pixel, Vec3::ZERO, Vec3::Z).map(|p| p.truncate())
    }

    /// Where the ray through `pixel` meets the plane through `origin` with
    /// unit normal `normal`, if in front of the camera.
    pub fn pixel_to(&self, pixel: Vec2, origin: Vec3, normal: Vec3) -> Option<Vec3> {
        let d = self.ray(pixel);
        let den = d.dot(normal);
        if den.abs() < 1e-12 {
            return None;
        }
        let t = (origin - self.position_mm).dot(normal) / den;
        (t > 0.0).then(|| self.position_mm + t * d)
    }

    /// Whether the square of pixels reaching `reach` pixels from `pixel`
    /// (continuous coordinates, pixel centres at integer + 0.5) sees only
    /// the sample. The plane's image is a projective map of the square and
    /// the sample is convex, so the four corners decide.
    pub fn sees_only(&self, sample: &SampleArea, pixel: Vec2, reach: f32) -> bool {
        [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
            .into_iter()
            .all(|(sx, sy)| self.pixel_to_plane(pixel + reach * Vec2::new(sx, sy)).is_some_and(|q| sample.contains(q)))
    }

    /// Unit direction from a point on the sample toward the camera (`o`).
    pub fn view_dir(&self, p: Vec3) -> Vec3 {
        (self.position_mm - p).normalize()
    }

    /// Relative illumination falloff of the lens at a pixel: the natural
    /// `cos^4` law of the angle from the optical axis.
    pub fn vignetting(&self, pixel: Vec2) -> f32 {
        let c = self.ray(pixel).dot(self.basis().forward).max(0.0);
        c * c * c * c
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projection_and_ray_are_inverse() {
        let c = CameraModel::oblique(45.0, 450.0, 15.0, 256, 256);
        for p in [Vec3::ZERO, Vec3::new(30.0, -40.0, 0.0), Vec3::new(-50.0, 50.0, 0.0)] {
            let px = c.project(p).unwrap();
            let back = c.pixel_to_plane(px).unwrap();
            assert!((back - p.truncate()).length() < 1e-3, "{p} -> {px} -> {back}");
        }
        let centre = c.project(Vec3::ZERO).unwrap();
        assert!((centre - Vec2::new(128.0, 128.0)).length() < 1e-3);
        // A pixel at the sample's centre sees only the sample, one at a
        // corner does not, nor does the square of pixels reaching past an
        // edge from a pixel inside.
        let s = SampleArea { width_mm: 100.0, height_mm: 100.0 };
        assert!(c.sees_only(&s, centre, 2.5));
        assert!(!c.sees_only(&s, c.project(Vec3::new(50.0, 50.0, 0.0)).unwrap(), 0.5));
        let near_edge = c.project(Vec3::new(0.0, 49.0, 0.0)).unwrap();
        assert!(c.sees_only(&s, near_edge, 0.1) && !c.sees_only(&s, near_edge, 2.5));
        // With a shifted principal point and distortion, projection and
        // ray still invert each other.
        let bent = CameraModel { principal_offset_px: Vec2::new(7.0, -4.0), radial_k: [0.3, -0.5], ..c };
        for p in [Vec3::ZERO, Vec3::new(30.0, -40.0, 0.0), Vec3::new(-50.0, 50.0, 0.0)] {
            let px = bent.project(p).unwrap();
            let back = bent.pixel_to_plane(px).unwrap();
            assert!((back - p.truncate()).length() < 1e-3, "{p} -> {px} -> {back}");
        }
        // The principal point moves the image of the optical axis by its
        // offset; distortion moves the rest radially about it.
        let axis = c.look_at_mm;
        assert!((bent.project(axis).unwrap() - c.project(axis).unwrap() - Vec2::new(7.0, -4.0)).length() < 1e-3);
        let off = Vec3::new(-50.0, 50.0, 0.0);
        let (d, u) = (bent.project(off).unwrap() - bent.principal_px(), c.project(off).unwrap() - c.principal_px());
        assert!(d.length() > u.length() + 0.5 && d.normalize().dot(u.normalize()) > 0.9999, "{d} vs {u}");
        // The whole 10 cm sample is in view.
        for p in [Vec3::new(-50.0, -50.0, 0.0), Vec3::new(50.0, 50.0, 0.0), Vec3::new(50.0, -50.0, 0.0)] {
            let px = c.project(p).unwrap();
            assert!(px.x > 0.0 && px.x < 256.0 && px.y > 0.0 && px.y < 256.0, "{p} at {px}");
        }
    }
}
