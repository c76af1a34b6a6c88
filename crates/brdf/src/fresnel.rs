//! Fresnel reflectance: exact dielectric (unpolarised), Schlick's
//! approximation, and exact conductor with a complex index of refraction.
//!
//! Every function takes `cos_d`, the cosine between the incident direction and
//! the microfacet normal (`i . h`), clamped to `[0, 1]`; the index is the ratio
//! of the material's index to the outside medium's.

use glam::Vec3;
use serde::{Deserialize, Serialize};

use crate::Rgb;

/// Exact unpolarised Fresnel reflectance of a dielectric interface
/// (Born and Wolf, eq. 1.5.20-21, averaged over both polarisations).
/// Handles `eta < 1` (light leaving a denser medium) with total internal
/// reflection.
pub fn dielectric(cos_d: f32, eta: f32) -> f32 {
    let cos_i = cos_d.clamp(0.0, 1.0);
    let sin2_t = (1.0 - cos_i * cos_i) / (eta * eta);
    if sin2_t >= 1.0 {
        return 1.0;
    }
    let cos_t = (1.0 - sin2_t).sqrt();
    let rs = (cos_i - eta * cos_t) / (cos_i + eta * cos_t);
    let rp = (eta * cos_i - cos_t) / (eta * cos_i + cos_t);
    (0.5 * (rs * rs + rp * rp)).clamp(0.0, 1.0)
}

/// Reflectance at normal incidence of a dielectric, `((eta-1)/(eta+1))^2`.
pub fn dielectric_f0(eta: f32) -> f32 {
    let r = (eta - 1.0) / (eta + 1.0);
    r * r
}

/// Schlick's approximation, `F0 + (1 - F0)(1 - cos)^5` (Schlick 1994).
/// Its absolute error against [`dielectric`] is below 0.07 for eta in
/// [1.3, 1.8], the largest near grazing incidence for small eta (tested).
pub fn schlick(cos_d: f32, f0: f32) -> f32 {
    let m = (1.0 - cos_d.clamp(0.0, 1.0)).clamp(0.0, 1.0);
    let m2 = m * m;
    f0 + (1.0 - f0) * m2 * m2 * m
}

/// Exact unpolarised reflectance of a conductor with complex index
/// `eta + i k` (the same derivation as the dielectric case with complex
/// arithmetic; see pbrt-v4 section 9.3.6 for the form used).
pub fn conductor(cos_d: f32, eta: f32, k: f32) -> f32 {
    let cos_i = cos_d.clamp(0.0, 1.0);
    let n = Complex::new(eta, k);
    let sin2_i = 1.0 - cos_i * cos_i;
    let sin2_t = Complex::real(sin2_i).div(n.mul(n));
    let cos_t = Complex::real(1.0).sub(sin2_t).sqrt();
    let ci = Complex::real(cos_i);
    let r_parl = n.mul(ci).sub(cos_t).div(n.mul(ci).add(cos_t));
    let r_perp = ci.sub(n.mul(cos_t)).div(ci.add(n.mul(cos_t)));
    let f = 0.5 * (r_parl.norm2() + r_perp.norm2());
    if f.is_finite() { f.clamp(0.0, 1.0) } else { 1.0 }
}

/// A Fresnel term as stored in materials and fitted models.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Fresnel {
    /// `F = 1` everywhere (the talk's first assumption).
    One,
    /// Exact dielectric reflectance with index `eta`.
    Dielectric { eta: f32 },
    /// Dielectric reflectance divided by its value at normal incidence, so
    /// `F(1) = 1` and the specular scale `k_s` carries the absolute level.
    /// This is what the fitter stores: `k_s` and the shape of `F` then do not
    /// trade against each other.
    DielectricRelative { eta: f32 },
    /// Schlick's approximation with a per-channel `F0`.
    Schlick { f0: Rgb },
    /// Exact conductor with per-channel complex index.
    Conductor { eta: Rgb, k: Rgb },
}

impl Fresnel {
    /// Reflectance per channel for `cos_d = i . h`.
    pub fn eval(&self, cos_d: f32) -> Rgb {
        match *self {
            Fresnel::One => Vec3::ONE,
            Fresnel::Dielectric { eta } => Vec3::splat(dielectric(cos_d, eta)),
            Fresnel::DielectricRelative { eta } => {
                let f0 = dielectric_f0(eta).max(RELATIVE_F0_FLOOR);
                Vec3::splat(dielectric(cos_d, eta) / f0)
            }
            Fresnel::Schlick { f0 } => Vec3::new(schlick(cos_d, f0.x), schlick(cos_d, f0.y), schlick(cos_d, f0.z)),
            Fresnel::Conductor { eta, k } => {
                Vec3::new(conductor(cos_d, eta.x, k.x), conductor(cos_d, eta.y, k.y), conductor(cos_d, eta.z, k.z))
            }
        }
    }

    /// Reflectance of channel `c` (0, 1 or 2) alone: `eval(cos_d)[c]`, to the
    /// last bit, without computing the other channels.
    pub fn channel(&self, cos_d: f32, c: usize) -> f32 {
        let pick = |v: Rgb| v[c.min(2)];
        match *self {
            Fresnel::Schlick { f0 } => schlick(cos_d, pick(f0)),
            Fresnel::Conductor { eta, k } => conductor(cos_d, pick(eta), pick(k)),
            Fresnel::One | Fresnel::Dielectric { .. } | Fresnel::DielectricRelative { .. } => pick(self.eval(cos_d)),
        }
    }

    /// The largest value the term can take, used to bound albedo in tests.
    pub fn max_value(&self) -> f32 {
        match *self {
            Fresnel::DielectricRelative { eta } => 1.0 / dielectric_f0(eta).max(RELATIVE_F0_FLOOR),
            _ => 1.0,
        }
    }
}

/// `eta` within 1e-3 of 1 has `F0 < 2.5e-7`; dividing by it would amplify
/// rounding noise into a huge grazing term. The floor keeps
/// [`Fresnel::DielectricRelative`] finite for any `eta` the fitter may try.
pub const RELATIVE_F0_FLOOR: f32 = 1e-6;

/// Minimal complex arithmetic for the conductor formula.
#[derive(Clone, Copy, Debug)]
struct Complex {
    re: f32,
    im: f32,
}

impl Complex {
    fn new(re: f32, im: f32) -> Self {
        Self { re, im }
    }
    fn real(re: f32) -> Self {
        Self { re, im: 0.0 }
    }
    fn add(self, o: Self) -> Self {
        Self::new(self.re + o.re, self.im + o.im)
    }
    fn sub(self, o: Self) -> Self {
        Self::new(self.re - o.re, self.im - o.im)
    }
    fn mul(self, o: Self) -> Self {
        Self::new(self.re * o.re - self.im * o.im, self.re * o.im + self.im * o.re)
    }
    fn norm2(self) -> f32 {
        self.re * self.re + self.im * self.im
    }
    fn div(self, o: Self) -> Self {
        let d = o.norm2();
        Self::new((self.re * o.re + self.im * o.im) / d, (self.im * o.re - self.re * o.im) / d)
    }
    /// Principal square root.
    fn sqrt(self) -> Self {
        let n = self.norm2().sqrt();
        if n == 0.0 {
            return Self::real(0.0);
        }
        let t1 = (0.5 * (n + self.re.abs())).sqrt();
        let t2 = 0.5 * self.im / t1;
        if self.re >= 0.0 { Self::new(t1, t2) } else { Self::new(t2.abs(), t1.copysign(self.im)) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dielectric_matches_known_values() {
        // Glass, eta = 1.5: F0 = 0.04; Brewster angle atan(1.5) has rp = 0,
        // so F = rs^2 / 2 there.
        assert!((dielectric(1.0, 1.5) - 0.04).abs() < 1e-6);
        assert!((dielectric(0.0, 1.5) - 1.0).abs() < 1e-6);
        let brewster = 1.5f32.atan();
        let f = dielectric(brewster.cos(), 1.5);
        assert!((f - 0.0739).abs() < 5e-4, "{f}");
    }

    #[test]
    fn total_internal_reflection() {
        assert_eq!(dielectric(0.3, 1.0 / 1.5), 1.0);
    }

    #[test]
    fn schlick_is_close_to_exact_for_common_dielectrics() {
        for eta in [1.3f32, 1.5, 1.8] {
            let f0 = dielectric_f0(eta);
            for k in 0..=100 {
                let c = k as f32 / 100.0;
                let e = (schlick(c, f0) - dielectric(c, eta)).abs();
                assert!(e < 0.07, "eta {eta} cos {c} err {e}");
            }
        }
    }

    #[test]
    fn conductor_with_zero_k_is_the_dielectric() {
        for k in 0..=20 {
            let c = k as f32 / 20.0;
            assert!((conductor(c, 1.5, 0.0) - dielectric(c, 1.5)).abs() < 1e-5);
        }
    }

    #[test]
    fn conductor_gold_at_normal_incidence() {
        // Gold at 600 nm: n = 0.25, k = 2.98 -> R = ((n-1)^2 + k^2)/((n+1)^2 + k^2).
        let (n, k) = (0.25f32, 2.98f32);
        let expect = ((n - 1.0).powi(2) + k * k) / ((n + 1.0).powi(2) + k * k);
        assert!((conductor(1.0, n, k) - expect).abs() < 1e-5);
        assert!((conductor(0.0, n, k) - 1.0).abs() < 1e-4);
    }

    #[test]
    fn relative_dielectric_is_one_at_normal_incidence() {
        let f = Fresnel::DielectricRelative { eta: 1.5 };
        assert!((f.eval(1.0).x - 1.0).abs() < 1e-5);
        assert!(f.eval(0.0).x > 20.0);
    }
}
