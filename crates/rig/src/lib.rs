//! Rig control: the devices (the microcontroller that drives the gantry and
//! the LEDs, and the camera), their backends, and the capture sequencing.
//! This is the only crate that opens devices.
//!
//! - [`mcu`]: the serial protocol client and the recovering [`mcu::Rig`].
//! - [`sequence`]: the capture loop that commits only confirmed exposures.
//! - [`clock`]: the one place that converts between clocks.

pub mod camera;
pub mod clock;
pub mod mcu;
pub mod sequence;
