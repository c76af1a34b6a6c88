//! Anisotropic GGX / Trowbridge-Reitz distribution (Trowbridge and Reitz
//! 1975; Walter et al. 2007; anisotropic form of Heitz 2014).
//!
//! `D(h) = 1 / (pi ax ay (hx^2/ax^2 + hy^2/ay^2 + hz^2)^2)` in the lobe frame,
//! which never divides by `hz`. Smith's projected area has the closed form
//! `sigma(v) = (vz + sqrt(vz^2 + vx^2 ax^2 + vy^2 ay^2)) / 2`.

use std::f32::consts::{PI, TAU};

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::{Ndf, clamp_alpha, from_lobe_frame, normal_from_slopes, to_lobe_frame};

/// Anisotropic GGX NDF with roughness `alpha_x`, `alpha_y` along a lobe frame
/// rotated by `angle_rad` about the normal.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Ggx {
    pub alpha_x: f32,
    pub alpha_y: f32,
    pub angle_rad: f32,
}

impl Ggx {
    pub fn new(alpha_x: f32, alpha_y: f32, angle_rad: f32) -> Self {
        Self { alpha_x: clamp_alpha(alpha_x), alpha_y: clamp_alpha(alpha_y), angle_rad }
    }

    pub fn isotropic(alpha: f32) -> Self {
        Self::new(alpha, alpha, 0.0)
    }
}

impl Ndf for Ggx {
    fn d(&self, h: Vec3) -> f32 {
        if h.z <= 0.0 {
            return 0.0;
        }
        let h = to_lobe_frame(h, self.angle_rad);
        let (ax, ay) = (self.alpha_x, self.alpha_y);
        let k = h.x * h.x / (ax * ax) + h.y * h.y / (ay * ay) + h.z * h.z;
        1.0 / (PI * ax * ay * k * k)
    }

    fn projected_area(&self, v: Vec3) -> f32 {
        if v.z <= 0.0 {
            return super::beckmann::projected_area_floor(v);
        }
        let v = to_lobe_frame(v, self.angle_rad);
        let r2 = (v.x * self.alpha_x).powi(2) + (v.y * self.alpha_y).powi(2);
        (0.5 * (v.z + (v.z * v.z + r2).sqrt())).max(v.z)
    }

    fn sample_h(&self, u: Vec2) -> Vec3 {
        // GGX slopes follow P22 = 1 / (pi ax ay (1 + sx^2/ax^2 + sy^2/ay^2)^2);
        // the radial CDF in scaled slope r is r^2 / (1 + r^2).
        let u1 = u.x.min(1.0 - f32::EPSILON);
        let r = (u1 / (1.0 - u1)).sqrt();
        let (s, c) = (TAU * u.y).sin_cos();
        let h = normal_from_slopes(self.alpha_x * r * c, self.alpha_y * r * s);
        from_lobe_frame(h, self.angle_rad)
    }
}
