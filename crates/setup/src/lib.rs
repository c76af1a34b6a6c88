//! What the rig is: its geometry ([`geometry`]), the camera's projection
//! ([`camera`]), the capture plan ([`plan`]) and the radiometric
//! calibration ([`calibration`]), and the ranges each may take
//! ([`valid`]). Pure data and math in millimetres, in the
//! sample frame (`z = 0` the sample, `+x` the gantry's travel); no IO.
//! The capture writes all of it into `capture.json`, so a fit needs nothing
//! but the capture directory.

pub mod calibration;
pub mod camera;
pub mod geometry;
pub mod plan;
pub mod target;
pub mod valid;

pub use calibration::Calibration;
pub use camera::CameraModel;
pub use geometry::{
    Gantry, LedBar, LedEmission, PointGrid, ReferencePatch, RigGeometry, SampleArea, trapezoid_seconds,
};
pub use plan::{Bracket, CapturePlan, PlanError, PlannedShot};
pub use target::CheckerTarget;
pub use valid::Invalid;
