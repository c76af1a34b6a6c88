//! Quality presets: the speed/accuracy trade of a capture and its fit, as
//! named sets of knobs that the operator can override one by one.
//!
//! | knob | fast | balanced | best |
//! |---|---|---|---|
//! | gantry steps | 32 | 64 | 64 |
//! | LEDs used | every other (20) | all 40 | all 40 |
//! | exposures (HDR bracket) | x1, x1/8 | x1, x1/8 | x1, x1/8 |
//! | shorter exposures taken (`setup::Bracket`) | where the longer clipped | the same | the same |
//! | sample points (per side) | 48 | 96 | 128 |
//! | simulated camera (pixels per side) | 128 | 224 | 320 |
//! | NDF table | 16 x 48 | 32 x 96 | 32 x 96 |
//! | masking iterations (max) | 2 | 4 | 6 |
//! | synthesis clusters | 32 | 96 | 192 |
//! | synthesis descriptor length | 16 | 32 | 32 |
//! | synthesis rotation angles | 48 | 96 | 384 |
//! | synthesis neighbours looked up per point | 24 | 48 | 96 |
//! | synthesis passes | 1 | 2 | 2 |
//! | lobe tail in the cells no match covers (`fit::synth::tail`) | no | yes | yes |
//! | analytic fits | Ward iso/aniso, Cook-Torrance, GGX and Beckmann aniso | all nine | all nine |
//! | analytic fit clusters (shape parameters shared) | 16 | 32 | 64 |
//! | pooled NDF clusters, at most (the data choose how many, `fit::pooled`) | 16 | 32 | 64 |
//! | model choice (`fit::select`) scored on | every 8th step, held out of a second fit | the same | the same |
//!
//! The figures behind these choices are in `refl tradeoff` (see the README).

use brdf::ndf::NdfGrid;
use brdf::params::AnalyticModel;
use fit::FitSettings;
use fit::analytic::AnalyticSettings;
use fit::pooled::PoolSettings;
use fit::synth::{SearchMode, SynthSettings};
use serde::{Deserialize, Serialize};
use setup::Bracket;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Quality {
    pub name: String,
    pub steps: u32,
    pub led_stride: u8,
    pub exposures_us: Vec<u32>,
    /// Which shorter exposures are taken; captures made before adaptive
    /// brackets took every one.
    #[serde(default)]
    pub bracket: Bracket,
    pub dark_frames: u32,
    pub grid: u32,
    pub sim_camera_px: u32,
    pub fit: FitSettings,
    #[serde(default)]
    pub synth: SynthSettings,
    #[serde(default)]
    pub analytic: AnalyticSettings,
    /// Pooled estimation of each material's NDF (`fit::pooled`); absent
    /// in captures made before it existed, which are refitted without it.
    #[serde(default)]
    pub pool: Option<PoolSettings>,
}

pub const PRESETS: [&str; 3] = ["fast", "balanced", "best"];

/// The named preset, or `None`.
pub fn preset(name: &str) -> Option<Quality> {
    let all = AnalyticModel::ALL.to_vec();
    let q = match name {
        "fast" => Quality {
            name: name.into(),
            steps: 32,
            led_stride: 2,
            exposures_us: vec![20_000, 2_500],
            bracket: Bracket::Clipped,
            dark_frames: 4,
            grid: 48,
            sim_camera_px: 128,
            fit: FitSettings {
                grid: NdfGrid { n_theta: 16, n_phi: 48 },
                max_masking_iterations: 2,
                ..FitSettings::default()
            },
            synth: SynthSettings {
                clusters: 32,
                descriptor: 16,
                rotations: 48,
                neighbours: 24,
                passes: 1,
                // No tail: on this coarse grid, with a quarter of the
                // lights, the splatting kernels already carry a lobe's
                // flanks past its observed cells (ward: 6.6% of the table's
                // mass where no point observed, against the truth's 4.2%),
                // and a lobe fitted to the blurred body adds more (NDF error
                // on observed cells 0.065 -> 0.070; stop 44's note).
                tail: false,
                ..SynthSettings::default()
            },
            analytic: AnalyticSettings {
                models: vec![
                    AnalyticModel::WardIso,
                    AnalyticModel::WardAniso,
                    AnalyticModel::CookTorrance,
                    AnalyticModel::GgxAniso,
                    AnalyticModel::BeckmannAniso,
                ],
                clusters: 16,
                seed: 7,
                ..AnalyticSettings::default()
            },
            pool: Some(PoolSettings { clusters: 16, seed: 1, turn: true, ..PoolSettings::default() }),
        },
        "balanced" => Quality {
            name: name.into(),
            steps: 64,
            led_stride: 1,
            exposures_us: vec![20_000, 2_500],
            bracket: Bracket::Clipped,
            dark_frames: 8,
            grid: 96,
            sim_camera_px: 224,
            fit: FitSettings::default(),
            synth: SynthSettings {
                clusters: 96,
                descriptor: 32,
                rotations: 96,
                neighbours: 48,
                passes: 2,
                ..SynthSettings::default()
            },
            analytic: AnalyticSettings { models: all, clusters: 32, seed: 7, ..AnalyticSettings::default() },
            pool: Some(PoolSettings { clusters: 32, seed: 1, turn: true, ..PoolSettings::default() }),
        },
        "best" => Quality {
            name: name.into(),
            steps: 64,
            led_stride: 1,
            exposures_us: vec![20_000, 2_500],
            bracket: Bracket::Clipped,
            dark_frames: 8,
            grid: 128,
            sim_camera_px: 320,
            fit: FitSettings { max_masking_iterations: 6, masking_tolerance: 1e-3, ..FitSettings::default() },
            synth: SynthSettings {
                mode: SearchMode::Accelerated,
                clusters: 192,
                descriptor: 32,
                rotations: 384,
                neighbours: 96,
                passes: 2,
                ..SynthSettings::default()
            },
            analytic: AnalyticSettings { models: all, clusters: 64, seed: 7, ..AnalyticSettings::default() },
            pool: Some(PoolSettings { clusters: 64, seed: 1, turn: true, ..PoolSettings::default() }),
        },
        _ => return None,
    };
    Some(q)
}

/// Individual overrides of a preset's knobs (each `None` keeps the preset).
/// A misspelt knob (from the daemon's socket or web page) is an error, not
/// a setting silently left at the preset's.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Overrides {
    pub steps: Option<u32>,
    pub led_stride: Option<u8>,
    pub hdr: Option<u32>,
    #[serde(default)]
    pub bracket: Option<Bracket>,
    pub grid: Option<u32>,
    pub camera_px: Option<u32>,
    pub ndf_theta: Option<u32>,
    pub clusters: Option<u32>,
    /// Skip microfacet synthesis (keep the partial NDFs).
    #[serde(default)]
    pub no_synthesis: bool,
    /// Skip the analytic fits and the model choice.
    #[serde(default)]
    pub no_analytic: bool,
    /// Estimate every point's NDF from its own samples alone (no pooling).
    #[serde(default)]
    pub no_pooling: bool,
}

impl Quality {
    /// The fitting stages this preset asks for, minus those switched off.
    pub fn stages(&self, o: &Overrides) -> fit::Stages {
        fit::Stages {
            pool: self.pool.clone().filter(|_| !o.no_pooling),
            synth: (!o.no_synthesis).then(|| self.synth.clone()),
            analytic: (!o.no_analytic && !self.analytic.models.is_empty()).then(|| self.analytic.clone()),
            keep_samples: false,
        }
    }

    pub fn apply(mut self, o: &Overrides) -> Result<Self, crate::ConfigError> {
        let ensure = |ok: bool, why: String| if ok { Ok(()) } else { Err(crate::ConfigError::Override(why)) };
        if let Some(v) = o.steps {
            ensure((2..=1000).contains(&v), format!("--steps {v}: use 2..=1000"))?;
            self.steps = v;
        }
        if let Some(v) = o.led_stride {
            ensure((1..=20).contains(&v), format!("--led-stride {v}: use 1..=20"))?;
            self.led_stride = v;
        }
        if let Some(v) = o.hdr {
            ensure((1..=4).contains(&v), format!("--hdr {v}: use 1..=4 brackets"))?;
            self.exposures_us = (0..v).map(|k| 20_000 >> (3 * k)).collect();
        }
        if let Some(b) = o.bracket {
            self.bracket = b;
        }
        if let Some(v) = o.grid {
            ensure((4..=1024).contains(&v), format!("--grid {v}: use 4..=1024 points per side"))?;
            self.grid = v;
        }
        if let Some(v) = o.camera_px {
            ensure((32..=2048).contains(&v), format!("--camera-px {v}: use 32..=2048"))?;
            self.sim_camera_px = v;
        }
        if let Some(v) = o.ndf_theta {
            ensure((4..=128).contains(&v), format!("--ndf-theta {v}: use 4..=128 rings"))?;
            self.fit.grid = NdfGrid { n_theta: v, n_phi: 3 * v };
        }
        if let Some(v) = o.clusters {
            ensure((1..=100_000).contains(&v), format!("--clusters {v}: use 1..=100000"))?;
            self.synth.clusters = v;
        }
        Ok(self)
    }
}
