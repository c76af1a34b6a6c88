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
    /// Kernel weight for a cell to count as observed. A cell among samples
    /// receives about 1.5 with the default kernel scale; one sample gives
    /// 0.2 to a cell 0.9 sample spacings away (`exp(-2 d^2 / s^2)` with the
    /// kernel at half the spacing), so the observed region ends about one
    /// sampling interval beyond the outermost sample: the resolution of the
    /// measurement, no further.
    pub observed_weight: f32,
    /// Splatting kernel width as a fraction of the local half-vector
    /// spacing (`FitContext::half_vector_spacing`, the larger of the two
    /// lattice directions): 0.5 keeps neighbouring kernels overlapping (no
    /// holes between samples) while blurring less than the sampling
    /// resolution. Measured: 0.6 and 0.8 bias eta and `ks` on the Ward
    /// surface of `tests/fit_accuracy.rs`, 0.5 passes it.
    pub kernel_scale: f32,
    /// Leave out every k-th gantry step (all of its lights: `step % k ==
    /// 0`) for hold-out validation; `None` uses every light. Whole steps,
    /// not single LEDs, so that a held-out light is never interpolated
    /// between training lights on both sides along the bar.
    pub holdout_every: Option<u32>,
}

impl FitSettings {
    /// Is light `q` of `plan` held out of the fit?
    pub fn holds_out(&self, plan: &setup::CapturePlan, q: usize) -> bool {
        let per_step = plan.leds.len().max(1);
        self.holdout_every.is_some_and(|k| k > 0 && ((q / per_step) as u32).is_multiple_of(k))
    }
}

impl Default for FitSettings {
    fn default() -> Self {
        Self {
            grid: NdfGrid::DEFAULT,
            max_masking_iterations: 4,
            masking_tolerance: 2e-3,
            fit_fresnel: true,
            min_samples: 24,
            observed_weight: 0.2,
            kernel_scale: 0.5,
            holdout_every: None,
        }
    }
}
