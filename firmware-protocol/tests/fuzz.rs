//! Fuzzing of the decoders that read bytes from outside: arbitrary bytes,
//! truncated and bit-flipped frames, and byte streams through the
//! accumulator. The decoders must never panic and never accept a corrupted
//! frame as a message. (Run in CI as property tests; no nightly toolchain
//! is needed.)

use firmware_protocol::frame::Push;
use firmware_protocol::{
    Command, CommandPacket, Faults, FrameAccumulator, HelloInfo, MAX_FRAME_LEN, NakReason, Reply, ReplyPacket,
    StatusFlags, StatusInfo,
};
use proptest::prelude::*;

fn command() -> impl Strategy<Value = Command> {
    prop_oneof![
        Just(Command::Hello),
        Just(Command::Home),
        any::<i32>().prop_map(|position_um| Command::MoveTo { position_um }),
        (any::<u8>(), any::<u16>(), any::<u16>())
            .prop_map(|(led, current_ma, max_on_ms)| { Command::SetLed { led, current_ma, max_on_ms } }),
        Just(Command::AllOff),
        Just(Command::Status),
        Just(Command::EStop),
        Just(Command::ClearFault),
        Just(Command::Heartbeat),
    ]
}

fn reply() -> impl Strategy<Value = Reply> {
    prop_oneof![
        (any::<[u8; 3]>(), any::<u8>(), any::<i32>(), any::<i32>(), any::<u16>(), any::<u16>()).prop_map(
            |(firmware, n_leds, a, b, max_current_ma, watchdog_ms)| Reply::Hello(HelloInfo {
                protocol_version: 1,
                firmware,
                n_leds,
                travel_min_um: a,
                travel_max_um: b,
                max_current_ma,
                watchdog_ms,
            })
        ),
        Just(Reply::Ack),
        (1u8..=10).prop_map(|r| Reply::Nak(NakReason::from_u8(r))),
        (any::<i32>(), any::<u8>(), any::<u8>(), any::<u8>()).prop_map(|(position_um, f, lit_led, x)| Reply::Status(
            StatusInfo { position_um, flags: StatusFlags(f), lit_led, faults: Faults(x) }
        )),
        any::<i32>().prop_map(|position_um| Reply::MoveDone { position_um }),
        Just(Reply::Boot),
    ]
}

fn frame_of_command(p: &CommandPacket) -> Vec<u8> {
    let mut b = [0u8; MAX_FRAME_LEN];
    let n = p.encode(&mut b).unwrap();
    b[..n].to_vec()
}

fn frame_of_reply(p: &ReplyPacket) -> Vec<u8> {
    let mut b = [0u8; MAX_FRAME_LEN];
    let n = p.encode(&mut b).unwrap();
    b[..n].to_vec()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn commands_round_trip(seq in any::<u8>(), c in command()) {
        let p = CommandPacket { seq, command: c };
        let f = frame_of_command(&p);
        prop_assert_eq!(*f.last().unwrap(), 0);
        prop_assert!(!f[..f.len() - 1].contains(&0));
        prop_assert_eq!(CommandPacket::decode(&f[..f.len() - 1]).unwrap(), p);
    }

    #[test]
    fn replies_round_trip(seq in any::<u8>(), boot_id in any::<u32>(), r in reply()) {
        let p = ReplyPacket { seq, boot_id, reply: r };
        let f = frame_of_reply(&p);
        prop_assert_eq!(ReplyPacket::decode(&f[..f.len() - 1]).unwrap(), p);
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..80)) {
        let _ = CommandPacket::decode(&bytes);
        let _ = ReplyPacket::decode(&bytes);
        let _ = CommandPacket::peek_seq(&bytes);
        let mut acc = FrameAccumulator::new();
        for b in &bytes {
            if let Push::Frame(f) = acc.push(*b) {
                let f = f.to_vec();
                let _ = CommandPacket::decode(&f);
                let _ = ReplyPacket::decode(&f);
            }
        }
    }

    #[test]
    fn single_bit_flips_are_never_accepted(seq in any::<u8>(), c in command(), r in reply(), boot_id in any::<u32>()) {
        for f in [frame_of_command(&CommandPacket { seq, command: c }), frame_of_reply(&ReplyPacket { seq, boot_id, reply: r })] {
            let body = &f[..f.len() - 1];
            for byte in 0..body.len() {
                for bit in 0..8 {
                    let mut g = body.to_vec();
                    g[byte] ^= 1 << bit;
                    let accepted = CommandPacket::decode(&g).ok();
                    prop_assert!(accepted.is_none(), "flipped frame {:02x?} accepted as {:?}", g, accepted);
                    prop_assert!(ReplyPacket::decode(&g).is_err(), "flipped frame {:02x?} accepted as reply", g);
                }
            }
        }
    }

    #[test]
    fn truncated_frames_are_rejected(seq in any::<u8>(), c in command(), cut in 1usize..12) {
        let f = frame_of_command(&CommandPacket { seq, command: c });
        let body = &f[..f.len() - 1];
        if cut < body.len() {
            prop_assert!(CommandPacket::decode(&body[..body.len() - cut]).is_err());
        }
    }

    #[test]
    fn accumulator_resynchronises_after_garbage(garbage in proptest::collection::vec(any::<u8>(), 0..200), seq in 1u8..=255, c in command()) {
        let p = CommandPacket { seq, command: c };
        let mut stream = garbage.clone();
        stream.push(0); // whatever the garbage was, a delimiter ends it
        stream.extend(frame_of_command(&p));
        let mut acc = FrameAccumulator::new();
        let mut last = None;
        for b in stream {
            if let Push::Frame(f) = acc.push(b) {
                last = CommandPacket::decode(f).ok();
            }
        }
        prop_assert_eq!(last, Some(p));
    }
}

#[test]
fn wrong_version_and_unknown_ids_are_reported() {
    use firmware_protocol::DecodeError;
    use firmware_protocol::frame::encode_frame;
    let mut out = [0u8; MAX_FRAME_LEN];
    let n = encode_frame(&[2, 7, 1], &mut out).unwrap();
    assert_eq!(CommandPacket::decode(&out[..n - 1]), Err(DecodeError::Version(2)));
    let n = encode_frame(&[1, 7, 0x42], &mut out).unwrap();
    assert_eq!(CommandPacket::decode(&out[..n - 1]), Err(DecodeError::UnknownId(0x42)));
    assert_eq!(CommandPacket::peek_seq(&out[..n - 1]), Some(7));
    let n = encode_frame(&[1, 7, 0x03, 1, 2], &mut out).unwrap();
    assert_eq!(CommandPacket::decode(&out[..n - 1]), Err(DecodeError::Length { id: 3, got: 2, want: 4 }));
}
