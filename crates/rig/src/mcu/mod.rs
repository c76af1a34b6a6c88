//! The rig's microcontroller: the protocol client ([`client`]), finding and
//! opening its port ([`port`]), and [`Rig`], the controller that recovers
//! from reboots, lost links and watchdog trips.

pub mod client;
pub mod port;
mod rig;

pub use client::{LinkError, LinkStats, McuClient};
pub use port::{PortLocator, open_serial};
pub use rig::{Connector, DuplexConnector, Recovery, Rig, RigError, RigSettings, SerialConnector};
