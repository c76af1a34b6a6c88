//! Ashikhmin and Shirley 2000, "An anisotropic Phong BRDF model":
//!
//! `f_s = sqrt((nu+1)(nv+1)) / (8 pi) (n.h)^(nu cos^2 phi_h + nv sin^2 phi_h)
//!        / ((h.k) max(cos_i, cos_o)) F(h.k)` with Schlick's `F` of `Rs`,
//! `f_d = 28 Rd / (23 pi) (1 - Rs) (1 - (1 - cos_i/2)^5) (1 - (1 - cos_o/2)^5)`.
//!
//! Sampling draws `h` with the paper's density
//! `sqrt((nu+1)(nv+1)) / (2 pi) cos^(nu cos^2 + nv sin^2)`, which is a
//! [`PowerCosine`] with exponents `nu - 1`, `nv - 1` (so both are kept >= 1).

use std::f32::consts::PI;

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::{Brdf, BrdfSample, both_above, mixture_pdf, sample_mixture, sanitize, specular_probability};
use crate::fresnel;
use crate::ndf::{Ndf, PowerCosine, to_lobe_frame};
use crate::{COS_FLOOR, Rgb, frame};

/// Largest exponent (a lobe of about 0.06 degrees).
pub const MAX_AS_EXPONENT: f32 = 1e6;

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct AshikhminShirley {
    pub rd: Rgb,
    pub rs: Rgb,
    pub nu: f32,
    pub nv: f32,
    pub angle_rad: f32,
}

impl AshikhminShirley {
    fn exponents(&self) -> (f32, f32) {
        let c = |n: f32| {
            if n.is_nan() { 1.0 } else { n.clamp(1.0, MAX_AS_EXPONENT) }
        };
        (c(self.nu), c(self.nv))
    }

    fn sampling_ndf(&self) -> PowerCosine {
        let (nu, nv) = self.exponents();
        PowerCosine::new(nu - 1.0, nv - 1.0, self.angle_rad)
    }

    /// Specular term per unit Fresnel (without `F`).
    pub fn specular_shape(&self, i: Vec3, o: Vec3) -> f32 {
        if !both_above(i, o) {
            return 0.0;
        }
        let Some(h) = frame::half_vector(i, o) else {
            return 0.0;
        };
        let (nu, nv) = self.exponents();
        let hl = to_lobe_frame(h, self.angle_rad);
        let (c2, s2) = frame::cos2_sin2_phi(hl);
        let e = nu * c2 + nv * s2;
        let hk = i.dot(h).max(COS_FLOOR);
        let v =
            ((nu + 1.0) * (nv + 1.0)).sqrt() / (8.0 * PI) * h.z.max(0.0).powf(e) / (hk * i.z.max(o.z).max(COS_FLOOR));
        if v.is_finite() { v } else { 0.0 }
    }
}

impl Brdf for AshikhminShirley {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        if !both_above(i, o) {
            return Vec3::ZERO;
        }
        let Some(h) = frame::half_vector(i, o) else {
            return Vec3::ZERO;
        };
        let hk = i.dot(h);
        let f = Vec3::new(
            fresnel::schlick(hk, self.rs.x),
            fresnel::schlick(hk, self.rs.y),
            fresnel::schlick(hk, self.rs.z),
        );
        let spec = f * self.specular_shape(i, o);
        let p5 = |c: f32| {
            let m = 1.0 - 0.5 * c;
            let m2 = m * m;
            1.0 - m2 * m2 * m
        };
        let diff = self.rd * (Vec3::ONE - self.rs) * (28.0 / (23.0 * PI)) * p5(i.z) * p5(o.z);
        sanitize(spec + diff)
    }

    fn sample(&self, o: Vec3, u: Vec2) -> Option<BrdfSample> {
        let ndf = self.sampling_ndf();
        sample_mixture(o, u, specular_probability(self.rd, self.rs), |u| ndf.sample_h(u), |h| ndf.pdf_h(h))
    }

    fn pdf(&self, o: Vec3, i: Vec3) -> f32 {
        let ndf = self.sampling_ndf();
        mixture_pdf(o, i, specular_probability(self.rd, self.rs), |h| ndf.pdf_h(h))
    }
}
