//! What is rendered: a camera, lights and an optional environment.

use std::f32::consts::{PI, TAU};

use brdf::Rgb;
use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};
use setup::CameraModel;

/// A light (positions in mm in the sample frame, `+z` up).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Light {
    /// Isotropic point light of radiant intensity `intensity` (per channel).
    Point { position_mm: Vec3, intensity: Rgb },
    /// Distant light: unit `direction` toward the light, irradiance on a
    /// surface facing it.
    Directional { direction: Vec3, irradiance: Rgb },
}

/// An environment map in latitude-longitude layout (`+z` up; row 0 at the
/// zenith; column 0 at azimuth 0 = `+x`), radiance per texel, with a
/// sampling distribution proportional to luminance times `sin(theta)`.
#[derive(Clone, Debug, PartialEq)]
pub struct EnvMap {
    pub width: usize,
    pub height: usize,
    pub texels: Vec<Rgb>,
    /// Row marginal CDF and per-row conditional CDFs.
    marginal: Vec<f32>,
    conditional: Vec<f32>,
    total: f32,
}

fn lum(c: Rgb) -> f32 {
    0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z
}

impl EnvMap {
    pub fn new(width: usize, height: usize, texels: Vec<Rgb>) -> Self {
        let mut conditional = vec![0.0f32; width * height];
        let mut marginal = vec![0.0f32; height];
        let mut acc_rows = 0.0f64;
        for y in 0..height {
            let theta = (y as f32 + 0.5) / height as f32 * PI;
            let s = theta.sin();
            let mut acc = 0.0f64;
            for x in 0..width {
                acc += (lum(texels[y * width + x]).max(0.0) * s) as f64;
                conditional[y * width + x] = acc as f32;
            }
            if acc > 0.0 {
                for x in 0..width {
                    conditional[y * width + x] /= acc as f32;
                }
            }
            acc_rows += acc;
            marginal[y] = acc_rows as f32;
        }
        let total = acc_rows as f32;
        if total > 0.0 {
            marginal.iter_mut().for_each(|m| *m /= total);
        }
        Self { width, height, texels, marginal, conditional, total }
    }

    /// A procedural sky: a blue gradient, a dim ground, and a small bright
    /// sun at (`sun_elevation_deg`, `sun_azimuth_deg`).
    pub fn sky(sun_elevation_deg: f32, sun_azimuth_deg: f32) -> Self {
        let (w, h) = (256, 128);
        let sun = dir_from(sun_elevation_deg.to_radians(), sun_azimuth_deg.to_radians());
        let mut t = Vec::with_capacity(w * h);
        for y in 0..h {
            for x in 0..w {
                let d = Self::texel_dir(x, y, w, h);
                let up = d.z.max(0.0);
                let mut c = if d.z >= 0.0 {
                    Vec3::new(0.35, 0.55, 0.95).lerp(Vec3::new(0.85, 0.9, 1.0), 1.0 - up) * 0.6
                } else {
                    Vec3::new(0.12, 0.1, 0.08)
                };
                if d.dot(sun) > 0.9995 {
                    c += Vec3::new(4000.0, 3800.0, 3500.0);
                }
                t.push(c);
            }
        }
        Self::new(w, h, t)
    }

    fn texel_dir(x: usize, y: usize, w: usize, h: usize) -> Vec3 {
        let theta = (y as f32 + 0.5) / h as f32 * PI;
        let phi = (x as f32 + 0.5) / w as f32 * TAU;
        Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
    }

    /// Radiance arriving from direction `d` (nearest texel).
    pub fn radiance(&self, d: Vec3) -> Rgb {
        let theta = d.z.clamp(-1.0, 1.0).acos();
        let phi = d.y.atan2(d.x).rem_euclid(TAU);
        let y = ((theta / PI * self.height as f32) as usize).min(self.height - 1);
        let x = ((phi / TAU * self.width as f32) as usize).min(self.width - 1);
        self.texels[y * self.width + x]
    }

    /// Draw a direction with probability proportional to luminance times
    /// solid angle; returns it with its pdf (per steradian).
    pub fn sample(&self, u: Vec2) -> Option<(Vec3, f32)> {
        if !(self.total > 0.0) {
            return None;
        }
        let y = self.marginal.partition_point(|&c| c <= u.x).min(self.height - 1);
        let row = &self.conditional[y * self.width..(y + 1) * self.width];
        let x = row.partition_point(|&c| c <= u.y).min(self.width - 1);
        let d = Self::texel_dir(x, y, self.width, self.height);
        let pdf = self.pdf(d);
        (pdf > 0.0).then_some((d, pdf))
    }

    /// Density of [`EnvMap::sample`] at `d`.
    pub fn pdf(&self, d: Vec3) -> f32 {
        if !(self.total > 0.0) {
            return 0.0;
        }
        let theta = d.z.clamp(-1.0, 1.0).acos();
        let s = theta.sin();
        if s <= 1e-6 {
            return 0.0;
        }
        let c = self.radiance(d);
        // Probability of the texel divided by its solid angle.
        let p_texel = lum(c).max(0.0) * s / self.total;
        let solid = (PI / self.height as f32) * (TAU / self.width as f32) * s;
        p_texel / solid
    }
}

pub fn dir_from(elevation_rad: f32, azimuth_rad: f32) -> Vec3 {
    let t = std::f32::consts::FRAC_PI_2 - elevation_rad;
    Vec3::new(t.sin() * azimuth_rad.cos(), t.sin() * azimuth_rad.sin(), t.cos())
}

/// A camera, lights and an environment.
#[derive(Clone, Debug)]
pub struct Scene {
    pub camera: CameraModel,
    pub lights: Vec<Light>,
    pub env: Option<std::sync::Arc<EnvMap>>,
    /// Environment samples per pixel (ignored without an environment).
    pub env_samples: u32,
}

impl Scene {
    /// A camera at `elevation_deg` from the normal and `azimuth_deg` around
    /// it, `distance_mm` from the centre, looking at the sample centre.
    pub fn camera(elevation_deg: f32, azimuth_deg: f32, distance_mm: f32, fov_y_deg: f32, px: u32) -> CameraModel {
        let e = elevation_deg.to_radians();
        let a = azimuth_deg.to_radians();
        let pos = Vec3::new(distance_mm * e.sin() * a.cos(), distance_mm * e.sin() * a.sin(), distance_mm * e.cos());
        // Straight overhead the +z up vector is degenerate; use +y then.
        let up = if elevation_deg.abs() < 1.0 { Vec3::Y } else { Vec3::Z };
        CameraModel::pinhole(pos, Vec3::ZERO, up, fov_y_deg, px, px)
    }
}
