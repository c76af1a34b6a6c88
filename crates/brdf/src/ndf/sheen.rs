//! The inverted-Gaussian distribution of cloth pile (Ashikhmin and Premoze
//! 2007, "Distribution-based BRDFs"): microfacet normals concentrate near
//! the horizon, which gives velvet its bright grazing rim and its
//! retro-reflection at grazing angles.
//!
//! `D(h) = N (1 + A exp(-cot^2(theta_h) / s^2))`, with `N` computed at
//! construction so that `integral D cos dw = 1` (a 1-D quadrature, the
//! distribution being isotropic). The projected area has no closed form and
//! is tabulated over `theta_v` at construction. Sampling draws `h` from the
//! cosine-weighted hemisphere, so `pdf_h = cos(theta_h) / pi` (not `D cos`).

use std::f32::consts::{FRAC_PI_2, PI};

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::Ndf;
use crate::frame;

/// Rings and sectors of the construction-time quadratures.
const QUAD_THETA: usize = 512;
const QUAD_PHI: usize = 64;
const SIGMA_SAMPLES: usize = 65;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sheen {
    pub sharpness: f32,
    pub amplitude: f32,
    norm: f32,
    /// `sigma(theta_v)` at `theta_v = k / (SIGMA_SAMPLES - 1) * pi/2`.
    sigma: Vec<f32>,
}

impl Sheen {
    pub fn new(sharpness: f32, amplitude: f32) -> Self {
        let s = sharpness.clamp(0.05, 2.0);
        let a = amplitude.clamp(0.0, 100.0);
        let shape = |h: Vec3| -> f32 {
            let s2 = frame::sin2_theta(h);
            if s2 <= 0.0 {
                return 1.0;
            }
            let cot2 = h.z * h.z / s2;
            1.0 + a * (-cot2 / (s * s)).exp()
        };
        // integral of shape * cos over the hemisphere (isotropic: 2 pi over phi).
        let mut integral = 0.0f64;
        for k in 0..QUAD_THETA {
            let t0 = k as f32 / QUAD_THETA as f32 * FRAC_PI_2;
            let t1 = (k + 1) as f32 / QUAD_THETA as f32 * FRAC_PI_2;
            let tm = 0.5 * (t0 + t1);
            let cos_measure = 0.5 * (t1.sin().powi(2) - t0.sin().powi(2)) * 2.0 * PI;
            integral += (shape(frame::spherical(tm, 0.0)) * cos_measure) as f64;
        }
        let norm = (1.0 / integral) as f32;
        let mut sigma = Vec::with_capacity(SIGMA_SAMPLES);
        for j in 0..SIGMA_SAMPLES {
            let tv = j as f32 / (SIGMA_SAMPLES - 1) as f32 * FRAC_PI_2;
            let v = frame::spherical(tv, 0.0);
            let mut acc = 0.0f64;
            for k in 0..QUAD_THETA / 2 {
                let t0 = k as f32 / (QUAD_THETA / 2) as f32 * FRAC_PI_2;
                let t1 = (k + 1) as f32 / (QUAD_THETA / 2) as f32 * FRAC_PI_2;
                let tm = 0.5 * (t0 + t1);
                let dw_ring = (t0.cos() - t1.cos()) * 2.0 * PI / QUAD_PHI as f32;
                for p in 0..QUAD_PHI {
                    let h = frame::spherical(tm, (p as f32 + 0.5) / QUAD_PHI as f32 * 2.0 * PI);
                    let dot = h.dot(v);
                    if dot > 0.0 {
                        acc += (dot * norm * shape(h) * dw_ring) as f64;
                    }
                }
            }
            sigma.push((acc as f32).max(v.z));
        }
        Self { sharpness: s, amplitude: a, norm, sigma }
    }

    /// The normalisation `N` of `D`.
    pub fn norm(&self) -> f32 {
        self.norm
    }

    /// The projected area of a direction above the surface from its polar
    /// angle `theta_v` and its `cos(theta_v)` (`v_z`): the table, linearly
    /// interpolated, and never less than `v_z`. [`Ndf::projected_area`]
    /// and a renderer with the angle at hand read it here.
    pub fn projected_area_at(&self, theta_v: f32, v_z: f32) -> f32 {
        let t = theta_v / FRAC_PI_2 * (SIGMA_SAMPLES - 1) as f32;
        let j = (t as usize).min(SIGMA_SAMPLES - 2);
        let f = (t - j as f32).clamp(0.0, 1.0);
        (self.sigma[j] * (1.0 - f) + self.sigma[j + 1] * f).max(v_z)
    }
}

impl Ndf for Sheen {
    fn d(&self, h: Vec3) -> f32 {
        if h.z <= 0.0 {
            return 0.0;
        }
        let s2 = frame::sin2_theta(h);
        if s2 <= 0.0 {
            return self.norm;
        }
        let cot2 = h.z * h.z / s2;
        self.norm * (1.0 + self.amplitude * (-cot2 / (self.sharpness * self.sharpness)).exp())
    }

    fn projected_area(&self, v: Vec3) -> f32 {
        if v.z <= 0.0 {
            return 1.0;
        }
        self.projected_area_at(frame::sin2_theta(v).sqrt().atan2(v.z), v.z)
    }

    fn sample_h(&self, u: Vec2) -> Vec3 {
        frame::sample_cosine_hemisphere(u)
    }

    fn pdf_h(&self, h: Vec3) -> f32 {
        frame::cosine_hemisphere_pdf(h)
    }

    fn closed_form_lobes(&self) -> Option<Vec<(f32, super::Lobe)>> {
        Some(vec![(1.0, super::Lobe::Sheen(self.clone()))])
    }
}
