//! The simulated rig: the real code path with fake physics.
//!
//! - [`mcu`]: the emulated microcontroller (firmware side of
//!   `firmware-protocol`) as a state machine.
//! - [`link`]: its byte transport, over an in-memory duplex or a real
//!   pseudo-terminal, with fault injection ([`faults`]).
//! - [`truth`]: where the rig's parts really are (the rig file perturbed
//!   within a bench's tolerances), which only the simulated camera sees.
//! - [`world`]: the physical timeline (carriage position, lit LED) that the
//!   simulated camera renders from and tests assert on.

mod batch;
pub mod camera;
pub mod faults;
pub mod link;
pub mod materials;
pub mod mcu;
mod noise;
mod reflect;
pub mod truth;
pub mod world;

pub use faults::FaultSpec;
pub use link::SimMcu;
pub use mcu::{Mcu, McuConfig, McuStats};
pub use truth::{RigTruth, Tolerances};
pub use world::{Effect, Event, OffCause, World};
