//! The camera: one trait, a V4L2 backend for real devices and (in `sim`) a
//! simulated one.
//!
//! A frame belongs to an LED only if its exposure started after the LED was
//! known to be lit, which is decided by timestamps, never by order:
//! [`FrameFilter`] is that rule, shared by every backend.

#[cfg(target_os = "linux")]
pub mod discover;
mod filter;
pub mod pixel;
#[cfg(target_os = "linux")]
pub mod v4l2;

use std::future::Future;
use std::time::Duration;

pub use filter::{FrameFilter, Verdict};
use frame::{Frame, MonoNs};
use serde::{Deserialize, Serialize};
use thiserror::Error;

/// What the capture asks of a camera. Every automatic mode (exposure, gain,
/// white balance) is always switched off; they are not settings.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraSettings {
    pub width: u32,
    pub height: u32,
    pub exposure_us: u32,
    pub gain: f32,
    pub fps: f32,
    /// Frames discarded after any control change (drivers apply controls
    /// with a delay of a frame or two).
    pub settle_frames: u32,
}

pub use frame::AppliedSettings;

#[derive(Debug, Error)]
pub enum CameraError {
    #[error(
        "no usable frame within {waited_ms} ms (is the camera streaming? check its cable and that no other program uses it)"
    )]
    Timeout { waited_ms: u64 },
    #[error("the camera is not there ({0}); check that it is plugged in and its USB cable")]
    Gone(String),
    #[error("the camera cannot deliver what the measurement needs: {0}")]
    Unsupported(String),
    #[error("camera error: {0}")]
    Io(#[from] std::io::Error),
}

/// Frames a camera threw away since it was configured, by reason; each
/// was replaced by a later frame, so nothing is missing from a capture.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Discards {
    /// The driver flagged the buffer as damaged.
    pub error_flagged: u64,
    /// Exposed before the LED was known to be lit (a stale buffer).
    pub stale: u64,
    /// Within the settle window after an exposure or gain change.
    pub settling: u64,
    /// Shorter than the format says (a torn transfer).
    pub short: u64,
}

/// A camera that streams frames with monotonic timestamps.
pub trait Camera: Send {
    fn describe(&self) -> String;

    /// Set format, size, exposure, gain and every automatic mode off; read
    /// everything back.
    fn configure(
        &mut self,
        settings: &CameraSettings,
    ) -> impl Future<Output = Result<AppliedSettings, CameraError>> + Send;

    /// Change exposure and gain between frames (HDR brackets).
    fn set_exposure(&mut self, exposure_us: u32, gain: f32) -> impl Future<Output = Result<(), CameraError>> + Send;

    /// The first good frame whose exposure started at or after `after`
    /// (error-flagged frames, frames from before `after`, and frames within
    /// the settle window of a control change are discarded).
    fn frame_after(
        &mut self,
        after: MonoNs,
        timeout: Duration,
    ) -> impl Future<Output = Result<Frame, CameraError>> + Send;

    /// What [`Camera::frame_after`] discarded since [`Camera::configure`].
    fn discards(&mut self) -> impl Future<Output = Discards> + Send;
}
