//! What the operator configures: the rig file (`rigfile`, specified in
//! RIGFILE.md) and the quality presets with their per-knob overrides
//! (`presets`). Both are read by the capture job, the fit of a stored
//! capture and the evaluation, so they live below all three.

pub mod presets;
pub mod rigfile;

pub use presets::{Overrides, PRESETS, Quality, preset};
pub use rigfile::{RIG_PARTS, RigFile, RigKind, SimRig};

/// A configuration the operator must correct; the message names the file
/// or flag and what it may be.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read rig file {path}: {source}")]
    Read { path: String, source: std::io::Error },
    #[error("{source_name} is not a valid rig file (see RIGFILE.md): {message}")]
    Syntax { source_name: String, message: String },
    #[error("{source_name}: {message} (see RIGFILE.md)")]
    Invalid { source_name: String, message: String },
    #[error("{0}")]
    Override(String),
}
