//! What a firmware would do with the protocol crate, compiled without `std`.
#![no_std]

use core::panic::PanicInfo;

use firmware_protocol::frame::Push;
use firmware_protocol::{CommandPacket, FrameAccumulator, MAX_FRAME_LEN, Reply, ReplyPacket};

/// Feed one received byte; when a command completes, encode an `Ack` for it
/// into `out` and return the number of bytes to send (0 otherwise).
#[unsafe(no_mangle)]
pub extern "C" fn rig_on_byte(acc: &mut FrameAccumulator, byte: u8, out: &mut [u8; MAX_FRAME_LEN]) -> usize {
    let seq = match acc.push(byte) {
        Push::Frame(f) => match CommandPacket::decode(f) {
            Ok(c) => c.seq,
            Err(_) => return 0,
        },
        _ => return 0,
    };
    ReplyPacket { seq, boot_id: 1, reply: Reply::Ack }.encode(out).unwrap_or(0)
}

#[panic_handler]
fn panic(_: &PanicInfo) -> ! {
    loop {}
}
