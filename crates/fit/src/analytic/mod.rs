//! Analytic model fits: Phong, isotropic and anisotropic Ward, Lafortune,
//! Cook-Torrance, Ashikhmin-Shirley, anisotropic GGX, He et al. and
//! anisotropic Beckmann, each fitted to the measured samples.
//!
//! **Per cluster shape, per point amplitudes.** Points are clustered by
//! their NDF (the descriptors of [`crate::synth::descriptor`]); each
//! cluster gets one set of shape parameters (roughness, orientation,
//! exponents, Fresnel index), and each point its own diffuse and specular
//! amplitudes per channel, which enter every model linearly and are solved
//! in closed form. The shape is found by Levenberg-Marquardt
//! (`levenberg-marquardt` crate, with `scale_diag` off as the design notes
//! found necessary for the rotation angle) on the samples of up to
//! [`POINTS_PER_CLUSTER`] member points, with the amplitudes projected out
//! at every evaluation (variable projection, Golub and Pereyra 1973).
//! An anisotropic lobe's orientation is then the point's own where the
//! point's samples say so beyond the noise ([`turned_amplitudes`]).
//!
//! **Objective.** The cosine-weighted L2 error of Ngan et al. (2005),
//! `sum ((f_model - rho) cos(theta_i))^2`, on the luminance.
//!
//! **Start.** Every shape starts from the slope moments of the cluster's
//! mean NDF ([`shape::Moments`]), converted to each model's parameters, and
//! the median fitted Fresnel index; or, given a prior fit of the same model
//! (the model choice's refit is given the main fit), from the prior's shape
//! at the cluster's first member with a lobe.

pub mod shape;

use std::time::Instant;

use brdf::model::{AsGeometry, AshikhminShirley};
use brdf::params::AnalyticModel;
use glam::Vec3;
use levenberg_marquardt::LevenbergMarquardt;
use nalgebra::DVector;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::context::FitContext;
use crate::lsq::{Numeric, Step};
use crate::partial::{Sample, lum, point_flag};
use crate::points::{PointMaps, gather};
use crate::samples::SampleStore;
use crate::settings::FitSettings;
use shape::Moments;

/// Member points whose samples enter a cluster's shape fit.
pub const POINTS_PER_CLUSTER: usize = 24;
/// Samples per member point in the shape fit.
const SAMPLES_PER_POINT: usize = 96;
/// Samples per point for the per-point amplitudes and residuals.
const AMPLITUDE_SAMPLES: usize = 256;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AnalyticSettings {
    pub models: Vec<AnalyticModel>,
    pub clusters: u32,
    pub seed: u64,
    /// The model choice scores each class on every k-th gantry step, left
    /// out of a second fit of every stage (`crate::select`); `None`, or a
    /// plan too short to spare them, scores on the fit's own samples.
    #[serde(default = "default_choice_holdout")]
    pub choice_holdout_every: Option<u32>,
}

/// Every 8th step: an eighth of the lights, in 4 or more steps for the
/// presets' plans, sparing the fit most of its data.
pub const CHOICE_HOLDOUT_EVERY: u32 = 8;

fn default_choice_holdout() -> Option<u32> {
    Some(CHOICE_HOLDOUT_EVERY)
}

impl Default for AnalyticSettings {
    fn default() -> Self {
        Self {
            models: AnalyticModel::ALL.to_vec(),
            clusters: 32,
            seed: 7,
            choice_holdout_every: default_choice_holdout(),
        }
    }
}

/// One model fitted over the grid.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelFit {
    pub model: AnalyticModel,
    /// `n_points x model.n_params()`.
    pub params: Vec<f32>,
    /// Per point: RMS cosine-weighted luminance residual; `None` where the
    /// model could not be built from the fitted parameters (outside its
    /// domain), so the point has no usable fit of this model.
    pub residual: Vec<Option<f32>>,
    pub seconds: f64,
}

/// What the fits share: the clusters, and each point's evaluation samples
/// where they are kept.
#[derive(Clone, Debug)]
pub struct Evidence {
    /// Cluster of each point (`u32::MAX` for points without specular).
    pub cluster: Vec<u32>,
    pub clusters: usize,
    samples: Vec<Vec<Sample>>,
    view: Vec<Vec3>,
}

impl Evidence {
    /// Each point's evaluation samples ([`point_evidence`]) and view
    /// direction, where [`fit_models`] was asked to keep them; else empty.
    pub fn samples(&self) -> (&[Vec<Sample>], &[Vec3]) {
        (&self.samples, &self.view)
    }
}

fn stride_sample(all: &[Sample], n: usize) -> Vec<Sample> {
    if all.len() <= n {
        return all.to_vec();
    }
    let step = all.len() as f32 / n as f32;
    (0..n).map(|k| all[(k as f32 * step) as usize]).collect()
}

/// One point's evaluation samples (up to [`AMPLITUDE_SAMPLES`], spread
/// over its lights) and view direction.
pub fn point_evidence(ctx: &FitContext, store: &SampleStore, p: usize, fit: &FitSettings) -> (Vec<Sample>, Vec3) {
    let ps = gather(ctx, store, p, fit);
    (stride_sample(&ps.samples, AMPLITUDE_SAMPLES), ps.o)
}

/// Cluster the points with a specular lobe by their tables; the evidence
/// holds no samples.
pub fn clusters(maps: &PointMaps, settings: &AnalyticSettings) -> Evidence {
    let n = maps.len();
    let eligible: Vec<usize> = (0..n).filter(|&p| maps.flags[p] & point_flag::NO_SPECULAR == 0).collect();
    let mut cluster = vec![u32::MAX; n];
    let mut clusters = 0;
    if !eligible.is_empty() {
        clusters = (settings.clusters as usize).clamp(1, eligible.len());
        let assign = crate::synth::cluster::by_table(&maps.tables, &eligible, 32, clusters, settings.seed);
        for (k, &p) in eligible.iter().enumerate() {
            cluster[p] = assign[k];
        }
    }
    Evidence { cluster, clusters, samples: Vec::new(), view: Vec::new() }
}

/// [`clusters`] with every point's evaluation samples held, for
/// [`fit_model`] (tests and small grids; the pipeline's [`fit_models`]
/// reads them a chunk at a time).
pub fn evidence(
    ctx: &FitContext,
    store: &SampleStore,
    maps: &PointMaps,
    fit: &FitSettings,
    settings: &AnalyticSettings,
) -> Evidence {
    let (samples, view) = (0..maps.len()).into_par_iter().map(|p| point_evidence(ctx, store, p, fit)).unzip();
    Evidence { samples, view, ..clusters(maps, settings) }
}

/// Points whose evaluation samples [`fit_models`] gathers at a time: 46 MB
/// of samples at 256 a point, where all of a grid's at once are 7 GB at
/// the talk's 800 x 800 points.
pub const EVIDENCE_CHUNK: usize = 4096;

/// What [`fit_models`] is asked for besides the fits.
pub struct FitModelsOptions<'a> {
    /// Per model, an earlier fit of it to start the shapes from
    /// ([`fit_model`]'s `prior`).
    pub prior: Option<&'a [ModelFit]>,
    /// Keep every point's evaluation samples in the evidence (the model
    /// choice scores on them when the plan cannot spare held-out steps).
    pub keep_samples: bool,
    /// Points gathered at a time ([`EVIDENCE_CHUNK`] in the pipeline).
    pub chunk: usize,
    pub stop: &'a dyn Fn() -> bool,
    /// Called with the work done: 1 after each model's shapes, the number
    /// of points after each chunk (`models + points` in all).
    pub advance: &'a dyn Fn(u64),
}

impl std::fmt::Debug for FitModelsOptions<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FitModelsOptions")
            .field("prior", &self.prior.map(|p| p.len()))
            .field("keep_samples", &self.keep_samples)
            .field("chunk", &self.chunk)
            .finish_non_exhaustive()
    }
}

/// Fit every model of `settings` over the grid, as [`fit_model`] does on
/// evidence holding every point's samples, reading each point's samples
/// from the store ([`point_evidence`]) a chunk of points at a time and
/// fitting every model to them before the next: the fits are the same to
/// the bit. `None` if `stop` said so.
pub fn fit_models(
    ctx: &FitContext,
    store: &SampleStore,
    maps: &PointMaps,
    fit: &FitSettings,
    settings: &AnalyticSettings,
    opts: FitModelsOptions,
) -> Option<(Vec<ModelFit>, Evidence)> {
    let mut ev = clusters(maps, settings);
    let n = maps.len();
    // The shape fits' members, gathered once for every model.
    let members = cluster_members(&ev);
    let mut wanted: Vec<usize> = settings
        .models
        .iter()
        .flat_map(|&model| members.iter().flat_map(move |m| chosen_members(m, shape_sampling(model).0)))
        .collect();
    wanted.sort_unstable();
    wanted.dedup();
    let gathered: std::collections::HashMap<usize, (Vec<Sample>, Vec3)> =
        wanted.into_par_iter().map(|p| (p, point_evidence(ctx, store, p, fit))).collect();
    let member_samples = |p: usize| {
        let (s, o) = &gathered[&p];
        (s.as_slice(), *o)
    };
    let mut shapes = Vec::with_capacity(settings.models.len());
    for &m in &settings.models {
        if (opts.stop)() {
            return None;
        }
        let t = Instant::now();
        let prior = opts.prior.and_then(|p| p.iter().find(|f| f.model == m));
        shapes.push((ModelShapes::fit(m, maps, &members, prior, member_samples), t.elapsed().as_secs_f64()));
        (opts.advance)(1);
    }
    drop(gathered);
    // Per model, the fit as its chunks are appended.
    let mut fits: Vec<ModelFit> = shapes.iter().map(|(s, _)| s.empty(n)).collect();
    let step = opts.chunk.max(1);
    for lo in (0..n).step_by(step) {
        if (opts.stop)() {
            return None;
        }
        let hi = (lo + step).min(n);
        let chunk: Vec<(Vec<Sample>, Vec3)> =
            (lo..hi).into_par_iter().map(|p| point_evidence(ctx, store, p, fit)).collect();
        for ((s, seconds), out) in shapes.iter_mut().zip(&mut fits) {
            let t = Instant::now();
            let points: Vec<_> = (lo..hi)
                .into_par_iter()
                .map(|p| {
                    let (samples, o) = &chunk[p - lo];
                    s.point(maps, &ev, p, samples, *o)
                })
                .collect();
            s.append(out, points);
            *seconds += t.elapsed().as_secs_f64();
        }
        if opts.keep_samples {
            for (s, o) in chunk {
                ev.samples.push(s);
                ev.view.push(o);
            }
        }
        (opts.advance)((hi - lo) as u64);
    }
    for ((_, seconds), f) in shapes.iter().zip(&mut fits) {
        f.seconds = *seconds;
    }
    Some((fits, ev))
}

fn rms_residual(samples: &[Sample], o: Vec3, f: impl Fn(Vec3, Vec3) -> f32) -> f32 {
    rms_residual_by(samples, |j| f(samples[j].i, o))
}

/// [`rms_residual`] with the model's luminance given per sample index.
fn rms_residual_by(samples: &[Sample], f: impl Fn(usize) -> f32) -> f32 {
    let ss: f64 = samples.iter().enumerate().map(|(j, x)| (((f(j) - lum(x.rho)) * x.i.z) as f64).powi(2)).sum();
    (ss / samples.len().max(1) as f64).sqrt() as f32
}

/// Largest specular amplitude of a model whose `ks` is a reflectance:
/// Cook-Torrance's and He's multiply the exact Fresnel reflectance, Ward's,
/// the modified Phong's and Ashikhmin-Shirley's are the lobe's albedo or
/// Fresnel reflectance, and above 1 a surface reflects more light than it
/// receives. Without a bound, a lobe sharper than the lights' spacing can
/// be fitted as a narrower lobe with a larger amplitude, which predicts
/// the lights it saw and blazes at the peaks the rig never hit.
pub const MAX_KS: f64 = 1.0;

/// The bound on a model's specular amplitude given its shape. GGX and
/// Beckmann carry the Fresnel term relative to normal incidence,
/// `ks F(theta) / F(0)`, which grows toward grazing by up to `1 / F(0)`
/// (25 at index 1.5): with `ks = 1` they reflect more than twice the light
/// they receive at a 60 degree view (`brdf`'s energy tests show it), and at
/// a grazing view a sharp lobe approaches `ks / F(0)`. They conserve energy
/// at every view for `ks <= F(0)`: the reflectance of a smooth interface of
/// their index (0.04 at 1.5, 0.87 at 30, 0.98 at
/// [`brdf::params::MAX_ETA`], a metal's range).
///
/// Lafortune's lobe is not normalised: its amplitude `rho` multiplies
/// `(c(i) . o)^n` with `c(i) = (Cx ix, Cy iy, iz)`, whose length is at most
/// 1 for the fitted `|Cx|, |Cy| < 1` ([`shape::shape`]). Its albedo is then
/// at most `rho` times the integral of `cos^n` over a hemisphere,
/// `2 pi / (n + 1)`, so `rho <= (n + 1) / (2 pi)` conserves energy at every
/// view. Unbounded, a lobe narrower than the lights' spacing took whatever
/// amplitude its tails asked for, and blazed at views the rig never sees:
/// `refl eval` gave Lafortune a render error of 5.9e13 on a balanced
/// capture of `ilm_solo_m_68` (`scripts/eval-all.sh --quality balanced`
/// before this bound; 1.08 with it).
fn max_ks(model: AnalyticModel, shape: &[f32]) -> f64 {
    match model {
        AnalyticModel::Lafortune => {
            shape.get(3).map_or(MAX_KS, |&n| MAX_KS * (n.max(0.0) as f64 + 1.0) / std::f64::consts::TAU)
        }
        AnalyticModel::GgxAniso | AnalyticModel::BeckmannAniso => {
            shape.get(3).map_or(MAX_KS, |&eta| brdf::fresnel::dielectric_f0(eta) as f64)
        }
        _ => MAX_KS,
    }
}

/// Closed-form amplitudes `rho ~ kd bd + ks bs` (weights `cos^2`) per
/// channel with `kd >= 0` and `0 <= ks <= max_ks`; returns `(kd, ks)`.
fn solve_amplitudes(bd: &[f32], bs: &[f32], samples: &[Sample], max_ks: f64) -> ([f32; 3], [f32; 3]) {
    let (mut dd, mut ds, mut ss) = (0.0f64, 0.0f64, 0.0f64);
    let mut rd = [0.0f64; 3];
    let mut rs = [0.0f64; 3];
    for (k, x) in samples.iter().enumerate() {
        let w = (x.i.z as f64).powi(2);
        let (a, b) = (bd[k] as f64, bs[k] as f64);
        dd += w * a * a;
        ds += w * a * b;
        ss += w * b * b;
        for c in 0..3 {
            rd[c] += w * a * x.rho[c] as f64;
            rs[c] += w * b * x.rho[c] as f64;
        }
    }
    let det = dd * ss - ds * ds;
    let mut kd = [0.0f32; 3];
    let mut ks = [0.0f32; 3];
    for c in 0..3 {
        // The objective is convex: its minimum over the box is the free
        // minimum when that lies inside, else the best of the minima along
        // the edges.
        let q = |a: f64, b: f64| a * a * dd + 2.0 * a * b * ds + b * b * ss - 2.0 * a * rd[c] - 2.0 * b * rs[c];
        let along_b = |b: f64| if dd > 0.0 { ((rd[c] - b * ds) / dd).max(0.0) } else { 0.0 };
        let along_a = |a: f64| if ss > 0.0 { ((rs[c] - a * ds) / ss).clamp(0.0, max_ks) } else { 0.0 };
        let mut candidates = vec![(along_b(0.0), 0.0), (0.0, along_a(0.0))];
        if max_ks.is_finite() {
            candidates.push((along_b(max_ks), max_ks));
        }
        if det.abs() > crate::tol::SINGULAR_REL * (dd * ss).max(crate::tol::SINGULAR_ABS) {
            let (a, b) = ((rd[c] * ss - rs[c] * ds) / det, (rs[c] * dd - rd[c] * ds) / det);
            if a >= 0.0 && (0.0..=max_ks).contains(&b) {
                candidates = vec![(a, b)];
            }
        }
        let (a, b) = candidates
            .into_iter()
            .filter(|(a, b)| a.is_finite() && b.is_finite())
            .min_by(|x, y| q(x.0, x.1).total_cmp(&q(y.0, y.1)))
            .unwrap_or((0.0, 0.0));
        kd[c] = a as f32;
        ks[c] = b as f32;
    }
    (kd, ks)
}

/// The specular amplitude the amplitude fits start from.
const AMPLITUDE_START: f32 = 0.05;

/// Fit one point's amplitudes for a model with a given shape, in closed
/// form; Ashikhmin-Shirley's by [`as_amplitudes`].
fn point_amplitudes(model: AnalyticModel, shape: &[f32], samples: &[Sample], o: Vec3) -> (Vec<f32>, Option<f32>) {
    if model == AnalyticModel::AshikhminShirley {
        let Some((params, geometry)) = as_amplitudes(shape, samples, o) else {
            return (vec![0.0; model.n_params()], None);
        };
        let residual = AshikhminShirley::from_params(&params)
            .map(|m| rms_residual_by(samples, |j| lum(m.eval_geometry(geometry[j].as_ref()).to_array())));
        return (params, residual);
    }
    // The specular basis per unit amplitude, from the lobe at a start
    // amplitude.
    let k = lum([AMPLITUDE_START; 3]).max(crate::tol::MIN_KS_START);
    let mut p = vec![0.0f32, 0.0, 0.0, k, k, k];
    p.extend_from_slice(shape);
    let Some(sm) = model.build(&p) else { return (vec![0.0; model.n_params()], None) };
    let bs: Vec<f32> = samples.iter().map(|x| sm.eval(x.i, o).x / k).collect();
    let bd = vec![std::f32::consts::FRAC_1_PI; samples.len()];
    let (kd, ks) = solve_amplitudes(&bd, &bs, samples, max_ks(model, shape));
    let mut params = Vec::with_capacity(model.n_params());
    params.extend_from_slice(&kd);
    params.extend_from_slice(&ks);
    params.extend_from_slice(shape);
    let residual = model.build(&params).map(|m| rms_residual(samples, o, |i, o| lum(m.eval(i, o).to_array())));
    (params, residual)
}

/// Ashikhmin-Shirley's amplitudes at one point, with each sample's
/// [`AshikhminShirley::geometry`] under `shape`: its diffuse term carries
/// `(1 - Rs)` and its specular term Schlick's Fresnel of `Rs`, neither
/// linear in the amplitude, so they are solved by a fixed-point iteration
/// on it (four steps), each the closed-form solve with the bases at the
/// last step's `Rs`. The geometry does not change with the amplitudes: it
/// is found once, not at every step. `None` if `shape` is not the model's.
fn as_amplitudes(shape: &[f32], samples: &[Sample], o: Vec3) -> Option<(Vec<f32>, Vec<Option<AsGeometry>>)> {
    let model = AnalyticModel::AshikhminShirley;
    let with = |rd: f32, rs: f32| {
        let mut p = vec![rd, rd, rd, rs, rs, rs];
        p.extend_from_slice(shape);
        AshikhminShirley::from_params(&p)
    };
    let geometry: Vec<Option<AsGeometry>> = {
        let m = with(0.0, 1.0)?;
        samples.iter().map(|x| m.geometry(x.i, o)).collect()
    };
    let mut ks_prev = [AMPLITUDE_START; 3];
    let mut kd = [0.0f32; 3];
    let mut ks = [0.0f32; 3];
    let mut bd = vec![0.0f32; samples.len()];
    let mut bs = vec![0.0f32; samples.len()];
    let mut k = 1.0;
    for _ in 0..4 {
        k = lum(ks_prev).max(crate::tol::MIN_KS_START);
        // The specular basis per unit amplitude, and the diffuse one as the
        // model with unit `rd` less its specular term.
        let (sm, dm) = (with(0.0, k)?, with(1.0, k)?);
        for (j, g) in geometry.iter().enumerate() {
            let s = sm.eval_geometry(g.as_ref()).x;
            bs[j] = s / k;
            bd[j] = dm.eval_geometry(g.as_ref()).x - s;
        }
        (kd, ks) = solve_amplitudes(&bd, &bs, samples, max_ks(model, shape));
        ks_prev = ks;
    }
    let mut params = Vec::with_capacity(model.n_params());
    params.extend_from_slice(&kd);
    params.extend_from_slice(&ks);
    params.extend_from_slice(shape);
    // The diffuse term is `rd (1 - Rs)` times a shape: the basis above
    // carried `(1 - k)` with the luminance `k` of `Rs`, so the solved
    // coefficient of channel c is `rd_c (1 - Rs_c) / (1 - k)`.
    for c in 0..3 {
        params[c] *= (1.0 - k) / (1.0 - params[3 + c]).max(0.05);
    }
    Some((params, geometry))
}

/// Index of a model's lobe orientation among its shape parameters, for the
/// models that have one.
fn angle_index(model: AnalyticModel) -> Option<usize> {
    match model {
        AnalyticModel::WardAniso
        | AnalyticModel::AshikhminShirley
        | AnalyticModel::GgxAniso
        | AnalyticModel::BeckmannAniso => Some(2),
        _ => None,
    }
}

/// Turns of the lobe tried at each point, degrees from the cluster's: a
/// coarse pass over [`TURN_COARSE_DEG`] in its steps, then a fine one
/// around the best, covering the coarse step; each scored on
/// [`TURN_SAMPLES`] of the point's samples: 19 trials of 64 per point and
/// anisotropic model (574b0e9's 25 trials of 96 took balanced satin's
/// analytic stage to 11.7 s, against 5.6-6.8 s without turns; these take
/// it to 7.7-8.1 s; `capture --quality balanced --sample satin`,
/// `report.json`'s `timings`).
const TURN_COARSE_DEG: (f32, f32) = (20.0, 5.0);
const TURN_FINE_DEG: (f32, f32) = (2.5, 0.5);
const TURN_SAMPLES: usize = 64;

/// [`point_amplitudes`] with the lobe turned to the point: an anisotropic
/// lobe shares its cluster's roughnesses and Fresnel index, but its
/// orientation is the point's own, the one (within
/// [`TURN_COARSE_DEG`]`.0` of the cluster's) whose fit of the point's
/// samples leaves the least residual, where that is less than the
/// cluster's orientation leaves by more than the noise explains
/// ([`turn_beyond_noise`]). A cluster gathers points whose
/// lobes point nearly the same way, not exactly: brushed metal's turns by
/// about a degree per millimetre, satin's weave drifts by 8 degrees over
/// the sample, and a narrow lobe a few degrees off misses its flanks by
/// more than the noise (`refl inspect`'s ratios).
fn turned_amplitudes(model: AnalyticModel, shape: &[f32], samples: &[Sample], o: Vec3) -> (Vec<f32>, Option<f32>) {
    let base = point_amplitudes(model, shape, samples, o);
    let Some(a) = angle_index(model) else { return base };
    if samples.is_empty() || shape.len() <= a {
        return base;
    }
    // The search scores each turn on the shape fit's share of the samples
    // with linear amplitudes (as the shape fit does); only the turn it
    // finds is fitted on them all and tested against the noise.
    let sub = stride_sample(samples, TURN_SAMPLES);
    let sse = |turn: f32| {
        let mut turned = shape.to_vec();
        turned[a] += turn;
        turn_sse(model, &turned, &sub, o)
    };
    let search = |best: &mut (f32, f64), (span, step): (f32, f32)| {
        let centre = best.0;
        let n = (span / step).round() as i32;
        for j in (-n..=n).filter(|&j| j != 0) {
            let turn = centre + (j as f32 * step).to_radians();
            let e = sse(turn);
            if e < best.1 {
                *best = (turn, e);
            }
        }
    };
    let mut best = (0.0f32, sse(0.0));
    search(&mut best, TURN_COARSE_DEG);
    search(&mut best, TURN_FINE_DEG);
    if best.0 == 0.0 {
        return base;
    }
    let mut turned = shape.to_vec();
    turned[a] += best.0;
    let fit = point_amplitudes(model, &turned, samples, o);
    if turn_beyond_noise(model, &base.0, &fit.0, samples, o) { fit } else { base }
}

/// The shape fit's objective at one point ([`ShapeProblem`]'s linear
/// amplitudes): the sum of squared cosine-weighted luminance residuals.
fn turn_sse(model: AnalyticModel, shape: &[f32], samples: &[Sample], o: Vec3) -> f64 {
    let mut p = vec![0.0f32, 0.0, 0.0, 1.0, 1.0, 1.0];
    p.extend_from_slice(shape);
    let Some(m) = model.build(&p) else { return f64::INFINITY };
    let mut r = Vec::with_capacity(samples.len());
    linear_residuals(m.as_ref(), samples, o, max_ks(model, shape), &mut r);
    let e: f64 = r.iter().map(|x| x * x).sum();
    if e.is_finite() { e } else { f64::INFINITY }
}

/// One point's cosine-weighted luminance residuals for the lobe `lm` (built
/// with unit specular amplitude and no diffuse) with the amplitudes solved
/// in closed form, `ks` at most `bound`: the shape fit's residuals for the
/// models linear in their amplitudes.
fn linear_residuals(lm: &dyn brdf::Brdf, samples: &[Sample], o: Vec3, bound: f64, r: &mut Vec<f64>) {
    let bs: Vec<f32> = samples.iter().map(|x| lm.eval(x.i, o).x).collect();
    let bd = vec![std::f32::consts::FRAC_1_PI; samples.len()];
    let (kd, ks) = solve_amplitudes(&bd, &bs, samples, bound);
    let (kd, ks) = (lum(kd), lum(ks));
    for (j, x) in samples.iter().enumerate() {
        r.push(((kd * bd[j] + ks * bs[j] - lum(x.rho)) * x.i.z) as f64);
    }
}

/// Whether the point's own turn (`turned`) fits its samples better than
/// the cluster's orientation (`shared`) by more than the noise can: by
/// [`crate::select::NOISE_SIGMAS`] deviations of the difference of the two
/// sums of squares, `2 sqrt(sum (r_a - r_b)^2 s^2)` (the model choice's
/// test, `crate::select`'s notes). A homogeneous sample's points
/// (`ward`'s) would otherwise each take the turn that fits their noise
/// best, and render the worse for it.
fn turn_beyond_noise(model: AnalyticModel, shared: &[f32], turned: &[f32], samples: &[Sample], o: Vec3) -> bool {
    let (Some(a), Some(b)) = (model.build(shared), model.build(turned)) else { return false };
    let (mut sa, mut sb, mut var) = (0.0f64, 0.0f64, 0.0f64);
    for x in samples {
        let c = x.i.z as f64;
        let y = lum(x.rho) as f64;
        let ra = (lum(a.eval(x.i, o).to_array()) as f64 - y) * c;
        let rb = (lum(b.eval(x.i, o).to_array()) as f64 - y) * c;
        sa += ra * ra;
        sb += rb * rb;
        var += (ra - rb).powi(2) * x.var as f64 * c * c;
    }
    sa - sb > crate::select::NOISE_SIGMAS * 2.0 * var.sqrt()
}

/// The shape fit of one cluster as a least-squares problem in `u`.
struct ShapeProblem<'a> {
    model: AnalyticModel,
    points: Vec<(&'a [Sample], Vec3)>,
    n_res: usize,
}

impl ShapeProblem<'_> {
    fn residuals_at(&self, u: &DVector<f64>) -> DVector<f64> {
        let shape = shape::shape(self.model, u.as_slice());
        let bound = max_ks(self.model, &shape);
        let mut r = Vec::with_capacity(self.n_res);
        let mut p = vec![0.0f32, 0.0, 0.0, 1.0, 1.0, 1.0];
        p.extend_from_slice(&shape);
        let linear = self.model.build(&p);
        for &(samples, o) in &self.points {
            if self.model == AnalyticModel::AshikhminShirley {
                // Amplitudes by fixed-point iteration ([`as_amplitudes`]).
                let fitted = as_amplitudes(&shape, samples, o)
                    .and_then(|(params, geometry)| Some((AshikhminShirley::from_params(&params)?, geometry)));
                match fitted {
                    Some((m, geometry)) => r.extend(
                        samples
                            .iter()
                            .zip(&geometry)
                            .map(|(x, g)| ((lum(m.eval_geometry(g.as_ref()).to_array()) - lum(x.rho)) * x.i.z) as f64),
                    ),
                    None => r.extend(samples.iter().map(|_| 1.0)),
                }
            } else if let Some(lm) = &linear {
                linear_residuals(lm.as_ref(), samples, o, bound, &mut r);
            } else {
                r.extend(samples.iter().map(|_| 1.0));
            }
        }
        crate::lsq::finite_or(DVector::from_vec(r), 1e3)
    }
}

/// Member points per cluster and samples per member in `model`'s shape
/// fit: half of each for the models costly to evaluate.
fn shape_sampling(model: AnalyticModel) -> (usize, usize) {
    if shape::expensive(model) {
        (POINTS_PER_CLUSTER / 2, SAMPLES_PER_POINT / 2)
    } else {
        (POINTS_PER_CLUSTER, SAMPLES_PER_POINT)
    }
}

/// Each cluster's member points whose samples enter its shape fit: up to
/// `per_cluster`, spread over its members.
fn chosen_members(m: &[usize], per_cluster: usize) -> Vec<usize> {
    let step = (m.len() as f32 / per_cluster as f32).max(1.0);
    (0..per_cluster.min(m.len())).map(|j| m[(j as f32 * step) as usize]).collect()
}

/// Each cluster's points, in order.
fn cluster_members(ev: &Evidence) -> Vec<Vec<usize>> {
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); ev.clusters];
    for (p, &c) in ev.cluster.iter().enumerate() {
        if (c as usize) < ev.clusters {
            members[c as usize].push(p);
        }
    }
    members
}

/// One model's shape per cluster, which each point's amplitudes are then
/// fitted with ([`ModelShapes::point`]).
struct ModelShapes {
    model: AnalyticModel,
    shapes: Vec<Vec<f32>>,
    /// The shape given to points without specular.
    default_shape: Vec<f32>,
}

impl ModelShapes {
    /// Fit each cluster's shape to its chosen members' samples
    /// (`samples_of(p)`: point `p`'s evaluation samples and view).
    fn fit<'s>(
        model: AnalyticModel,
        maps: &PointMaps,
        members: &[Vec<usize>],
        prior: Option<&ModelFit>,
        samples_of: impl Fn(usize) -> (&'s [Sample], Vec3) + Sync,
    ) -> Self {
        let n = maps.len();
        let (per_cluster, per_point) = shape_sampling(model);
        let mut etas: Vec<f32> = maps.eta.clone();
        etas.sort_by(|a, b| a.total_cmp(b));
        let eta = etas.get(etas.len() / 2).copied().unwrap_or(1.5);
        let shapes: Vec<Vec<f32>> = members
            .par_iter()
            .map(|m| {
                let start = match m.first() {
                    Some(_) => {
                        // Moments of the members' mean table.
                        let g = maps.tables.grid();
                        let mut mean = brdf::ndf::NdfTable::zeros(g);
                        for &p in m.iter().take(64) {
                            let t = maps.tables.get(p);
                            for c in 0..g.len() {
                                if t.coverage().get(c) {
                                    mean.values_mut()[c] += t.values()[c];
                                    mean.coverage_mut().set(c, true);
                                }
                            }
                        }
                        Moments::of(&mean)
                    }
                    None => Moments { alpha_x: 0.3, alpha_y: 0.3, angle_rad: 0.0 },
                };
                let k = model.n_params();
                // The prior's shape at the first member it gave a specular lobe.
                let from_prior = prior.filter(|f| f.model == model && f.params.len() == n * k).and_then(|f| {
                    let p = *m.iter().find(|&&p| f.params[p * k + 3..p * k + 6].iter().any(|&x| x > 0.0))?;
                    shape::unshape(model, &f.params[p * k + 6..(p + 1) * k])
                });
                let u0 = from_prior.unwrap_or_else(|| shape::init(model, &start, eta));
                let chosen = chosen_members(m, per_cluster);
                let subs: Vec<(Vec<Sample>, Vec3)> = chosen
                    .iter()
                    .map(|&p| {
                        let (s, o) = samples_of(p);
                        (stride_sample(s, per_point), o)
                    })
                    .collect();
                if subs.iter().all(|s| s.0.is_empty()) {
                    return shape::shape(model, &u0);
                }
                let points: Vec<(&[Sample], Vec3)> = subs.iter().map(|(s, o)| (s.as_slice(), *o)).collect();
                let n_res = points.iter().map(|p| p.0.len()).sum();
                let shape_problem = ShapeProblem { model, points, n_res };
                // Forward differences (step 1e-4 in the unconstrained
                // parameters, which are logarithms or angles: a relative step
                // of 1e-4).
                let problem = Numeric::new(
                    |u: &DVector<f64>| shape_problem.residuals_at(u),
                    DVector::from_vec(u0.clone()),
                    Step::Forward(1e-4),
                );
                let (solved, report) =
                    LevenbergMarquardt::new().with_scale_diag(false).with_patience(40).minimize(problem);
                let u = if report.objective_function.is_finite() { solved.u.as_slice().to_vec() } else { u0 };
                shape::shape(model, &u)
            })
            .collect();
        let default_shape =
            shape::shape(model, &shape::init(model, &Moments { alpha_x: 0.3, alpha_y: 0.3, angle_rad: 0.0 }, eta));
        Self { model, shapes, default_shape }
    }

    /// Point `p`'s parameters and residual from its evaluation `samples`
    /// seen from `o`: its cluster's shape (turned to the point where its
    /// samples say so) with its own amplitudes, or its diffuse albedo alone
    /// where it has no specular.
    fn point(&self, maps: &PointMaps, ev: &Evidence, p: usize, samples: &[Sample], o: Vec3) -> (Vec<f32>, Option<f32>) {
        let model = self.model;
        let c = ev.cluster[p] as usize;
        let strided;
        let samples = if shape::expensive(model) {
            strided = stride_sample(samples, 64);
            &strided[..]
        } else {
            samples
        };
        if c < ev.clusters {
            turned_amplitudes(model, &self.shapes[c], samples, o)
        } else {
            // No specular: the diffuse albedo alone.
            let mut params = maps.kd[p].to_vec();
            params.extend_from_slice(&[0.0, 0.0, 0.0]);
            params.extend_from_slice(&self.default_shape);
            let r = model.build(&params).map(|m| rms_residual(samples, o, |i, o| lum(m.eval(i, o).to_array())));
            (params, r)
        }
    }

    /// A fit of no points yet, with room for `n`.
    fn empty(&self, n: usize) -> ModelFit {
        let params = Vec::with_capacity(n * self.model.n_params());
        ModelFit { model: self.model, params, residual: Vec::with_capacity(n), seconds: 0.0 }
    }

    /// Append the next points' [`ModelShapes::point`] to `fit`, in order.
    fn append(&self, fit: &mut ModelFit, points: Vec<(Vec<f32>, Option<f32>)>) {
        for (pp, r) in points {
            fit.params.extend(pp.into_iter().map(|v| if v.is_finite() { v } else { 0.0 }));
            fit.residual.push(r.filter(|r| r.is_finite()));
        }
    }
}

/// Fit `model` over the grid, on evidence holding every point's samples.
/// With `prior` (an earlier fit of the same model over the same grid), each
/// cluster starts from the prior's shape at its first member where that is
/// in the model's domain, instead of from the moments of its tables.
pub fn fit_model(model: AnalyticModel, maps: &PointMaps, ev: &Evidence, prior: Option<&ModelFit>) -> ModelFit {
    let t0 = Instant::now();
    let members = cluster_members(ev);
    let shapes = ModelShapes::fit(model, maps, &members, prior, |p| (ev.samples[p].as_slice(), ev.view[p]));
    let mut fit = shapes.empty(maps.len());
    let points =
        (0..maps.len()).into_par_iter().map(|p| shapes.point(maps, ev, p, &ev.samples[p], ev.view[p])).collect();
    shapes.append(&mut fit, points);
    fit.seconds = t0.elapsed().as_secs_f64();
    fit
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples `rho = kd / pi + ks b_j` on a spread of specular basis
    /// values, all channels alike.
    fn samples(kd: f32, ks: f32) -> (Vec<f32>, Vec<f32>, Vec<Sample>) {
        let bs: Vec<f32> = (0..40).map(|j| (j as f32 * 0.37).sin().abs() * 3.0).collect();
        let bd = vec![std::f32::consts::FRAC_1_PI; bs.len()];
        let s = bs
            .iter()
            .map(|&b| Sample {
                i: Vec3::Z,
                rho: [kd / std::f32::consts::PI + ks * b; 3],
                var: 1e-4,
                channel_var: [1e-4; 3],
                kernel_rad: 0.1,
            })
            .collect();
        (bd, bs, s)
    }

    #[test]
    fn a_prior_fit_gives_each_cluster_its_start() {
        // Two points in one cluster and no samples to fit: the shape is the
        // start. The prior gave point 0 no lobe and point 1 a Beckmann lobe.
        let n = 2;
        let maps = PointMaps::alike(n);
        let ev = Evidence { cluster: vec![0; n], clusters: 1, samples: vec![Vec::new(); n], view: vec![Vec3::Z; n] };
        let model = AnalyticModel::BeckmannAniso;
        let lobe = [0.07f32, 0.21, 0.5, 1.8];
        let mut params = vec![0.2, 0.2, 0.2, 0.0, 0.0, 0.0, 0.3, 0.3, 0.0, 1.5];
        params.extend([0.2, 0.2, 0.2, 0.5, 0.5, 0.5]);
        params.extend(lobe);
        let prior = ModelFit { model, params, residual: vec![None; n], seconds: 0.0 };
        let fit = fit_model(model, &maps, &ev, Some(&prior));
        let k = model.n_params();
        for (a, b) in fit.params[6..k].iter().zip(&lobe) {
            assert!((a - b).abs() < 1e-5, "{:?} against {lobe:?}", &fit.params[6..k]);
        }
        // Without the prior, the start is the tables' moments (empty here).
        let fit = fit_model(model, &maps, &ev, None);
        assert!((fit.params[6] - lobe[0]).abs() > 0.01, "{:?}", &fit.params[..k]);
    }

    /// The rig's view, 45 degrees from the normal.
    fn view_45() -> Vec3 {
        Vec3::new(-(45f32.to_radians().sin()), 0.0, 45f32.to_radians().cos())
    }

    /// Noise-free samples of `b` seen from `o`, lit from a square of
    /// `2 half + 1` by `2 half + 1` directions `step` apart around the
    /// mirror direction.
    fn lit_around_mirror(b: &dyn brdf::Brdf, o: Vec3, half: i32, step: f32) -> Vec<Sample> {
        let mut v = Vec::new();
        for a in -half..=half {
            for e in -half..=half {
                let i = Vec3::new(-o.x + a as f32 * step, e as f32 * step, o.z).normalize();
                v.push(Sample { i, rho: b.eval(i, o).to_array(), var: 1e-8, channel_var: [1e-8; 3], kernel_rad: 0.01 });
            }
        }
        v
    }

    #[test]
    fn each_point_turns_its_clusters_lobe_to_its_own() {
        // A narrow Beckmann lobe (brushed metal's roughnesses) seen from
        // the rig's 45 degree view, lit from a grid of directions around
        // the mirror direction; the point's lobe is turned 8.5 degrees
        // from its cluster's.
        let model = AnalyticModel::BeckmannAniso;
        let o = view_45();
        let cluster = [0.25f32, 0.05, 0.3, 1.8];
        let mut truth = vec![0.02, 0.02, 0.02, 0.05, 0.05, 0.05];
        truth.extend_from_slice(&cluster);
        truth[8] += 8.5f32.to_radians();
        let b = model.build(&truth).unwrap();
        let samples = lit_around_mirror(b.as_ref(), o, 10, 0.03);
        let (_, shared) = point_amplitudes(model, &cluster, &samples, o);
        let (params, turned) = turned_amplitudes(model, &cluster, &samples, o);
        let turn = (params[8] - cluster[2]).to_degrees();
        // The search's fine step is half a degree: the turn is found to
        // within half of it, and the fit is then far better than the
        // cluster's orientation allows.
        assert!((turn - 8.5).abs() <= 0.25 + 1e-3, "turned by {turn} degrees");
        let (shared, turned) = (shared.unwrap(), turned.unwrap());
        assert!(turned < 0.2 * shared, "residual {turned} turned against {shared} shared");
        // Roughnesses and Fresnel index stay the cluster's.
        assert_eq!((params[6], params[7], params[9]), (cluster[0], cluster[1], cluster[3]));
        // The same point measured with noise far above the lobe's flanks:
        // a turn that only fits the noise is not taken.
        let loud: Vec<Sample> = samples
            .iter()
            .enumerate()
            .map(|(j, x)| {
                let e = 1e-3 * ((j as f32 * 12.9898).sin() * 43_758.547).fract();
                let mut rho = b.eval(x.i, o).to_array();
                rho.iter_mut().for_each(|r| *r += e);
                Sample { rho, var: 1e3, ..*x }
            })
            .collect();
        let (params, _) = turned_amplitudes(model, &cluster, &loud, o);
        assert_eq!(params[8], cluster[2], "a turn within the noise");
        // An isotropic model has nothing to turn.
        let ct = [0.2f32, 1.8];
        assert_eq!(
            turned_amplitudes(AnalyticModel::CookTorrance, &ct, &samples, o).0,
            point_amplitudes(AnalyticModel::CookTorrance, &ct, &samples, o).0
        );
    }

    #[test]
    fn a_cluster_whose_lobe_turns_across_it_is_fitted_point_by_point() {
        // Twelve points of one cluster, brushed metal's lobe turning by 20
        // degrees across them (as a cluster of its points does), fitted
        // from the cluster's true shape at its mean orientation.
        let model = AnalyticModel::BeckmannAniso;
        let o = view_45();
        let n = 12;
        let turn = |p: usize| (-10.0 + 20.0 * p as f32 / (n - 1) as f32).to_radians();
        let shape = [0.25f32, 0.05, 0.3, 1.8];
        let samples: Vec<Vec<Sample>> = (0..n)
            .map(|p| {
                let mut q = vec![0.02, 0.02, 0.02, 0.05, 0.05, 0.05];
                q.extend_from_slice(&shape);
                q[8] += turn(p);
                lit_around_mirror(model.build(&q).unwrap().as_ref(), o, 8, 0.04)
            })
            .collect();
        let ev = Evidence { cluster: vec![0; n], clusters: 1, samples, view: vec![o; n] };
        let k = model.n_params();
        let mut start = Vec::new();
        for _ in 0..n {
            start.extend([0.02, 0.02, 0.02, 0.05, 0.05, 0.05]);
            start.extend(shape);
        }
        let prior = ModelFit { model, params: start, residual: vec![None; n], seconds: 0.0 };
        let fit = fit_model(model, &PointMaps::alike(n), &ev, Some(&prior));
        // The turns lie on the search's half-degree steps from the
        // cluster's fitted orientation, so each point's is found to
        // within a quarter degree of its own where the cluster's
        // roughnesses are its true ones; a shared shape fitted to turned
        // members is a little broader, and half a degree is allowed.
        for p in 0..n {
            let got = fit.params[p * k + 8];
            let want = shape[2] + turn(p);
            let d = (got - want).to_degrees();
            assert!(d.abs() <= 0.5, "point {p}: orientation off by {d} degrees");
        }
    }

    #[test]
    fn a_metals_lobe_is_fitted_with_its_reflectance() {
        // Brushed aluminium (the built-in sample's lobe and conductor
        // Fresnel; F(0) 0.92-0.93 per channel) seen from the rig's 45
        // degree view and lit around the mirror direction, noise-free. The
        // fitted Beckmann lobe's amplitude bound `F(0)` of its index must
        // admit the metal's reflectance: with the index held at 30 it
        // stopped at 0.875 and the diffuse part grew to make up the rest.
        let model = AnalyticModel::BeckmannAniso;
        let o = view_45();
        let truth = brdf::model::Microfacet {
            kd: Vec3::splat(0.01),
            ks: Vec3::ONE,
            ndf: brdf::ndf::Beckmann::new(0.25, 0.05, 0.3),
            fresnel: brdf::fresnel::Fresnel::Conductor {
                eta: Vec3::new(1.66, 0.88, 0.52),
                k: Vec3::new(9.2, 6.3, 4.8),
            },
        };
        let samples = lit_around_mirror(&truth, o, 10, 0.03);
        let maps = PointMaps::alike(1);
        let ev = Evidence { cluster: vec![0], clusters: 1, samples: vec![samples], view: vec![o] };
        // Started from the shape with the old bound's index.
        let prior = ModelFit {
            model,
            params: vec![0.05, 0.05, 0.05, 0.8, 0.8, 0.8, 0.25, 0.05, 0.3, 30.0],
            residual: vec![None],
            seconds: 0.0,
        };
        let fit = fit_model(model, &maps, &ev, Some(&prior));
        let p = &fit.params;
        // At the lights' angles (about 22 degrees from the facets) the
        // metal's reflectance is above 0.91 in every channel.
        assert!(p[3..6].iter().all(|&ks| ks > 0.91), "ks {:?} (eta {})", &p[3..6], p[9]);
        assert!(p[0..3].iter().all(|&kd| kd < 0.02), "kd {:?}", &p[0..3]);
    }

    /// [`as_amplitudes`], which evaluates the model through each sample's
    /// geometry found once, gives the amplitudes, to the bit, of the
    /// fixed-point iteration written with the model's own `eval` at every
    /// step.
    #[test]
    fn ashikhmin_shirleys_amplitudes_are_those_of_its_own_evaluation() {
        let model = AnalyticModel::AshikhminShirley;
        let o = view_45();
        let truth = AshikhminShirley {
            rd: Vec3::new(0.4, 0.3, 0.2),
            rs: Vec3::splat(0.08),
            nu: 60.0,
            nv: 20.0,
            angle_rad: 0.3,
        };
        let samples = lit_around_mirror(&truth, o, 6, 0.05);
        let shape = [45.0f32, 25.0, 0.25];
        let mut ks_prev = [AMPLITUDE_START; 3];
        let (mut kd, mut ks, mut k) = ([0.0f32; 3], [0.0f32; 3], 1.0);
        for _ in 0..4 {
            k = lum(ks_prev).max(crate::tol::MIN_KS_START);
            let build = |rd: f32| model.build(&[rd, rd, rd, k, k, k, shape[0], shape[1], shape[2]]).unwrap();
            let (sm, dm) = (build(0.0), build(1.0));
            let bs: Vec<f32> = samples.iter().map(|x| sm.eval(x.i, o).x / k).collect();
            let bd: Vec<f32> = samples.iter().map(|x| dm.eval(x.i, o).x - sm.eval(x.i, o).x).collect();
            (kd, ks) = solve_amplitudes(&bd, &bs, &samples, max_ks(model, &shape));
            ks_prev = ks;
        }
        let rd = [0, 1, 2].map(|c| kd[c] * ((1.0 - k) / (1.0 - ks[c]).max(0.05)));
        let (params, geometry) = as_amplitudes(&shape, &samples, o).unwrap();
        assert_eq!(params, [rd[0], rd[1], rd[2], ks[0], ks[1], ks[2], shape[0], shape[1], shape[2]]);
        assert_eq!(geometry.len(), samples.len());
        let m = model.build(&params).unwrap();
        let direct = rms_residual(&samples, o, |i, o| lum(m.eval(i, o).to_array()));
        assert_eq!(point_amplitudes(model, &shape, &samples, o).1, Some(direct));
    }

    #[test]
    fn amplitudes_inside_the_physical_box_are_recovered_exactly() {
        let (bd, bs, s) = samples(0.3, 0.6);
        let (kd, ks) = solve_amplitudes(&bd, &bs, &s, MAX_KS);
        assert!((kd[0] - 0.3).abs() < 1e-4 && (ks[1] - 0.6).abs() < 1e-5, "{kd:?} {ks:?}");
    }

    #[test]
    fn a_specular_amplitude_above_one_is_held_at_one_and_the_diffuse_refitted() {
        let (bd, bs, s) = samples(0.2, 3.0);
        // An unnormalised lobe (Lafortune's) of exponent 100 may reach
        // (100 + 1) / 2 pi, about 16: it keeps its amplitude of 3.
        let (_, free) = solve_amplitudes(&bd, &bs, &s, max_ks(AnalyticModel::Lafortune, &[-0.9, -0.9, 1.0, 100.0]));
        assert!((free[0] - 3.0).abs() < 1e-4, "{free:?}");
        // At exponent 10 its bound is 11 / 2 pi, about 1.75.
        let bound = max_ks(AnalyticModel::Lafortune, &[-0.9, -0.9, 1.0, 10.0]);
        let (_, held) = solve_amplitudes(&bd, &bs, &s, bound);
        assert!((held[0] as f64 - 11.0 / std::f64::consts::TAU).abs() < 1e-5, "{held:?}");
        let (kd, ks) = solve_amplitudes(&bd, &bs, &s, MAX_KS);
        assert_eq!(ks, [MAX_KS as f32; 3]);
        // With ks at 1 the diffuse term takes what it can of the rest: the
        // least-squares kd for that ks, not the unconstrained 0.2.
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for (j, x) in s.iter().enumerate() {
            num += bd[j] as f64 * (x.rho[0] - bs[j]) as f64;
            den += (bd[j] as f64).powi(2);
        }
        assert!((kd[0] as f64 - num / den).abs() < 1e-4, "{kd:?} against {}", num / den);
        // Negative data give zero amplitudes, never negative ones.
        let (bd, bs, s) = samples(-0.5, -0.1);
        let (kd, ks) = solve_amplitudes(&bd, &bs, &s, MAX_KS);
        assert_eq!((kd, ks), ([0.0; 3], [0.0; 3]));
    }
}
