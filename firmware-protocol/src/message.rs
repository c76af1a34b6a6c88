//! Layer 2, packets and messages.
//!
//! Command packet (host to MCU): `version u8 | seq u8 | id u8 | body`.
//! Reply packet (MCU to host): `version u8 | seq u8 | id u8 | boot_id u32 | body`.
//! All integers are little-endian; every body has a fixed length per id and
//! a packet of any other length is rejected.

use crate::PROTOCOL_VERSION;
use crate::frame::{self, FrameError, MAX_PACKET_LEN};

/// Message ids of commands.
pub mod id {
    pub const HELLO: u8 = 0x01;
    pub const HOME: u8 = 0x02;
    pub const MOVE_TO: u8 = 0x03;
    pub const SET_LED: u8 = 0x04;
    pub const ALL_OFF: u8 = 0x05;
    pub const STATUS: u8 = 0x06;
    pub const E_STOP: u8 = 0x07;
    pub const CLEAR_FAULT: u8 = 0x08;
    pub const HEARTBEAT: u8 = 0x09;

    pub const R_HELLO: u8 = 0x81;
    pub const R_ACK: u8 = 0x82;
    pub const R_NAK: u8 = 0x83;
    pub const R_STATUS: u8 = 0x84;
    pub const R_MOVE_DONE: u8 = 0x85;
    pub const R_BOOT: u8 = 0x86;
}

/// A command from the host. Every command is absolute and idempotent:
/// executing it twice leaves the rig in the same state as executing it once.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// Identify: firmware and protocol version, boot id, capabilities.
    Hello,
    /// Home the gantry against its minimum limit switch; position 0 is the
    /// switch. Replies `Ack` at once and `MoveDone` when homed.
    Home,
    /// Move to an absolute position. Refused until homed and outside the soft
    /// limits. Replies `Ack` at once and `MoveDone` when settled.
    MoveTo { position_um: i32 },
    /// Light LED `led` alone at `current_ma` (every other LED off in the same
    /// step); it goes off by itself after `max_on_ms`. `Ack` means the LED is lit.
    SetLed { led: u8, current_ma: u16, max_on_ms: u16 },
    /// Every LED off. `Ack` means they are off.
    AllOff,
    /// Report position, flags, lit LED and latched faults.
    Status,
    /// Stop motion, all LEDs off, latch the e-stop fault. Handled ahead of
    /// anything in progress; the position is then unknown (re-home).
    EStop,
    /// Clear latched faults (the e-stop and watchdog faults).
    ClearFault,
    /// Nothing but proof that the host is alive (feeds the watchdog).
    Heartbeat,
}

/// A command with its sequence number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CommandPacket {
    pub seq: u8,
    pub command: Command,
}

/// What the MCU reports on `Hello`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HelloInfo {
    pub protocol_version: u8,
    pub firmware: [u8; 3],
    pub n_leds: u8,
    pub travel_min_um: i32,
    pub travel_max_um: i32,
    pub max_current_ma: u16,
    pub watchdog_ms: u16,
}

/// Status flag bits.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StatusFlags(pub u8);

impl StatusFlags {
    pub const HOMED: u8 = 0x01;
    pub const MOVING: u8 = 0x02;
    pub const HOMING: u8 = 0x04;
    pub const LIMIT_MIN: u8 = 0x08;
    pub const LIMIT_MAX: u8 = 0x10;
    pub const LED_ON: u8 = 0x20;

    pub const fn has(self, bit: u8) -> bool {
        self.0 & bit != 0
    }
}

/// Latched fault bits (cleared by `ClearFault`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Faults(pub u8);

impl Faults {
    pub const E_STOP: u8 = 0x01;
    pub const WATCHDOG: u8 = 0x02;
    pub const HARD_LIMIT: u8 = 0x04;
    /// Not latched as a fault that blocks commands: records that an LED
    /// reached its maximum on-time and was switched off by the MCU.
    pub const LED_OVERTIME: u8 = 0x08;

    pub const fn has(self, bit: u8) -> bool {
        self.0 & bit != 0
    }

    /// Faults that block motion and LED commands until cleared.
    pub const fn blocking(self) -> bool {
        self.0 & (Self::E_STOP | Self::WATCHDOG | Self::HARD_LIMIT) != 0
    }
}

/// `lit_led` value meaning no LED is lit.
pub const NO_LED: u8 = 0xFF;

/// What the MCU reports on `Status`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StatusInfo {
    pub position_um: i32,
    pub flags: StatusFlags,
    pub lit_led: u8,
    pub faults: Faults,
}

/// Why a command was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u8)]
pub enum NakReason {
    UnknownCommand = 1,
    BadLength = 2,
    VersionMismatch = 3,
    NotHomed = 4,
    OutOfRange = 5,
    LedOutOfRange = 6,
    CurrentTooHigh = 7,
    EStopLatched = 8,
    FaultLatched = 9,
    Busy = 10,
    /// A reason this host does not know (newer firmware).
    Other = 255,
}

impl NakReason {
    pub const fn from_u8(v: u8) -> Self {
        match v {
            1 => Self::UnknownCommand,
            2 => Self::BadLength,
            3 => Self::VersionMismatch,
            4 => Self::NotHomed,
            5 => Self::OutOfRange,
            6 => Self::LedOutOfRange,
            7 => Self::CurrentTooHigh,
            8 => Self::EStopLatched,
            9 => Self::FaultLatched,
            10 => Self::Busy,
            _ => Self::Other,
        }
    }
}

/// A reply (or announcement) from the MCU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reply {
    Hello(HelloInfo),
    Ack,
    Nak(NakReason),
    Status(StatusInfo),
    /// A `Home` or `MoveTo` with this packet's sequence number finished.
    MoveDone {
        position_um: i32,
    },
    /// Sent once after reset with sequence number 0.
    Boot,
}

/// A reply with the sequence number of the command it answers and the MCU's
/// boot id (random per power-up: a new id means the MCU restarted).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReplyPacket {
    pub seq: u8,
    pub boot_id: u32,
    pub reply: Reply,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    Frame(FrameError),
    /// The packet's protocol version is not ours.
    Version(u8),
    /// A message id this side does not know.
    UnknownId(u8),
    /// The body length does not match the id.
    Length {
        id: u8,
        got: usize,
        want: usize,
    },
}

impl From<FrameError> for DecodeError {
    fn from(e: FrameError) -> Self {
        DecodeError::Frame(e)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EncodeError {
    /// The output buffer is shorter than [`crate::MAX_FRAME_LEN`].
    BufferTooSmall,
}

/// Little-endian writer over a fixed buffer.
struct Writer<'a> {
    buf: &'a mut [u8],
    len: usize,
}

impl<'a> Writer<'a> {
    fn new(buf: &'a mut [u8]) -> Self {
        Self { buf, len: 0 }
    }
    fn u8(&mut self, v: u8) -> &mut Self {
        self.buf[self.len] = v;
        self.len += 1;
        self
    }
    fn bytes(&mut self, v: &[u8]) -> &mut Self {
        self.buf[self.len..self.len + v.len()].copy_from_slice(v);
        self.len += v.len();
        self
    }
    fn u16(&mut self, v: u16) -> &mut Self {
        self.bytes(&v.to_le_bytes())
    }
    fn u32(&mut self, v: u32) -> &mut Self {
        self.bytes(&v.to_le_bytes())
    }
    fn i32(&mut self, v: i32) -> &mut Self {
        self.bytes(&v.to_le_bytes())
    }
}

/// Little-endian reader; callers check the body length first.
struct Reader<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Reader<'a> {
    fn new(buf: &'a [u8]) -> Self {
        Self { buf, pos: 0 }
    }
    fn u8(&mut self) -> u8 {
        let v = self.buf[self.pos];
        self.pos += 1;
        v
    }
    fn u16(&mut self) -> u16 {
        let v = u16::from_le_bytes([self.buf[self.pos], self.buf[self.pos + 1]]);
        self.pos += 2;
        v
    }
    fn u32(&mut self) -> u32 {
        let mut b = [0u8; 4];
        b.copy_from_slice(&self.buf[self.pos..self.pos + 4]);
        self.pos += 4;
        u32::from_le_bytes(b)
    }
    fn i32(&mut self) -> i32 {
        self.u32() as i32
    }
}

fn check_len(id: u8, body: &[u8], want: usize) -> Result<(), DecodeError> {
    if body.len() == want { Ok(()) } else { Err(DecodeError::Length { id, got: body.len(), want }) }
}

impl CommandPacket {
    /// Packet bytes (header + body) into `out`; returns the length.
    pub fn encode_packet(&self, out: &mut [u8; MAX_PACKET_LEN]) -> usize {
        let mut w = Writer::new(out);
        w.u8(PROTOCOL_VERSION).u8(self.seq);
        match self.command {
            Command::Hello => w.u8(id::HELLO),
            Command::Home => w.u8(id::HOME),
            Command::MoveTo { position_um } => w.u8(id::MOVE_TO).i32(position_um),
            Command::SetLed { led, current_ma, max_on_ms } => w.u8(id::SET_LED).u8(led).u16(current_ma).u16(max_on_ms),
            Command::AllOff => w.u8(id::ALL_OFF),
            Command::Status => w.u8(id::STATUS),
            Command::EStop => w.u8(id::E_STOP),
            Command::ClearFault => w.u8(id::CLEAR_FAULT),
            Command::Heartbeat => w.u8(id::HEARTBEAT),
        };
        w.len
    }

    /// A complete frame (with delimiter) into `out`; returns the length.
    pub fn encode(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        let mut p = [0u8; MAX_PACKET_LEN];
        let n = self.encode_packet(&mut p);
        frame::encode_frame(&p[..n], out).ok_or(EncodeError::BufferTooSmall)
    }

    /// Parse packet bytes. A version mismatch is reported before anything
    /// else so the MCU can answer it; the sequence number is still returned
    /// through [`CommandPacket::peek_seq`].
    pub fn decode_packet(p: &[u8]) -> Result<Self, DecodeError> {
        if p.len() < 3 {
            return Err(DecodeError::Frame(FrameError::TooShort));
        }
        if p[0] != PROTOCOL_VERSION {
            return Err(DecodeError::Version(p[0]));
        }
        let (seq, mid, body) = (p[1], p[2], &p[3..]);
        let mut r = Reader::new(body);
        let command = match mid {
            id::HELLO => check_len(mid, body, 0).map(|_| Command::Hello)?,
            id::HOME => check_len(mid, body, 0).map(|_| Command::Home)?,
            id::MOVE_TO => check_len(mid, body, 4).map(|_| Command::MoveTo { position_um: r.i32() })?,
            id::SET_LED => check_len(mid, body, 5).map(|_| Command::SetLed {
                led: r.u8(),
                current_ma: r.u16(),
                max_on_ms: r.u16(),
            })?,
            id::ALL_OFF => check_len(mid, body, 0).map(|_| Command::AllOff)?,
            id::STATUS => check_len(mid, body, 0).map(|_| Command::Status)?,
            id::E_STOP => check_len(mid, body, 0).map(|_| Command::EStop)?,
            id::CLEAR_FAULT => check_len(mid, body, 0).map(|_| Command::ClearFault)?,
            id::HEARTBEAT => check_len(mid, body, 0).map(|_| Command::Heartbeat)?,
            other => return Err(DecodeError::UnknownId(other)),
        };
        Ok(Self { seq, command })
    }

    /// Decode a frame's COBS bytes (without delimiter).
    pub fn decode(encoded: &[u8]) -> Result<Self, DecodeError> {
        let mut p = [0u8; MAX_PACKET_LEN + 2];
        let n = frame::decode_frame(encoded, &mut p)?;
        Self::decode_packet(&p[..n])
    }

    /// The sequence number of a CRC-valid frame whose packet could not be
    /// decoded (so the MCU can address its `Nak` to it).
    pub fn peek_seq(encoded: &[u8]) -> Option<u8> {
        let mut p = [0u8; MAX_PACKET_LEN + 2];
        let n = frame::decode_frame(encoded, &mut p).ok()?;
        (n >= 2).then_some(p[1])
    }
}

impl ReplyPacket {
    pub fn encode_packet(&self, out: &mut [u8; MAX_PACKET_LEN]) -> usize {
        let mut w = Writer::new(out);
        w.u8(PROTOCOL_VERSION).u8(self.seq);
        let id = match self.reply {
            Reply::Hello(_) => id::R_HELLO,
            Reply::Ack => id::R_ACK,
            Reply::Nak(_) => id::R_NAK,
            Reply::Status(_) => id::R_STATUS,
            Reply::MoveDone { .. } => id::R_MOVE_DONE,
            Reply::Boot => id::R_BOOT,
        };
        w.u8(id).u32(self.boot_id);
        match self.reply {
            Reply::Hello(h) => {
                w.u8(h.protocol_version)
                    .bytes(&h.firmware)
                    .u8(h.n_leds)
                    .i32(h.travel_min_um)
                    .i32(h.travel_max_um)
                    .u16(h.max_current_ma)
                    .u16(h.watchdog_ms);
            }
            Reply::Nak(r) => {
                w.u8(r as u8);
            }
            Reply::Status(s) => {
                w.i32(s.position_um).u8(s.flags.0).u8(s.lit_led).u8(s.faults.0);
            }
            Reply::MoveDone { position_um } => {
                w.i32(position_um);
            }
            Reply::Ack | Reply::Boot => {}
        }
        w.len
    }

    pub fn encode(&self, out: &mut [u8]) -> Result<usize, EncodeError> {
        let mut p = [0u8; MAX_PACKET_LEN];
        let n = self.encode_packet(&mut p);
        frame::encode_frame(&p[..n], out).ok_or(EncodeError::BufferTooSmall)
    }

    pub fn decode_packet(p: &[u8]) -> Result<Self, DecodeError> {
        if p.len() < 7 {
            return Err(DecodeError::Frame(FrameError::TooShort));
        }
        if p[0] != PROTOCOL_VERSION {
            return Err(DecodeError::Version(p[0]));
        }
        let (seq, mid) = (p[1], p[2]);
        let boot_id = u32::from_le_bytes([p[3], p[4], p[5], p[6]]);
        let body = &p[7..];
        let mut r = Reader::new(body);
        let reply = match mid {
            id::R_HELLO => {
                check_len(mid, body, 17)?;
                Reply::Hello(HelloInfo {
                    protocol_version: r.u8(),
                    firmware: [r.u8(), r.u8(), r.u8()],
                    n_leds: r.u8(),
                    travel_min_um: r.i32(),
                    travel_max_um: r.i32(),
                    max_current_ma: r.u16(),
                    watchdog_ms: r.u16(),
                })
            }
            id::R_ACK => check_len(mid, body, 0).map(|_| Reply::Ack)?,
            id::R_NAK => check_len(mid, body, 1).map(|_| Reply::Nak(NakReason::from_u8(r.u8())))?,
            id::R_STATUS => {
                check_len(mid, body, 7)?;
                Reply::Status(StatusInfo {
                    position_um: r.i32(),
                    flags: StatusFlags(r.u8()),
                    lit_led: r.u8(),
                    faults: Faults(r.u8()),
                })
            }
            id::R_MOVE_DONE => check_len(mid, body, 4).map(|_| Reply::MoveDone { position_um: r.i32() })?,
            id::R_BOOT => check_len(mid, body, 0).map(|_| Reply::Boot)?,
            other => return Err(DecodeError::UnknownId(other)),
        };
        Ok(Self { seq, boot_id, reply })
    }

    pub fn decode(encoded: &[u8]) -> Result<Self, DecodeError> {
        let mut p = [0u8; MAX_PACKET_LEN + 2];
        let n = frame::decode_frame(encoded, &mut p)?;
        Self::decode_packet(&p[..n])
    }
}
