//! The fit's stages in their one order. Every fit runs through here: the
//! streaming fit beside a capture, `refl fit`, the hold-out refit of
//! `refl eval`, the benchmarks and the test support.
//!
//! 1. **Ingest**: frames become reflectance samples ([`Pipeline::push_dark`],
//!    [`Pipeline::push_shot`]); or a caller hands over a [`SampleStore`] it
//!    made otherwise ([`run_stages`]).
//! 2. **Per point**: diffuse/specular split, partial NDF, masking, `k_s`,
//!    Fresnel ([`crate::points::fit_points`]).
//! 3. **Synthesis** (optional): each point's partial NDF completed from
//!    other points' rotated NDFs, then every completed point refitted with
//!    its completed table ([`synthesis_stage`]). The tables as they were
//!    are kept packed until the fit ends ([`brdf::ndf::PackedTables`]).
//! 4. **Analytic fits** (optional): every analytic model fitted per
//!    point, starting from the points' own tables ([`analytic_stage`]).
//! 5. **Pooling** (optional): the points of one material share one NDF,
//!    estimated from all their samples ([`crate::pooled`]). It runs after
//!    the analytic fits, which start from the tables as they were before
//!    it, so that no second copy of every point's tables is kept for them.
//! 6. **Model choice** (with the analytic fits): stages 2-5 run a second
//!    time without every k-th gantry step (on a quarter of the points of a
//!    large grid, and with only the analytic models the choice weighs), and
//!    each region takes the simplest class that predicts those steps as
//!    well as any ([`crate::select`]).
//!
//! A fit spread over machines runs the same stages: each tile ingests
//! every frame into its own points' samples and fits them
//! ([`TilePipeline`]), and the tiles joined run stages 3-6
//! ([`run_merged`]).
//!
//! Between stages (and between analytic models) the caller's `stop` is
//! polled; a stop ends the run with [`FitError::Stopped`].

use std::time::Instant;

use brdf::ndf::{MaskingOperator, PackedTables, TableSet};
use frame::Frame;
use serde::Serialize;
use setup::PlannedShot;
use thiserror::Error;

use crate::analytic::{AnalyticSettings, Evidence, ModelFit};
use crate::samples::{Census, SampleStore};
use crate::select::Selection;
use crate::settings::StepSet;
use crate::synth::{SynthSettings, SynthStats};
use crate::{FitContext, FitSettings, Ingest, PointMaps, point_flag};

/// The optional stages after the per-point fit.
#[derive(Clone, Debug, Default)]
pub struct Stages {
    /// Pool the points of a material into one NDF (`crate::pooled`).
    pub pool: Option<crate::pooled::PoolSettings>,
    pub synth: Option<SynthSettings>,
    pub analytic: Option<AnalyticSettings>,
    /// Return the sample store with the result (hold-out prediction,
    /// tests); otherwise it is freed as soon as the last stage is done.
    pub keep_samples: bool,
}

/// Wall time of each stage, seconds.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Timings {
    /// Ingesting frames (overlaps the capture when streaming).
    pub ingest_s: f64,
    /// From the last frame to the end of the per-point stage.
    pub points_s: f64,
    /// The LED drift correction after the last frame (`crate::drift`;
    /// counted in `points_s` too).
    pub drift_s: f64,
    /// Pooling the points of each material (`crate::pooled`).
    pub pool_s: f64,
    /// Synthesis and the refit of the points it completed.
    pub synthesis_s: f64,
    /// Of `synthesis_s`, the refit of the completed points.
    pub refit_s: f64,
    pub analytic_s: f64,
    pub selection_s: f64,
}

/// The per-point fit as it was before synthesis replaced its tables.
#[derive(Clone, Debug, PartialEq)]
pub struct PartialMaps {
    pub tables: TableSet,
    pub ks: Vec<[f32; 3]>,
    pub eta: Vec<f32>,
}

/// Everything a fit produced.
#[derive(Debug)]
pub struct FitResult {
    /// The final per-point maps (synthesized and refitted when synthesis ran).
    pub maps: PointMaps,
    pub census: Census,
    /// Bytes the sample store held.
    pub sample_bytes: usize,
    pub frames: u64,
    pub timings: Timings,
    pub settings: FitSettings,
    /// The per-point fit before synthesis (and pooling), when synthesis ran.
    pub partial: Option<PartialMaps>,
    pub pool: Option<crate::pooled::PoolStats>,
    pub synth: Option<SynthStats>,
    pub models: Vec<ModelFit>,
    pub selection: Option<Selection>,
    /// The samples, when [`Stages::keep_samples`] asked for them.
    pub samples: Option<SampleStore>,
    /// Set when far fewer samples were usable than the geometry allows.
    pub few_samples: Option<String>,
    /// What the LED drift correction did (frames fed through [`Pipeline`]
    /// on a rig with reference patches).
    pub drift: Option<crate::drift::DriftSummary>,
}

/// Why a fit produced nothing.
#[derive(Debug, Error)]
pub enum FitError {
    #[error("the fit was stopped")]
    Stopped,
    #[error("no usable samples: {0}; check the calibration (LED intensities, black level) and the exposure")]
    NoSamples(String),
    #[error("too few usable samples: {0}; shorten the exposure or add HDR brackets (--hdr), then capture again")]
    Saturated(String),
    #[error("the tiles do not make up the capture's grid of {0} points: fit the missing ones")]
    Tiles(usize),
}

/// Fewer usable samples than this fraction of those the geometry allows
/// is reported in [`FitResult::few_samples`] (too dark, saturated or
/// missing frames).
pub const FEW_USABLE: f64 = 0.1;

/// Refuse a fit with nothing to fit, or one whose frames are nearly all
/// saturated (far fewer samples than the plan promises); describe a thin
/// one (frames missing, much of the sample at grazing light).
pub fn check_census(c: &Census, total: usize) -> Result<Option<String>, FitError> {
    let allowed = (total as u64).saturating_sub(c.occluded).max(1);
    let why = format!(
        "{} of {allowed} samples the geometry allows are usable ({} missing frames, {} saturated, {} at grazing or \
         dim light)",
        c.usable, c.missing, c.saturated, c.dim
    );
    if c.usable == 0 {
        return Err(FitError::NoSamples(why));
    }
    if (c.usable as f64) < FEW_USABLE * (c.usable + c.saturated) as f64 {
        return Err(FitError::Saturated(why));
    }
    Ok(((c.usable as f64) < FEW_USABLE * allowed as f64).then_some(why))
}

/// More than this fraction of the lit samples clipped (one in 200) and the
/// fit warns: the clipped samples are a lobe's brightest, so a sharp
/// highlight loses its peak (`capture --quality fast --sample
/// brushed-metal` clips 3.6% of its samples; `refl eval` renders its
/// anisotropic Beckmann fit at 0.33, and at 0.09 with `--hdr 2`).
pub const CLIPPED_WARN: f64 = 0.005;

/// A warning when the brightest samples were lost to clipping at every
/// exposure (see [`CLIPPED_WARN`]).
pub fn clipped_warning(c: &Census) -> Option<String> {
    let lit = (c.usable + c.saturated).max(1) as f64;
    let share = c.saturated as f64 / lit;
    (share > CLIPPED_WARN).then(|| {
        format!(
            "{:.1}% of the lit samples ({} of {}) were clipped at every exposure: the brightest highlights are lost \
             and every model underestimates them; capture again with HDR brackets (--hdr 2) or a shorter exposure",
            100.0 * share,
            c.saturated,
            c.usable + c.saturated
        )
    })
}

/// A fit fed frame by frame.
#[derive(Debug)]
pub struct Pipeline<'a> {
    ctx: &'a FitContext,
    ingest: Ingest<'a>,
    settings: FitSettings,
    stages: Stages,
    ingest_s: f64,
    last_frame: Instant,
}

impl<'a> Pipeline<'a> {
    pub fn new(ctx: &'a FitContext, settings: FitSettings, stages: Stages) -> Self {
        Self { ctx, ingest: Ingest::new(ctx), settings, stages, ingest_s: 0.0, last_frame: Instant::now() }
    }

    /// A dark frame (all LEDs off) of exposure `exposure`.
    pub fn push_dark(&mut self, exposure: u8, frame: &Frame) {
        let t = Instant::now();
        self.ingest.push_dark(exposure, frame);
        self.ingested(t);
    }

    /// A planned shot's frame.
    pub fn push_shot(&mut self, shot: &PlannedShot, frame: &Frame) {
        let t = Instant::now();
        self.ingest.push_shot(shot, frame);
        self.ingested(t);
    }

    fn ingested(&mut self, started: Instant) {
        self.ingest_s += started.elapsed().as_secs_f64();
        self.last_frame = Instant::now();
    }

    /// No more frames: run the stages.
    pub fn finish(self, stop: &dyn Fn() -> bool) -> Result<FitResult, FitError> {
        let frames = self.ingest.frames;
        let t = Instant::now();
        self.ctx.progress.begin(crate::FitStage::Drift, 1);
        let (store, drift) = self.ingest.finish();
        self.ctx.progress.advance(1);
        let drift_s = t.elapsed().as_secs_f64();
        let mut r = run_from(self.ctx, store, self.settings, &self.stages, None, stop, self.last_frame)?;
        r.frames = frames;
        r.drift = drift;
        r.timings.drift_s = drift_s;
        r.timings.ingest_s = self.ingest_s;
        Ok(r)
    }
}

/// One tile's share of a fit spread over machines (`refl fit --tile`): the
/// samples of its points and their per-point fits, stage 2 of the one
/// order, made exactly as the whole grid's fit makes them.
#[derive(Debug)]
pub struct TileFit {
    pub store: SampleStore,
    pub maps: PointMaps,
    pub drift: Option<crate::drift::DriftSummary>,
    pub frames: u64,
    pub ingest_s: f64,
    /// The drift correction and the per-point fits, after the last frame.
    pub points_s: f64,
}

/// A tile's ingest and per-point fit, fed frame by frame like [`Pipeline`].
#[derive(Debug)]
pub struct TilePipeline<'a> {
    ctx: &'a FitContext,
    ingest: Ingest<'a>,
    settings: FitSettings,
    ingest_s: f64,
}

impl<'a> TilePipeline<'a> {
    /// The grid's points `points` (one tile's run of them).
    pub fn new(ctx: &'a FitContext, settings: FitSettings, points: std::ops::Range<usize>) -> Self {
        Self { ctx, ingest: Ingest::for_points(ctx, points), settings, ingest_s: 0.0 }
    }

    /// No more frames: correct the drift and fit the tile's points.
    pub fn finish(self, stop: &dyn Fn() -> bool) -> Result<TileFit, FitError> {
        let t = Instant::now();
        let frames = self.ingest.frames;
        self.ctx.progress.begin(crate::FitStage::Drift, 1);
        let (store, drift) = self.ingest.finish();
        self.ctx.progress.advance(1);
        if stop() {
            return Err(FitError::Stopped);
        }
        let op = MaskingOperator::new(self.settings.grid);
        let maps = crate::points::fit_points(self.ctx, &store, &self.settings, &op);
        Ok(TileFit { store, maps, drift, frames, ingest_s: self.ingest_s, points_s: t.elapsed().as_secs_f64() })
    }
}

impl crate::ingest::FrameSink for TilePipeline<'_> {
    fn push_dark(&mut self, exposure: u8, frame: &Frame) {
        let t = Instant::now();
        self.ingest.push_dark(exposure, frame);
        self.ingest_s += t.elapsed().as_secs_f64();
    }
    fn push_shot(&mut self, shot: &PlannedShot, frame: &Frame) {
        let t = Instant::now();
        self.ingest.push_shot(shot, frame);
        self.ingest_s += t.elapsed().as_secs_f64();
    }
}

/// The fit's stages after the per-point fit, on the tiles of a fit joined
/// into one over the whole grid (`whole`): the same result as [`Pipeline`]
/// fed the same frames, as the tiles' samples and per-point fits are the
/// whole grid's.
pub fn run_merged(
    ctx: &FitContext,
    whole: TileFit,
    settings: FitSettings,
    stages: &Stages,
    stop: &dyn Fn() -> bool,
) -> Result<FitResult, FitError> {
    let TileFit { store, maps, drift, frames, ingest_s, points_s } = whole;
    if store.points() != (0..ctx.n_points()) || maps.len() != ctx.n_points() {
        return Err(FitError::Tiles(ctx.n_points()));
    }
    let mut r = run_from(ctx, store, settings, stages, Some(maps), stop, Instant::now())?;
    r.frames = frames;
    r.drift = drift;
    r.timings.ingest_s = ingest_s;
    r.timings.points_s = points_s;
    Ok(r)
}

impl crate::ingest::FrameSink for Pipeline<'_> {
    fn push_dark(&mut self, exposure: u8, frame: &Frame) {
        Pipeline::push_dark(self, exposure, frame);
    }
    fn push_shot(&mut self, shot: &PlannedShot, frame: &Frame) {
        Pipeline::push_shot(self, shot, frame);
    }
}

/// Run the stages on samples made elsewhere (benchmarks, tests).
pub fn run_stages(
    ctx: &FitContext,
    store: SampleStore,
    settings: FitSettings,
    stages: &Stages,
    stop: &dyn Fn() -> bool,
) -> Result<FitResult, FitError> {
    run_from(ctx, store, settings, stages, None, stop, Instant::now())
}

/// The stages from the per-point fit on (`points`: its maps, made already
/// by a fit's tiles).
fn run_from(
    ctx: &FitContext,
    store: SampleStore,
    settings: FitSettings,
    stages: &Stages,
    points: Option<PointMaps>,
    stop: &dyn Fn() -> bool,
    started: Instant,
) -> Result<FitResult, FitError> {
    if stop() {
        return Err(FitError::Stopped);
    }
    let census = store.census();
    let few_samples = check_census(&census, store.n_points() * store.n_lights())?;
    if let Some(w) = &few_samples {
        tracing::warn!("few usable samples: {w}");
    }
    if let Some(w) = clipped_warning(&census) {
        tracing::warn!("{w}");
    }
    let mut timings = Timings::default();
    // The choice's held-out steps, decided once: without them it scores on
    // the evidence's samples, which are kept only then.
    let held = stages.analytic.as_ref().and_then(|a| choice_held_out(ctx, a));
    let keep_evidence_samples = stages.analytic.is_some() && held.is_none();
    let fitted =
        fit_stages(ctx, &store, &settings, stages, points, None, keep_evidence_samples, stop, started, &mut timings)?;
    let selection = match (&stages.analytic, &fitted.evidence) {
        (Some(a), Some(ev)) => {
            let t = Instant::now();
            let scores = choice_scores(ctx, &store, &settings, stages, a, held, ev, &fitted, stop)?;
            let selection = crate::select::select(&fitted.maps, &ev.cluster, ev.clusters, &scores);
            timings.selection_s = t.elapsed().as_secs_f64();
            selection
        }
        _ => None,
    };
    let sample_bytes = store.bytes();
    // The store goes here unless kept, before the tables are unpacked.
    let samples = stages.keep_samples.then_some(store);
    Ok(FitResult {
        maps: fitted.maps,
        census,
        sample_bytes,
        frames: 0,
        timings,
        settings,
        partial: fitted.partial.map(KeptPartial::unpack),
        pool: fitted.pool,
        synth: fitted.synth,
        models: fitted.models,
        selection,
        samples,
        few_samples,
        drift: None,
    })
}

/// [`PartialMaps`] while the fit goes on: its tables packed (the per-point
/// fit's tables' covered cells only, about half: some 1.8 of 4.2 GB saved
/// at 800 x 800 points), with the cells each point's own samples observed,
/// which is all pooling reads of them.
struct KeptPartial {
    tables: PackedTables,
    observed_cells: Vec<u32>,
    ks: Vec<[f32; 3]>,
    eta: Vec<f32>,
}

impl KeptPartial {
    fn new(p: PartialMaps) -> Self {
        let observed_cells = (0..p.tables.len()).map(|k| p.tables.covered_cells(k) as u32).collect();
        Self { tables: p.tables.pack(), observed_cells, ks: p.ks, eta: p.eta }
    }

    fn unpack(self) -> PartialMaps {
        PartialMaps { tables: self.tables.unpack(), ks: self.ks, eta: self.eta }
    }
}

/// What the stages before the model choice produced.
struct Fitted {
    maps: PointMaps,
    partial: Option<KeptPartial>,
    pool: Option<crate::pooled::PoolStats>,
    synth: Option<SynthStats>,
    models: Vec<ModelFit>,
    evidence: Option<Evidence>,
}

/// Stages 2-5 without the choice: per point (unless `points` holds its
/// maps already), synthesis, analytic fits (their shapes started from
/// `prior`'s where given), pooling. The analytic evidence keeps its
/// samples only if `keep_evidence_samples`.
#[allow(clippy::too_many_arguments)]
fn fit_stages(
    ctx: &FitContext,
    store: &SampleStore,
    settings: &FitSettings,
    stages: &Stages,
    points: Option<PointMaps>,
    prior: Option<&[ModelFit]>,
    keep_evidence_samples: bool,
    stop: &dyn Fn() -> bool,
    started: Instant,
    timings: &mut Timings,
) -> Result<Fitted, FitError> {
    let stopped = || if stop() { Err(FitError::Stopped) } else { Ok(()) };
    let op = MaskingOperator::new(settings.grid);
    let mut maps = match points {
        Some(maps) => maps,
        None => crate::points::fit_points(ctx, store, settings, &op),
    };
    timings.points_s = started.elapsed().as_secs_f64();
    stopped()?;
    let (partial, synth) = match &stages.synth {
        Some(ss) => {
            let t = Instant::now();
            let (partial, stats, refit_s) = synthesis_stage(ctx, store, &mut maps, ss, settings, &op);
            timings.synthesis_s = t.elapsed().as_secs_f64();
            timings.refit_s = refit_s;
            (Some(KeptPartial::new(partial)), Some(stats))
        }
        None => (None, None),
    };
    // The analytic fits keep to the points' own tables, as without
    // pooling: started from pooled tables' moments brushed metal's
    // anisotropic Ward fit lost half its accuracy (measured in issue 16's
    // note). So they run before pooling replaces those tables, and no copy
    // of the maps is kept for them (the tables alone are 6.5 KB a point on
    // the 32 x 96 grid: 4.2 GB at 800 x 800 points).
    let (models, evidence) = match &stages.analytic {
        Some(a) if !a.models.is_empty() => {
            let a = analytic_stage(ctx, store, &maps, settings, a, prior, keep_evidence_samples, stop)?;
            timings.analytic_s = a.analytic_s;
            (a.models, Some(a.evidence))
        }
        _ => (Vec::new(), None),
    };
    stopped()?;
    // Pooling runs on the completed tables (their masking is the better
    // start).
    let pool = stages.pool.as_ref().map(|ps| {
        let t = Instant::now();
        let observed = partial.as_ref().map(|p| &p.observed_cells[..]);
        let stats = crate::pooled::pool(ctx, store, &mut maps, settings, ps, &op, observed);
        timings.pool_s = t.elapsed().as_secs_f64();
        stats
    });
    stopped()?;
    Ok(Fitted { maps, partial, pool, synth, models, evidence })
}

/// The model choice's refit fits every other point along each axis (a
/// quarter of them) on grids at least this many points a side: 256 or
/// more points, tens per region, each with tens of held-out samples. Its
/// pooled tables and syntheses draw on a quarter of the points, which
/// still number hundreds per material; the held-out steps lie between the
/// training steps, where synthesis adds nothing.
const CHOICE_STRIDE_MIN_SIDE: u32 = 32;

/// The model choice's scores ([`crate::select`]): every stage fitted again
/// without the choice's `held` steps ([`choice_held_out`]; on a quarter of
/// the points of a large grid), each class of that fit scored on their
/// samples; on the fit's own samples (`ev`'s) when the plan cannot spare
/// two such steps. The refit's analytic shapes start from the main fit's,
/// so that the choice scores the lobes the material keeps rather than
/// another local minimum of the smaller problem (balanced brushed metal
/// with `--hdr 2`: started from moments, some of the refit's Beckmann
/// clusters ended far from the main fit's, the choice took GGX as the
/// anisotropic candidate and the table over it, and `auto` rendered 0.152
/// where Beckmann renders 0.045).
/// The start has seen the held-out steps; the refit's minimisation has
/// not.
#[allow(clippy::too_many_arguments)]
fn choice_scores(
    ctx: &FitContext,
    store: &SampleStore,
    settings: &FitSettings,
    stages: &Stages,
    a: &AnalyticSettings,
    held: Option<StepSet>,
    ev: &Evidence,
    fitted: &Fitted,
    stop: &dyn Fn() -> bool,
) -> Result<crate::select::Scores, FitError> {
    use crate::select::{ScoredOn, scores, scores_by};
    let Some(held) = held else {
        let (samples, view) = ev.samples();
        return Ok(scores(ScoredOn::FitSamples, samples, view, &fitted.maps, &fitted.models));
    };
    let g = ctx.inputs.grid;
    let stride = (g.cols >= CHOICE_STRIDE_MIN_SIDE && g.rows >= CHOICE_STRIDE_MIN_SIDE).then_some(2);
    let refit = FitSettings { choice_holdout: Some(held), point_stride: stride, ..settings.clone() };
    // Only the candidates' scores are read; each model's fit is its own
    // (the clusters and samples they share do not depend on the list).
    let candidates = AnalyticSettings {
        models: a.models.iter().copied().filter(|&m| crate::select::is_candidate(m)).collect(),
        ..a.clone()
    };
    let refit_stages = Stages { analytic: Some(candidates), ..stages.clone() };
    let mut ignored = Timings::default();
    ctx.progress.begin(crate::FitStage::Choice, 0);
    ctx.progress.set_refitting(true);
    let h = fit_stages(
        ctx,
        store,
        &refit,
        &refit_stages,
        None,
        Some(&fitted.models),
        false,
        stop,
        Instant::now(),
        &mut ignored,
    );
    ctx.progress.set_refitting(false);
    // Only the refit's maps and models are scored: the rest (its tables
    // before synthesis, its clusters) goes before the held-out samples are
    // gathered.
    let Fitted { maps: h_maps, models: h_models, .. } = h?;
    // Each point's held-out samples are gathered as it is scored, never
    // all at once (320 samples of 44 bytes a point at the presets' plans).
    ctx.progress.begin(crate::FitStage::Choice, ctx.n_points() as u64);
    Ok(scores_by(ScoredOn::HeldOutSteps, &h_maps, &h_models, |p| {
        let ps = crate::points::gather_choice_held_out(ctx, store, p, &refit);
        ctx.progress.advance(1);
        (std::borrow::Cow::Owned(ps.samples), ps.o)
    }))
}

/// The gantry steps the model choice holds out of its refit; `None` when
/// the plan cannot spare two, and the choice scores on the fit's own
/// samples (the analytic evidence's).
fn choice_held_out(ctx: &FitContext, a: &AnalyticSettings) -> Option<StepSet> {
    a.choice_holdout_every.map(StepSet::for_choice).filter(|s| s.count(ctx.inputs.plan.steps) >= 2)
}

/// Synthesis: complete every point's partial table from other points'
/// rotated tables, then refit the points that gained cells with their
/// completed table. Returns the maps as they were before, the synthesis's
/// statistics and the refit's wall time (seconds).
pub fn synthesis_stage(
    ctx: &FitContext,
    store: &SampleStore,
    maps: &mut PointMaps,
    synth: &SynthSettings,
    settings: &FitSettings,
    op: &MaskingOperator,
) -> (PartialMaps, SynthStats, f64) {
    let eligible: Vec<bool> = maps.flags.iter().map(|f| f & point_flag::NO_SPECULAR == 0).collect();
    let out = crate::synth::synthesize_watched(&maps.tables, &eligible, synth, &ctx.progress);
    let added: Vec<bool> = out.mass_factor.iter().map(|&k| k != 1.0).collect();
    // The maps take the completed tables of the points synthesis added to
    // (the refit reads them there) and keep their own elsewhere (synthesis
    // may rewrite an eligible point's table whose mass it leaves unchanged,
    // and writes no other); the partial maps take the tables as they were,
    // moved rather than copied, so that two copies of every point's tables
    // are held here, not three.
    let mut tables = out.tables;
    for p in (0..maps.len()).filter(|&p| eligible[p] && !added.get(p).copied().unwrap_or(false)) {
        tables.copy_from(p, &maps.tables);
    }
    let partial =
        PartialMaps { tables: std::mem::replace(&mut maps.tables, tables), ks: maps.ks.clone(), eta: maps.eta.clone() };
    let t = Instant::now();
    crate::points::refit_completed(ctx, store, maps, &added, settings, op);
    (partial, out.stats, t.elapsed().as_secs_f64())
}

/// What [`analytic_stage`] produced.
#[derive(Debug)]
pub struct AnalyticOutcome {
    pub models: Vec<ModelFit>,
    /// The clusters the fits shared, and their evaluation samples if kept.
    pub evidence: Evidence,
    pub analytic_s: f64,
}

/// Fit every analytic model per point, starting from the points' own
/// tables (`init`: the maps before pooling, which runs after this stage),
/// or from `prior`'s shapes (an earlier fit of the same models) where
/// given. The evidence keeps every point's evaluation samples only if
/// `keep_samples` (the fits read them from the store a chunk at a time).
#[allow(clippy::too_many_arguments)]
pub fn analytic_stage(
    ctx: &FitContext,
    store: &SampleStore,
    init: &PointMaps,
    settings: &FitSettings,
    a: &AnalyticSettings,
    prior: Option<&[ModelFit]>,
    keep_samples: bool,
    stop: &dyn Fn() -> bool,
) -> Result<AnalyticOutcome, FitError> {
    let t = Instant::now();
    // A unit per model's shapes and one per point.
    ctx.progress.begin(crate::FitStage::Analytic, (a.models.len() + init.len()) as u64);
    let advance = |k: u64| ctx.progress.advance(k);
    let chunk = crate::analytic::EVIDENCE_CHUNK;
    let opts = crate::analytic::FitModelsOptions { prior, keep_samples, chunk, stop, advance: &advance };
    let (models, evidence) =
        crate::analytic::fit_models(ctx, store, init, settings, a, opts).ok_or(FitError::Stopped)?;
    Ok(AnalyticOutcome { models, evidence, analytic_s: t.elapsed().as_secs_f64() })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clipping_beyond_one_sample_in_200_is_warned_of() {
        let c = |usable, saturated| Census { usable, saturated, ..Census::default() };
        assert!(clipped_warning(&c(1000, 0)).is_none());
        assert!(clipped_warning(&c(996, 4)).is_none());
        let w = clipped_warning(&c(964, 36)).expect("3.6% clipped");
        assert!(w.contains("3.6%") && w.contains("--hdr"), "{w}");
    }

    #[test]
    fn a_fit_without_usable_samples_is_refused_and_a_thin_one_described() {
        let none = Census { usable: 0, missing: 10, occluded: 5, saturated: 3, dim: 82 };
        let e = check_census(&none, 100).unwrap_err().to_string();
        assert!(e.contains("no usable samples") && e.contains("82 at grazing"), "{e}");
        // Nearly every sample with light saturated: the exposure is wrong.
        let burnt = Census { usable: 4, missing: 0, occluded: 5, saturated: 60, dim: 31 };
        assert!(matches!(check_census(&burnt, 100), Err(FitError::Saturated(_))));
        // 5 of the 95 samples the geometry allows: below a tenth.
        let thin = Census { usable: 5, missing: 0, occluded: 5, saturated: 0, dim: 90 };
        assert!(check_census(&thin, 100).unwrap().is_some_and(|w| w.contains("5 of 95")));
        let fine = Census { usable: 60, missing: 0, occluded: 5, saturated: 5, dim: 30 };
        assert!(check_census(&fine, 100).unwrap().is_none());
    }
}
