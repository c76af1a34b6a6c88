//! Materials: what a point of a sample reflects ([`PointMaterial`]), the
//! spatially varying interface every consumer evaluates ([`SvBrdf`]: the
//! simulated camera, the renderer, the evaluator), and the on-disk format
//! the fitter writes.

pub mod point;

pub use point::{PointMaterial, SvBrdf};
