//! Anisotropic Beckmann distribution (Beckmann and Spizzichino 1963), the
//! elliptical Gaussian of Ward (1992) written as an NDF.
//!
//! `D(h) = exp(-(hx^2/ax^2 + hy^2/ay^2) / hz^2) / (pi ax ay hz^4)`
//! in the lobe frame. Smith's `Lambda` (Walter et al. 2007, eq. 27) gives the
//! projected area in closed form:
//! `sigma(v) = vz (1 + erf(a)) / 2 + r exp(-a^2) / (2 sqrt(pi))`, with
//! `r = sqrt(vx^2 ax^2 + vy^2 ay^2)` and `a = vz / r`.
//! This form has no division by `vz` and stays finite on the horizon.

use std::f32::consts::{PI, TAU};

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::{Ndf, clamp_alpha, from_lobe_frame, normal_from_slopes};

/// Anisotropic Beckmann NDF with roughness `alpha_x`, `alpha_y` (RMS slope
/// times sqrt 2) along a lobe frame rotated by `angle_rad` about the normal.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Beckmann {
    pub alpha_x: f32,
    pub alpha_y: f32,
    pub angle_rad: f32,
}

impl Beckmann {
    pub fn new(alpha_x: f32, alpha_y: f32, angle_rad: f32) -> Self {
        Self { alpha_x: clamp_alpha(alpha_x), alpha_y: clamp_alpha(alpha_y), angle_rad }
    }

    pub fn isotropic(alpha: f32) -> Self {
        Self::new(alpha, alpha, 0.0)
    }
}

impl Ndf for Beckmann {
    fn d(&self, h: Vec3) -> f32 {
        if h.z <= 0.0 {
            return 0.0;
        }
        BeckmannLobe::new(self).d(h, h.z.ln())
    }

    fn projected_area(&self, v: Vec3) -> f32 {
        BeckmannLobe::new(self).projected_area(v)
    }

    fn beckmann_lobes(&self) -> Option<Vec<(f32, Beckmann)>> {
        Some(vec![(1.0, *self)])
    }

    fn sample_h(&self, u: Vec2) -> Vec3 {
        // Beckmann slopes are Gaussian: P22 = exp(-(sx^2/ax^2 + sy^2/ay^2)) / (pi ax ay),
        // and D(h) cos(h) dw = P22 dslope, so drawing slopes draws h with pdf D cos.
        let r = (-(1.0 - u.x).max(f32::MIN_POSITIVE).ln()).sqrt();
        let (s, c) = (TAU * u.y).sin_cos();
        let h = normal_from_slopes(self.alpha_x * r * c, self.alpha_y * r * s);
        from_lobe_frame(h, self.angle_rad)
    }
}

/// A [`Beckmann`] lobe prepared for evaluation at many directions: its
/// rotation's sine and cosine and its normalisation computed once. It is
/// the one implementation of the distribution (`Beckmann`'s own methods
/// prepare one per call), so a renderer that keeps one per lobe gets the
/// same values to the last bit, only sooner.
#[derive(Clone, Copy, Debug)]
pub struct BeckmannLobe {
    alpha_x: f32,
    alpha_y: f32,
    alpha_x2: f32,
    alpha_y2: f32,
    /// Sine and cosine of the rotation into the lobe frame; `None` for an
    /// unrotated lobe.
    to_lobe: Option<(f32, f32)>,
    /// `ln(pi ax ay)`.
    ln_norm: f32,
}

impl BeckmannLobe {
    pub fn new(b: &Beckmann) -> Self {
        let (ax, ay) = (b.alpha_x, b.alpha_y);
        Self {
            alpha_x: ax,
            alpha_y: ay,
            alpha_x2: ax * ax,
            alpha_y2: ay * ay,
            to_lobe: (b.angle_rad != 0.0).then(|| (-b.angle_rad).sin_cos()),
            ln_norm: (PI * ax * ay).ln(),
        }
    }

    /// Its roughnesses `(alpha_x, alpha_y)`.
    pub fn alphas(&self) -> (f32, f32) {
        (self.alpha_x, self.alpha_y)
    }

    /// Sine and cosine of the rotation into the lobe frame.
    pub fn rotation(&self) -> (f32, f32) {
        self.to_lobe.unwrap_or((0.0, 1.0))
    }

    /// `ln(pi ax ay)`, the logarithm of its normalisation.
    pub fn ln_norm(&self) -> f32 {
        self.ln_norm
    }

    #[inline]
    fn in_lobe_frame(&self, v: Vec3) -> Vec3 {
        match self.to_lobe {
            None => v,
            Some((s, c)) => Vec3::new(c * v.x - s * v.y, s * v.x + c * v.y, v.z),
        }
    }

    /// `D(h)` for `h.z > 0`, given `ln_hz = ln(h.z)` (shared by every lobe
    /// of a mixture evaluated at the same `h`).
    #[inline]
    pub fn d(&self, h: Vec3, ln_hz: f32) -> f32 {
        let h = self.in_lobe_frame(h);
        let e = (h.x * h.x / self.alpha_x2 + h.y * h.y / self.alpha_y2) / (h.z * h.z);
        // Log domain: hz^4 underflows f32 for hz < 1e-10 while exp(-e) is
        // already zero there; evaluating the logarithm keeps 0/0 out.
        let ln_d = -e - 4.0 * ln_hz - self.ln_norm;
        let d = ln_d.exp();
        if d.is_finite() { d } else { 0.0 }
    }

    /// The projected area `sigma(v)` (module doc).
    #[inline]
    pub fn projected_area(&self, v: Vec3) -> f32 {
        if v.z <= 0.0 {
            return projected_area_floor(v);
        }
        let v = self.in_lobe_frame(v);
        let r = ((v.x * self.alpha_x).powi(2) + (v.y * self.alpha_y).powi(2)).sqrt();
        if r <= 0.0 {
            return v.z;
        }
        let a = v.z / r;
        if a >= SIGMA_IS_VZ_FROM {
            return v.z;
        }
        let sigma = 0.5 * v.z * (1.0 + libm::erff(a)) + r * (-a * a).exp() / (2.0 * PI.sqrt());
        sigma.max(v.z)
    }
}

/// From this `a = vz / r` on, `sigma(v)` is `vz` in `f32`, to the last bit:
/// `erfc(4) = 1.5e-8` is below half an ulp of 1 (`2^-25 = 3.0e-8`), so
/// `1 + erf(a)` rounds to 2, and the second term is at most
/// `vz exp(-16) / (8 sqrt(pi)) = 7.9e-9 vz`, below half an ulp of `vz`. Returning
/// `vz` there skips an `erf` and an `exp` for every direction within about
/// `atan(1 / (4 alpha))` of the normal (tested against the full formula).
const SIGMA_IS_VZ_FROM: f32 = 4.0;

/// Projected area for directions at or below the horizon, where no model is
/// evaluated: a positive constant so that callers dividing by it stay finite.
pub(crate) fn projected_area_floor(_v: Vec3) -> f32 {
    1.0
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    /// The formula `projected_area` skips from `a = 4` on, evaluated in full.
    fn sigma_in_full(l: &BeckmannLobe, v: Vec3) -> f32 {
        let v = l.in_lobe_frame(v);
        let r = ((v.x * l.alpha_x).powi(2) + (v.y * l.alpha_y).powi(2)).sqrt();
        let a = v.z / r;
        let sigma = 0.5 * v.z * (1.0 + libm::erff(a)) + r * (-a * a).exp() / (2.0 * PI.sqrt());
        sigma.max(v.z)
    }

    /// Where the shortcut applies it returns what the full formula gives,
    /// bit for bit, over roughnesses from a mirror's to a matte's and
    /// directions from the normal to the shortcut's edge and the horizon.
    #[test]
    fn projected_area_shortcut_is_the_full_formula_to_the_bit() {
        let mut rng = Pcg64::seed_from_u64(11);
        let mut checked = 0;
        for _ in 0..400_000 {
            let b = Beckmann::new(
                10f32.powf(rng.random_range(-3.0..0.5)),
                10f32.powf(rng.random_range(-3.0..0.5)),
                rng.random_range(-PI..PI),
            );
            let l = BeckmannLobe::new(&b);
            let z: f32 = if rng.random_bool(0.5) {
                rng.random_range(0.0..1.0)
            } else {
                1.0 - 10f32.powf(rng.random_range(-7.0..-1.0))
            };
            let phi: f32 = rng.random_range(0.0..TAU);
            let s = (1.0 - z * z).max(0.0).sqrt();
            let v = Vec3::new(s * phi.cos(), s * phi.sin(), z);
            if v.z <= 0.0 {
                continue;
            }
            let full = sigma_in_full(&l, v);
            let fast = l.projected_area(v);
            if full.is_nan() {
                continue;
            }
            assert_eq!(fast.to_bits(), full.to_bits(), "{b:?} v {v}: {fast} against {full}");
            checked += 1;
        }
        assert!(checked > 300_000);
    }
}
