//! Phong's model (1975) as the talk writes it, Lewis's energy-normalised
//! "modified Phong" (1994), and normalised Blinn-Phong (Blinn 1977).

use std::f32::consts::{FRAC_1_PI, PI, TAU};

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::{Brdf, BrdfSample, both_above, mixture_pdf, sample_mixture, sanitize, specular_probability};
use crate::Rgb;
use crate::frame;
use crate::ndf::{Ndf, PowerCosine};

/// `cos(theta_i)` floor for [`PhongOriginal`]'s `1 / (n . i)`: the model
/// diverges at grazing incidence. With 1e-3 (0.06 degrees from the horizon)
/// its value is bounded by `1000 ks`, and the radiance it predicts,
/// `f cos(theta_i)`, is unaffected for any direction more than 0.06 degrees
/// above the horizon.
pub const PHONG_COS_FLOOR: f32 = 1e-3;

/// Largest Phong exponent: `cos^1e6` is a lobe of about 0.06 degrees.
pub const MAX_PHONG_EXPONENT: f32 = 1e6;

fn clamp_exponent(n: f32) -> f32 {
    if n.is_nan() { 0.0 } else { n.clamp(0.0, MAX_PHONG_EXPONENT) }
}

/// Phong 1975 as in the talk: `f = ks (o . r)^n / (n . i)`, `r` the mirror of
/// `i`. Neither reciprocal nor energy conserving; kept for comparison.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PhongOriginal {
    pub ks: Rgb,
    pub exponent: f32,
}

impl Brdf for PhongOriginal {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        if !both_above(i, o) {
            return Vec3::ZERO;
        }
        let c = o.dot(frame::reflect_about_normal(i)).max(0.0);
        let lobe = c.powf(clamp_exponent(self.exponent));
        sanitize(self.ks * lobe / i.z.max(PHONG_COS_FLOOR))
    }

    fn sample(&self, o: Vec3, u: Vec2) -> Option<BrdfSample> {
        sample_phong_lobe(o, u, clamp_exponent(self.exponent))
    }

    fn pdf(&self, o: Vec3, i: Vec3) -> f32 {
        phong_lobe_pdf(o, i, clamp_exponent(self.exponent))
    }
}

/// Modified Phong (Lewis 1994): `f = kd / pi + ks (n + 2) / (2 pi) (o . r)^n`.
/// Reciprocal, and its albedo is at most `kd + ks`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct PhongModified {
    pub kd: Rgb,
    pub ks: Rgb,
    pub exponent: f32,
}

impl Brdf for PhongModified {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        if !both_above(i, o) {
            return Vec3::ZERO;
        }
        let n = clamp_exponent(self.exponent);
        let c = o.dot(frame::reflect_about_normal(i)).max(0.0);
        sanitize(self.kd * FRAC_1_PI + self.ks * (n + 2.0) / TAU * c.powf(n))
    }

    fn sample(&self, o: Vec3, u: Vec2) -> Option<BrdfSample> {
        let n = clamp_exponent(self.exponent);
        let p = specular_probability(self.kd, self.ks);
        if o.z <= 0.0 {
            return None;
        }
        let i = if u.x < p {
            sample_phong_lobe(o, Vec2::new(u.x / p, u.y), n)?.i
        } else {
            frame::sample_cosine_hemisphere(Vec2::new((u.x - p) / (1.0 - p), u.y))
        };
        let pdf = self.pdf(o, i);
        (pdf > 0.0).then_some(BrdfSample { i, pdf })
    }

    fn pdf(&self, o: Vec3, i: Vec3) -> f32 {
        if o.z <= 0.0 || i.z <= 0.0 {
            return 0.0;
        }
        let p = specular_probability(self.kd, self.ks);
        p * phong_lobe_pdf(o, i, clamp_exponent(self.exponent)) + (1.0 - p) * frame::cosine_hemisphere_pdf(i)
    }
}

/// Normalised Blinn-Phong: `f = kd / pi + ks (n + 8) / (8 pi) (n . h)^n`
/// (the common approximate normalisation; see the model table for where it
/// exceeds unit albedo).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BlinnPhong {
    pub kd: Rgb,
    pub ks: Rgb,
    pub exponent: f32,
}

impl Brdf for BlinnPhong {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        if !both_above(i, o) {
            return Vec3::ZERO;
        }
        let n = clamp_exponent(self.exponent);
        let spec = match frame::half_vector(i, o) {
            Some(h) => (n + 8.0) / (8.0 * PI) * h.z.max(0.0).powf(n),
            None => 0.0,
        };
        sanitize(self.kd * FRAC_1_PI + self.ks * spec)
    }

    fn sample(&self, o: Vec3, u: Vec2) -> Option<BrdfSample> {
        let ndf = PowerCosine::isotropic(clamp_exponent(self.exponent));
        let p = specular_probability(self.kd, self.ks);
        sample_mixture(o, u, p, |u| ndf.sample_h(u), |h| ndf.pdf_h(h))
    }

    fn pdf(&self, o: Vec3, i: Vec3) -> f32 {
        let ndf = PowerCosine::isotropic(clamp_exponent(self.exponent));
        mixture_pdf(o, i, specular_probability(self.kd, self.ks), |h| ndf.pdf_h(h))
    }
}

/// Draw `i` from the density `(n + 1) / (2 pi) (r(o) . i)^n` around the mirror
/// direction of `o` (the Phong lobe is symmetric: `o . r(i) = r(o) . i`).
fn sample_phong_lobe(o: Vec3, u: Vec2, n: f32) -> Option<BrdfSample> {
    if o.z <= 0.0 {
        return None;
    }
    let axis = frame::reflect_about_normal(o);
    let cos_t = u.x.max(0.0).powf(1.0 / (n + 1.0));
    let sin_t = (1.0 - cos_t * cos_t).max(0.0).sqrt();
    let (s, c) = (TAU * u.y).sin_cos();
    let (t, b) = axis.any_orthonormal_pair();
    let i = (t * (sin_t * c) + b * (sin_t * s) + axis * cos_t).normalize();
    if i.z <= 0.0 {
        return None;
    }
    let pdf = phong_lobe_pdf(o, i, n);
    (pdf > 0.0).then_some(BrdfSample { i, pdf })
}

fn phong_lobe_pdf(o: Vec3, i: Vec3, n: f32) -> f32 {
    if o.z <= 0.0 || i.z <= 0.0 {
        return 0.0;
    }
    let c = frame::reflect_about_normal(o).dot(i).max(0.0);
    (n + 1.0) / TAU * c.powf(n)
}
