//! The fit, run beside the capture: frames stream into a fitter thread as
//! they are stored, so only the stages after ingest remain after the last
//! frame. `refl fit DIR` replays a stored capture through the same code.
//! The stages themselves are `fit::Pipeline`'s; this is only the thread
//! and its channel.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;

use anyhow::{Result, anyhow};
use fit::{FitContext, FitInputs, FitProgress, FitResult, FitSettings, Pipeline, Stages};
use tokio::sync::mpsc;

pub use assess::replay::{FrameMsg, fit_inputs};

/// A fitter thread fed through a bounded channel (back-pressure: a capture
/// never runs more than 32 frames ahead of the fitter). The channel is
/// tokio's: async code waits on it without holding a runtime worker.
#[derive(Debug)]
pub struct FitJob {
    tx: Option<mpsc::Sender<FrameMsg>>,
    handle: Option<JoinHandle<Result<FitResult>>>,
    stop: Arc<AtomicBool>,
    progress: Arc<FitProgress>,
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
        let (tx, rx) = mpsc::channel::<FrameMsg>(32);
        Self::spawn(Some(tx), move |stop, progress| run(inputs, settings, stages, rx, stop, progress))
    }

    /// A job fitting a capture whose points were fitted in tiles elsewhere
    /// (`crate::tiles`), joined into `whole`: it takes no frames, and runs
    /// the stages after the per-point fit.
    pub fn start_merged(inputs: FitInputs, settings: FitSettings, stages: Stages, whole: fit::TileFit) -> Self {
        Self::spawn(None, move |stop, progress| {
            let ctx = FitContext::new(inputs).with_progress(progress);
            Ok(fit::run_merged(&ctx, whole, settings, &stages, &|| stop.load(Ordering::Relaxed))?)
        })
    }

    fn spawn(
        tx: Option<mpsc::Sender<FrameMsg>>,
        body: impl FnOnce(&AtomicBool, Arc<FitProgress>) -> Result<FitResult> + Send + 'static,
    ) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let stop2 = stop.clone();
        let progress = Arc::new(FitProgress::new());
        let progress2 = progress.clone();
        let handle = std::thread::Builder::new()
            .name("fitter".into())
            .spawn(move || body(&stop2, progress2))
            .map_err(|e| anyhow!("cannot start the fitter thread: {e}"));
        match handle {
            Ok(h) => Self { tx, handle: Some(h), stop, progress },
            Err(e) => {
                tracing::error!("{e}");
                Self { tx: None, handle: None, stop, progress }
            }
        }
    }

    /// Where the fit is (its stages after ingest), for a display to poll.
    pub fn progress(&self) -> Arc<FitProgress> {
        self.progress.clone()
    }

    fn sender(&self) -> Result<&mpsc::Sender<FrameMsg>> {
        self.tx.as_ref().ok_or_else(|| anyhow!("the fitter is not running"))
    }

    /// Hand a frame to the fitter, waiting while it is 32 frames behind.
    pub async fn send(&self, msg: FrameMsg) -> Result<()> {
        self.sender()?.send(msg).await.map_err(|_| anyhow!("the fitter stopped"))
    }

    /// [`FitJob::send`] for blocking code (outside the async runtime, or in
    /// `block_in_place`).
    pub fn send_blocking(&self, msg: FrameMsg) -> Result<()> {
        self.sender()?.blocking_send(msg).map_err(|_| anyhow!("the fitter stopped"))
    }

    /// No more frames: wait for the fit (blocking).
    pub fn finish(mut self) -> Result<FitResult> {
        drop(self.tx.take());
        let h = self.handle.take().ok_or_else(|| anyhow!("the fitter is not running"))?;
        h.join().map_err(|_| anyhow!("the fitter thread panicked"))?
    }

    /// No more frames: wait for the fit without holding a runtime worker.
    /// Dropping the returned future (a stop request won a `select!`) drops
    /// the job, so its thread gives up at its next stage.
    pub async fn finish_async(self) -> Result<FitResult> {
        tokio::task::spawn_blocking(move || self.finish())
            .await
            .map_err(|e| anyhow!("the fitter thread failed: {e}"))?
    }
}

fn run(
    inputs: FitInputs,
    settings: FitSettings,
    stages: Stages,
    mut rx: mpsc::Receiver<FrameMsg>,
    stop: &AtomicBool,
    progress: Arc<FitProgress>,
) -> Result<FitResult> {
    let ctx = FitContext::new(inputs).with_progress(progress);
    let mut pipeline = Pipeline::new(&ctx, settings, stages);
    while let Some(msg) = rx.blocking_recv() {
        msg.feed(&mut pipeline);
    }
    Ok(pipeline.finish(&|| stop.load(Ordering::Relaxed))?)
}

/// Replay a stored capture's frames into a fit job. A stop request
/// (`stop()` true) ends the replay with [`Interrupted`].
///
/// [`Interrupted`]: crate::Interrupted
pub fn replay(
    root: &std::path::Path,
    entries: &[store::ManifestEntry],
    job: &FitJob,
    stop: &dyn Fn() -> bool,
) -> Result<u64> {
    assess::replay::for_each_frame(root, entries, &mut |msg| {
        if stop() {
            return Err(crate::Interrupted.into());
        }
        job.send_blocking(msg)
    })
}
