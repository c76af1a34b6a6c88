//! The rig file: one TOML file that says what the rig is (simulated or
//! hardware), how to reach its devices, and its geometry. See RIGFILE.md.

use std::path::{Path, PathBuf};

use rig::mcu::PortLocator;
use serde::{Deserialize, Serialize};
use setup::RigGeometry;

use crate::ConfigError;

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

/// The parts of the simulated rig a perturbation can touch, by name (bit
/// `k` of [`SimRig::Perturbed`]'s `parts` is `RIG_PARTS[k]`): the camera
/// (pose and lens), the LEDs (positions, bar height and tilt), the gantry
/// (offset, scale, backlash), the sample's height and tilt, and the sensor
/// and room (dark current, hot pixels, ambient light), and the LEDs' drift
/// as the bar warms.
pub const RIG_PARTS: [&str; 6] = ["camera", "leds", "gantry", "sample", "sensor", "drift"];

/// Every part perturbed.
pub const ALL_PARTS: u8 = (1 << RIG_PARTS.len()) - 1;

/// Which physical rig the simulator renders: the rig file exactly, or one
/// that departs from it within a bench's tolerances, drawn from a seed
/// (`sim::RigTruth`). Written `"ideal"`, `"perturbed:SEED"`, or
/// `"perturbed:SEED:PART+PART"` for a rig whose other parts are exactly as
/// filed (the same draw, with the other errors left out: what each part's
/// errors cost a fit).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum SimRig {
    Ideal,
    Perturbed { seed: u64, parts: u8 },
}

impl Default for SimRig {
    fn default() -> Self {
        SimRig::Perturbed { seed: 1, parts: ALL_PARTS }
    }
}

impl SimRig {
    /// Whether the rig's part named `part` (one of [`RIG_PARTS`]) departs
    /// from the rig file.
    pub fn perturbs(&self, part: &str) -> bool {
        match self {
            SimRig::Ideal => false,
            SimRig::Perturbed { parts, .. } => {
                RIG_PARTS.iter().position(|p| *p == part).is_some_and(|k| parts >> k & 1 == 1)
            }
        }
    }
}

impl std::str::FromStr for SimRig {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || {
            format!(
                "'{s}' is not a simulated rig: use 'ideal', 'perturbed:SEED' (e.g. perturbed:1) or \
                 'perturbed:SEED:PART+PART' with parts among {}",
                RIG_PARTS.join(", ")
            )
        };
        let mut it = s.split(':');
        match (it.next(), it.next(), it.next(), it.next()) {
            (Some("ideal"), None, ..) => Ok(SimRig::Ideal),
            (Some("perturbed"), None, ..) => Ok(SimRig::default()),
            (Some("perturbed"), Some(seed), parts, None) => {
                let seed = seed.parse().map_err(|_| bad())?;
                let parts = match parts {
                    None => ALL_PARTS,
                    Some(list) => list.split('+').try_fold(0u8, |acc, name| {
                        RIG_PARTS.iter().position(|p| *p == name).map(|k| acc | 1 << k).ok_or_else(bad)
                    })?,
                };
                Ok(SimRig::Perturbed { seed, parts })
            }
            _ => Err(bad()),
        }
    }
}

impl std::fmt::Display for SimRig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SimRig::Ideal => f.write_str("ideal"),
            SimRig::Perturbed { seed, parts } if *parts == ALL_PARTS => write!(f, "perturbed:{seed}"),
            SimRig::Perturbed { seed, parts } => {
                let names: Vec<&str> =
                    RIG_PARTS.iter().enumerate().filter(|(k, _)| parts >> k & 1 == 1).map(|(_, p)| *p).collect();
                write!(f, "perturbed:{seed}:{}", names.join("+"))
            }
        }
    }
}

impl TryFrom<String> for SimRig {
    type Error = String;

    fn try_from(s: String) -> Result<Self, String> {
        s.parse()
    }
}

impl From<SimRig> for String {
    fn from(r: SimRig) -> String {
        r.to_string()
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimSection {
    #[serde(default)]
    pub seed: u64,
    /// The physical rig behind the rig file.
    #[serde(default)]
    pub rig: SimRig,
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
        Self { seed: 1, rig: SimRig::default(), realtime: false, fps: 30.0, time_scale: 0.001 }
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
    pub fn parse(text: &str, source: &str) -> Result<Self, ConfigError> {
        let invalid = |message: String| ConfigError::Invalid { source_name: source.to_string(), message };
        let r: RigFile = toml::from_str(text)
            .map_err(|e| ConfigError::Syntax { source_name: source.to_string(), message: e.to_string() })?;
        if r.kind == RigKind::Hardware && (r.serial.is_none() || r.camera.is_none()) {
            return Err(invalid("a hardware rig needs [serial] and [camera] sections".into()));
        }
        r.validate().map_err(|e| invalid(e.to_string()))?;
        Ok(r)
    }

    /// Check every field against the ranges a rig can have.
    pub fn validate(&self) -> Result<(), setup::Invalid> {
        use setup::valid::{above, count, within};
        within("white_reference_albedo", self.white_reference_albedo, 0.1, 1.0)?;
        count("led_current_ma", self.led_current_ma as u64, 1, 10_000)?;
        if let Some(g) = &self.geometry {
            g.validate()?;
        }
        if let Some(c) = &self.camera {
            above("camera.e_per_dn", c.e_per_dn, 0.0, 1e6)?;
            above("camera.fps", c.fps, 0.0, 10_000.0)?;
            count("camera.buffers", c.buffers as u64, 2, 32)?;
        }
        if let Some(s) = &self.serial {
            count("serial.baud", s.baud as u64, 300, 100_000_000)?;
        }
        above("sim.fps", self.sim.fps, 0.0, 10_000.0)?;
        within("sim.time_scale", self.sim.time_scale, 0.0, 100.0)?;
        Ok(())
    }

    /// `--rig FILE`, else the system-wide file, else the embedded default.
    pub fn load(path: Option<&Path>) -> Result<(Self, String), ConfigError> {
        let read = |p: &Path| {
            std::fs::read_to_string(p).map_err(|source| ConfigError::Read { path: p.display().to_string(), source })
        };
        let (text, source) = match path {
            Some(p) => (read(p)?, p.display().to_string()),
            None if Path::new(SYSTEM_RIG).exists() => (read(Path::new(SYSTEM_RIG))?, SYSTEM_RIG.to_string()),
            None => (DEFAULT_RIG.to_string(), "embedded simulated rig".to_string()),
        };
        Ok((Self::parse(&text, &source)?, source))
    }

    /// The name calibrations are kept under: the rig's name, and on the
    /// simulated rig which physical rig it is (a calibration of one
    /// simulated rig is wrong for another).
    pub fn calibration_key(&self) -> String {
        match self.kind {
            RigKind::Hardware => self.name.clone(),
            RigKind::Sim => format!("{}-{}", self.name, self.sim.rig.to_string().replace(':', "-")),
        }
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
        assert!(e.to_string().contains("x.toml"));
        assert_eq!(r.sim.rig, SimRig::Perturbed { seed: 1, parts: ALL_PARTS });
        assert_eq!(r.calibration_key(), "sim-perturbed-1");
        for (text, rig) in [
            ("ideal", SimRig::Ideal),
            ("perturbed:7", SimRig::Perturbed { seed: 7, parts: ALL_PARTS }),
            ("perturbed:7:camera+sensor", SimRig::Perturbed { seed: 7, parts: 0b10001 }),
        ] {
            assert_eq!(text.parse::<SimRig>().unwrap(), rig);
            assert_eq!(rig.to_string(), text);
        }
        let only = "perturbed:2:sample".parse::<SimRig>().unwrap();
        assert!(only.perturbs("sample") && !only.perturbs("camera") && !SimRig::Ideal.perturbs("sample"));
        for bad in ["perturbed:x", "perturbed:1:lens", "perturbed:1:camera:leds", "tilted"] {
            assert!(bad.parse::<SimRig>().unwrap_err().contains("perturbed:SEED"), "{bad}");
        }
        let e = RigFile::parse(
            "name='s'\nkind='sim'\nwhite_reference_albedo=0.9\nled_current_ma=9\n[sim]\nrig='tilted'\n",
            "t.toml",
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("perturbed:SEED") && e.contains("t.toml"), "{e}");
        let hw = "name='a'\nkind='hardware'\nwhite_reference_albedo=0.99\nled_current_ma=200\n";
        assert!(format!("{}", RigFile::parse(hw, "hw.toml").unwrap_err()).contains("[serial]"));
    }

    /// Every impossible value the issue found accepted is refused, naming
    /// the field and its range.
    #[test]
    fn impossible_rigs_are_refused_naming_the_field() {
        let base = "name='s'\nkind='sim'\nwhite_reference_albedo=0.95\nled_current_ma=200\n";
        let cases = [
            ("[sim]\ntime_scale = nan\n", "sim.time_scale"),
            ("[sim]\nfps = -30.0\n", "sim.fps"),
            ("[sim]\nfps = 0.0\n", "sim.fps"),
        ];
        for (extra, field) in cases {
            let e = format!("{}", RigFile::parse(&format!("{base}{extra}"), "r.toml").unwrap_err());
            assert!(e.contains(field) && e.contains("must be") && e.contains("r.toml"), "{extra}: {e}");
        }
        let geometry = toml::to_string(&RigFile {
            geometry: Some(RigGeometry::default()),
            ..RigFile::parse(DEFAULT_RIG, "default").unwrap()
        })
        .unwrap();
        for (from, to, field) in [
            ("fov_y_deg = 15.0", "fov_y_deg = nan", "geometry.camera.fov_y_deg"),
            ("height_mm = 40.0", "height_mm = -40.0", "geometry.bar.height_mm"),
            ("width_mm = 100.0", "width_mm = -100.0", "geometry.sample.width_mm"),
            ("speed_mm_s = 100.0", "speed_mm_s = 0.0", "geometry.gantry.speed_mm_s"),
        ] {
            assert!(geometry.contains(from), "{from} not in {geometry}");
            let e = format!("{}", RigFile::parse(&geometry.replacen(from, to, 1), "r.toml").unwrap_err());
            assert!(e.contains(field), "{to}: {e}");
        }
    }
}
