//! The fitter's knobs. Quality presets (`fast`, `balanced`, `best`) are
//! defined by the callers from these; every knob has a documented default.

use brdf::ndf::NdfGrid;
use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FitSettings {
    /// NDF table resolution.
    pub grid: NdfGrid,
    /// Upper bound on the alternation between `D` and the masking term.
    pub max_masking_iterations: u32,
    /// Stop when the NDF changes by less than this (relative L2) between
    /// iterations.
    pub masking_tolerance: f32,
    /// Fit the Fresnel index from centrally symmetric cell pairs.
    pub fit_fresnel: bool,
    /// Fewer usable samples than this and a point gets no specular fit.
    pub min_samples: usize,
    /// Kernel weight for a cell to count as observed (a cell among samples
    /// receives about 2 with the default kernel scale).
    pub observed_weight: f32,
    /// Splatting kernel width as a fraction of the local half-vector
    /// spacing: 0.6 keeps neighbouring kernels overlapping (no holes between
    /// samples) while blurring less than the sampling resolution.
    pub kernel_scale: f32,
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            grid: NdfGrid::DEFAULT,
            max_masking_iterations: 4,
            masking_tolerance: 2e-3,
            fit_fresnel: true,
            min_samples: 24,
            observed_weight: 0.5,
            kernel_scale: 0.6,
        }
    }
}
