//! Per-model shape parameters: their unconstrained form for the optimiser,
//! and starting values from the NDF's slope moments.

use brdf::ndf::NdfTable;
use brdf::params::{AnalyticModel, MAX_ETA};

use crate::partial::ETA_RANGE;

/// The second moments of an NDF's slopes, as an anisotropic Beckmann lobe:
/// `Sigma = integral D cos (s s^T) dw` with slopes `s = (hx/hz, hy/hz)`, and
/// for Beckmann `E[s_x^2] = alpha_x^2 / 2` along the principal axes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Moments {
    pub alpha_x: f32,
    pub alpha_y: f32,
    /// Direction of the `alpha_x` axis from the sample's x axis.
    pub angle_rad: f32,
}

impl Moments {
    pub fn of(t: &NdfTable) -> Self {
        let g = t.grid();
        let (mut sxx, mut syy, mut sxy, mut w) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for tt in 0..g.n_theta as usize {
            let cm = g.cos_measure(tt) as f64;
            for p in 0..g.n_phi as usize {
                let c = g.index(tt, p);
                if !t.coverage().get(c) {
                    continue;
                }
                let h = g.direction(tt, p);
                let (sx, sy) = ((h.x / h.z) as f64, (h.y / h.z) as f64);
                let d = t.values()[c] as f64 * cm;
                sxx += d * sx * sx;
                syy += d * sy * sy;
                sxy += d * sx * sy;
                w += d;
            }
        }
        if !(w > 0.0) {
            return Self { alpha_x: 0.3, alpha_y: 0.3, angle_rad: 0.0 };
        }
        let (a, b, c) = (sxx / w, syy / w, sxy / w);
        let tr = a + b;
        let det = a * b - c * c;
        let disc = (tr * tr / 4.0 - det).max(0.0).sqrt();
        let (l1, l2) = (tr / 2.0 + disc, (tr / 2.0 - disc).max(1e-8));
        let angle = 0.5 * (2.0 * c).atan2(a - b);
        let al = |l: f64| ((2.0 * l).sqrt() as f32).clamp(0.01, 1.5);
        Self { alpha_x: al(l1), alpha_y: al(l2), angle_rad: angle as f32 }
    }

    pub fn alpha_iso(&self) -> f32 {
        (self.alpha_x * self.alpha_y).sqrt()
    }
}

/// Blinn/Phong exponent of a Beckmann roughness (Walter et al. 2007, eq. 33).
fn exponent(alpha: f32) -> f32 {
    (2.0 / (alpha * alpha) - 2.0).max(1.0)
}

/// Unconstrained starting vector `u` for a model.
pub fn init(model: AnalyticModel, m: &Moments, eta: f32) -> Vec<f64> {
    let ln = |v: f32| (v.max(1e-6) as f64).ln();
    let eta_u = ln((eta - ETA_RANGE.0).max(0.02));
    match model {
        AnalyticModel::Phong => vec![ln(exponent(m.alpha_iso()))],
        AnalyticModel::WardIso => vec![ln(m.alpha_iso())],
        AnalyticModel::WardAniso => vec![ln(m.alpha_x), ln(m.alpha_y), m.angle_rad as f64],
        AnalyticModel::Lafortune => {
            // (Cx ix ox + Cy iy oy + iz oz)^n with Cx = Cy = -1 is the Phong
            // lobe around the mirror direction; n as Phong's exponent, and
            // |C| = 0.95 (see `shape`).
            vec![3.0, 3.0, ln(exponent(m.alpha_iso()))]
        }
        AnalyticModel::CookTorrance => vec![ln(m.alpha_iso()), eta_u],
        AnalyticModel::AshikhminShirley => vec![ln(exponent(m.alpha_x)), ln(exponent(m.alpha_y)), m.angle_rad as f64],
        AnalyticModel::GgxAniso => vec![ln(m.alpha_x * 0.8), ln(m.alpha_y * 0.8), m.angle_rad as f64, eta_u],
        AnalyticModel::BeckmannAniso => vec![ln(m.alpha_x), ln(m.alpha_y), m.angle_rad as f64, eta_u],
        // A Gaussian surface of RMS height sigma0 and autocorrelation length
        // tau has RMS slope sqrt(2) sigma0 / tau = alpha / sqrt(2).
        AnalyticModel::He => vec![ln(m.alpha_iso() * 3.0 / 2.0), ln(3.0), eta_u],
    }
}

/// Physical shape parameters (the model's layout after kd and ks) from `u`.
/// A Fresnel index is `ETA_RANGE.0 + exp(u)`, held below
/// [`brdf::params::MAX_ETA`]: a metal's reflectance, not the tables' upper
/// bound (`ETA_RANGE.1`), which only the shape of `F(theta) / F(0)` sets.
pub fn shape(model: AnalyticModel, u: &[f64]) -> Vec<f32> {
    let e = |x: f64| x.clamp(-20.0, 20.0).exp() as f32;
    let eta = |x: f64| (ETA_RANGE.0 + e(x)).min(MAX_ETA);
    match model {
        AnalyticModel::Phong => vec![e(u[0])],
        AnalyticModel::WardIso => vec![e(u[0])],
        AnalyticModel::WardAniso => vec![e(u[0]), e(u[1]), u[2] as f32],
        AnalyticModel::Lafortune => {
            // Cz = 1 and |Cx|, |Cy| < 1: then `Cx ix ox + Cy iy oy + iz oz <= 1`
            // everywhere and the lobe is largest near the mirror direction.
            // Letting |C| exceed Cz lets the lobe grow as `(|C| / Cz)^n`
            // towards grazing angles this rig never observes (its camera
            // is at 45 degrees); fits that did so predicted renders ten
            // times too bright there.
            let s = |x: f64| (1.0 / (1.0 + (-x).exp())) as f32;
            vec![-s(u[0]), -s(u[1]), 1.0, e(u[2])]
        }
        AnalyticModel::CookTorrance => vec![e(u[0]), eta(u[1])],
        AnalyticModel::AshikhminShirley => vec![e(u[0]), e(u[1]), u[2] as f32],
        AnalyticModel::GgxAniso | AnalyticModel::BeckmannAniso => vec![e(u[0]), e(u[1]), u[2] as f32, eta(u[3])],
        AnalyticModel::He => vec![e(u[0]), e(u[1]), eta(u[2])],
    }
}

/// The unconstrained vector whose [`shape`] is `q` (a model's shape
/// parameters as fitted), to start a fit where another ended; `None` for a
/// shape outside the model's domain.
pub fn unshape(model: AnalyticModel, q: &[f32]) -> Option<Vec<f64>> {
    let ln = |v: f32| (v > 0.0 && v.is_finite()).then(|| (v as f64).ln());
    let eta = |v: f32| ln((v - ETA_RANGE.0).max(0.02));
    let logit = |v: f32| (v > 0.0 && v < 1.0).then(|| ((v / (1.0 - v)) as f64).ln());
    let angle = |v: f32| v.is_finite().then_some(v as f64);
    let u = match model {
        AnalyticModel::Phong | AnalyticModel::WardIso => vec![ln(*q.first()?)?],
        AnalyticModel::WardAniso | AnalyticModel::AshikhminShirley => {
            vec![ln(*q.first()?)?, ln(*q.get(1)?)?, angle(*q.get(2)?)?]
        }
        AnalyticModel::Lafortune => vec![logit(-*q.first()?)?, logit(-*q.get(1)?)?, ln(*q.get(3)?)?],
        AnalyticModel::CookTorrance => vec![ln(*q.first()?)?, eta(*q.get(1)?)?],
        AnalyticModel::GgxAniso | AnalyticModel::BeckmannAniso => {
            vec![ln(*q.first()?)?, ln(*q.get(1)?)?, angle(*q.get(2)?)?, eta(*q.get(3)?)?]
        }
        AnalyticModel::He => vec![ln(*q.first()?)?, ln(*q.get(1)?)?, eta(*q.get(2)?)?],
    };
    Some(u)
}

/// Cost class: He evaluates a series per sample (about 40x slower).
pub fn expensive(model: AnalyticModel) -> bool {
    model == AnalyticModel::He
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unshape_inverts_shape_for_every_model() {
        for &model in AnalyticModel::ALL.iter() {
            let m = Moments { alpha_x: 0.12, alpha_y: 0.3, angle_rad: 0.4 };
            let u = init(model, &m, 1.7);
            let q = shape(model, &u);
            let back = unshape(model, &q).unwrap_or_else(|| panic!("{model:?}: {q:?}"));
            assert_eq!(shape(model, &back).len(), q.len());
            for (a, b) in shape(model, &back).iter().zip(&q) {
                assert!((a - b).abs() <= 1e-5 * b.abs().max(1.0), "{model:?}: {q:?} -> {back:?}");
            }
        }
        assert!(unshape(AnalyticModel::GgxAniso, &[0.0, 0.1, 0.0, 1.5]).is_none());
    }
    use brdf::ndf::{Beckmann, NdfGrid};

    #[test]
    fn moments_recover_a_beckmann_lobe() {
        let g = NdfGrid::DEFAULT;
        let mut t = NdfTable::from_ndf(g, &Beckmann::new(0.12, 0.35, 0.5));
        t.normalize();
        let m = Moments::of(&t);
        assert!((m.alpha_y - 0.12).abs() < 0.02 || (m.alpha_x - 0.35).abs() < 0.03, "{m:?}");
        assert!((m.alpha_x - 0.35).abs() < 0.04, "{m:?}");
        assert!((m.alpha_y - 0.12).abs() < 0.02, "{m:?}");
        // The major axis is alpha_y's direction: 0.5 + 90 degrees.
        let d = (m.angle_rad - (0.5 + std::f32::consts::FRAC_PI_2)).rem_euclid(std::f32::consts::PI);
        assert!(d < 0.05 || d > std::f32::consts::PI - 0.05, "{m:?}");
    }
}
