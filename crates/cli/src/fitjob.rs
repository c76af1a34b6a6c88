//! The fit, run beside the capture: frames stream into a fitter thread as
//! they are stored, so only the per-point stage remains after the last
//! frame. `refl fit DIR` replays a stored capture through the same code.

use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;
use std::time::Instant;

use anyhow::{Context, Result, anyhow};
use brdf::ndf::MaskingOperator;
use fit::samples::Census;
use fit::{FitContext, FitInputs, FitSettings, Ingest, PointMaps};
use frame::Frame;
use serde::Serialize;
use setup::PlannedShot;

/// A frame on its way to the fitter.
#[derive(Debug)]
pub enum FrameMsg {
    Dark { exposure: u8, frame: Frame },
    Shot { shot: PlannedShot, frame: Frame },
}

/// Wall time of each fitting stage, seconds.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct FitTimings {
    /// Ingesting frames (overlaps the capture when streaming).
    pub ingest_s: f64,
    /// From the last frame to the end of the per-point stage.
    pub points_s: f64,
    pub synthesis_s: f64,
    pub analytic_s: f64,
    pub selection_s: f64,
}

#[derive(Debug)]
pub struct FitOutcome {
    pub ctx: FitContext,
    pub maps: PointMaps,
    pub census: Census,
    pub sample_bytes: usize,
    pub frames: u64,
    pub timings: FitTimings,
    pub settings: FitSettings,
    /// The fit before synthesis, when synthesis replaced it in `maps`.
    pub partial: Option<material::PartialFit>,
    pub synth: Option<fit::synth::SynthStats>,
    pub models: Vec<fit::analytic::ModelFit>,
    pub selection: Option<fit::select::Selection>,
}

/// What the fitter does after the per-point stage.
#[derive(Clone, Debug, Default)]
pub struct Stages {
    pub synth: Option<fit::synth::SynthSettings>,
    pub analytic: Option<fit::analytic::AnalyticSettings>,
}

/// A fitter thread fed through a bounded channel (back-pressure: a capture
/// never runs more than 32 frames ahead of the fitter).
#[derive(Debug)]
pub struct FitJob {
    tx: Option<SyncSender<FrameMsg>>,
    handle: Option<JoinHandle<Result<FitOutcome>>>,
}

impl FitJob {
    pub fn start(inputs: FitInputs, settings: FitSettings, stages: Stages) -> Self {
        let (tx, rx) = sync_channel::<FrameMsg>(32);
        let handle = std::thread::Builder::new()
            .name("fitter".into())
            .spawn(move || run(inputs, settings, stages, rx))
            .map_err(|e| anyhow!("cannot start the fitter thread: {e}"));
        match handle {
            Ok(h) => Self { tx: Some(tx), handle: Some(h) },
            Err(e) => {
                tracing::error!("{e}");
                Self { tx: None, handle: None }
            }
        }
    }

    pub fn send(&self, msg: FrameMsg) -> Result<()> {
        self.tx
            .as_ref()
            .ok_or_else(|| anyhow!("the fitter is not running"))?
            .send(msg)
            .map_err(|_| anyhow!("the fitter stopped"))
    }

    /// No more frames: wait for the fit.
    pub fn finish(mut self) -> Result<FitOutcome> {
        drop(self.tx.take());
        let h = self.handle.take().ok_or_else(|| anyhow!("the fitter is not running"))?;
        h.join().map_err(|_| anyhow!("the fitter thread panicked"))?
    }
}

fn run(inputs: FitInputs, settings: FitSettings, stages: Stages, rx: Receiver<FrameMsg>) -> Result<FitOutcome> {
    let ctx = FitContext::new(inputs);
    let t0 = Instant::now();
    let mut ingest_s = 0.0;
    let mut ingest = Ingest::new(&ctx);
    let mut last_frame = Instant::now();
    for msg in rx {
        let t = Instant::now();
        match msg {
            FrameMsg::Dark { exposure, frame } => ingest.push_dark(exposure, &frame),
            FrameMsg::Shot { shot, frame } => ingest.push_shot(&shot, &frame),
        }
        ingest_s += t.elapsed().as_secs_f64();
        last_frame = Instant::now();
    }
    let _ = t0;
    let frames = ingest.frames;
    let store = ingest.finish();
    let census = store.census();
    let sample_bytes = store.bytes();
    let op = MaskingOperator::new(settings.grid);
    let mut maps = fit::fit_points(&ctx, &store, &settings, &op);
    let points_s = last_frame.elapsed().as_secs_f64();
    let mut timings = FitTimings { ingest_s, points_s, ..FitTimings::default() };
    let (partial, synth_stats) = match stages.synth {
        Some(ss) => {
            let t = Instant::now();
            let eligible: Vec<bool> = maps.flags.iter().map(|f| f & fit::point_flag::NO_SPECULAR == 0).collect();
            let out = fit::synth::synthesize(&maps.tables, &eligible, &ss);
            let partial =
                material::PartialFit { tables: maps.tables.clone(), ks: maps.ks.clone(), eta: maps.eta.clone() };
            let added: Vec<bool> = out.mass_factor.iter().map(|&k| k != 1.0).collect();
            fit::points::refit_completed(&ctx, &store, &mut maps, &out.tables, &added, &settings, &op);
            timings.synthesis_s = t.elapsed().as_secs_f64();
            (Some(partial), Some(out.stats))
        }
        None => (None, None),
    };
    let (models, selection) = match stages.analytic {
        Some(a) if !a.models.is_empty() => {
            let t = Instant::now();
            let ev = fit::analytic::evidence(&ctx, &store, &maps, &settings, &a);
            let models: Vec<_> = a.models.iter().map(|&m| fit::analytic::fit_model(m, &maps, &ev)).collect();
            timings.analytic_s = t.elapsed().as_secs_f64();
            let t = Instant::now();
            let selection = fit::select::select(&maps, &ev, &models);
            timings.selection_s = t.elapsed().as_secs_f64();
            (models, selection)
        }
        _ => (Vec::new(), None),
    };
    drop(store);
    Ok(FitOutcome {
        ctx,
        maps,
        census,
        sample_bytes,
        frames,
        timings,
        settings,
        partial,
        synth: synth_stats,
        models,
        selection,
    })
}

/// Replay a stored capture's frames into a fit job (manifest order: dark
/// frames were stored before the shots of their exposure).
pub fn replay(root: &std::path::Path, entries: &[store::ManifestEntry], job: &FitJob) -> Result<u64> {
    let mut n = 0;
    for e in entries {
        let frame = store::CaptureDir::read_frame(root, e).with_context(|| format!("reading {}", e.file))?;
        let msg = match e.frame {
            store::FrameKind::Dark { exposure, .. } => FrameMsg::Dark { exposure, frame },
            store::FrameKind::Shot { index, step, led, exposure, position_um } => {
                FrameMsg::Shot { shot: PlannedShot { index, step, led, exposure, position_um }, frame }
            }
        };
        job.send(msg)?;
        n += 1;
    }
    Ok(n)
}

/// What the fitter needs to know about a stored capture.
pub fn fit_inputs(info: &store::CaptureInfo) -> fit::FitInputs {
    fit::FitInputs {
        geometry: info.geometry.clone(),
        plan: info.plan.clone(),
        calibration: info.calibration.clone(),
        grid: info.grid,
        e_per_dn: info.sensor.e_per_dn,
        bit_depth: info.sensor.bit_depth,
    }
}
