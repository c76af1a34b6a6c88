//! A pinhole camera: pose, field of view and resolution. Pixel `(u, v)`
//! has its centre at `(u + 0.5, v + 0.5)`; `u` grows to the right, `v`
//! downward, as in every image format.
//!
//! Lens distortion is not modelled: the rig's camera is calibrated for it
//! beforehand (e.g. with a checkerboard) and frames are treated as
//! distortion-free; the simulator renders distortion-free frames.

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
        }
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
        Some(Vec2::new(
            0.5 * self.width as f32 + b.focal_px * d.dot(b.right) / z,
            0.5 * self.height as f32 + b.focal_px * d.dot(b.down) / z,
        ))
    }

    /// Unit ray direction through continuous pixel coordinates.
    pub fn ray(&self, pixel: Vec2) -> Vec3 {
        let b = self.basis();
        let x = (pixel.x - 0.5 * self.width as f32) / b.focal_px;
        let y = (pixel.y - 0.5 * self.height as f32) / b.focal_px;
        (b.forward + x * b.right + y * b.down).normalize()
    }

    /// Where the ray through `pixel` meets the sample plane `z = 0`.
    pub fn pixel_to_plane(&self, pixel: Vec2) -> Option<Vec2> {
        let d = self.ray(pixel);
        if d.z >= 0.0 {
            return None;
        }
        let t = -self.position_mm.z / d.z;
        let p = self.position_mm + t * d;
        Some(Vec2::new(p.x, p.y))
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
        // The whole 10 cm sample is in view.
        for p in [Vec3::new(-50.0, -50.0, 0.0), Vec3::new(50.0, 50.0, 0.0), Vec3::new(50.0, -50.0, 0.0)] {
            let px = c.project(p).unwrap();
            assert!(px.x > 0.0 && px.x < 256.0 && px.y > 0.0 && px.y < 256.0, "{p} at {px}");
        }
    }
}
