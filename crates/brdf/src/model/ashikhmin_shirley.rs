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
    /// The model of an [`crate::params::AnalyticModel::AshikhminShirley`]
    /// parameter vector (`rd`, `rs`, `nu`, `nv`, angle; negative
    /// amplitudes read as 0), as [`crate::params::AnalyticModel::build`]
    /// gives it; `None` if the length is wrong.
    pub fn from_params(p: &[f32]) -> Option<Self> {
        let &[rd_r, rd_g, rd_b, rs_r, rs_g, rs_b, nu, nv, angle_rad] = p else {
            return None;
        };
        let rd = Vec3::new(rd_r, rd_g, rd_b).max(Vec3::ZERO);
        let rs = Vec3::new(rs_r, rs_g, rs_b).max(Vec3::ZERO);
        Some(Self { rd, rs, nu, nv, angle_rad })
    }

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
        match frame::half_vector(i, o) {
            Some(h) => self.specular_shape_at(i, o, h),
            None => 0.0,
        }
    }

    /// [`Self::specular_shape`] with the half vector `h` of `i` and `o`
    /// given (both above the surface).
    fn specular_shape_at(&self, i: Vec3, o: Vec3, h: Vec3) -> f32 {
        let (nu, nv) = self.exponents();
        let hl = to_lobe_frame(h, self.angle_rad);
        let (c2, s2) = frame::cos2_sin2_phi(hl);
        let e = nu * c2 + nv * s2;
        let hk = i.dot(h).max(COS_FLOOR);
        let v =
            ((nu + 1.0) * (nv + 1.0)).sqrt() / (8.0 * PI) * h.z.max(0.0).powf(e) / (hk * i.z.max(o.z).max(COS_FLOOR));
        if v.is_finite() { v } else { 0.0 }
    }

    /// What [`Brdf::eval`] needs of the directions `i` and `o` beyond the
    /// amplitudes `rd` and `rs`: it depends on the exponents and the angle
    /// only, so a fit that solves for the amplitudes of one shape finds it
    /// once per sample rather than once per amplitude it tries. `None` where
    /// the model is zero whatever its amplitudes.
    pub fn geometry(&self, i: Vec3, o: Vec3) -> Option<AsGeometry> {
        if !both_above(i, o) {
            return None;
        }
        let h = frame::half_vector(i, o)?;
        let p5 = |c: f32| {
            let m = 1.0 - 0.5 * c;
            let m2 = m * m;
            1.0 - m2 * m2 * m
        };
        Some(AsGeometry { hk: i.dot(h), shape: self.specular_shape_at(i, o, h), p5_i: p5(i.z), p5_o: p5(o.z) })
    }

    /// The model's value for directions whose [`Self::geometry`] (under
    /// this model's exponents and angle) is `g`: [`Brdf::eval`], to the bit.
    pub fn eval_geometry(&self, g: Option<&AsGeometry>) -> Rgb {
        let Some(g) = g else {
            return Vec3::ZERO;
        };
        let f = Vec3::new(
            fresnel::schlick(g.hk, self.rs.x),
            fresnel::schlick(g.hk, self.rs.y),
            fresnel::schlick(g.hk, self.rs.z),
        );
        let spec = f * g.shape;
        let diff = self.rd * (Vec3::ONE - self.rs) * (28.0 / (23.0 * PI)) * g.p5_i * g.p5_o;
        sanitize(spec + diff)
    }
}

/// [`AshikhminShirley::geometry`]: the cosine of the half vector with the
/// light (Schlick's Fresnel reads it), the specular term per unit Fresnel
/// and the diffuse term's two factors `1 - (1 - cos/2)^5`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AsGeometry {
    hk: f32,
    shape: f32,
    p5_i: f32,
    p5_o: f32,
}

impl Brdf for AshikhminShirley {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        self.eval_geometry(self.geometry(i, o).as_ref())
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The geometry found under one pair of amplitudes evaluates any other
    /// pair of the same shape exactly as `eval` does: a fit may find it
    /// once per sample and try amplitudes on it.
    #[test]
    fn one_geometry_serves_every_amplitude_of_a_shape() {
        let shape = |rd: Vec3, rs: Vec3| AshikhminShirley { rd, rs, nu: 80.0, nv: 12.0, angle_rad: 0.7 };
        let found = shape(Vec3::ZERO, Vec3::ONE);
        let others = [
            shape(Vec3::splat(0.3), Vec3::splat(0.04)),
            shape(Vec3::new(0.9, 0.2, 0.05), Vec3::new(0.5, 0.6, 0.95)),
            shape(Vec3::ONE, Vec3::ZERO),
        ];
        let dir = |theta: f32, phi: f32| Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
        let mut lit = 0;
        for a in 0..24 {
            for b in 0..24 {
                // Lights and views over the hemisphere, a few below it.
                let i = dir(-0.1 + 1.7 * a as f32 / 23.0, 0.53 * a as f32);
                let o = dir(1.6 * b as f32 / 23.0, 2.1 + 0.29 * b as f32);
                let g = found.geometry(i, o);
                lit += usize::from(g.is_some());
                for m in &others {
                    assert_eq!(m.eval_geometry(g.as_ref()).to_array(), m.eval(i, o).to_array(), "i {i} o {o}");
                }
            }
        }
        assert!(lit > 400, "{lit} of 576 pairs above the surface");
    }
}
