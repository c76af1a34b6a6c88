//! What one camera pixel's surface reflects toward the camera, prepared
//! once for the pixel's fixed view direction and colour channel, then
//! evaluated for every light of every frame.
//!
//! [`Reflectance::eval`] gives exactly `PointMaterial::eval(i, o)[channel]`,
//! to the last bit (tested), so the camera's frames do not depend on it. It
//! is sooner because what depends on the view alone is done once: the
//! projected area `sigma(o)` of a microfacet model, the diffuse term, the
//! choice of channel (one Fresnel channel instead of three), and for a
//! distribution made of Beckmann lobes (every built-in glossy sample) each
//! lobe's rotation and normalisation ([`brdf::ndf::BeckmannLobe`]).

use std::f32::consts::FRAC_1_PI;
use std::sync::Arc;

use brdf::fresnel::Fresnel;
use brdf::ndf::{BeckmannLobe, Lobe, Ndf, Sheen};
use brdf::{Brdf, frame};
use glam::Vec3;
use material::PointMaterial;

pub(crate) enum Reflectance {
    /// Nothing reflects: the pixel's ray meets no surface, or sees it from
    /// below.
    Black,
    /// A diffuse surface's `kd / pi` in the pixel's channel.
    Diffuse(f32),
    /// The microfacet model, with what the view fixes computed.
    Microfacet(Box<ViewedMicrofacet>),
    /// Any other model: its own evaluation.
    General { brdf: Arc<PointMaterial>, channel: usize },
}

pub(crate) struct ViewedMicrofacet {
    /// `kd / pi` in the channel.
    diffuse: f32,
    ks: f32,
    fresnel: Fresnel,
    channel: usize,
    /// `sigma(o)`.
    sigma_o: f32,
    ndf: ViewedNdf,
}

enum ViewedNdf {
    /// Weighted Beckmann lobes, each prepared.
    Lobes(Vec<(f32, BeckmannLobe)>),
    Other(Arc<dyn Ndf>),
}

impl ViewedNdf {
    #[inline]
    fn d(&self, h: Vec3) -> f32 {
        match self {
            ViewedNdf::Lobes(lobes) => {
                // The caller's `h` is above the surface (both `i` and `o` are).
                let ln_hz = h.z.ln();
                let mut d = 0.0;
                for (w, l) in lobes {
                    d += w * l.d(h, ln_hz);
                }
                d
            }
            ViewedNdf::Other(n) => n.d(h),
        }
    }

    #[inline]
    fn projected_area(&self, v: Vec3) -> f32 {
        match self {
            ViewedNdf::Lobes(lobes) => {
                let mut s = 0.0;
                for (w, l) in lobes {
                    s += w * l.projected_area(v);
                }
                // A mixture's area is never less than the macro surface's
                // (a single lobe's already is not, so this changes nothing).
                s.max(v.z)
            }
            ViewedNdf::Other(n) => n.projected_area(v),
        }
    }
}

impl Reflectance {
    /// `brdf` seen from `o` (the sample's frame) in colour channel `channel`.
    pub(crate) fn new(brdf: Arc<PointMaterial>, o: Vec3, channel: usize) -> Self {
        let below = !(o.z > 0.0);
        match &*brdf {
            PointMaterial::Diffuse { .. } | PointMaterial::Microfacet(_) if below => Reflectance::Black,
            PointMaterial::Diffuse { kd } => Reflectance::Diffuse((kd.max(Vec3::ZERO) * FRAC_1_PI)[channel]),
            PointMaterial::Microfacet(m) => {
                let ndf = match m.ndf.beckmann_lobes() {
                    Some(lobes) => {
                        ViewedNdf::Lobes(lobes.into_iter().map(|(w, b)| (w, BeckmannLobe::new(&b))).collect())
                    }
                    None => ViewedNdf::Other(m.ndf.clone()),
                };
                Reflectance::Microfacet(Box::new(ViewedMicrofacet {
                    diffuse: (m.kd * FRAC_1_PI)[channel],
                    ks: m.ks[channel],
                    fresnel: m.fresnel,
                    channel,
                    sigma_o: m.ndf.projected_area(o),
                    ndf,
                }))
            }
            PointMaterial::Model(_) => Reflectance::General { brdf, channel },
        }
    }

    /// What the camera's batched evaluation ([`crate::batch`]) needs, if it
    /// can evaluate this reflectance: nothing, a diffuse surface, or a
    /// microfacet surface of at most [`MAX_BATCHED_LOBES`] lobes, each a
    /// Beckmann lobe or a pile distribution (every built-in sample).
    pub(crate) fn batched(&self) -> Option<Batched> {
        match self {
            Reflectance::Black => Some(Batched::default()),
            Reflectance::Diffuse(f) => Some(Batched { black: false, diffuse: *f, ..Batched::default() }),
            Reflectance::Microfacet(m) => {
                let lobes: Vec<(f32, BatchLobe)> = match &m.ndf {
                    ViewedNdf::Lobes(l) => l.iter().map(|&(w, b)| (w, BatchLobe::Beckmann(b))).collect(),
                    ViewedNdf::Other(n) => n
                        .closed_form_lobes()?
                        .into_iter()
                        .map(|(w, l)| match l {
                            Lobe::Beckmann(b) => (w, BatchLobe::Beckmann(BeckmannLobe::new(&b))),
                            Lobe::Sheen(s) => (w, BatchLobe::Sheen(Arc::new(s))),
                        })
                        .collect(),
                };
                if lobes.is_empty() || lobes.len() > MAX_BATCHED_LOBES {
                    return None;
                }
                let fresnel = match m.fresnel {
                    Fresnel::One => BatchedFresnel::Schlick { f0: 1.0 },
                    Fresnel::Schlick { f0 } => BatchedFresnel::Schlick { f0: f0[m.channel.min(2)] },
                    Fresnel::Dielectric { eta } => BatchedFresnel::Dielectric { eta, scale: 1.0 },
                    Fresnel::DielectricRelative { eta } => BatchedFresnel::Dielectric {
                        eta,
                        scale: 1.0 / brdf::fresnel::dielectric_f0(eta).max(brdf::fresnel::RELATIVE_F0_FLOOR),
                    },
                    Fresnel::Conductor { eta, k } => {
                        BatchedFresnel::Conductor { eta: eta[m.channel.min(2)], k: k[m.channel.min(2)] }
                    }
                };
                Some(Batched { diffuse: m.diffuse, ks: m.ks, sigma_o: m.sigma_o, fresnel, lobes, black: false })
            }
            Reflectance::General { .. } => None,
        }
    }

    pub(crate) fn is_black(&self) -> bool {
        matches!(self, Reflectance::Black)
    }

    /// The BRDF for light from `i` toward the prepared view `o`.
    #[inline]
    pub(crate) fn eval(&self, i: Vec3, o: Vec3) -> f32 {
        match self {
            Reflectance::Black => 0.0,
            Reflectance::Diffuse(f) => {
                if i.z > 0.0 {
                    *f
                } else {
                    0.0
                }
            }
            Reflectance::Microfacet(m) => m.eval(i, o),
            Reflectance::General { brdf, channel } => brdf.eval(i, o)[*channel],
        }
    }
}

/// The most lobes a batched pixel may have.
pub(crate) const MAX_BATCHED_LOBES: usize = 2;

/// A pixel's reflectance as plain numbers ([`Reflectance::batched`]).
#[derive(Clone, Debug)]
pub(crate) struct Batched {
    /// Nothing reflects (the radiance is the ambient light's alone).
    pub black: bool,
    pub diffuse: f32,
    /// 0 for a surface without a specular term.
    pub ks: f32,
    pub sigma_o: f32,
    pub fresnel: BatchedFresnel,
    pub lobes: Vec<(f32, BatchLobe)>,
}

/// One lobe of a batched pixel's distribution.
#[derive(Clone, Debug)]
pub(crate) enum BatchLobe {
    Beckmann(BeckmannLobe),
    /// The pile distribution (velvet), whose projected area is read from
    /// its own table as [`Sheen`]'s `projected_area` reads it.
    Sheen(Arc<Sheen>),
}

impl Default for Batched {
    fn default() -> Self {
        Self {
            black: true,
            diffuse: 0.0,
            ks: 0.0,
            sigma_o: 1.0,
            fresnel: BatchedFresnel::Schlick { f0: 1.0 },
            lobes: Vec::new(),
        }
    }
}

/// The Fresnel terms the batch evaluates: `scale` times the exact
/// dielectric's, Schlick's (`f0 = 1` is no Fresnel term), or the exact
/// conductor's, in the pixel's channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum BatchedFresnel {
    Dielectric { eta: f32, scale: f32 },
    Schlick { f0: f32 },
    Conductor { eta: f32, k: f32 },
}

impl ViewedMicrofacet {
    /// `brdf::model::Microfacet::eval`, one channel, `sigma(o)` known.
    #[inline]
    fn eval(&self, i: Vec3, o: Vec3) -> f32 {
        if !(i.z > 0.0) {
            return 0.0;
        }
        let specular = match frame::half_vector(i, o) {
            None => 0.0,
            Some(h) => {
                let d = self.ndf.d(h);
                if d <= 0.0 {
                    0.0
                } else {
                    let denom = 4.0 * self.ndf.projected_area(i) * self.sigma_o;
                    self.fresnel.channel(i.dot(h), self.channel) * (d / denom)
                }
            }
        };
        let f = self.diffuse + self.ks * specular;
        if f.is_finite() && f > 0.0 { f } else { 0.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec2;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64;

    /// Every built-in sample, the mirror and a material of every kind the
    /// camera can meet: the prepared evaluation equals the material's own
    /// bit for bit, over directions from grazing to normal on both sides.
    #[test]
    fn prepared_reflectance_is_the_materials_own_to_the_bit() {
        let mut materials: Vec<Arc<PointMaterial>> = Vec::new();
        for (name, _) in crate::materials::BUILTIN {
            let m = crate::materials::builtin(name).unwrap();
            for p in [Vec2::ZERO, Vec2::new(-31.0, 17.5), Vec2::new(2.6, -40.2), Vec2::new(44.0, 44.0)] {
                materials.push(Arc::new(m.at(p)));
            }
        }
        materials.push(Arc::new(material::SvBrdf::at(&crate::materials::Mirror, Vec2::ZERO)));
        let ggx = brdf::model::Microfacet {
            kd: Vec3::new(0.1, 0.2, 0.3),
            ks: Vec3::splat(0.7),
            ndf: brdf::ndf::Ggx::new(0.2, 0.4, 0.3),
            fresnel: Fresnel::Schlick { f0: Vec3::new(0.9, 0.6, 0.3) },
        };
        materials.push(Arc::new(PointMaterial::Model(Arc::new(ggx))));
        let mut rng = Pcg64::seed_from_u64(7);
        let dir = |rng: &mut Pcg64| {
            let z: f32 = rng.random_range(-0.2..1.0);
            let phi: f32 = rng.random_range(0.0..std::f32::consts::TAU);
            let s = (1.0 - z * z).sqrt();
            Vec3::new(s * phi.cos(), s * phi.sin(), z)
        };
        let mut compared = 0;
        for m in &materials {
            for _ in 0..60 {
                let o = dir(&mut rng);
                for channel in 0..3 {
                    let r = Reflectance::new(m.clone(), o, channel);
                    for _ in 0..40 {
                        let i = dir(&mut rng);
                        let want = m.eval(i, o)[channel];
                        let got = r.eval(i, o);
                        assert_eq!(got.to_bits(), want.to_bits(), "{m:?} i {i} o {o} channel {channel}");
                        compared += 1;
                    }
                }
            }
        }
        assert!(compared > 100_000);
    }
}
