//! Anisotropic power-cosine distribution: Blinn's (1977) `cos^n` NDF and its
//! anisotropic form from Ashikhmin and Shirley (2000),
//! `D(h) = sqrt((nu + 2)(nv + 2)) / (2 pi) * cos(theta_h)^(nu cos^2 phi + nv sin^2 phi)`.
//!
//! The normalisation is exact for any `nu`, `nv`: Ashikhmin and Shirley's
//! sampling inversion (their eq. 9) with exponents `nu + 1`, `nv + 1` has the
//! density `sqrt((nu + 2)(nv + 2)) / (2 pi) cos^(e + 1)`, which is `D cos`, and
//! a density integrates to one. The tests check both numerically.
//!
//! There is no closed-form Smith term for this NDF. The projected area uses
//! the usual Beckmann equivalence `alpha = sqrt(2 / (n + 2))` (Walter et al.
//! 2007, section 5.2); its error against numerical integration is pinned by
//! a test.

use std::f32::consts::{FRAC_PI_2, PI};

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::{Beckmann, Ndf, from_lobe_frame, to_lobe_frame};

/// Largest exponent accepted: `cos^n` with `n = 1e6` is a lobe of about
/// 0.06 degrees, already below any camera's angular resolution.
pub const MAX_EXPONENT: f32 = 1e6;

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PowerCosine {
    pub nu: f32,
    pub nv: f32,
    pub angle_rad: f32,
}

impl PowerCosine {
    pub fn new(nu: f32, nv: f32, angle_rad: f32) -> Self {
        let clamp = |n: f32| {
            if n.is_nan() { 0.0 } else { n.clamp(0.0, MAX_EXPONENT) }
        };
        Self { nu: clamp(nu), nv: clamp(nv), angle_rad }
    }

    pub fn isotropic(n: f32) -> Self {
        Self::new(n, n, 0.0)
    }

    fn exponent(&self, h_lobe: Vec3) -> f32 {
        let (c2, s2) = crate::frame::cos2_sin2_phi(h_lobe);
        self.nu * c2 + self.nv * s2
    }

    fn beckmann_equivalent(&self) -> Beckmann {
        Beckmann::new((2.0 / (self.nu + 2.0)).sqrt(), (2.0 / (self.nv + 2.0)).sqrt(), self.angle_rad)
    }
}

impl Ndf for PowerCosine {
    fn d(&self, h: Vec3) -> f32 {
        if h.z <= 0.0 {
            return 0.0;
        }
        let hl = to_lobe_frame(h, self.angle_rad);
        let norm = ((self.nu + 2.0) * (self.nv + 2.0)).sqrt() / (2.0 * PI);
        norm * h.z.min(1.0).powf(self.exponent(hl))
    }

    fn projected_area(&self, v: Vec3) -> f32 {
        self.beckmann_equivalent().projected_area(v)
    }

    fn sample_h(&self, u: Vec2) -> Vec3 {
        // Ashikhmin-Shirley 2000, eq. 9, with exponents nu+1 and nv+1: the
        // azimuth in the first quadrant, then mirrored into the others.
        let (a, b) = (self.nu + 2.0, self.nv + 2.0);
        let quad = (u.x * 4.0).floor().min(3.0);
        let uq = u.x * 4.0 - quad;
        let mut phi = ((a / b).sqrt() * (FRAC_PI_2 * uq).tan()).atan();
        phi = match quad as u32 {
            0 => phi,
            1 => PI - phi,
            2 => PI + phi,
            _ => 2.0 * PI - phi,
        };
        let (sp, cp) = phi.sin_cos();
        let e = (self.nu + 1.0) * cp * cp + (self.nv + 1.0) * sp * sp;
        let cos_t = (1.0 - u.y).max(0.0).powf(1.0 / (e + 1.0));
        let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
        from_lobe_frame(Vec3::new(sin_t * cp, sin_t * sp, cos_t), self.angle_rad)
    }
}
