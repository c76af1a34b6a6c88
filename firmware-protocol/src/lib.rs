//! The wire protocol between the reflectometer host and the rig's
//! microcontroller (MCU). Both sides depend on this crate: it is `no_std`,
//! allocates nothing, and encodes and decodes into caller buffers.
//!
//! The protocol is specified in layers in `PROTOCOL.md` beside this crate:
//! framing ([`frame`]: COBS with a 0x00 delimiter, CRC-16), packets and
//! messages ([`message`]: version, sequence number, explicit message ids,
//! fixed little-endian bodies), reliability (stop-and-wait with retransmit of
//! the same sequence number; the MCU answers a duplicate from its cached
//! reply without executing it again) and semantics (absolute, idempotent
//! commands; e-stop ahead of the queue and latched; a host-silence
//! watchdog; a per-boot id in every reply). [`timing`] holds the named
//! timeouts both sides agree on.
#![no_std]
#![forbid(unsafe_code)]

pub mod frame;
pub mod message;
pub mod timing;

pub use frame::{FrameAccumulator, FrameError, MAX_FRAME_LEN, MAX_PACKET_LEN};
pub use message::{
    Command, CommandPacket, DecodeError, EncodeError, Faults, HelloInfo, NakReason, Reply, ReplyPacket, StatusFlags,
    StatusInfo,
};

/// Protocol version carried in every packet. A peer that receives another
/// version answers `Nak(VersionMismatch)` (MCU) or reports the mismatch to the
/// operator (host); it never guesses at a foreign layout.
pub const PROTOCOL_VERSION: u8 = 1;

/// Sequence number reserved for frames the MCU sends on its own (the boot
/// announcement). The host numbers its commands 1..=255, wrapping to 1.
pub const UNSOLICITED_SEQ: u8 = 0;

/// The next host sequence number after `seq` (skips [`UNSOLICITED_SEQ`]).
pub const fn next_seq(seq: u8) -> u8 {
    if seq == u8::MAX { 1 } else { seq + 1 }
}
