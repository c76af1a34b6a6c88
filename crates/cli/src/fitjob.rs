//! The fit, run beside the capture: frames stream into a fitter thread as
//! they are stored, so only the per-point stage remains after the last
//! frame. `refl fit DIR` replays a stored capture through the same code.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
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
    stop: Arc<AtomicBool>,
}

impl Drop for FitJob {
    /// A job dropped before it finished (an error, a stop) tells its thread
    /// to give up at its next stage instead of fitting for nobody.
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

impl FitJob {
    pub fn start(inputs: FitInputs, settings: FitSettings, stages: Stages) -> Self {
        let (tx, rx) = sync_channel::<FrameMsg>(32);
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let handle = std::thread::Builder::new()
            .name("fitter".into())
            .spawn(move || run(inputs, settings, stages, rx, &stop2))
            .map_err(|e| anyhow!("cannot start the fitter thread: {e}"));
        match handle {
            Ok(h) => Self { tx: Some(tx), handle: Some(h), stop },
            Err(e) => {
                tracing::error!("{e}");
                Self { tx: None, handle: None, stop }
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

    /// No more frames: wait for the fit (blocking).
    pub fn finish(mut self) -> Result<FitOutcome> {
        drop(self.tx.take());
        let h = self.handle.take().ok_or_else(|| anyhow!("the fitter is not running"))?;
        h.join().map_err(|_| anyhow!("the fitter thread panicked"))?
    }

    /// No more frames: wait for the fit without holding a runtime worker.
    /// Dropping the returned future (a stop request won a `select!`) drops
    /// the job, so its thread gives up at its next stage.
    pub async fn finish_async(self) -> Result<FitOutcome> {
        tokio::task::spawn_blocking(move || self.finish())
            .await
            .map_err(|e| anyhow!("the fitter thread failed: {e}"))?
    }
}

/// Fewer usable samples than this fraction of those the geometry allows
/// is worth a warning (too dark, saturated or missing frames).
const FEW_USABLE: f64 = 0.1;

/// Refuse a fit with nothing to fit, and say what removed the samples.
fn check_census(c: &Census, total: usize) -> Result<Option<String>> {
    let allowed = (total as u64).saturating_sub(c.occluded).max(1);
    let why = format!(
        "{} of {allowed} samples the geometry allows are usable ({} missing frames, {} saturated, {} too dark)",
        c.usable, c.missing, c.saturated, c.dim
    );
    if c.usable == 0 {
        anyhow::bail!(
            "no usable samples: {why}; check the calibration (LED intensities, black level) and the exposure"
        );
    }
    Ok(((c.usable as f64) < FEW_USABLE * allowed as f64).then_some(why))
}

fn run(
    inputs: FitInputs,
    settings: FitSettings,
    stages: Stages,
    rx: Receiver<FrameMsg>,
    stop: &AtomicBool,
) -> Result<FitOutcome> {
    let stopped = || -> Result<()> {
        if stop.load(Ordering::Relaxed) { Err(anyhow!("the fit was stopped")) } else { Ok(()) }
    };
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
    stopped()?;
    let frames = ingest.frames;
    let store = ingest.finish();
    let census = store.census();
    if let Some(few) = check_census(&census, store.n_points() * store.n_lights())? {
        tracing::warn!("few usable samples: {few}");
    }
    let sample_bytes = store.bytes();
    let op = MaskingOperator::new(settings.grid);
    stopped()?;
    let mut maps = fit::fit_points(&ctx, &store, &settings, &op);
    let points_s = last_frame.elapsed().as_secs_f64();
    let mut timings = FitTimings { ingest_s, points_s, ..FitTimings::default() };
    stopped()?;
    let (partial, synth_stats) = match stages.synth {
        Some(ss) => {
            let t = Instant::now();
            let eligible: Vec<bool> = maps.flags.iter().map(|f| f & fit::point_flag::NO_SPECULAR == 0).collect();
            let out = fit::synth::synthesize(&maps.tables, &eligible, &ss);
            stopped()?;
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
            stopped()?;
            let t = Instant::now();
            let ev = fit::analytic::evidence(&ctx, &store, &maps, &settings, &a);
            let mut models = Vec::with_capacity(a.models.len());
            for &m in &a.models {
                stopped()?;
                models.push(fit::analytic::fit_model(m, &maps, &ev));
            }
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
/// A stop request (`stop()` true) ends the replay with [`Interrupted`].
///
/// [`Interrupted`]: crate::capture::Interrupted
pub fn replay(
    root: &std::path::Path,
    entries: &[store::ManifestEntry],
    job: &FitJob,
    stop: &dyn Fn() -> bool,
) -> Result<u64> {
    let mut n = 0;
    for e in entries {
        if stop() {
            return Err(crate::capture::Interrupted.into());
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_fit_without_usable_samples_is_refused_and_a_thin_one_warned() {
        let none = Census { usable: 0, missing: 10, occluded: 5, saturated: 3, dim: 82 };
        let e = check_census(&none, 100).unwrap_err().to_string();
        assert!(e.contains("no usable samples") && e.contains("82 too dark"), "{e}");
        // 5 of the 95 samples the geometry allows: below a tenth, warned.
        let thin = Census { usable: 5, missing: 0, occluded: 5, saturated: 0, dim: 90 };
        assert!(check_census(&thin, 100).unwrap().is_some_and(|w| w.contains("5 of 95")));
        let fine = Census { usable: 60, missing: 0, occluded: 5, saturated: 5, dim: 30 };
        assert!(check_census(&fine, 100).unwrap().is_none());
    }
}
