//! Renders a material on its flat sample for any camera and any set of point
//! or directional lights, and under an environment map ([`render`]); writes
//! linear EXR and tone-mapped PNG, draws labelled comparison sheets, and
//! computes the image metric the evaluator uses ([`output`]).

pub mod output;
pub mod render;
pub mod scene;

pub use output::{rel_rmse, write_exr, write_png, write_sheet};
pub use render::{Image, render, render_subpixels};
pub use scene::{EnvMap, Light, Scene};
