//! From frames to a measured, spatially varying microfacet material. No IO:
//! callers stream frames in and get maps and tables out.
//!
//! Stages (Wang et al., "Modeling Anisotropic Surface Reflectance with
//! Example-Based Microfacet Synthesis", SIGGRAPH 2008, and its talk):
//! 1. [`ingest`]: frames (streamed during capture, or replayed from a stored
//!    capture) become per-(light, point) reflectance samples
//!    `rho = I / ((n.i) L |P - x|^2)` with calibration, dark subtraction,
//!    HDR merging and masks ([`samples`] holds them; [`context`] the
//!    geometry).
//! 2. [`partial`]: per point, the diffuse/specular split ([`diffuse`]), the
//!    partial NDF by splatting and push-pull ([`pushpull`]), the masking
//!    term by integration, `k_s` and the Fresnel index; [`points`] runs it
//!    over the grid in parallel.
//! 3. [`synth`]: microfacet synthesis completes each point's partial NDF
//!    from other points' rotated NDFs (clustering, pruning, approximate
//!    nearest neighbours); the completed points are refitted.
//! 4. [`analytic`] and [`select`]: analytic models fitted per point and
//!    the per-point choice among them and the table.
//!
//! [`pipeline`] runs these stages in their one order; every caller (the
//! streaming fit, `refl fit`, the hold-out refit, benchmarks, tests) goes
//! through it. [`calibrate`] solves the white scan's calibration, [`geometric`]
//! the camera's from views of a checkerboard.
//!
//! Conventions are those of the `brdf` crate: local frame with the normal
//! on `+z` and `x` along the gantry, `i` toward the light, `o` toward the
//! camera, `integral D cos = 1`, and the fitted model
//! `f = kd / pi + ks D(h) F_rel(i.h) / (4 sigma(i) sigma(o))` with
//! `F_rel(1) = 1` (so `ks` is the specular albedo at normal incidence).

pub mod analytic;
pub mod calibrate;
pub mod context;
pub mod diffuse;
pub mod drift;
pub mod geometric;
pub mod ingest;
pub mod lsq;
pub mod mirror;
pub mod partial;
pub mod pipeline;
pub mod points;
pub mod pooled;
pub mod progress;
pub mod pushpull;
pub mod samples;
pub mod select;
pub mod settings;
pub mod synth;
pub mod tol;

pub use context::{FitContext, FitInputs};
pub use ingest::{FrameSink, Ingest};
pub use partial::{DEFAULT_ETA, PointFit, PointSamples, Sample, point_flag};
pub use pipeline::{FitError, FitResult, PartialMaps, Pipeline, Stages, TileFit, TilePipeline, Timings, run_merged};
pub use points::{PointMaps, fit_points};
pub use progress::{FitProgress, FitStage};
pub use samples::SampleStore;
pub use settings::FitSettings;
