//! The rig file: one TOML file that says what the rig is (simulated or
//! hardware), how to reach its devices, and its geometry. See RIGFILE.md.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use rig::mcu::PortLocator;
use serde::{Deserialize, Serialize};
use setup::RigGeometry;

/// The embedded default (the simulated rig).
pub const DEFAULT_RIG: &str = include_str!("../rigs/sim.toml");

/// Where a system-wide rig file is looked for when `--rig` is not given.
pub const SYSTEM_RIG: &str = "/etc/reflectometer/rig.toml";

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RigKind {
    Sim,
    Hardware,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SerialSection {
    #[serde(flatten)]
    pub locator: PortLocator,
    #[serde(default = "default_baud")]
    pub baud: u32,
}

fn default_baud() -> u32 {
    rig::mcu::port::DEFAULT_BAUD
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraSection {
    /// Device path (`/dev/reflectometer/camera`, the udev rule's link).
    pub device: PathBuf,
    /// Electrons per DN at unit gain (datasheet or photon transfer curve).
    pub e_per_dn: f32,
    #[serde(default = "default_fps")]
    pub fps: f32,
    /// Pixel format by its code (`"Y16"`, `"BA81"`); by default the deepest
    /// raw format the camera offers (`capture --list-cameras` shows them).
    #[serde(default)]
    pub format: Option<String>,
    /// The gain control's value that means unit gain; by default the
    /// control's default value.
    #[serde(default)]
    pub gain_unity: Option<i64>,
    /// Driver buffers mapped for streaming.
    #[serde(default = "default_buffers")]
    pub buffers: u32,
}

fn default_buffers() -> u32 {
    4
}

fn default_fps() -> f32 {
    30.0
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimSection {
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub realtime: bool,
    #[serde(default = "default_fps")]
    pub fps: f32,
    #[serde(default = "default_time_scale")]
    pub time_scale: f32,
}

fn default_time_scale() -> f32 {
    0.001
}

impl Default for SimSection {
    fn default() -> Self {
        Self { seed: 1, realtime: false, fps: 30.0, time_scale: 0.001 }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RigFile {
    pub name: String,
    pub kind: RigKind,
    #[serde(default)]
    pub geometry: Option<RigGeometry>,
    pub serial: Option<SerialSection>,
    pub camera: Option<CameraSection>,
    #[serde(default)]
    pub sim: SimSection,
    pub white_reference_albedo: f32,
    pub led_current_ma: u16,
}

impl RigFile {
    pub fn parse(text: &str, source: &str) -> Result<Self> {
        let r: RigFile =
            toml::from_str(text).with_context(|| format!("{source} is not a valid rig file (see RIGFILE.md)"))?;
        if r.kind == RigKind::Hardware && (r.serial.is_none() || r.camera.is_none()) {
            bail!("{source}: a hardware rig needs [serial] and [camera] sections (see RIGFILE.md)");
        }
        if !(0.1..=1.0).contains(&r.white_reference_albedo) {
            bail!("{source}: white_reference_albedo {} is not a plausible albedo", r.white_reference_albedo);
        }
        Ok(r)
    }

    /// `--rig FILE`, else the system-wide file, else the embedded default.
    pub fn load(path: Option<&Path>) -> Result<(Self, String)> {
        let (text, source) = match path {
            Some(p) => (
                std::fs::read_to_string(p).with_context(|| format!("cannot read rig file {}", p.display()))?,
                p.display().to_string(),
            ),
            None if Path::new(SYSTEM_RIG).exists() => (
                std::fs::read_to_string(SYSTEM_RIG).with_context(|| format!("cannot read {SYSTEM_RIG}"))?,
                SYSTEM_RIG.to_string(),
            ),
            None => (DEFAULT_RIG.to_string(), "embedded simulated rig".to_string()),
        };
        Ok((Self::parse(&text, &source)?, source))
    }

    pub fn geometry(&self) -> RigGeometry {
        self.geometry.clone().unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_default_parses_and_bad_files_are_explained() {
        let r = RigFile::parse(DEFAULT_RIG, "default").unwrap();
        assert_eq!(r.kind, RigKind::Sim);
        let e = RigFile::parse("name = 1", "x.toml").unwrap_err();
        assert!(format!("{e:#}").contains("x.toml"));
        let hw = "name='a'\nkind='hardware'\nwhite_reference_albedo=0.99\nled_current_ma=200\n";
        assert!(format!("{:#}", RigFile::parse(hw, "hw.toml").unwrap_err()).contains("[serial]"));
    }
}
