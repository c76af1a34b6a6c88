//! Model only what the sample needs: per region (a cluster of points with
//! like NDFs), the simplest class of model that predicts data it was not
//! fitted to as well as any other.
//!
//! **Classes**, simplest first: diffuse (the points whose own fit found no
//! measurable specular), an isotropic analytic lobe (Cook-Torrance), an
//! anisotropic analytic lobe (GGX or Beckmann: of the two, the one with the
//! lower total score over the material), and the tabulated NDF (the
//! material's pooled table, or the point's own where pooling's test kept
//! it).
//!
//! **Why only microfacet lobes.** The rig sees the sample from one
//! direction, so no held-out data can tell how a model extrapolates to
//! other views. The tabulated model gets that from physics (the masking
//! term and Fresnel of its microfacet form), and so do Cook-Torrance, GGX
//! and Beckmann; Ward's `1 / sqrt(cos i cos o)`, Phong's, Lafortune's and
//! Ashikhmin-Shirley's view dependence is empirical. On a fast capture of
//! `ward` (an anisotropic Beckmann surface), anisotropic Ward predicts
//! `refl eval`'s held-out steps better than GGX (0.119 against 0.129) and
//! renders other views more than twice as badly (0.207 against 0.093;
//! `scripts/eval-all.sh` keeps each eval's JSON). The other
//! analytic fits are kept for comparison and export; a material without an
//! isotropic and an anisotropic microfacet fit has no choice.
//!
//! **Scores.** The pipeline fits every stage a second time without every
//! k-th gantry step ([`crate::settings::StepSet::for_choice`]) and predicts
//! those steps' samples with each class of that fit ([`scores`]); a
//! class's score is the sum of squared cosine-weighted luminance residuals
//! (the analytic fits' objective). Held-out residuals charge a model for
//! what it cannot predict between the lights it saw (a table whose lobe is
//! sharper than the lights' spacing) and for what it fitted to noise (a
//! per-point table's hundreds of free cells), with no count of parameters
//! to guess. A plan too short to spare the steps is scored on the fit's own
//! samples, which favour the table; the summary says which.
//!
//! **Choice.** Per cluster, the class with the lowest score wins, unless a
//! simpler class's score is within [`NOISE_SIGMAS`] standard deviations of
//! it, the deviation being the larger of two:
//! - the noise's: with Gaussian noise of variance `s_j^2` per sample, a sum
//!   of squared residuals varies by `sqrt(2 sum s_j^4)` from the noise
//!   alone, and a difference chance can make does not buy a more complex
//!   model. This is the complexity penalty, derived from the noise model
//!   rather than from a count of parameters; it is the whole deviation
//!   where both classes fit to within the noise.
//! - the points' (a paired test with the region's points as the units):
//!   the per-point differences of the two scores, summed over the `n`
//!   points with scored samples, vary by
//!   `sqrt(n / (n - 1) sum (d_p - mean d)^2)`. Where neither class fits to
//!   within the noise (a lobe sharper than the lights' spacing, whose peak
//!   samples every class misses by many noise deviations) the noise says
//!   nothing about which misses less in general, and a sum that a few
//!   points' peaks decide is not evidence for the more complex class.

use brdf::Brdf;
use brdf::ndf::{MaskingOperator, TabulatedNdf};
use brdf::params::AnalyticModel;
use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::analytic::ModelFit;
use crate::partial::{Sample, lum, point_flag};
use crate::points::PointMaps;

/// A simpler class is kept while its score exceeds the best one's by less
/// than twice the noise's standard deviation of the score (a one-sided
/// test at about 2%).
pub const NOISE_SIGMAS: f64 = 2.0;

/// Class codes as stored in the material (`material::Choice`).
pub const DIFFUSE: u8 = 0;
pub const ISOTROPIC: u8 = 1;
pub const ANISOTROPIC: u8 = 2;
pub const TABULATED: u8 = 3;

/// What the scores were computed on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ScoredOn {
    /// Every k-th gantry step, left out of a second fit.
    #[default]
    HeldOutSteps,
    /// The fit's own samples (too few steps to hold any out).
    FitSamples,
}

/// Per point, each class's sum of squared cosine-weighted luminance
/// residuals on the scored samples, and the noise's sums over them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Scores {
    pub on: ScoredOn,
    /// The analytic models scored, and per model the per-point sums
    /// (`NaN` where the model could not be built at the point).
    pub models: Vec<AnalyticModel>,
    pub model_sse: Vec<Vec<f64>>,
    /// The tabulated model's per-point sums.
    pub table_sse: Vec<f64>,
    /// Per point: samples scored, `sum s_j^2` and `sum s_j^4` of their
    /// cosine-weighted noise variances.
    pub n: Vec<u32>,
    pub noise_ss: Vec<f64>,
    pub noise_ss2: Vec<f64>,
}

/// Score the tabulated model of `maps` and every fitted analytic model on
/// each point's `samples` (seen from `view[p]`).
pub fn scores(on: ScoredOn, samples: &[Vec<Sample>], view: &[Vec3], maps: &PointMaps, fits: &[ModelFit]) -> Scores {
    let op = MaskingOperator::new(maps.tables.grid());
    let n_params: Vec<usize> = fits.iter().map(|f| f.model.n_params()).collect();
    let per_point: Vec<(f64, Vec<f64>, u32, f64, f64)> = (0..maps.len())
        .into_par_iter()
        .map(|p| {
            let s = &samples[p];
            let o = view[p];
            let sse = |f: &dyn Fn(Vec3) -> f32| -> f64 {
                s.iter().map(|x| (((f(x.i) - lum(x.rho)) * x.i.z) as f64).powi(2)).sum()
            };
            let kd = Vec3::from(maps.kd[p]);
            let t = maps.tables.get(p);
            let table: Box<dyn Brdf> = if maps.flags[p] & point_flag::NO_SPECULAR == 0 && t.integral_cos() > 0.0 {
                Box::new(brdf::model::Microfacet {
                    kd,
                    ks: Vec3::from(maps.ks[p]),
                    ndf: TabulatedNdf::new(t, &op),
                    fresnel: brdf::fresnel::Fresnel::DielectricRelative { eta: maps.eta[p] },
                })
            } else {
                Box::new(brdf::model::Lambert { albedo: kd })
            };
            let table_sse = sse(&|i| lum(table.eval(i, o).to_array()));
            let model_sse = fits
                .iter()
                .zip(&n_params)
                .map(|(f, &k)| match f.params.get(p * k..(p + 1) * k).and_then(|q| f.model.build(q)) {
                    Some(m) => sse(&|i| lum(m.eval(i, o).to_array())),
                    None => f64::NAN,
                })
                .collect();
            let v = |x: &Sample| x.var as f64 * (x.i.z as f64).powi(2);
            let ss = s.iter().map(v).sum();
            let ss2 = s.iter().map(|x| v(x).powi(2)).sum();
            (table_sse, model_sse, s.len() as u32, ss, ss2)
        })
        .collect();
    let mut out = Scores { on, models: fits.iter().map(|f| f.model).collect(), ..Scores::default() };
    out.model_sse = vec![Vec::with_capacity(maps.len()); fits.len()];
    for (t, m, n, ss, ss2) in per_point {
        out.table_sse.push(t);
        for (k, v) in m.into_iter().enumerate() {
            out.model_sse[k].push(v);
        }
        out.n.push(n);
        out.noise_ss.push(ss);
        out.noise_ss2.push(ss2);
    }
    out
}

/// One region's evidence and choice, as `refl inspect` shows it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RegionChoice {
    pub points: usize,
    /// Scored samples over the region's points.
    pub samples: u64,
    /// RMS residual of the isotropic, anisotropic and tabulated classes
    /// over the noise's RMS on the same samples (1 is a perfect model).
    pub ratio: [Option<f32>; 3],
    /// The noise's standard deviation of a score, relative to the noise's
    /// sum.
    pub resolution: f32,
    /// Per class, how far its ratio^2 may lie above the best class's and
    /// still be chosen: [`NOISE_SIGMAS`] times the larger of the noise's
    /// and the points' deviation of the difference, relative to the
    /// noise's sum (absent from materials made before the points' test).
    #[serde(default)]
    pub margin: [Option<f32>; 3],
    pub chosen: u8,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SelectionSummary {
    pub isotropic_model: String,
    pub anisotropic_model: String,
    #[serde(default)]
    pub scored_on: ScoredOn,
    /// Measured points per class: diffuse, isotropic, anisotropic,
    /// tabulated.
    pub points: [usize; 4],
    /// Per class, the mean over its points' regions of the region's
    /// ratio for the class chosen (0 for diffuse and for empty classes).
    pub ratio: [f32; 4],
    #[serde(default)]
    pub regions: Vec<RegionChoice>,
    /// Bytes per point of each representation.
    pub bytes_per_point: [usize; 4],
    /// Storage if every point kept its tabulated NDF, and with the choice.
    pub bytes_all_tabulated: usize,
    pub bytes_chosen: usize,
}

#[derive(Clone, Debug)]
pub struct Selection {
    pub choice: Vec<u8>,
    pub isotropic: AnalyticModel,
    pub anisotropic: AnalyticModel,
    pub summary: SelectionSummary,
}

/// The analytic classes' candidates (see the module's notes).
const ISOTROPIC_MODELS: [AnalyticModel; 1] = [AnalyticModel::CookTorrance];
const ANISOTROPIC_MODELS: [AnalyticModel; 2] = [AnalyticModel::GgxAniso, AnalyticModel::BeckmannAniso];

/// Choose per cluster (`cluster[p]`, `u32::MAX` or `>= clusters` for
/// points outside every cluster) from `scores`; `None` if neither an
/// isotropic nor an anisotropic analytic model was scored.
pub fn select(maps: &PointMaps, cluster: &[u32], clusters: usize, scores: &Scores) -> Option<Selection> {
    let n = maps.len();
    let specular: Vec<usize> =
        (0..n).filter(|&p| maps.flags[p] & point_flag::NO_SPECULAR == 0 && (cluster[p] as usize) < clusters).collect();
    // Of each kind, the candidate built at the most specular points, then
    // with the lowest total over them.
    let rank = |k: usize| -> (usize, f64) {
        let sse = specular.iter().map(|&p| scores.model_sse[k][p]);
        (sse.clone().filter(|x| !x.is_finite()).count(), sse.filter(|x| x.is_finite()).sum())
    };
    let pick = |kinds: &[AnalyticModel]| -> Option<usize> {
        (0..scores.models.len()).filter(|&k| kinds.contains(&scores.models[k])).min_by(|&a, &b| {
            let (ra, rb) = (rank(a), rank(b));
            ra.0.cmp(&rb.0).then(ra.1.total_cmp(&rb.1))
        })
    };
    let iso = pick(&ISOTROPIC_MODELS)?;
    let aniso = pick(&ANISOTROPIC_MODELS)?;
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); clusters];
    for &p in &specular {
        members[cluster[p] as usize].push(p);
    }
    let mut choice = vec![DIFFUSE; n];
    let mut regions = Vec::new();
    for m in members.iter().filter(|m| !m.is_empty()) {
        let sum = |f: &dyn Fn(usize) -> f64| m.iter().map(|&p| f(p)).sum::<f64>();
        let noise = sum(&|p| scores.noise_ss[p]);
        let sd = (2.0 * sum(&|p| scores.noise_ss2[p])).sqrt();
        // Simplest first; a class unusable at any member is out.
        let per_point = |k: usize, p: usize| match k {
            0 => scores.model_sse[iso][p],
            1 => scores.model_sse[aniso][p],
            _ => scores.table_sse[p],
        };
        let class_sse: [f64; 3] = std::array::from_fn(|k| sum(&|p| per_point(k, p)));
        let best = class_sse.iter().copied().filter(|x| x.is_finite()).fold(f64::INFINITY, f64::min);
        let best_k = class_sse.iter().position(|&x| x == best).unwrap_or(2);
        let margin: [f64; 3] = std::array::from_fn(|k| {
            let scored = m.iter().filter(|&&p| scores.n[p] > 0);
            NOISE_SIGMAS * sd.max(paired_sd(scored.map(|&p| per_point(k, p) - per_point(best_k, p))))
        });
        // A region with no scored sample (none of its points in the
        // choice's refit) keeps the full model: the table.
        let k = if noise > 0.0 {
            (0..3).position(|k| class_sse[k].is_finite() && class_sse[k] <= best + margin[k]).unwrap_or(2)
        } else {
            2
        };
        let class = [ISOTROPIC, ANISOTROPIC, TABULATED][k];
        for &p in m {
            choice[p] = class;
        }
        let ratio = |x: f64| (x.is_finite() && noise > 0.0).then(|| (x / noise).sqrt() as f32);
        regions.push(RegionChoice {
            points: m.len(),
            samples: m.iter().map(|&p| scores.n[p] as u64).sum(),
            ratio: class_sse.map(ratio),
            resolution: if noise > 0.0 { (sd / noise) as f32 } else { 0.0 },
            margin: std::array::from_fn(|k| {
                (class_sse[k].is_finite() && noise > 0.0).then(|| (margin[k] / noise) as f32)
            }),
            chosen: class,
        });
    }
    let g = maps.tables.grid();
    let (iso_m, aniso_m) = (scores.models[iso], scores.models[aniso]);
    let bytes = [12, 4 * iso_m.n_params(), 4 * aniso_m.n_params(), 2 * g.len() + g.len().div_ceil(8) + 28];
    let mut summary = SelectionSummary {
        isotropic_model: iso_m.name().into(),
        anisotropic_model: aniso_m.name().into(),
        scored_on: scores.on,
        bytes_per_point: bytes,
        bytes_all_tabulated: n * bytes[3],
        ..SelectionSummary::default()
    };
    for (p, &c) in choice.iter().enumerate() {
        // A point the camera did not measure shows a neighbour's choice.
        if maps.flags[p] & point_flag::OUT_OF_VIEW == 0 {
            summary.points[c as usize] += 1;
        }
        summary.bytes_chosen += bytes[c as usize];
    }
    for c in [ISOTROPIC, ANISOTROPIC, TABULATED] {
        let (mut s, mut w) = (0.0f64, 0usize);
        for r in regions.iter().filter(|r| r.chosen == c) {
            if let Some(x) = r.ratio[c as usize - 1] {
                s += x as f64 * r.points as f64;
                w += r.points;
            }
        }
        summary.ratio[c as usize] = if w > 0 { (s / w as f64) as f32 } else { 0.0 };
    }
    summary.regions = regions;
    Some(Selection { choice, isotropic: iso_m, anisotropic: aniso_m, summary })
}

/// The standard deviation of a sum of per-point differences, estimated
/// from their spread: `sqrt(n / (n - 1) sum (d - mean d)^2)`, 0 for fewer
/// than two points (ignoring points where the difference is not finite,
/// which a finite class score never has).
fn paired_sd(d: impl Iterator<Item = f64>) -> f64 {
    let d: Vec<f64> = d.filter(|x| x.is_finite()).collect();
    let n = d.len();
    if n < 2 {
        return 0.0;
    }
    let mean = d.iter().sum::<f64>() / n as f64;
    let ss: f64 = d.iter().map(|x| (x - mean).powi(2)).sum();
    (n as f64 / (n - 1) as f64 * ss).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use brdf::ndf::{NdfGrid, TableSet};

    /// `n` points in one cluster, all specular, 200 samples each with
    /// noise variance 1 (cosine-weighted).
    fn maps(n: usize) -> PointMaps {
        PointMaps {
            kd: vec![[0.2; 3]; n],
            ks: vec![[0.1; 3]; n],
            eta: vec![1.5; n],
            flags: vec![0; n],
            tables: TableSet::new(NdfGrid::DEFAULT, n),
            stats: vec![Default::default(); n],
        }
    }

    /// Scores whose ratios^2 per point are `iso`, `aniso` and `table`
    /// (sum of squares over the noise's sum).
    fn scored(n: usize, iso: f64, aniso: f64, table: f64) -> Scores {
        let k = 200.0;
        Scores {
            on: ScoredOn::HeldOutSteps,
            models: vec![AnalyticModel::CookTorrance, AnalyticModel::GgxAniso],
            model_sse: vec![vec![iso * k; n], vec![aniso * k; n]],
            table_sse: vec![table * k; n],
            n: vec![200; n],
            noise_ss: vec![k; n],
            noise_ss2: vec![k; n],
        }
    }

    fn chosen(s: &Scores, n: usize) -> u8 {
        let sel = select(&maps(n), &vec![0; n], 1, s).unwrap();
        assert!(sel.choice.iter().all(|&c| c == sel.choice[0]), "one region, one class");
        sel.choice[0]
    }

    #[test]
    fn the_model_that_predicts_best_wins_when_the_difference_is_beyond_noise() {
        // 10 points x 200 samples: the noise moves a ratio^2 by
        // sqrt(2 / 2000) = 0.032; a difference of 0.2 is 6 of those.
        assert_eq!(chosen(&scored(10, 1.5, 1.4, 1.2), 10), TABULATED);
        assert_eq!(chosen(&scored(10, 1.5, 1.0, 1.2), 10), ANISOTROPIC);
        assert_eq!(chosen(&scored(10, 1.0, 1.0, 1.2), 10), ISOTROPIC);
    }

    #[test]
    fn a_simpler_model_within_noise_of_the_best_is_kept() {
        // 0.05 apart is 1.6 standard deviations: not enough for the table.
        assert_eq!(chosen(&scored(10, 1.05, 1.2, 1.0), 10), ISOTROPIC);
        // With 100 times the samples the same 0.05 is 16 deviations.
        assert_eq!(chosen(&scored(1000, 1.05, 1.2, 1.0), 1000), TABULATED);
    }

    #[test]
    fn a_difference_that_a_few_points_decide_does_not_buy_the_table() {
        // 20 points; the table misses by 4 noise variances per sample
        // where the anisotropic lobe misses by 5, far beyond the noise's
        // resolution (0.1 in ratio^2 with 4,000 samples).
        let n = 20;
        let mut s = scored(n, 9.0, 5.0, 4.0);
        assert_eq!(chosen(&s, n), TABULATED, "consistently better at every point");
        // The same totals, but decided by two points: at the others the
        // table misses by more than the lobe.
        for p in 0..n {
            s.table_sse[p] = if p < 2 { 0.0 } else { (4.0 * 20.0 / 18.0) * 200.0 };
            s.model_sse[1][p] = if p < 2 { 12.0 * 200.0 } else { (5.0 * 20.0 - 24.0) / 18.0 * 200.0 };
        }
        let total = |v: &[f64]| v.iter().sum::<f64>();
        assert!((total(&s.table_sse) - 4.0 * 200.0 * 20.0).abs() < 1e-6);
        assert!((total(&s.model_sse[1]) - 5.0 * 200.0 * 20.0).abs() < 1e-6);
        assert_eq!(chosen(&s, n), ANISOTROPIC);
    }

    #[test]
    fn a_region_without_evidence_keeps_the_table() {
        let mut s = scored(3, 1.0, 1.0, 2.0);
        for p in 0..3 {
            (s.n[p], s.noise_ss[p], s.noise_ss2[p], s.model_sse[0][p], s.model_sse[1][p], s.table_sse[p]) =
                (0, 0.0, 0.0, 0.0, 0.0, 0.0);
        }
        assert_eq!(chosen(&s, 3), TABULATED);
    }

    #[test]
    fn a_model_that_cannot_be_built_is_never_chosen() {
        let mut s = scored(4, 1.0, 1.0, 3.0);
        s.model_sse[0][2] = f64::NAN;
        s.model_sse[1][2] = f64::NAN;
        // Both analytic classes fail at one member: the region takes the table.
        assert_eq!(chosen(&s, 4), TABULATED);
    }

    #[test]
    fn diffuse_points_stay_diffuse_and_regions_are_reported() {
        let n = 6;
        let mut m = maps(n);
        m.flags[5] = point_flag::NO_SPECULAR;
        let cluster = [0, 0, 1, 1, 1, u32::MAX];
        let mut s = scored(n, 1.0, 1.0, 1.0);
        // Region 1's analytic fits miss by far more than noise.
        for p in 2..5 {
            s.model_sse[0][p] *= 3.0;
            s.model_sse[1][p] *= 3.0;
        }
        let sel = select(&m, &cluster, 2, &s).unwrap();
        assert_eq!(sel.choice, vec![ISOTROPIC, ISOTROPIC, TABULATED, TABULATED, TABULATED, DIFFUSE]);
        assert_eq!(sel.summary.points, [1, 2, 0, 3]);
        assert_eq!(sel.summary.regions.len(), 2);
        let r = &sel.summary.regions[1];
        assert_eq!((r.points, r.samples, r.chosen), (3, 600, TABULATED));
        assert!((r.ratio[0].unwrap() - 3f32.sqrt()).abs() < 1e-5 && (r.ratio[2].unwrap() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn only_microfacet_lobes_stand_for_the_analytic_classes() {
        let n = 4;
        // Ward fits the held-out steps best, but its view dependence is
        // not physical: it is not a candidate.
        let mut s = scored(n, 1.3, 1.2, 1.0);
        s.models.extend([AnalyticModel::WardIso, AnalyticModel::WardAniso]);
        s.model_sse.extend([vec![0.5 * 200.0; n], vec![0.5 * 200.0; n]]);
        let sel = select(&maps(n), &vec![0; n], 1, &s).unwrap();
        assert_eq!((sel.isotropic, sel.anisotropic), (AnalyticModel::CookTorrance, AnalyticModel::GgxAniso));
        assert_eq!(sel.choice[0], TABULATED);
        // Without the microfacet fits there is nothing to choose among.
        s.models = vec![AnalyticModel::WardIso, AnalyticModel::WardAniso];
        s.model_sse.drain(..2);
        assert!(select(&maps(n), &vec![0; n], 1, &s).is_none());
    }
}
