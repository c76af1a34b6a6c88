//! The capture directory, the lab's primary data.
//!
//! ```text
//! DIR/
//!   capture.json     what was captured and how: rig, plan, calibration, camera, status
//!   manifest.jsonl   append-only: one line per stored frame, with its checksum
//!   frames/          lossless 16-bit PNGs of the raw sensor data
//!   material/        the fitted material (written by the fitter's caller)
//!   report.json      timings and fit summary
//!   renders/         preview renders
//! ```
//!
//! Every frame is written to a temporary file and renamed into place, then
//! recorded in the manifest, so a crash or `kill -9` leaves either a
//! complete frame with its manifest line or nothing that counts. A resume
//! re-reads the manifest (a torn last line is ignored), verifies every
//! listed frame against its CRC-32, drops what does not verify, and
//! reports which shots remain.

mod calibrations;
mod dir;
mod format;

pub use calibrations::CalibrationStore;
pub use dir::{CaptureDir, DirLock, ResumeState, StoreError};
pub use format::{
    CAPTURE_FORMAT_VERSION, CaptureInfo, CaptureStatus, FrameKind, ManifestEntry, SensorInfo, SimInfo, clipped_shots,
    wanted_shots,
};
