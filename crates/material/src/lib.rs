//! Materials: what a point of a sample reflects ([`PointMaterial`]), the
//! spatially varying interface every consumer evaluates ([`SvBrdf`]: the
//! simulated camera, the renderer, the evaluator), the fitted material in
//! memory ([`Material`]), its on-disk format ([`io`], specified in
//! `MATERIAL.md`), and a view that evaluates any stored model
//! ([`MaterialView`]).

pub mod data;
pub mod io;
pub mod merl;
pub mod point;
pub mod rgl;
pub mod view;

pub use data::{Choice, ChoiceMap, Material, ModelMap, NdfKind, PartialFit, UNMEASURED};
pub use io::{MaterialError, WriteMode, read, read_channels, write};
pub use point::{PointMaterial, SvBrdf};
pub use view::{MaterialView, ModelChoice};
