//! Rig control: the devices (the microcontroller that drives the gantry and
//! the LEDs, and the camera), their backends, and the capture sequencing.
//! This is the only crate that opens devices.
//!
//! - [`mcu`]: the serial protocol client and the recovering [`mcu::Rig`]
//!   (recovery is a bounded loop: attempts and time per operation,
//!   attempts per session).
//! - [`camera`]: the camera trait, the frame filter and what it discarded,
//!   pixel formats, the V4L2 backend and camera discovery.
//! - [`sequence`]: the capture loop that commits only confirmed exposures
//!   (its shots are the plan's own `setup::PlannedShot`).
//! - [`clock`]: the one place that converts between clocks.

pub mod camera;
pub mod clock;
pub mod mcu;
pub mod sequence;
