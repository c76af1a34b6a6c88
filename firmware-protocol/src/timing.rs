//! Named timeouts and intervals both sides agree on. The reasoning for each
//! value is in `PROTOCOL.md`, section "Timeouts".

/// Host: how long to wait for the reply to any command before sending the
/// same packet again. A USB CDC round trip is about 1 ms and a firmware
/// command takes well under 1 ms, so 50 ms is 25x the worst expected round
/// trip while keeping a lost frame's cost to a few percent of a 30 fps frame.
pub const REPLY_TIMEOUT_MS: u32 = 50;

/// Host: retransmissions of one packet before the link is declared down
/// (8 x 50 ms = 0.4 s of silence, below the watchdog).
pub const MAX_RETRIES: u32 = 8;

/// MCU: silence from the host after which LEDs go off, motion stops and the
/// watchdog fault is latched. Reported in `Hello`; the host sends a
/// `Heartbeat` whenever it has been quiet for a quarter of this.
pub const WATCHDOG_MS: u16 = 1000;

/// Host: slack added to a move's predicted duration before `MoveDone` is
/// considered late and the host asks for `Status`.
pub const MOVE_DONE_SLACK_MS: u32 = 500;

/// Host: time allowed for homing from anywhere on the rail.
pub const HOME_TIMEOUT_MS: u32 = 30_000;

/// Host: after opening the port, how long to wait for the MCU's `Boot`
/// announcement (boards that reset on DTR) before sending `Hello` anyway.
pub const BOOT_WAIT_MS: u32 = 1500;
