//! The serialised types of a capture directory.

use frame::{FrameMeta, Layout};
use serde::{Deserialize, Serialize};
use setup::{Calibration, CapturePlan, PlannedShot, PointGrid, RigGeometry};

/// Version of `capture.json` and `manifest.jsonl`.
pub const CAPTURE_FORMAT_VERSION: u32 = 1;

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CaptureStatus {
    /// Frames are being taken (or the process died while taking them).
    InProgress,
    /// Stopped by the operator or an error; `--resume` continues it.
    Interrupted,
    /// Every planned frame is stored, but the fit has not written the
    /// material yet (it is running, or was stopped or failed: `--resume`
    /// or `refl fit` makes it).
    Captured,
    /// Every planned frame is stored, and the material (unless the capture
    /// was made with `--no-fit`), renders and report are written.
    Complete,
}

/// Sensor properties the fitter's noise model needs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensorInfo {
    pub bit_depth: u8,
    /// Electrons per DN at unit gain (from the datasheet or a photon
    /// transfer measurement).
    pub e_per_dn: f32,
    /// The sensor's sample layout (Bayer, mono, RGB), which sets how pixel
    /// noise reaches a sample; absent from captures made before it was
    /// recorded, whose noise is modelled as one pixel's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub layout: Option<frame::Layout>,
}

/// For simulated captures: what was simulated (the ground truth).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimInfo {
    /// Built-in material name, or `None` when `material_dir` is used.
    pub material: Option<String>,
    pub material_dir: Option<String>,
    pub faults: String,
    pub seed: u64,
    /// The physical rig behind the rig file (`ideal`, `perturbed:SEED`);
    /// captures from before it was recorded were made on the ideal rig.
    #[serde(default = "ideal_rig")]
    pub rig: String,
}

fn ideal_rig() -> String {
    "ideal".into()
}

/// `capture.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CaptureInfo {
    pub format_version: u32,
    pub sample: String,
    pub created_utc: String,
    pub status: CaptureStatus,
    pub geometry: RigGeometry,
    pub plan: CapturePlan,
    pub calibration: Calibration,
    /// Where the calibration came from (its directory), if stored.
    pub calibration_source: Option<String>,
    pub sensor: SensorInfo,
    /// The camera's settings as read back from the device (`null` until
    /// the camera is configured).
    pub camera: Option<frame::AppliedSettings>,
    /// The point grid the material is fitted on.
    pub grid: PointGrid,
    /// Quality preset and knobs, as the operator chose them: the
    /// application's settings type (`config::Quality`), which reads
    /// them back on resume and refit; the fixture test
    /// (`tests/operator.rs`) keeps a capture of this format version
    /// readable.
    pub settings: serde_json::Value,
    pub simulated: Option<SimInfo>,
}

/// What a stored frame is.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum FrameKind {
    /// A planned shot: one LED alone at one gantry position and exposure
    /// (its fields inline in the JSON, beside `kind`).
    Shot(PlannedShot),
    /// All LEDs off (black level and fixed pattern).
    Dark { exposure: u8, n: u32 },
}

impl FrameKind {
    pub fn file_name(&self) -> String {
        match self {
            FrameKind::Shot(s) => format!("s{:03}_l{:02}_e{}.png", s.step, s.led, s.exposure),
            FrameKind::Dark { exposure, n } => format!("dark_e{exposure}_{n:03}.png"),
        }
    }
}

/// One line of `manifest.jsonl`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ManifestEntry {
    pub frame: FrameKind,
    /// Path relative to the capture directory.
    pub file: String,
    pub crc32: u32,
    pub bytes: u64,
    pub width: u32,
    pub height: u32,
    pub layout: Layout,
    pub bit_depth: u8,
    pub meta: FrameMeta,
    /// When the LED was known to be lit (monotonic ns), for shots.
    pub lit_at_ns: Option<u64>,
    /// A shot's pixels clipped on the sample, where the capture counted
    /// them (its bracket's shorter exposure follows from it:
    /// [`setup::CapturePlan::wants`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clipped: Option<u32>,
}

/// The shots a complete capture under `plan` holds, given what the stored
/// frames `entries` recorded: every shot of a whole bracket; of an adaptive
/// one, the shorter exposures of the lights whose longer exposure clipped
/// or is not stored yet.
pub fn wanted_shots(plan: &setup::CapturePlan, entries: &[ManifestEntry]) -> Vec<setup::PlannedShot> {
    let clipped = clipped_shots(entries);
    plan.shots().into_iter().filter(|s| plan.wants(s, |k| clipped.get(&k).copied())).collect()
}

/// Whether each stored shot (by plan index) clipped on the sample; a frame
/// stored without a count counts as clipped, so that what follows from it
/// is taken rather than guessed away.
pub fn clipped_shots(entries: &[ManifestEntry]) -> std::collections::HashMap<u32, bool> {
    entries
        .iter()
        .filter_map(|e| match e.frame {
            FrameKind::Shot(s) => Some((s.index, e.clipped.is_none_or(|n| n > 0))),
            FrameKind::Dark { .. } => None,
        })
        .collect()
}
