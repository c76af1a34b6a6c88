//! `report.json`: what a capture and its fit did and how long each stage took.

use serde::Serialize;

#[derive(Clone, Debug, Default, Serialize)]
pub struct Report {
    pub sample: String,
    pub quality: String,
    pub rig: String,
    pub calibration: String,
    pub simulated: bool,
    /// Seconds per stage.
    pub timings: serde_json::Map<String, serde_json::Value>,
    pub frames: serde_json::Value,
    pub link: serde_json::Value,
    pub recoveries: Vec<String>,
    pub fit: serde_json::Value,
    pub material: Option<String>,
    pub peak_memory_mb: Option<f64>,
    /// Set when the material was fitted from an incomplete capture
    /// (`refl fit --partial`): planned and stored shots.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub partial: Option<serde_json::Value>,
}

impl Report {
    pub fn time(&mut self, stage: &str, seconds: f64) {
        self.timings.insert(stage.into(), serde_json::json!((seconds * 1000.0).round() / 1000.0));
    }
}

/// Peak resident memory of this process (Linux `VmHWM`), in MB.
pub fn peak_memory_mb() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}
