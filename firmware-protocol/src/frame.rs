//! Layer 1, framing: `COBS(packet || CRC-16) || 0x00`.
//!
//! The CRC is CRC-16/IBM-3740 (poly 0x1021, init 0xFFFF, no reflection, no
//! xor-out; also called CRC-16/CCITT-FALSE) over the packet bytes, appended
//! little-endian. COBS removes every 0x00 from the encoded bytes, so 0x00
//! only ever delimits frames and a receiver resynchronises at the next
//! delimiter after any corruption, drop or overflow.

use crc::{CRC_16_IBM_3740, Crc};

/// Largest packet (header + body) either side sends.
pub const MAX_PACKET_LEN: usize = 32;

/// Largest frame on the wire: COBS overhead for packet + CRC, plus the
/// delimiter.
pub const MAX_FRAME_LEN: usize = cobs::max_encoding_length(MAX_PACKET_LEN + 2) + 1;

const CRC16: Crc<u16> = Crc::<u16>::new(&CRC_16_IBM_3740);

/// CRC-16/IBM-3740 of `bytes`.
pub fn crc16(bytes: &[u8]) -> u16 {
    CRC16.checksum(bytes)
}

/// Why a frame was rejected. Rejected frames are dropped silently on the
/// wire (the sender retransmits); the reason is for logs and counters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameError {
    /// The frame was empty (two delimiters in a row).
    Empty,
    /// COBS decoding failed: a length code pointed past the frame.
    Cobs,
    /// Shorter than the smallest packet plus CRC.
    TooShort,
    /// Longer than [`MAX_FRAME_LEN`]; the receiver skipped to the next delimiter.
    TooLong,
    /// The CRC did not match.
    Crc,
}

/// Encode `packet` as a complete frame (including the trailing delimiter)
/// into `out`; returns the number of bytes written.
pub fn encode_frame(packet: &[u8], out: &mut [u8]) -> Option<usize> {
    if packet.len() > MAX_PACKET_LEN || out.len() < MAX_FRAME_LEN {
        return None;
    }
    let mut raw = [0u8; MAX_PACKET_LEN + 2];
    raw[..packet.len()].copy_from_slice(packet);
    let crc = crc16(packet).to_le_bytes();
    raw[packet.len()..packet.len() + 2].copy_from_slice(&crc);
    let n = cobs::encode(&raw[..packet.len() + 2], out);
    out[n] = 0;
    Some(n + 1)
}

/// Decode one frame's COBS bytes (without the delimiter) into `packet`,
/// checking the CRC. Returns the packet length.
pub fn decode_frame(encoded: &[u8], packet: &mut [u8; MAX_PACKET_LEN + 2]) -> Result<usize, FrameError> {
    if encoded.is_empty() {
        return Err(FrameError::Empty);
    }
    if encoded.len() > MAX_FRAME_LEN - 1 {
        return Err(FrameError::TooLong);
    }
    // COBS never produces 0x00; one inside a frame means corruption.
    if encoded.contains(&0) {
        return Err(FrameError::Cobs);
    }
    let n = match cobs::decode(encoded, packet) {
        Ok(report) => report.frame_size(),
        Err(_) => return Err(FrameError::Cobs),
    };
    if n < 3 + 2 {
        return Err(FrameError::TooShort);
    }
    let body = n - 2;
    let want = u16::from_le_bytes([packet[body], packet[body + 1]]);
    if crc16(&packet[..body]) != want {
        return Err(FrameError::Crc);
    }
    Ok(body)
}

/// Splits a byte stream into frames at 0x00 delimiters. Bytes beyond
/// [`MAX_FRAME_LEN`] before a delimiter mark the frame as too long; it is
/// reported once and the stream resynchronises at the next delimiter.
#[derive(Debug)]
pub struct FrameAccumulator {
    buf: [u8; MAX_FRAME_LEN],
    len: usize,
    overflow: bool,
}

impl Default for FrameAccumulator {
    fn default() -> Self {
        Self::new()
    }
}

/// What one byte did to the accumulator.
#[derive(Debug, PartialEq, Eq)]
pub enum Push<'a> {
    /// Still inside a frame.
    Pending,
    /// A frame's COBS bytes (without delimiter) are complete.
    Frame(&'a [u8]),
    /// A frame was dropped for being too long or empty.
    Dropped(FrameError),
}

impl FrameAccumulator {
    pub const fn new() -> Self {
        Self { buf: [0; MAX_FRAME_LEN], len: 0, overflow: false }
    }

    /// Forget any partial frame (e.g. after reopening the port).
    pub fn reset(&mut self) {
        self.len = 0;
        self.overflow = false;
    }

    pub fn push(&mut self, byte: u8) -> Push<'_> {
        if byte == 0 {
            let (len, overflow) = (self.len, self.overflow);
            self.len = 0;
            self.overflow = false;
            return if overflow {
                Push::Dropped(FrameError::TooLong)
            } else if len == 0 {
                Push::Dropped(FrameError::Empty)
            } else {
                Push::Frame(&self.buf[..len])
            };
        }
        if self.len < self.buf.len() {
            self.buf[self.len] = byte;
            self.len += 1;
        } else {
            self.overflow = true;
        }
        Push::Pending
    }
}
