//! Cook and Torrance 1982: Beckmann NDF, the V-groove shadowing of Torrance
//! and Sparrow (1967), exact dielectric Fresnel, and the `4 cos_i cos_o`
//! denominator (Cook and Torrance printed `pi`; the factor 4 is the
//! correction derived by Walter et al. 2007, section 4, for an NDF normalised
//! as here).
//!
//! `f = kd / pi + ks D(h) G F(i . h) / (4 cos_i cos_o)`,
//! `G = min(1, 2 (n.h)(n.o) / (o.h), 2 (n.h)(n.i) / (o.h))`.

use std::f32::consts::FRAC_1_PI;

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::{Brdf, BrdfSample, both_above, mixture_pdf, sample_mixture, sanitize, specular_probability};
use crate::fresnel;
use crate::ndf::{Beckmann, Ndf};
use crate::{COS_FLOOR, Rgb, frame};

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CookTorrance {
    pub kd: Rgb,
    pub ks: Rgb,
    /// Beckmann roughness `m` (RMS slope times sqrt 2, same as alpha).
    pub m: f32,
    /// Relative index of refraction of the dielectric.
    pub eta: f32,
}

impl CookTorrance {
    /// The specular term per unit `ks`.
    pub fn lobe(&self, i: Vec3, o: Vec3) -> f32 {
        if !both_above(i, o) {
            return 0.0;
        }
        let Some(h) = frame::half_vector(i, o) else {
            return 0.0;
        };
        let oh = o.dot(h).max(COS_FLOOR);
        let (ci, co) = (i.z.max(COS_FLOOR), o.z.max(COS_FLOOR));
        // G / (4 ci co) without dividing by a product of two small cosines.
        let g_over = (1.0 / (4.0 * ci * co)).min(h.z / (2.0 * oh * ci)).min(h.z / (2.0 * oh * co));
        let d = Beckmann::isotropic(self.m).d(h);
        let f = fresnel::dielectric(i.dot(h), self.eta.max(1.0 + 1e-4));
        let v = d * f * g_over;
        if v.is_finite() { v } else { 0.0 }
    }
}

impl Brdf for CookTorrance {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        if !both_above(i, o) {
            return Vec3::ZERO;
        }
        sanitize(self.kd * FRAC_1_PI + self.ks * self.lobe(i, o))
    }

    fn sample(&self, o: Vec3, u: Vec2) -> Option<BrdfSample> {
        let ndf = Beckmann::isotropic(self.m);
        sample_mixture(o, u, specular_probability(self.kd, self.ks), |u| ndf.sample_h(u), |h| ndf.pdf_h(h))
    }

    fn pdf(&self, o: Vec3, i: Vec3) -> f32 {
        let ndf = Beckmann::isotropic(self.m);
        mixture_pdf(o, i, specular_probability(self.kd, self.ks), |h| ndf.pdf_h(h))
    }
}
