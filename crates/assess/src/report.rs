//! `report.json`: what a capture and its fit did and how long each stage
//! took. Typed and versioned ([`REPORT_FORMAT_VERSION`]); [`read`] refuses
//! another version with a clear error.

use std::collections::BTreeMap;
use std::path::Path;

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};

/// Version of `report.json`.
pub const REPORT_FORMAT_VERSION: u32 = 1;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub format_version: u32,
    pub sample: String,
    pub quality: String,
    pub rig: String,
    pub calibration: String,
    pub simulated: bool,
    /// Seconds per stage.
    pub timings: BTreeMap<String, f64>,
    pub frames: Option<FramesReport>,
    pub link: Option<LinkReport>,
    pub recoveries: Vec<String>,
    pub fit: Option<FitReport>,
    pub material: Option<String>,
    pub peak_memory_mb: Option<f64>,
    /// Set when the material was fitted from an incomplete capture
    /// (`refl fit --partial`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub partial: Option<PartialReport>,
}

impl Default for Report {
    fn default() -> Self {
        Self {
            format_version: REPORT_FORMAT_VERSION,
            sample: String::new(),
            quality: String::new(),
            rig: String::new(),
            calibration: String::new(),
            simulated: false,
            timings: BTreeMap::new(),
            frames: None,
            link: None,
            recoveries: Vec::new(),
            fit: None,
            material: None,
            peak_memory_mb: None,
            partial: None,
        }
    }
}

/// The frames of a capture.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FramesReport {
    pub committed: u64,
    /// Shots taken again because the rig recovered while they were exposed.
    pub retakes: u64,
    pub moves: u64,
    /// Frames the camera discarded and replaced.
    pub camera_discards: rig::camera::Discards,
    /// Stored shots at one of the bracket's shorter exposures (an
    /// adaptive bracket takes them only where the longer one clipped).
    #[serde(default)]
    pub shorter_exposures: u64,
}

/// The serial link's counters over the capture.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LinkReport {
    pub commands: u64,
    pub retransmits: u64,
    pub stale_replies: u64,
    pub bad_frames: u64,
    pub mean_rtt_us: Option<f64>,
}

/// What the fit produced.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FitReport {
    pub points: usize,
    /// Points carrying each flag, by the flag's name.
    pub flags: BTreeMap<String, usize>,
    pub samples: fit::samples::Census,
    pub sample_store_mb: f64,
    pub ndf_tables_mb: f64,
    pub material_disk_mb: f64,
    pub synthesis: Option<fit::synth::SynthStats>,
    /// Points pooled into their material's NDF, and those that kept their own.
    #[serde(default)]
    pub pooling: Option<fit::pooled::PoolStats>,
    pub analytic: Vec<AnalyticReport>,
    pub model_choice: Option<fit::select::SelectionSummary>,
    /// What the LED drift correction did (absent on a rig without
    /// reference patches).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drift: Option<fit::drift::DriftSummary>,
}

/// One analytic model's fit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AnalyticReport {
    pub model: String,
    pub seconds: f64,
    /// Mean over the points with a fit (summed residuals over all points).
    pub mean_residual: f32,
    /// Points where the model could not be built from its fit.
    pub points_without_fit: usize,
}

/// Shots a partial material was fitted from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PartialReport {
    pub planned_shots: usize,
    pub stored_shots: usize,
}

impl Report {
    pub fn time(&mut self, stage: &str, seconds: f64) {
        self.timings.insert(stage.into(), (seconds * 1000.0).round() / 1000.0);
    }
}

/// Read a capture's `report.json`, refusing another format version.
pub fn read(dir: &Path) -> Result<Report> {
    let p = dir.join("report.json");
    let bytes = std::fs::read(&p).with_context(|| format!("cannot read {}", p.display()))?;
    let v: serde_json::Value = serde_json::from_slice(&bytes).with_context(|| format!("{} is damaged", p.display()))?;
    let found = v.get("format_version").and_then(|x| x.as_u64()).unwrap_or(0);
    if found != REPORT_FORMAT_VERSION as u64 {
        bail!("{} is report format version {found}; this program reads version {REPORT_FORMAT_VERSION}", p.display());
    }
    serde_json::from_value(v).with_context(|| format!("{} is damaged", p.display()))
}

/// Peak resident memory of this process (Linux `VmHWM`), in MB.
pub fn peak_memory_mb() -> Option<f64> {
    status_mb("VmHWM:")
}

/// Resident memory of this process now (Linux `VmRSS`), in MB.
pub fn resident_memory_mb() -> Option<f64> {
    status_mb("VmRSS:")
}

/// A size in kB that `/proc/self/status` gives on the line starting `key`, in MB.
fn status_mb(key: &str) -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(key))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_report_reads_back_and_another_version_is_refused() {
        let d = std::env::temp_dir().join(format!("report-test-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let mut r = Report { sample: "satin".into(), ..Report::default() };
        r.time("capture_s", 1.23456);
        std::fs::write(d.join("report.json"), serde_json::to_vec(&r).unwrap()).unwrap();
        let back = read(&d).unwrap();
        assert_eq!(back.timings["capture_s"], 1.235);
        assert_eq!(back, Report { timings: back.timings.clone(), ..r.clone() });
        let mut v = serde_json::to_value(&r).unwrap();
        v["format_version"] = serde_json::json!(2);
        std::fs::write(d.join("report.json"), serde_json::to_vec(&v).unwrap()).unwrap();
        let e = format!("{:#}", read(&d).unwrap_err());
        assert!(e.contains("version 2"), "{e}");
        std::fs::remove_dir_all(&d).unwrap();
    }
}
