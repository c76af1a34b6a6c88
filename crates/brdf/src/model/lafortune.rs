//! Lafortune et al. 1997, generalised cosine lobes:
//! `f = kd / pi + sum_j rho_j max(0, Cx ix ox + Cy iy oy + Cz iz oz)^n_j`.
//! A Phong-like specular lobe has `Cx = Cy < 0` and `Cz > 0`; off-specular,
//! retro-reflective and anisotropic lobes come from other signs and
//! `Cx != Cy`. Reciprocal by construction; its albedo depends on the lobes.

use std::f32::consts::FRAC_1_PI;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::{Brdf, both_above, sanitize};
use crate::Rgb;

/// Largest lobe exponent (same bound as the Phong exponent).
pub const MAX_LAFORTUNE_EXPONENT: f32 = 1e6;

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LafortuneLobe {
    pub cx: f32,
    pub cy: f32,
    pub cz: f32,
    pub n: f32,
    pub rho: Rgb,
}

impl LafortuneLobe {
    /// The lobe's value per unit `rho`.
    pub fn value(&self, i: Vec3, o: Vec3) -> f32 {
        let base = self.cx * i.x * o.x + self.cy * i.y * o.y + self.cz * i.z * o.z;
        if !(base > 0.0) {
            return 0.0;
        }
        let n = if self.n.is_nan() { 0.0 } else { self.n.clamp(0.0, MAX_LAFORTUNE_EXPONENT) };
        let v = base.powf(n);
        if v.is_finite() { v } else { 0.0 }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Lafortune {
    pub kd: Rgb,
    pub lobes: Vec<LafortuneLobe>,
}

impl Brdf for Lafortune {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        if !both_above(i, o) {
            return Vec3::ZERO;
        }
        let spec = self.lobes.iter().fold(Vec3::ZERO, |acc, l| acc + l.rho * l.value(i, o));
        sanitize(self.kd * FRAC_1_PI + spec)
    }
}
