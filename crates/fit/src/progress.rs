//! Where a running fit is, for whoever watches it from another thread (a
//! progress bar, the daemon's status). The fitter writes it with relaxed
//! atomics, one count per unit of work (a point, an analytic model); a
//! watcher polls [`FitProgress::snapshot`] as often as it likes. Nothing
//! here changes what the fit computes.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Instant;

use serde::{Deserialize, Serialize};

/// The stages after ingest, in the order the pipeline runs them
/// (`crate::pipeline`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FitStage {
    /// The LED drift read from the reference patches and divided out.
    Drift,
    /// Diffuse/specular split, partial NDF, masking, `k_s`, Fresnel.
    Points,
    /// Partial NDFs completed from other points' rotated NDFs.
    Synthesis,
    /// Every point refitted with its completed table.
    Refit,
    /// The analytic models: each one's cluster shapes, then every point's
    /// amplitudes, a chunk of points at a time.
    Analytic,
    /// One NDF per material from the samples of all its points.
    Pooling,
    /// The model choice: the stages again without its held-out steps, then
    /// the scores.
    Choice,
}

impl FitStage {
    /// What the stage does, for people.
    pub fn describe(self) -> &'static str {
        match self {
            FitStage::Drift => "LED drift",
            FitStage::Points => "per-point NDFs",
            FitStage::Synthesis => "microfacet synthesis",
            FitStage::Refit => "refit of completed points",
            FitStage::Analytic => "analytic models",
            FitStage::Pooling => "pooled NDFs",
            FitStage::Choice => "model choice",
        }
    }
}

/// A moment of a fit's progress.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Snapshot {
    pub stage: FitStage,
    /// Within the model choice, the stage its refit is in.
    pub within: Option<FitStage>,
    pub done: u64,
    pub total: u64,
    /// Seconds since the stage began.
    pub elapsed_s: f64,
    /// Seconds left in this stage at its rate so far (none before its
    /// first unit is done, or once the stage's counts cannot tell).
    pub eta_s: Option<f64>,
}

#[derive(Debug)]
struct Current {
    stage: FitStage,
    within: Option<FitStage>,
    started: Instant,
}

/// A running fit's stage and its counts.
#[derive(Debug, Default)]
pub struct FitProgress {
    current: Mutex<Option<Current>>,
    /// Set while the model choice refits: the stages it runs are reported
    /// within it.
    refitting: AtomicBool,
    done: AtomicU64,
    total: AtomicU64,
}

impl FitProgress {
    pub fn new() -> Self {
        Self::default()
    }

    /// Stage `stage` begins, with `total` units of work.
    pub fn begin(&self, stage: FitStage, total: u64) {
        let mut g = self.current.lock().unwrap_or_else(|p| p.into_inner());
        let refit = self.refitting.load(Ordering::Relaxed) && stage != FitStage::Choice;
        let now = Instant::now();
        *g = Some(match (refit, g.take()) {
            // The choice's refit keeps the choice's clock; its counts are
            // the inner stage's.
            (true, Some(c)) => Current { stage: FitStage::Choice, within: Some(stage), started: c.started },
            _ => Current { stage, within: None, started: now },
        });
        self.done.store(0, Ordering::Relaxed);
        self.total.store(total, Ordering::Relaxed);
    }

    /// `n` more units of the current stage done (callable from any thread).
    #[inline]
    pub fn advance(&self, n: u64) {
        self.done.fetch_add(n, Ordering::Relaxed);
    }

    /// The stages that follow run as the model choice's refit (true) or as
    /// the fit itself (false).
    pub(crate) fn set_refitting(&self, on: bool) {
        self.refitting.store(on, Ordering::Relaxed);
    }

    /// Where the fit is now; `None` before its first stage.
    pub fn snapshot(&self) -> Option<Snapshot> {
        let g = self.current.lock().unwrap_or_else(|p| p.into_inner());
        let c = g.as_ref()?;
        let total = self.total.load(Ordering::Relaxed);
        let done = self.done.load(Ordering::Relaxed).min(total);
        let elapsed_s = c.started.elapsed().as_secs_f64();
        // The choice's clock spans its inner stages, whose counts restart:
        // no rate of one applies to the whole.
        let eta_s = (c.within.is_none() && done > 0).then(|| elapsed_s * (total - done) as f64 / done as f64);
        Some(Snapshot { stage: c.stage, within: c.within, done, total, elapsed_s, eta_s })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_restart_with_each_stage_and_the_choice_reports_its_refit_within_it() {
        let p = FitProgress::new();
        assert!(p.snapshot().is_none());
        p.begin(FitStage::Points, 10);
        p.advance(4);
        let s = p.snapshot().unwrap();
        assert_eq!((s.stage, s.within, s.done, s.total), (FitStage::Points, None, 4, 10));
        // Four of ten done: the rest takes 6/4 of the time so far.
        let eta = s.eta_s.unwrap();
        assert!((eta - 1.5 * s.elapsed_s).abs() <= 1.5 * s.elapsed_s * 1e-6 + 1e-3, "{eta} {}", s.elapsed_s);
        p.begin(FitStage::Choice, 0);
        p.set_refitting(true);
        p.begin(FitStage::Points, 3);
        p.advance(5);
        let s = p.snapshot().unwrap();
        // Over-counting cannot report more than the total.
        assert_eq!((s.stage, s.within, s.done, s.total), (FitStage::Choice, Some(FitStage::Points), 3, 3));
        assert!(s.eta_s.is_none());
        p.set_refitting(false);
        p.begin(FitStage::Analytic, 2);
        assert_eq!(p.snapshot().unwrap().within, None);
    }
}
