//! The serial driver against the emulated MCU at the real rig's speeds, on
//! tokio's paused clock: the emulator and the driver share one in-memory
//! link and one virtual clock, so seconds of gantry travel, the watchdog
//! and the reconnect timeout run in microseconds, and every time below is
//! exact rather than "within what a loaded CI machine manages". The same
//! behaviour through a real pseudo-terminal (on the wall clock, 50 times
//! faster mechanics) is in `serial.rs`.

use std::time::Duration;

use firmware_protocol::timing::{MOVE_DONE_SLACK_MS, REPLY_TIMEOUT_MS, WATCHDOG_MS};
use rig::mcu::{DuplexConnector, Rig, RigError, RigSettings};
use setup::RigGeometry;
use sim::world::{Effect, OffCause};
use sim::{FaultSpec, McuConfig, SimMcu, World};
use tokio::time::Instant;

/// The emulated controller of the default rig at real speed (time scale
/// 1), and the driver's settings for it.
fn real_rig() -> (McuConfig, RigSettings) {
    let g = RigGeometry::default();
    let mut s = RigSettings::for_geometry(&g, 1.0, 200);
    // Longer than the watchdog, so that an LED switched off while the host
    // is silent was switched off by the watchdog.
    s.led_max_on_ms = 5 * WATCHDOG_MS;
    (McuConfig::for_geometry(&g, 1.0), s)
}

async fn open(faults: &str) -> (SimMcu, Rig<DuplexConnector>, World) {
    let (cfg, settings) = real_rig();
    let world = World::new();
    let (sim, host) = SimMcu::spawn_duplex(cfg, FaultSpec::parse(faults).unwrap(), world.clone());
    let rig = Rig::open(DuplexConnector(Some(host)), settings).await.expect("open the rig");
    (sim, rig, world)
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

/// A full-travel move at the rig's real speed (2.4 s of travel, longer than
/// the 1 s watchdog) ends when physics says it does: the driver predicts
/// `MoveDone`, keeps the link alive meanwhile, and needs no retransmit or
/// recovery.
#[tokio::test(start_paused = true)]
async fn a_real_speed_move_takes_its_physical_time_without_tripping_the_watchdog() {
    let (sim, mut rig, world) = open("").await;
    rig.home().await.expect("home");
    let (cfg, _) = real_rig();
    let (from, to) = (cfg.travel_min_um, cfg.travel_max_um);
    rig.move_to(from).await.expect("move to the start");
    let t0 = Instant::now();
    rig.move_to(to).await.expect("full-travel move");
    let took = t0.elapsed();
    let physical = Duration::from_secs_f64(cfg.profile.duration_s((to - from) as f64) + cfg.settle_ms / 1000.0);
    assert!(physical > Duration::from_millis(WATCHDOG_MS as u64), "the move must outlast the watchdog");
    // MoveDone is sent when the carriage has settled; the driver may learn
    // of it no earlier, and no later than its own slack (after which it
    // would ask with Status).
    assert!(took >= physical, "done after {:.1} ms, physics needs {:.1} ms", ms(took), ms(physical));
    let late = took - physical;
    assert!(late <= Duration::from_millis(MOVE_DONE_SLACK_MS as u64), "{:.1} ms late", ms(late));
    let s = rig.link_stats();
    assert_eq!(s.retransmits, 0, "{s:?}");
    assert!(rig.recoveries().is_empty(), "{:?}", rig.recoveries());
    let halted = world.events().iter().any(|e| matches!(e.effect, Effect::Halt { .. }));
    assert!(!halted, "the watchdog or a fault halted the carriage");
    rig.shutdown().await;
    sim.stop().await.unwrap();
}

/// A host that goes silent with an LED lit: the controller switches it off
/// exactly one watchdog period after the last command it received.
#[tokio::test(start_paused = true)]
async fn a_silent_host_has_its_led_switched_off_one_watchdog_period_later() {
    let (sim, mut rig, world) = open("").await;
    rig.home().await.expect("home");
    rig.led_on(7).await.expect("LED on");
    // The host says nothing more.
    tokio::time::sleep(Duration::from_millis(3 * WATCHDOG_MS as u64)).await;
    let events = world.events();
    let on = events.iter().rev().find(|e| matches!(e.effect, Effect::LedOn { led: 7, .. })).expect("LED 7 lit").t;
    let off = events
        .iter()
        .find(|e| e.t >= on && matches!(e.effect, Effect::LedOff { led: 7, .. }))
        .expect("LED 7 still lit long after the host went silent");
    assert_eq!(off.effect, Effect::LedOff { led: 7, cause: OffCause::Watchdog });
    // SetLed is the last command; the LED went on as it arrived (no delay
    // on the in-memory link, none on a paused clock).
    assert_eq!(off.t - on, Duration::from_millis(WATCHDOG_MS as u64));
    rig.shutdown().await;
    sim.stop().await.unwrap();
}

/// A controller that stops answering mid-session: each command is sent
/// `MAX_RETRIES + 1` times `REPLY_TIMEOUT_MS` apart, then the link counts
/// as down and the driver looks for the port again until its reconnect
/// timeout (here nothing can reconnect), and the operation fails with
/// `LinkLost`, not a hang.
#[tokio::test(start_paused = true)]
async fn a_controller_that_stops_answering_ends_in_link_lost_after_the_reconnect_timeout() {
    // Count the commands opening and homing take (deterministic on a
    // paused clock), then hang from the first command after them.
    let (probe, mut rig, _) = open("").await;
    rig.home().await.expect("home");
    let through_home = rig.link_stats().commands;
    rig.shutdown().await;
    probe.stop().await.unwrap();
    let (sim, mut rig, _) = open(&format!("hang-at={}", through_home + 1)).await;
    rig.home().await.expect("home");
    let t0 = Instant::now();
    let e = rig.led_on(3).await.expect_err("a hung controller cannot light an LED");
    let took = t0.elapsed();
    assert!(matches!(e, RigError::LinkLost { .. }), "{e:?}");
    let reconnect = rig.settings().reconnect_timeout;
    let retries = Duration::from_millis(REPLY_TIMEOUT_MS as u64) * (firmware_protocol::timing::MAX_RETRIES + 1);
    // First every retransmit times out, then the port is looked for
    // until the timeout; the driver's poll between looks is shorter than
    // one round of retransmits.
    assert!(took >= reconnect + retries, "gave up after {:.0} ms, too early", ms(took));
    assert!(took <= reconnect + 2 * retries, "gave up after {:.0} ms, too late", ms(took));
    sim.stop().await.unwrap();
}
