//! Model only what the sample needs: per region (a cluster of points with
//! like NDFs), the simplest class of model that predicts data it was not
//! fitted to as well as any other.
//!
//! **Classes**, simplest first: diffuse (the point's diffuse albedo alone,
//! as the material renders it; the points whose own fit found no
//! measurable specular are diffuse without a choice), an isotropic
//! analytic lobe (Cook-Torrance), an anisotropic analytic lobe (GGX or
//! Beckmann: of the two, the one with the lower total score over the
//! material), and the tabulated NDF (the material's pooled table, or the
//! point's own where pooling's test kept it). A lobe too faint for the
//! held-out samples to tell from the diffuse part is not modelled.
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
//! **Stand-ins.** A cluster's analytic shape can fail at a few of its
//! points by orders of magnitude (a lobe sharper than the lights' spacing
//! that a point's amplitude turns into a spike where a held-out light
//! falls) while it predicts as well as the table elsewhere; so can the
//! diffuse class at the few glossy points of a matte region. Per
//! region and simpler class, a point whose excess score over the table is
//! an outlier among the region's excesses and beyond the noise at the point
//! keeps its table ([`stand_ins`]); the class's region score counts the
//! table there. Only the refit's points are scored (a quarter of a large
//! grid), so only they can be found; the rest take the region's class.
//!
//! **Regions without evidence.** A small cluster may have none of its
//! points in the refit, or fewer than [`MIN_SCORED_POINTS`]: too few to
//! tell outliers or estimate the points' spread (with two points, the
//! spread of their differences admits anything: on balanced
//! vch_golden_yellow two such regions took the diffuse part though it
//! missed their lobes by 20 times the noise, and `auto` rendered six times
//! worse than the table). It takes the class that the whole material's
//! scored points choose as one region: the evidence nearest to it, where
//! the most complex class (the default before) rendered brushed metal's
//! unscored regions with tables far coarser than its lobe.
//!
//! **Choice.** Per cluster, the class with the lowest score wins, unless a
//! simpler class's score is within [`NOISE_SIGMAS`] standard deviations of
//! it, the deviation being the larger of two:
//! - the noise's: the two classes' residuals on a sample differ by
//!   `r_a - r_b` whatever the noise, and their squares by that times
//!   `r_a + r_b`, whose noise has variance `4 s^2` (cosine-weighted); so
//!   the difference of the sums varies by `2 sqrt(sum (r_a - r_b)^2 s^2)`
//!   from the noise alone ([`Scores::pair_var`]). A difference chance can
//!   make does not buy a more complex model: this is the complexity
//!   penalty, from the noise model rather than a count of parameters.
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

/// Scored points a region needs for the choice's tests of its points (the
/// outliers' and the points' spread): with fewer, a spread is not
/// estimated, and the region takes the material's class.
pub const MIN_SCORED_POINTS: usize = 3;

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
    /// The diffuse model's (the point's diffuse albedo alone, as the
    /// material renders a point it calls diffuse) per-point sums.
    pub diffuse_sse: Vec<f64>,
    /// Per point: samples scored, `sum s_j^2` and `sum s_j^4` of their
    /// cosine-weighted noise variances.
    pub n: Vec<u32>,
    pub noise_ss: Vec<f64>,
    pub noise_ss2: Vec<f64>,
    /// Per point, per pair of predictors `(a, b)` (the models in order,
    /// then the table, then the diffuse model):
    /// `sum_j (r_aj - r_bj)^2 s_j^2`, the residuals' difference squared
    /// times the sample's noise variance, all
    /// cosine-weighted: a quarter of the noise's variance of the
    /// difference of the two scores. With `r = (f - y) cos` and `y` noisy
    /// with variance `s^2`, `r_a^2 - r_b^2 = (r_a - r_b)(r_a + r_b)`, whose
    /// noise is `(r_a - r_b)` times a term of variance `4 s^2 cos^2`.
    /// Row-major `(models + 2)^2` per point.
    pub pair_var: Vec<f64>,
}

impl Scores {
    /// Predictor `a`'s score at point `p` (the models in order, then the
    /// table, then the diffuse model).
    pub fn sse(&self, a: usize, p: usize) -> f64 {
        let m = self.models.len();
        if a == m {
            self.table_sse[p]
        } else if a == m + 1 {
            self.diffuse_sse[p]
        } else {
            self.model_sse[a][p]
        }
    }

    /// The index of the tabulated predictor.
    pub fn table(&self) -> usize {
        self.models.len()
    }

    /// The index of the diffuse predictor.
    pub fn diffuse(&self) -> usize {
        self.models.len() + 1
    }

    /// [`Scores::pair_var`] of predictors `a` and `b` at point `p`.
    pub fn pair(&self, p: usize, a: usize, b: usize) -> f64 {
        let w = self.models.len() + 2;
        self.pair_var[p * w * w + a * w + b]
    }
}

/// Score the tabulated model of `maps`, its diffuse part alone and every
/// fitted analytic model on each point's `samples` (seen from `view[p]`).
pub fn scores(on: ScoredOn, samples: &[Vec<Sample>], view: &[Vec3], maps: &PointMaps, fits: &[ModelFit]) -> Scores {
    scores_by(on, maps, fits, |p| (std::borrow::Cow::Borrowed(samples[p].as_slice()), view[p]))
}

/// [`scores`] with each point's samples and view given by `point(p)`, as
/// they are needed (the model choice gathers its held-out samples from the
/// store point by point, never holding every point's at once).
pub fn scores_by<'s>(
    on: ScoredOn,
    maps: &PointMaps,
    fits: &[ModelFit],
    point: impl Fn(usize) -> (std::borrow::Cow<'s, [Sample]>, Vec3) + Sync,
) -> Scores {
    let op = MaskingOperator::new(maps.tables.grid());
    let n_params: Vec<usize> = fits.iter().map(|f| f.model.n_params()).collect();
    let m = fits.len();
    let per_point: Vec<(Vec<f64>, u32, f64, f64, Vec<f64>)> = (0..maps.len())
        .into_par_iter()
        .map(|p| {
            let (s, o) = point(p);
            let s = &*s;
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
            let diffuse = brdf::model::Lambert { albedo: kd };
            let models: Vec<Option<std::sync::Arc<dyn Brdf>>> = fits
                .iter()
                .zip(&n_params)
                .map(|(f, &k)| f.params.get(p * k..(p + 1) * k).and_then(|q| f.model.build(q)))
                .collect();
            // Per predictor (the models, the table, the diffuse part): the
            // sum of squared residuals; per pair, the sum of squared
            // differences of their residuals times each sample's noise
            // variance.
            let w = m + 2;
            let mut sse = vec![0.0f64; w];
            let mut pair = vec![0.0f64; w * w];
            let mut r = vec![0.0f64; w];
            let (mut ss, mut ss2) = (0.0f64, 0.0f64);
            for x in s {
                let c = x.i.z as f64;
                let y = lum(x.rho) as f64;
                for (k, b) in models.iter().enumerate() {
                    r[k] = b.as_ref().map_or(f64::NAN, |b| (lum(b.eval(x.i, o).to_array()) as f64 - y) * c);
                }
                r[m] = (lum(table.eval(x.i, o).to_array()) as f64 - y) * c;
                r[m + 1] = (lum(diffuse.eval(x.i, o).to_array()) as f64 - y) * c;
                let v = x.var as f64 * c * c;
                ss += v;
                ss2 += v * v;
                for a in 0..w {
                    sse[a] += r[a] * r[a];
                    for b in a + 1..w {
                        let d = (r[a] - r[b]).powi(2) * v;
                        pair[a * w + b] += d;
                        pair[b * w + a] += d;
                    }
                }
            }
            (sse, s.len() as u32, ss, ss2, pair)
        })
        .collect();
    let mut out = Scores { on, models: fits.iter().map(|f| f.model).collect(), ..Scores::default() };
    out.model_sse = vec![Vec::with_capacity(maps.len()); m];
    for (sse, n, ss, ss2, pair) in per_point {
        out.table_sse.push(sse[m]);
        out.diffuse_sse.push(sse[m + 1]);
        for (k, v) in sse.into_iter().take(m).enumerate() {
            out.model_sse[k].push(v);
        }
        out.n.push(n);
        out.noise_ss.push(ss);
        out.noise_ss2.push(ss2);
        out.pair_var.extend(pair);
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
    /// over the noise's RMS on the same samples (1 is a perfect model); an
    /// analytic class's counts the table at its stand-ins.
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
    /// Per analytic class, the members where it fails so far beyond the
    /// table that the table stands in for it ([`stand_ins`]).
    #[serde(default)]
    pub stand_ins: [usize; 2],
    /// Members kept on their tables though the region chose an analytic
    /// class (its stand-ins).
    #[serde(default)]
    pub tabulated_points: usize,
    pub chosen: u8,
    /// The diffuse class's ratio, margin and stand-ins, as the others'
    /// (absent from materials made before it was a candidate).
    #[serde(default)]
    pub diffuse_ratio: Option<f32>,
    #[serde(default)]
    pub diffuse_margin: Option<f32>,
    #[serde(default)]
    pub diffuse_stand_ins: usize,
    /// Fewer than [`MIN_SCORED_POINTS`] of the region's points were
    /// scored: it took the material's class.
    #[serde(default)]
    pub from_material: bool,
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
    /// The whole material's evidence taken as one region: the class of a
    /// region with fewer than [`MIN_SCORED_POINTS`] scored points.
    #[serde(default)]
    pub material: Option<RegionChoice>,
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

/// Whether the choice reads `m`'s scores (an isotropic or anisotropic
/// candidate); the others' are never read, so the choice's refit need not
/// fit them.
pub fn is_candidate(m: AnalyticModel) -> bool {
    ISOTROPIC_MODELS.contains(&m) || ANISOTROPIC_MODELS.contains(&m)
}

/// Choose per cluster (`cluster[p]`, `u32::MAX` or `>= clusters` for
/// points outside every cluster) from `scores`, a cluster with fewer than
/// [`MIN_SCORED_POINTS`] scored points taking the material's class; `None` if neither an isotropic nor
/// an anisotropic analytic model was scored.
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
    let predictor = [scores.diffuse(), iso, aniso, scores.table()];
    // The whole material as one region: the choice of a region with too
    // few scored points.
    let material = decide(scores, &specular, &predictor, None);
    let fallback = (material.noise > 0.0).then_some(material.k);
    let mut choice = vec![DIFFUSE; n];
    let mut regions = Vec::new();
    for m in members.iter().filter(|m| !m.is_empty()) {
        let d = decide(scores, m, &predictor, fallback);
        for (i, &p) in m.iter().enumerate() {
            choice[p] = CLASSES[d.at(d.k, i)];
        }
        regions.push(d.report(m, scores));
    }
    let summary_material = (!specular.is_empty()).then(|| material.report(&specular, scores));
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
    summary.material = summary_material;
    Some(Selection { choice, isotropic: iso_m, anisotropic: aniso_m, summary })
}

/// The classes in order of complexity, as indices of [`decide`]'s arrays.
const CLASSES: [u8; 4] = [DIFFUSE, ISOTROPIC, ANISOTROPIC, TABULATED];

/// The class (index into [`CLASSES`]) that class `k` uses at the `i`-th
/// member, given each simpler class's stand-ins: the table where it stands
/// in.
fn class_at(stand_in: &[Vec<bool>; 3], k: usize, i: usize) -> usize {
    if k < 3 && stand_in[k][i] { 3 } else { k }
}

/// One set of points' evidence and the class it chose.
struct Decision {
    /// Index into [`CLASSES`].
    k: usize,
    /// Per class, the sum of its scores over the members (the table's at
    /// its stand-ins).
    class_sse: [f64; 4],
    /// Per class, how far its sum may lie above the best's.
    margin: [f64; 4],
    /// Per simpler class, the members where the table stands in.
    stand_in: [Vec<bool>; 3],
    /// The noise's sum over the scored samples, and its deviation.
    noise: f64,
    sd: f64,
    /// Whether the class is the material's, the region having too few
    /// scored points of its own.
    from_material: bool,
}

impl Decision {
    /// The class (index into [`CLASSES`]) that class `k` uses at the
    /// `i`-th member.
    fn at(&self, k: usize, i: usize) -> usize {
        class_at(&self.stand_in, k, i)
    }

    fn report(&self, m: &[usize], scores: &Scores) -> RegionChoice {
        let noise = self.noise;
        let ratio = |x: f64| (x.is_finite() && noise > 0.0).then(|| (x / noise).sqrt() as f32);
        let margin = |k: usize| (self.class_sse[k].is_finite() && noise > 0.0).then(|| (self.margin[k] / noise) as f32);
        let stand_ins = |k: usize| self.stand_in[k].iter().filter(|&&x| x).count();
        RegionChoice {
            points: m.len(),
            samples: m.iter().map(|&p| scores.n[p] as u64).sum(),
            ratio: [ratio(self.class_sse[1]), ratio(self.class_sse[2]), ratio(self.class_sse[3])],
            resolution: if noise > 0.0 { (self.sd / noise) as f32 } else { 0.0 },
            margin: [margin(1), margin(2), margin(3)],
            stand_ins: [stand_ins(1), stand_ins(2)],
            tabulated_points: if self.k < 3 { stand_ins(self.k) } else { 0 },
            chosen: CLASSES[self.k],
            diffuse_ratio: ratio(self.class_sse[0]),
            diffuse_margin: margin(0),
            diffuse_stand_ins: stand_ins(0),
            from_material: self.from_material,
        }
    }
}

/// The class the points `m` choose, each class `k` predicted by
/// `predictor[k]` of `scores` (the table's standing in where the class
/// fails as an outlier); `fallback` is the class of a set with fewer than
/// [`MIN_SCORED_POINTS`] scored points (the table where there is none).
fn decide(scores: &Scores, m: &[usize], predictor: &[usize; 4], fallback: Option<usize>) -> Decision {
    let sum = |f: &dyn Fn(usize) -> f64| m.iter().map(|&p| f(p)).sum::<f64>();
    let noise = sum(&|p| scores.noise_ss[p]);
    let sd = (2.0 * sum(&|p| scores.noise_ss2[p])).sqrt();
    let table = predictor[3];
    let stand_in: [Vec<bool>; 3] = std::array::from_fn(|k| stand_ins(scores, m, predictor[k], table));
    let at = |k: usize, i: usize| predictor[class_at(&stand_in, k, i)];
    let class_sse: [f64; 4] =
        std::array::from_fn(|k| m.iter().enumerate().map(|(i, &p)| scores.sse(at(k, i), p)).sum());
    let best = class_sse.iter().copied().filter(|x| x.is_finite()).fold(f64::INFINITY, f64::min);
    let best_k = class_sse.iter().position(|&x| x == best).unwrap_or(3);
    let margin: [f64; 4] = std::array::from_fn(|k| {
        let noise_sd =
            2.0 * m.iter().enumerate().map(|(i, &p)| scores.pair(p, at(k, i), at(best_k, i))).sum::<f64>().sqrt();
        let diff = m
            .iter()
            .enumerate()
            .filter(|&(_, &p)| scores.n[p] > 0)
            .map(|(i, &p)| scores.sse(at(k, i), p) - scores.sse(at(best_k, i), p));
        NOISE_SIGMAS * noise_sd.max(paired_sd(diff))
    });
    let mut d = Decision { k: 3, class_sse, margin, stand_in, noise, sd, from_material: false };
    // Simplest first; a class unusable at any member is out. A region
    // with too few scored points for its tests takes the material's class.
    let scored = m.iter().filter(|&&p| scores.n[p] > 0).count();
    d.k = if noise > 0.0 && (scored >= MIN_SCORED_POINTS || fallback.is_none()) {
        (0..4).position(|k| d.class_sse[k].is_finite() && d.class_sse[k] <= best + d.margin[k]).unwrap_or(3)
    } else {
        d.from_material = fallback.is_some();
        fallback.unwrap_or(3)
    };
    d
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

/// The region's members (`m`) where the predictor `a` misses its scored
/// samples so much worse than the table that the table stands in for it:
/// the point's excess over the table's score lies beyond the noise's
/// [`NOISE_SIGMAS`] deviations of that difference at the point, and is an
/// outlier among the members' excesses (beyond the median by
/// [`outlier_z`] robust deviations, `1.4826` times the median absolute
/// deviation). An analytic shape shared by a cluster can fail at a few of
/// its points (a lobe sharper than the lights' spacing whose peak a
/// point's amplitude turns into a spike); a region's sum that a few such
/// points decide says nothing about the rest, and those points are better
/// served by their tables whatever the region chooses.
fn stand_ins(scores: &Scores, m: &[usize], a: usize, table: usize) -> Vec<bool> {
    let excess = |p: usize| scores.sse(a, p) - scores.sse(table, p);
    let mut d: Vec<f64> =
        m.iter().filter(|&&p| scores.n[p] > 0).map(|&p| excess(p)).filter(|x| x.is_finite()).collect();
    if d.len() < MIN_SCORED_POINTS {
        return vec![false; m.len()];
    }
    let median = |v: &mut [f64]| {
        v.sort_by(f64::total_cmp);
        let h = v.len() / 2;
        if v.len() % 2 == 1 { v[h] } else { 0.5 * (v[h - 1] + v[h]) }
    };
    let med = median(&mut d);
    let mut dev: Vec<f64> = d.iter().map(|x| (x - med).abs()).collect();
    let spread = 1.4826 * median(&mut dev);
    let z = outlier_z(d.len());
    m.iter()
        .map(|&p| {
            let e = excess(p);
            scores.n[p] > 0
                && e.is_finite()
                && e - med > z * spread
                && e > NOISE_SIGMAS * 2.0 * scores.pair(p, a, table).sqrt()
        })
        .collect()
}

/// The chance that any of a region's points counts as an outlier when the
/// excesses are Gaussian: the same one-sided 2% as [`NOISE_SIGMAS`], shared
/// among the points.
const OUTLIER_CHANCE: f64 = 0.0228;

/// The standard normal's upper quantile at `OUTLIER_CHANCE / n` (a
/// Bonferroni bound over `n` points): 2.0 for one point, 3.5 for 100, 4.1
/// for 1,000.
fn outlier_z(n: usize) -> f64 {
    let p = OUTLIER_CHANCE / n.max(1) as f64;
    // Bisection on the upper tail, which falls monotonically.
    let (mut lo, mut hi) = (0.0f64, 40.0f64);
    for _ in 0..100 {
        let mid = 0.5 * (lo + hi);
        if upper_tail(mid) > p { lo = mid } else { hi = mid }
    }
    0.5 * (lo + hi)
}

/// `P(Z > z)` for a standard normal `Z`, `z >= 0`: `erfc(z / sqrt 2) / 2`
/// with erfc from Abramowitz and Stegun 7.1.26 (absolute error below
/// 1.5e-7).
fn upper_tail(z: f64) -> f64 {
    let x = z / std::f64::consts::SQRT_2;
    let t = 1.0 / (1.0 + 0.327_591_1 * x);
    let poly =
        t * (0.254_829_592 + t * (-0.284_496_736 + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    0.5 * poly * (-x * x).exp()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `n` points in one cluster, all specular, 200 samples each with
    /// noise variance 1 (cosine-weighted).
    fn maps(n: usize) -> PointMaps {
        PointMaps::alike(n)
    }

    /// Scores whose ratios^2 per point are `iso`, `aniso` and `table`
    /// (sum of squares over the noise's sum), the diffuse part alone
    /// missing a lobe by 100 noise variances per sample.
    fn scored(n: usize, iso: f64, aniso: f64, table: f64) -> Scores {
        let k = 200.0;
        Scores {
            on: ScoredOn::HeldOutSteps,
            models: vec![AnalyticModel::CookTorrance, AnalyticModel::GgxAniso],
            model_sse: vec![vec![iso * k; n], vec![aniso * k; n]],
            table_sse: vec![table * k; n],
            diffuse_sse: vec![100.0 * k; n],
            n: vec![200; n],
            noise_ss: vec![k; n],
            noise_ss2: vec![k; n],
            pair_var: pairs(n, 4, k),
        }
    }

    /// Pair variances for `n` points and `w` predictors where every
    /// difference of two scores moves by `sqrt(2 k)` per point from the
    /// noise, as each score does.
    fn pairs(n: usize, w: usize, k: f64) -> Vec<f64> {
        (0..n).flat_map(|_| (0..w * w).map(move |i| if i % (w + 1) == 0 { 0.0 } else { k / 2.0 })).collect()
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
    fn a_difference_that_a_few_points_decide_does_not_buy_the_table_for_the_region() {
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
        // The region keeps the lobe; the two points where it fails keep
        // their tables.
        let sel = select(&maps(n), &vec![0; n], 1, &s).unwrap();
        assert_eq!(&sel.choice[..2], &[TABULATED; 2]);
        assert!(sel.choice[2..].iter().all(|&c| c == ANISOTROPIC), "{:?}", sel.choice);
        let r = &sel.summary.regions[0];
        assert_eq!((r.chosen, r.tabulated_points, r.stand_ins[1]), (ANISOTROPIC, 2, 2));
    }

    #[test]
    fn a_simple_class_that_fails_at_a_few_points_is_kept_only_where_it_holds() {
        // 40 points where the isotropic lobe predicts as well as the table,
        // but at three of them it puts a spike where a held-out light
        // falls: 10^4 noise variances. Its total is 250 times the table's,
        // and the points' spread of the difference is about as large as
        // the total: the spikes are the whole difference.
        let n = 40;
        let mut s = scored(n, 1.0, 1.1, 1.0);
        for p in [3, 17, 31] {
            s.model_sse[0][p] = 1e4 * 200.0;
            s.model_sse[1][p] = 1e4 * 200.0;
        }
        let sel = select(&maps(n), &vec![0; n], 1, &s).unwrap();
        for p in 0..n {
            let expected = if [3, 17, 31].contains(&p) { TABULATED } else { ISOTROPIC };
            assert_eq!(sel.choice[p], expected, "point {p}");
        }
        // The region's ratios count the table at the spikes.
        let r = &sel.summary.regions[0];
        assert!((r.ratio[0].unwrap() - 1.0).abs() < 1e-6, "{:?}", r.ratio);
        assert_eq!(r.stand_ins, [3, 3]);
    }

    #[test]
    fn a_broad_spread_of_differences_has_no_stand_ins() {
        // The table's advantage varies smoothly from point to point (a
        // lobe missed by every class, by more or less): no point is an
        // outlier, whatever the noise says of each one alone.
        let n = 60;
        let mut s = scored(n, 50.0, 40.0, 40.0);
        for p in 0..n {
            let x = (p as f64 + 0.5) / n as f64;
            s.model_sse[1][p] = 200.0 * (40.0 + 20.0 * (x - 0.5));
        }
        let sel = select(&maps(n), &vec![0; n], 1, &s).unwrap();
        assert_eq!(sel.summary.regions[0].stand_ins[1], 0);
    }

    #[test]
    fn the_outlier_threshold_is_the_normal_quantile_shared_among_the_points() {
        // One point: the one-sided 2.28% quantile, 2.0.
        assert!((outlier_z(1) - 2.0).abs() < 2e-3, "{}", outlier_z(1));
        // P(Z > 3.5) = 2.33e-4 (about 2.28% / 100); P(Z > 4.08) = 2.25e-5.
        assert!((outlier_z(100) - 3.5).abs() < 0.02, "{}", outlier_z(100));
        assert!((outlier_z(1000) - 4.08).abs() < 0.02, "{}", outlier_z(1000));
        assert!((upper_tail(0.0) - 0.5).abs() < 1e-6 && (upper_tail(1.0) - 0.158_655).abs() < 1e-6);
    }

    /// Clear point `p`'s scores: none of its samples was held out.
    fn unscored(s: &mut Scores, p: usize) {
        (s.n[p], s.noise_ss[p], s.noise_ss2[p], s.model_sse[0][p], s.model_sse[1][p], s.table_sse[p]) =
            (0, 0.0, 0.0, 0.0, 0.0, 0.0);
        s.diffuse_sse[p] = 0.0;
    }

    #[test]
    fn a_material_without_evidence_keeps_the_table() {
        let mut s = scored(3, 1.0, 1.0, 2.0);
        (0..3).for_each(|p| unscored(&mut s, p));
        assert_eq!(chosen(&s, 3), TABULATED);
        let sel = select(&maps(3), &[0; 3], 1, &s).unwrap();
        assert!(!sel.summary.regions[0].from_material);
    }

    #[test]
    fn a_region_without_evidence_takes_the_materials_class() {
        // Two regions; the second's points were all left out of the
        // choice's refit. The first's evidence (the isotropic lobe as good
        // as the table, far beyond the noise better than the diffuse
        // part) is the material's, and the second takes its class rather
        // than the most complex one.
        let n = 10;
        let mut s = scored(n, 1.0, 1.0, 1.0);
        (5..n).for_each(|p| unscored(&mut s, p));
        let cluster = [0, 0, 0, 0, 0, 1, 1, 1, 1, 1];
        let sel = select(&maps(n), &cluster, 2, &s).unwrap();
        assert!(sel.choice.iter().all(|&c| c == ISOTROPIC), "{:?}", sel.choice);
        let r = &sel.summary.regions;
        assert_eq!((r[0].from_material, r[1].from_material), (false, true));
        assert_eq!(r[1].samples, 0);
        assert_eq!(sel.summary.material.as_ref().map(|m| (m.points, m.chosen)), Some((n, ISOTROPIC)));
        // With a better table in the first region, both take the table.
        let mut s2 = scored(n, 1.5, 1.5, 1.0);
        (5..n).for_each(|p| unscored(&mut s2, p));
        let sel = select(&maps(n), &cluster, 2, &s2).unwrap();
        assert!(sel.choice.iter().all(|&c| c == TABULATED), "{:?}", sel.choice);
    }

    #[test]
    fn a_lobe_the_noise_cannot_see_is_not_modelled() {
        // 10 points x 200 samples: a lobe whose whole contribution to the
        // scored samples is 0.02 noise variances per sample (0.6 of the
        // noise's deviation of the difference) buys nothing: diffuse.
        let mut s = scored(10, 1.0, 1.0, 1.0);
        s.diffuse_sse = vec![1.02 * 200.0; 10];
        assert_eq!(chosen(&s, 10), DIFFUSE);
        // A lobe worth 0.2 noise variances per sample is 6 deviations:
        // the simplest class that models it.
        s.diffuse_sse = vec![1.2 * 200.0; 10];
        assert_eq!(chosen(&s, 10), ISOTROPIC);
    }

    #[test]
    fn a_region_of_too_few_scored_points_takes_the_materials_class() {
        // Region 0: ten points where the isotropic lobe predicts as well
        // as the table. Region 1: five points, two of them scored; the
        // diffuse part misses the lobe at one by 300 noise variances per
        // sample and fits the other. The two points' spread is as large as
        // their sum, which alone would keep the diffuse part; the region
        // takes the material's class.
        let n = 15;
        let mut s = scored(n, 1.0, 1.0, 1.0);
        (12..n).for_each(|p| unscored(&mut s, p));
        s.diffuse_sse[10] = 300.0 * 200.0;
        s.diffuse_sse[11] = 200.0;
        let d = [s.diffuse_sse[10] - s.table_sse[10], s.diffuse_sse[11] - s.table_sse[11]];
        assert!(
            d.iter().sum::<f64>() <= NOISE_SIGMAS * paired_sd(d.into_iter()),
            "the spread alone admits the diffuse part"
        );
        let cluster: Vec<u32> = (0..n).map(|p| u32::from(p >= 10)).collect();
        let sel = select(&maps(n), &cluster, 2, &s).unwrap();
        assert!(sel.choice.iter().all(|&c| c == ISOTROPIC), "{:?}", sel.choice);
        assert!(sel.summary.regions[1].from_material && !sel.summary.regions[0].from_material);
    }

    #[test]
    fn glints_in_a_diffuse_region_keep_their_tables() {
        // 40 matte points, three of them with a glint the diffuse part
        // misses by 10^3 noise variances per sample.
        let n = 40;
        let mut s = scored(n, 1.0, 1.0, 1.0);
        s.diffuse_sse = vec![1.0 * 200.0; n];
        for p in [5, 20, 33] {
            s.diffuse_sse[p] = 1e3 * 200.0;
        }
        let sel = select(&maps(n), &vec![0; n], 1, &s).unwrap();
        for p in 0..n {
            let expected = if [5, 20, 33].contains(&p) { TABULATED } else { DIFFUSE };
            assert_eq!(sel.choice[p], expected, "point {p}");
        }
        let r = &sel.summary.regions[0];
        assert_eq!((r.diffuse_stand_ins, r.tabulated_points), (3, 3));
        assert!((r.diffuse_ratio.unwrap() - 1.0).abs() < 1e-6, "{r:?}");
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
        let n = 7;
        let mut m = maps(n);
        m.flags[6] = point_flag::NO_SPECULAR;
        let cluster = [0, 0, 0, 1, 1, 1, u32::MAX];
        let mut s = scored(n, 1.0, 1.0, 1.0);
        // Region 1's analytic fits miss by far more than noise.
        for p in 3..6 {
            s.model_sse[0][p] *= 3.0;
            s.model_sse[1][p] *= 3.0;
        }
        let sel = select(&m, &cluster, 2, &s).unwrap();
        assert_eq!(sel.choice, vec![ISOTROPIC, ISOTROPIC, ISOTROPIC, TABULATED, TABULATED, TABULATED, DIFFUSE]);
        assert_eq!(sel.summary.points, [1, 3, 0, 3]);
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
        s.pair_var = pairs(n, 6, 200.0);
        let sel = select(&maps(n), &vec![0; n], 1, &s).unwrap();
        assert_eq!((sel.isotropic, sel.anisotropic), (AnalyticModel::CookTorrance, AnalyticModel::GgxAniso));
        assert_eq!(sel.choice[0], TABULATED);
        // Without the microfacet fits there is nothing to choose among.
        s.models = vec![AnalyticModel::WardIso, AnalyticModel::WardAniso];
        s.model_sse.drain(..2);
        assert!(select(&maps(n), &vec![0; n], 1, &s).is_none());
    }
}
