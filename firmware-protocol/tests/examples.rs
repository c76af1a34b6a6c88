//! The byte-exact examples in PROTOCOL.md are checked here: each labelled
//! line `E<n>` in the document must be the encoding of the message this
//! table gives for that label, and must decode back to it.

use firmware_protocol::{
    Command, CommandPacket, Faults, HelloInfo, MAX_FRAME_LEN, NakReason, Reply, ReplyPacket, StatusFlags, StatusInfo,
};

const DOC: &str = include_str!("../PROTOCOL.md");

enum Msg {
    C(CommandPacket),
    R(ReplyPacket),
}

fn examples() -> Vec<(&'static str, Msg)> {
    let boot_id = 0x1234_5678;
    let c = |seq, command| Msg::C(CommandPacket { seq, command });
    let r = |seq, reply| Msg::R(ReplyPacket { seq, boot_id, reply });
    vec![
        ("E1", c(1, Command::Hello)),
        (
            "E2",
            r(
                1,
                Reply::Hello(HelloInfo {
                    protocol_version: 1,
                    firmware: [1, 0, 0],
                    n_leds: 40,
                    travel_min_um: -120_000,
                    travel_max_um: 120_000,
                    max_current_ma: 350,
                    watchdog_ms: 1000,
                }),
            ),
        ),
        ("E3", c(2, Command::Home)),
        ("E4", r(2, Reply::Ack)),
        ("E5", r(2, Reply::MoveDone { position_um: 0 })),
        ("E6", c(3, Command::MoveTo { position_um: -37_500 })),
        ("E7", c(4, Command::SetLed { led: 17, current_ma: 200, max_on_ms: 500 })),
        ("E8", r(4, Reply::Nak(NakReason::NotHomed))),
        ("E9", c(5, Command::Status)),
        (
            "E10",
            r(
                5,
                Reply::Status(StatusInfo {
                    position_um: -37_500,
                    flags: StatusFlags(StatusFlags::HOMED | StatusFlags::LED_ON),
                    lit_led: 17,
                    faults: Faults(0),
                }),
            ),
        ),
        ("E11", c(6, Command::EStop)),
        ("E12", r(0, Reply::Boot)),
    ]
}

fn encode(m: &Msg) -> Vec<u8> {
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = match m {
        Msg::C(c) => c.encode(&mut buf).unwrap(),
        Msg::R(r) => r.encode(&mut buf).unwrap(),
    };
    buf[..n].to_vec()
}

fn hex(b: &[u8]) -> String {
    b.iter().map(|x| format!("{x:02x}")).collect::<Vec<_>>().join(" ")
}

fn doc_hex(label: &str) -> Option<Vec<u8>> {
    // A label's description may wrap; its bytes follow the first "=>".
    let prefix = format!("{label}:");
    let start = DOC.lines().position(|l| l.trim_start().starts_with(&prefix))?;
    let line = DOC.lines().skip(start).find(|l| l.contains("=>"))?;
    let hex_part = line.split_once("=>")?.1;
    hex_part.split_whitespace().map(|h| u8::from_str_radix(h, 16).ok()).collect()
}

#[test]
fn protocol_md_examples_are_exact() {
    let mut missing = Vec::new();
    for (label, msg) in examples() {
        let bytes = encode(&msg);
        match doc_hex(label) {
            Some(doc) => {
                assert_eq!(
                    doc,
                    bytes,
                    "{label}: PROTOCOL.md says {} but the encoder writes {}",
                    hex(&doc),
                    hex(&bytes)
                );
                let body = &doc[..doc.len() - 1];
                match msg {
                    Msg::C(c) => assert_eq!(CommandPacket::decode(body).unwrap(), c),
                    Msg::R(r) => assert_eq!(ReplyPacket::decode(body).unwrap(), r),
                }
            }
            None => missing.push(format!("{label}: => {}", hex(&bytes))),
        }
    }
    assert!(missing.is_empty(), "PROTOCOL.md lacks examples:\n{}", missing.join("\n"));
}
