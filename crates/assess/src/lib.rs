//! What the lab does with a capture and its material once they exist:
//!
//! - `eval`: scores against ground truth (simulated captures) and by
//!   hold-out (any capture); `truth` finds a simulated capture's ground
//!   truth.
//! - `renders`: preview renders and comparison sheets.
//! - `replay`: a stored capture as the fitter's input, for every caller
//!   that refits one.
//! - `report`: `report.json`, typed and versioned.
//! - `tradeoff`: the speed/accuracy sweep over the quality presets.
//! - `bench`: the fitter's and the simulator's benchmarks; `budget`: the
//!   fitter's error by source.
//! - `inspect`, `gltf`: a material's summary and its glTF export;
//!   `export`: a capture's calibrated samples as NumPy arrays.
//!
//! These are the application's tools, not its job: they sit below
//! `crates/cli` (which drives the capture and the daemon) and, like it,
//! report errors with `anyhow` for a person to read.

pub mod bench;
pub mod budget;
pub mod eval;
pub mod export;
pub mod footprint;
pub mod gltf;
pub mod inspect;
pub mod renders;
pub mod replay;
pub mod report;
pub mod tradeoff;
pub mod truth;

/// Where long work reports its stages (the application's progress
/// display, a log, or nothing).
pub trait Progress {
    fn stage(&mut self, stage: &str, detail: String);
}

/// Progress nobody watches.
#[derive(Debug, Default)]
pub struct Quiet;

impl Progress for Quiet {
    fn stage(&mut self, _: &str, _: String) {}
}
