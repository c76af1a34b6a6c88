//! The microfacet model the talk fits, generic over the NDF:
//!
//! `f = kd / pi + ks D(h) S(i) S(o) F(i . h) / (4 cos_i cos_o)`
//!
//! with Smith's separable masking `S(v) = cos(theta_v) / sigma(v)`. Written as
//! `ks D(h) F / (4 sigma(i) sigma(o))`, which has no division by a cosine and
//! stays finite at grazing angles. `ks` is the specular albedo at normal
//! incidence when `F(1) = 1` (as with [`Fresnel::DielectricRelative`]).
//! With a [`crate::ndf::Ggx`] NDF this is anisotropic GGX with Smith masking.
//!
//! [`Fresnel::DielectricRelative`]: crate::fresnel::Fresnel::DielectricRelative

use std::f32::consts::FRAC_1_PI;

use glam::{Vec2, Vec3};

use super::{Brdf, BrdfSample, both_above, mixture_pdf, sample_mixture, sanitize, specular_probability};
use crate::fresnel::Fresnel;
use crate::ndf::Ndf;
use crate::{Rgb, frame};

#[derive(Clone, Debug)]
pub struct Microfacet<N> {
    pub kd: Rgb,
    pub ks: Rgb,
    pub ndf: N,
    pub fresnel: Fresnel,
}

impl<N: Ndf> Microfacet<N> {
    /// The specular term per unit `ks` (including `F`).
    pub fn specular(&self, i: Vec3, o: Vec3) -> Rgb {
        if !both_above(i, o) {
            return Vec3::ZERO;
        }
        let Some(h) = frame::half_vector(i, o) else {
            return Vec3::ZERO;
        };
        let d = self.ndf.d(h);
        if d <= 0.0 {
            return Vec3::ZERO;
        }
        let denom = 4.0 * self.ndf.projected_area(i) * self.ndf.projected_area(o);
        self.fresnel.eval(i.dot(h)) * (d / denom)
    }
}

impl<N: Ndf> Brdf for Microfacet<N> {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        if !both_above(i, o) {
            return Vec3::ZERO;
        }
        sanitize(self.kd * FRAC_1_PI + self.ks * self.specular(i, o))
    }

    fn sample(&self, o: Vec3, u: Vec2) -> Option<BrdfSample> {
        let p = specular_probability(self.kd, self.ks);
        sample_mixture(o, u, p, |u| self.ndf.sample_h(u), |h| self.ndf.pdf_h(h))
    }

    fn pdf(&self, o: Vec3, i: Vec3) -> f32 {
        mixture_pdf(o, i, specular_probability(self.kd, self.ks), |h| self.ndf.pdf_h(h))
    }
}
