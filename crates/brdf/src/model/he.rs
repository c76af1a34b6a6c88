//! He, Torrance, Sillion and Greenberg 1991, "A comprehensive physical model
//! for light reflection": the directional-diffuse term of physical optics
//! plus a uniform diffuse term. The ideal specular spike is a Dirac delta in
//! direction and is not part of a BRDF that is evaluated pointwise; a camera
//! sees it only through the directional-diffuse term for any surface with
//! measurable roughness.
//!
//! Formulation followed (unpolarised, with the published errata):
//! - shadowing `S = S1(i) S1(o)`, `S1 = (1 - erfc(c)/2) / (Lambda + 1)`,
//!   `Lambda = exp(-c^2) / (2 sqrt(pi) c) - erfc(c)/2`, `c = tau cot(theta) / (2 sigma0)`
//!   (He eqs. 24-25 with the exponential that the errata of Holzschuch and
//!   Pacanowski restores);
//! - geometrical factor `G = (|v|^2 / v_z)^2` with `v = i + o` (eq. 76: for
//!   unpolarised light the polarisation-basis products reduce to this,
//!   because `(s.k)^2 + (p.k)^2 = 1 - (k_i.k_r)^2` for any orthonormal `s, p` normal to `k`);
//! - effective roughness `sigma = sigma0 / sqrt(1 + z0^2/sigma0^2)` with `z0`
//!   from eq. 80 by Newton's method;
//! - `g = (2 pi sigma (cos_i + cos_o) / lambda)^2` (eq. 79);
//! - `D = pi^2 tau^2 / (4 lambda^2) sum_m g^m e^-g / (m! m) exp(-v_xy^2 tau^2 / (4 m))`
//!   (eq. 78) with `v_xy` in wave-number units `2 pi / lambda |i_xy + o_xy|`,
//!   as in Westin's reference implementation; for `g > ROUGH_LIMIT_G` the
//!   sum is replaced by its rough-surface limit (see [`rough_limit`]);
//! - `rho_dd = ks F S G D / (pi cos_i cos_o)` with exact (conductor or
//!   dielectric) Fresnel at `cos = i . h`.
//!
//! Lengths are in micrometres. `ks` is 1 for the physical model; the fitter
//! may scale it.

use std::f32::consts::FRAC_1_PI;
use std::f64::consts::PI as PI64;
use std::sync::OnceLock;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::{Brdf, both_above, sanitize};
use crate::{COS_FLOOR, Rgb, fresnel};

/// The sum `E[exp(-E/m) / m]` over `m ~ Poisson(g)` (eq. 78 without its
/// constant) for large `g`: the rough-surface limit `f(g) = exp(-E/g) / g`
/// (Beckmann and Spizzichino 1963, sec. 5.3) with the second-order term of
/// its expansion about the mean, `f''(g) Var(m) / 2` with `Var(m) = g`.
fn rough_limit(g: f64, e: f64) -> f64 {
    let f = (-e / g).exp() / g;
    let d1 = e / (g * g) - 1.0 / g;
    let d2 = 1.0 / (g * g) - 2.0 * e / (g * g * g);
    f * (1.0 + 0.5 * g * (d1 * d1 + d2))
}

/// Above this `g` the Taylor series of eq. 78 needs hundreds of terms and its
/// rough-surface limit with its second-order correction is within 0.2% of it (checked in the tests at the
/// threshold), so the limit is used.
pub const ROUGH_LIMIT_G: f64 = 200.0;

/// The series' logarithms of its term `m`: `ln(m!)` and `ln(m)`.
fn series_log(m: usize) -> (f64, f64) {
    let mf = m as f64;
    (libm::lgamma(mf + 1.0), mf.ln())
}

/// The most terms the series sums at `g` (it stops earlier once they no
/// longer count).
fn series_terms(g: f64) -> usize {
    (g + 12.0 * g.sqrt() + 30.0).ceil() as usize
}

/// [`series_log`] for every term the series takes below
/// [`ROUGH_LIMIT_G`] ([`series_terms`], at most 400), found once: the same
/// values, a table read instead of a log-gamma and a logarithm per term of
/// every evaluation.
fn series_logs() -> &'static [(f64, f64)] {
    static LOGS: OnceLock<Vec<(f64, f64)>> = OnceLock::new();
    LOGS.get_or_init(|| (0..=series_terms(ROUGH_LIMIT_G)).map(series_log).collect())
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct He {
    /// Uniform diffuse albedo `a(lambda)`.
    pub kd: Rgb,
    /// Scale of the directional-diffuse term (1 for the physical model).
    pub ks: Rgb,
    /// RMS surface height `sigma0`, micrometres.
    pub sigma0_um: f32,
    /// Autocorrelation length `tau`, micrometres.
    pub tau_um: f32,
    /// Wavelength, micrometres.
    pub wavelength_um: f32,
    /// Real part of the index of refraction.
    pub eta: f32,
    /// Extinction coefficient (0 for a dielectric).
    pub k: f32,
}

impl He {
    /// A plastic-like surface: `sigma0 = 0.18 um`, `tau = 3 um`, `lambda = 0.55 um`, `eta = 1.5`.
    pub fn plastic(kd: Rgb) -> Self {
        Self { kd, ks: Vec3::ONE, sigma0_um: 0.18, tau_um: 3.0, wavelength_um: 0.55, eta: 1.5, k: 0.0 }
    }

    fn params(&self) -> (f64, f64, f64) {
        let pos = |x: f32, lo: f32| {
            if x.is_finite() { x.max(lo) as f64 } else { lo as f64 }
        };
        (pos(self.sigma0_um, 0.0), pos(self.tau_um, 1e-6), pos(self.wavelength_um, 1e-3))
    }

    /// One-directional shadowing `S1` (eqs. 24-25 with errata).
    fn s1(&self, v: Vec3) -> f64 {
        let (sigma0, tau, _) = self.params();
        let sin = ((v.x * v.x + v.y * v.y) as f64).sqrt();
        if sin <= 0.0 || sigma0 <= 0.0 {
            return 1.0;
        }
        let c = tau * (v.z as f64) / (sin * 2.0 * sigma0);
        if c <= 0.0 {
            return 0.0;
        }
        let erfc_half = 0.5 * libm::erfc(c);
        let lambda = (-c * c).exp() / (2.0 * PI64.sqrt() * c) - erfc_half;
        ((1.0 - erfc_half) / (lambda + 1.0)).clamp(0.0, 1.0)
    }

    /// Effective roughness (eq. 80-83) by Newton's method on
    /// `x exp(x^2/2) = (K_i + K_o) / sqrt(8 pi)`, `x = z0 / sigma0`.
    fn sigma_eff(&self, i: Vec3, o: Vec3) -> f64 {
        let (sigma0, tau, _) = self.params();
        if sigma0 <= 0.0 {
            return 0.0;
        }
        let k = |v: Vec3| {
            let tan = ((v.x * v.x + v.y * v.y) as f64).sqrt() / (v.z as f64).max(COS_FLOOR as f64);
            if tan <= 0.0 { 0.0 } else { tan * libm::erfc(tau / (2.0 * sigma0 * tan)) }
        };
        let f0 = (k(i) + k(o)) / (8.0 * PI64).sqrt();
        let mut x = if f0 <= 1.0 { f0 } else { (2.0 * f0.ln()).sqrt() };
        for _ in 0..8 {
            let e = (0.5 * x * x).exp();
            let grad = (1.0 + x * x) * e;
            x -= (x * e - f0) / grad;
            x = x.max(0.0);
        }
        sigma0 / (1.0 + x * x).sqrt()
    }

    /// The sum of eq. 78 (without its constant factor).
    fn series(g: f64, e_base: f64) -> f64 {
        if g <= 1e-12 {
            return 0.0;
        }
        if g > ROUGH_LIMIT_G {
            return rough_limit(g, e_base);
        }
        let ln_g = g.ln();
        let m_max = series_terms(g);
        let logs = series_logs();
        let mut sum = 0.0;
        for m in 1..=m_max {
            let mf = m as f64;
            let (ln_factorial, ln_m) = logs.get(m).copied().unwrap_or_else(|| series_log(m));
            let ln_term = -g + mf * ln_g - ln_factorial - ln_m - e_base / mf;
            let term = ln_term.exp();
            sum += term;
            if mf > g && term < 1e-14 * sum {
                break;
            }
        }
        sum
    }

    /// The directional-diffuse term per unit `ks` (including Fresnel).
    pub fn directional_diffuse(&self, i: Vec3, o: Vec3) -> f32 {
        if !both_above(i, o) {
            return 0.0;
        }
        let (_, tau, lambda) = self.params();
        let (ci, co) = (i.z as f64, o.z as f64);
        let v = i + o;
        let vz = v.z as f64;
        let v2 = v.length_squared() as f64;
        let geometry = (v2 / vz).powi(2);
        let sig = self.sigma_eff(i, o);
        let g = (2.0 * PI64 * sig * (ci + co) / lambda).powi(2);
        let vxy2 = (v.x * v.x + v.y * v.y) as f64;
        let e_base = PI64 * PI64 * tau * tau * vxy2 / (lambda * lambda);
        let d = PI64 * PI64 * tau * tau / (4.0 * lambda * lambda) * Self::series(g, e_base);
        let cos_half = ((1.0 + i.dot(o)) * 0.5).max(0.0).sqrt();
        let f = fresnel::conductor(cos_half, self.eta.max(1e-3), self.k.max(0.0)) as f64;
        // S1 / cos stays bounded at grazing angles (S1 ~ cos there).
        let s_over = self.s1(i) / ci.max(COS_FLOOR as f64) * self.s1(o) / co.max(COS_FLOOR as f64);
        let r = f * geometry * d * s_over / PI64;
        if r.is_finite() { r as f32 } else { 0.0 }
    }
}

impl Brdf for He {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        if !both_above(i, o) {
            return Vec3::ZERO;
        }
        sanitize(self.kd * FRAC_1_PI + self.ks * self.directional_diffuse(i, o))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rough_limit_is_close_to_the_series_at_the_threshold() {
        for e_base in [0.0, 10.0, 100.0, 1000.0] {
            let g = ROUGH_LIMIT_G;
            let series = {
                let ln_g = g.ln();
                (1..2000)
                    .map(|m| {
                        let mf = m as f64;
                        (-g + mf * ln_g - libm::lgamma(mf + 1.0) - mf.ln() - e_base / mf).exp()
                    })
                    .sum::<f64>()
            };
            let limit = rough_limit(g, e_base);
            assert!((series - limit).abs() / series < 0.002, "e {e_base}: {series} vs {limit}");
        }
    }

    /// The table holds every term the series can take below the rough
    /// limit, each the logarithms found directly.
    #[test]
    fn the_series_logarithms_are_tabled_for_every_term_below_the_rough_limit() {
        let logs = series_logs();
        for g in [1e-6, 0.5, 7.0, 60.0, ROUGH_LIMIT_G] {
            assert!(series_terms(g) < logs.len(), "g {g}");
        }
        for (m, &l) in logs.iter().enumerate() {
            assert_eq!(l, series_log(m), "term {m}");
        }
        assert_eq!(logs[1], (0.0, 0.0));
        assert!((logs[10].0 - 3_628_800f64.ln()).abs() < 1e-12);
    }

    #[test]
    fn smooth_normal_view_has_unit_shadowing() {
        let m = He::plastic(Vec3::splat(0.5));
        assert!((m.s1(Vec3::Z) - 1.0).abs() < 1e-12);
    }
}
