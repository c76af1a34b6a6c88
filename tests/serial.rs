//! The serial driver against the emulated MCU through a real
//! pseudo-terminal, with injected faults: corrupted, dropped and duplicated
//! bytes, a reboot in the middle and a disconnect/reconnect. The emulator's
//! timeline is the judge of what physically happened.

use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Duration;

use rig::mcu::{PortLocator, Rig, RigError, RigSettings, SerialConnector};
use rig::sequence::{self, Exposer, Shot};
use sim::world::{Effect, OffCause};
use sim::{FaultSpec, McuConfig, SimMcu, World};
use tokio::time::Instant;

fn fast_mcu() -> McuConfig {
    // Mechanics 50x faster than real time; protocol timing unchanged.
    McuConfig { time_scale: 0.02, ..McuConfig::default() }
}

fn settings() -> RigSettings {
    RigSettings {
        reconnect_timeout: Duration::from_secs(5),
        speed_um_s: 100_000.0 / 0.02,
        accel_um_s2: 1_000_000.0 / (0.02 * 0.02),
        settle_ms: 30.0 * 0.02,
        homing_speed_um_s: 50_000.0 / 0.02,
        // The PTY round trip is ~0.1 ms; a short retransmit timeout keeps
        // the test quick with a third of the frames damaged.
        reply_timeout: Duration::from_millis(5),
        move_done_slack: Duration::from_millis(20),
        ..RigSettings::default()
    }
}

fn plan(steps: u32, leds: u8) -> Vec<Shot> {
    let mut v = Vec::new();
    for s in 0..steps {
        let x = -120_000 + (240_000 / (steps.max(2) - 1) as i32) * s as i32;
        for l in 0..leds {
            v.push(Shot { index: v.len() as u32, step: s, led: l, exposure: 0, position_um: x });
        }
    }
    v
}

/// Holds each LED for a short dwell and records what it committed.
struct Dwell {
    dwell: Duration,
    committed: Vec<(Shot, Instant, Instant)>,
    discarded: u64,
    /// Shots (by index) passed over, as an adaptive bracket passes over a
    /// shorter exposure nobody needs.
    unwanted: Vec<u32>,
}

impl Exposer for Dwell {
    type Item = (Instant, Instant);
    type Error = RigError;
    async fn expose(&mut self, _shot: &Shot, lit_at: Instant) -> Result<Option<Self::Item>, RigError> {
        tokio::time::sleep(self.dwell).await;
        Ok(Some((lit_at, Instant::now())))
    }
    async fn commit(&mut self, shot: &Shot, item: Self::Item) -> Result<(), RigError> {
        self.committed.push((*shot, item.0, item.1));
        Ok(())
    }
    fn discarded(&mut self, _shot: &Shot) {
        self.discarded += 1;
    }
    fn wants(&mut self, shot: &Shot) -> bool {
        !self.unwanted.contains(&shot.index)
    }
}

struct Firing {
    led: u8,
    on: Instant,
    off: Option<(Instant, OffCause)>,
}

fn firings(world: &World) -> (Vec<Firing>, bool) {
    let mut out: Vec<Firing> = Vec::new();
    let mut lit: Option<usize> = None;
    let mut overlap = false;
    for e in world.events() {
        match e.effect {
            Effect::LedOn { led, .. } => {
                if lit.is_some() {
                    overlap = true;
                }
                out.push(Firing { led, on: e.t, off: None });
                lit = Some(out.len() - 1);
            }
            Effect::LedOff { led, cause } => {
                if let Some(k) = lit.take() {
                    assert_eq!(out[k].led, led, "LedOff for an LED that was not lit");
                    out[k].off = Some((e.t, cause));
                }
            }
            Effect::Reboot { .. } => {
                if let Some(k) = lit.take() {
                    out[k].off = Some((e.t, OffCause::Reboot));
                }
            }
            _ => {}
        }
    }
    (out, overlap)
}

async fn try_open(sim: &SimMcu) -> Result<Rig<SerialConnector>, RigError> {
    let locator = PortLocator::Path { path: sim.link_path.clone().unwrap() };
    let s = RigSettings { led_max_on_ms: 1000, ..settings() };
    let mut rig = Rig::open(SerialConnector { locator, baud: 1_000_000 }, s).await?;
    rig.home().await?;
    Ok(rig)
}

async fn open(sim: &SimMcu) -> Rig<SerialConnector> {
    try_open(sim).await.expect("open and home the rig")
}

fn link_path(dir: &tempfile::TempDir) -> PathBuf {
    dir.path().join("mcu")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn full_plan_survives_corruption_drops_duplicates_reboot_and_disconnect() {
    let dir = tempfile::tempdir().unwrap();
    let faults =
        FaultSpec::parse("corrupt=0.01,drop=0.005,dup=0.05,reboot-at=1300,disconnect-at=2200,reconnect-ms=300,seed=11")
            .unwrap();
    let world = World::new();
    let sim = SimMcu::spawn_pty(fast_mcu(), faults, world.clone(), Some(link_path(&dir))).await.unwrap();
    let _ = tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_test_writer()
        .try_init();
    let started = std::time::Instant::now();
    let mut rig = open(&sim).await;
    let shots = plan(64, 40);
    let mut ex = Dwell { dwell: Duration::from_micros(300), committed: Vec::new(), discarded: 0, unwanted: Vec::new() };
    let stats = sequence::run(&mut rig, &shots, &mut ex).await.expect("the plan completes despite the faults");
    rig.shutdown().await;
    let link = rig.link_stats();
    let recoveries = rig.recoveries().to_vec();
    tokio::time::sleep(Duration::from_millis(20)).await;
    sim.stop().await.unwrap();

    // Every shot committed exactly once.
    assert_eq!(stats.committed as usize, shots.len());
    let mut seen = HashMap::new();
    for (s, _, _) in &ex.committed {
        *seen.entry(s.index).or_insert(0) += 1;
    }
    assert!(seen.values().all(|&n| n == 1) && seen.len() == shots.len(), "a shot was committed twice or never");

    let (fired, overlap) = firings(&world);
    assert!(!overlap, "two LEDs were lit at once");
    // All off at the end.
    assert!(fired.iter().all(|f| f.off.is_some()), "an LED was left on");
    // Each committed exposure lies inside a firing of its LED at its position.
    for (shot, t0, t1) in &ex.committed {
        let f = fired
            .iter()
            .find(|f| f.led == shot.led && f.on <= *t0 && f.off.is_some_and(|(off, _)| off >= *t1))
            .unwrap_or_else(|| panic!("no firing of LED {} covers the exposure of shot {}", shot.led, shot.index));
        let pos = world.position_at(f.on, fast_mcu().rest_um);
        assert!(
            (pos - shot.position_um as f64).abs() < 1.0,
            "shot {} fired at {pos} um, not {}",
            shot.index,
            shot.position_um
        );
        let pos_end = world.position_at(*t1, fast_mcu().rest_um);
        assert!((pos_end - shot.position_um as f64).abs() < 1.0, "the carriage moved during shot {}", shot.index);
        // Retakes included, every position was reached moving toward +x,
        // so the backlash lies the same way for every shot.
        assert!(world.forward_at(*t0), "shot {} was approached toward -x", shot.index);
    }
    // Every firing beyond one per shot is explained: it was discarded for a
    // retake, cut short by the reboot or the disconnect, or was the command
    // in flight when a recovery began (re-sent after it).
    let cut_short = fired.iter().filter(|f| matches!(f.off, Some((_, OffCause::Reboot)))).count() as u64;
    let extra = fired.len() as u64 - shots.len() as u64;
    assert!(
        extra <= stats.retakes + cut_short + recoveries.len() as u64,
        "{extra} unexplained extra firings ({} retakes, {cut_short} cut short, {} recoveries)",
        stats.retakes,
        recoveries.len()
    );
    eprintln!(
        "plan 64x40 in {:.1} s: {} commands, {} retransmits, {} retakes, {} extra firings, recoveries {:?}",
        started.elapsed().as_secs_f64(),
        link.commands,
        link.retransmits,
        stats.retakes,
        extra,
        recoveries
    );
    assert!(
        recoveries.iter().any(|r| matches!(r, rig::mcu::Recovery::Rebooted { .. })),
        "the reboot went unnoticed: {recoveries:?}"
    );
    eprintln!(
        "plan 64x40 in {:.1} s: {} commands, {} retransmits, {} retakes, {} extra firings, recoveries {:?}",
        started.elapsed().as_secs_f64(),
        link.commands,
        link.retransmits,
        stats.retakes,
        extra,
        recoveries
    );
    assert!(
        recoveries.iter().any(|r| matches!(r, rig::mcu::Recovery::Reconnected { .. })),
        "no reconnect: {recoveries:?}"
    );
    assert!(link.retransmits > 100, "faults were not exercised: {link:?}");
    eprintln!(
        "plan 64x40 in {:.1} s: {} commands, {} retransmits, {} retakes, {} extra firings, recoveries {:?}",
        started.elapsed().as_secs_f64(),
        link.commands,
        link.retransmits,
        stats.retakes,
        extra,
        recoveries
    );
}

/// Shots the exposer does not want are passed over without lighting their
/// LED, the last ones of the plan included: the last wanted shot is still
/// confirmed and committed, and the bar ends dark.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unwanted_shots_are_passed_over_and_the_last_wanted_one_is_committed() {
    let dir = tempfile::tempdir().unwrap();
    let world = World::new();
    let sim = SimMcu::spawn_pty(fast_mcu(), FaultSpec::default(), world.clone(), Some(link_path(&dir))).await.unwrap();
    let mut rig = open(&sim).await;
    let shots = plan(3, 4);
    let unwanted = vec![1, 2, 4, 5, 6, 7, 9, 10, 11];
    let mut ex =
        Dwell { dwell: Duration::from_micros(100), committed: Vec::new(), discarded: 0, unwanted: unwanted.clone() };
    let stats = sequence::run(&mut rig, &shots, &mut ex).await.unwrap();
    rig.shutdown().await;
    tokio::time::sleep(Duration::from_millis(20)).await;
    sim.stop().await.unwrap();
    let committed: Vec<u32> = ex.committed.iter().map(|(s, _, _)| s.index).collect();
    assert_eq!(committed, vec![0, 3, 8]);
    assert_eq!(stats.committed, 3);
    // Step 1 has no wanted shot, so the gantry goes from step 0 to step 2;
    // both moves after homing go toward +x, so nothing more moves.
    assert_eq!(stats.moves, 2);
    let moves: Vec<(f64, f64)> = world
        .events()
        .iter()
        .filter_map(|e| match e.effect {
            Effect::MoveStart { from_um, to_um, .. } => Some((from_um, to_um)),
            _ => None,
        })
        .collect();
    assert_eq!(moves.len(), 3, "homing and two moves: {moves:?}");
    let (fired, overlap) = firings(&world);
    assert!(!overlap, "two LEDs were lit at once");
    assert_eq!(fired.iter().map(|f| f.led).collect::<Vec<_>>(), vec![0, 3, 0], "an unwanted shot was lit");
    assert!(fired.iter().all(|f| f.off.is_some()), "an LED was left on");
}

/// A reboot at every command of a small plan in turn: wherever it lands,
/// every shot is committed once, and every committed exposure was taken
/// with the carriage arrived moving toward +x, retakes after the sequence
/// had moved on included (`rig::sequence::APPROACH_UM`).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn wherever_a_reboot_lands_every_shot_is_approached_from_the_same_side() {
    let shots = plan(3, 3);
    let mut backward_retakes = 0;
    for at in 1..=40 {
        let dir = tempfile::tempdir().unwrap();
        let faults = FaultSpec::parse(&format!("reboot-at={at}")).unwrap();
        let world = World::new();
        let sim = SimMcu::spawn_pty(fast_mcu(), faults, world.clone(), Some(link_path(&dir))).await.unwrap();
        // A reboot while the rig is opened and homed fails the opening:
        // the sweep is over the sequence's commands.
        let Ok(mut rig) = try_open(&sim).await else { continue };
        let mut ex =
            Dwell { dwell: Duration::from_micros(100), committed: Vec::new(), discarded: 0, unwanted: Vec::new() };
        sequence::run(&mut rig, &shots, &mut ex).await.unwrap();
        rig.shutdown().await;
        tokio::time::sleep(Duration::from_millis(20)).await;
        sim.stop().await.unwrap();
        let mut committed: Vec<u32> = ex.committed.iter().map(|(s, _, _)| s.index).collect();
        committed.sort();
        assert_eq!(committed, (0..shots.len() as u32).collect::<Vec<_>>(), "reboot at command {at}");
        for (shot, t0, _) in &ex.committed {
            assert!(world.forward_at(*t0), "reboot at command {at}: shot {} approached toward -x", shot.index);
        }
        // A retake of a step's last shot after the move to the next step
        // (a move toward -x that is not homing, which ends at -120 mm).
        let moves_back = world.events().iter().any(
            |e| matches!(e.effect, Effect::MoveStart { from_um, to_um, .. } if to_um < from_um && to_um > -119_000.0),
        );
        backward_retakes += moves_back as u32;
    }
    assert!(backward_retakes > 0, "no reboot made the sequence go back a step: the sweep tests nothing");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_link_that_never_comes_back_ends_with_a_clear_error_and_leds_off() {
    let dir = tempfile::tempdir().unwrap();
    let faults = FaultSpec::parse("disconnect-at=30,reconnect-ms=60000").unwrap();
    let world = World::new();
    let sim = SimMcu::spawn_pty(fast_mcu(), faults, world.clone(), Some(link_path(&dir))).await.unwrap();
    let mut rig = open(&sim).await;
    rig.settings_mut().reconnect_timeout = Duration::from_millis(800);
    let shots = plan(4, 40);
    let mut ex = Dwell { dwell: Duration::from_micros(100), committed: Vec::new(), discarded: 0, unwanted: Vec::new() };
    let err = sequence::run(&mut rig, &shots, &mut ex).await.expect_err("must fail");
    let msg = err.to_string();
    assert!(msg.contains("USB cable") || msg.contains("power"), "error does not say what to check: {msg}");
    let (fired, _) = firings(&world);
    assert!(fired.iter().all(|f| f.off.is_some()), "an LED was left on after the failure");
    sim.stop().await.unwrap();
}

/// A controller that stops answering while its port still opens (wedged
/// firmware behind a live USB link): the operation gives up after its
/// recovery budget, saying what to do, instead of reconnecting forever.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_controller_that_stops_answering_exhausts_a_bounded_budget() {
    let dir = tempfile::tempdir().unwrap();
    let faults = FaultSpec::parse("hang-at=60").unwrap();
    let world = World::new();
    let sim = SimMcu::spawn_pty(fast_mcu(), faults, world.clone(), Some(link_path(&dir))).await.unwrap();
    let mut rig = open(&sim).await;
    let budget = rig.settings().max_recoveries_per_op;
    let shots = plan(4, 40);
    let mut ex = Dwell { dwell: Duration::from_micros(100), committed: Vec::new(), discarded: 0, unwanted: Vec::new() };
    let err = sequence::run(&mut rig, &shots, &mut ex).await.expect_err("a hung controller cannot finish the plan");
    assert!(matches!(err, RigError::GaveUp { n, .. } if n == budget), "{err}");
    assert!(err.to_string().contains("power-cycle the controller"), "{err}");
    let reconnects = rig.recoveries().iter().filter(|r| matches!(r, rig::mcu::Recovery::Reconnected { .. })).count();
    assert!((1..=budget as usize).contains(&reconnects), "{reconnects} reconnects for a budget of {budget}");
    // Every later operation fails the same bounded way (a resume of a
    // capture on the same wedged controller).
    let before = rig.recoveries().len();
    let again = rig.home().await.expect_err("still wedged");
    assert!(matches!(again, RigError::GaveUp { .. }), "{again}");
    let more =
        rig.recoveries()[before..].iter().filter(|r| matches!(r, rig::mcu::Recovery::Reconnected { .. })).count();
    assert!(more <= budget as usize, "{more} reconnects in the second operation");
    sim.stop().await.unwrap();
}

/// Environment variable that turns this test binary into the host process
/// of [`killing_the_host_leaves_the_leds_off_within_the_watchdog_time`].
const HOST_PORT_ENV: &str = "REFLECTOMETER_TEST_HOST_PORT";

/// The host side, run in a child process: connect, light LED 7 with a long
/// maximum on-time, then keep the link alive until killed.
async fn host_until_killed(path: PathBuf) -> ! {
    let mut s = settings();
    s.led_max_on_ms = 30_000;
    let locator = PortLocator::Path { path };
    let mut rig = Rig::open(SerialConnector { locator, baud: 1_000_000 }, s).await.expect("open rig");
    rig.home().await.expect("home");
    rig.led_on(7).await.expect("led on");
    loop {
        tokio::time::sleep(Duration::from_millis(100)).await;
        let _ = rig.keepalive().await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killing_the_host_leaves_the_leds_off_within_the_watchdog_time() {
    if let Some(p) = std::env::var_os(HOST_PORT_ENV) {
        host_until_killed(PathBuf::from(p)).await;
    }
    let dir = tempfile::tempdir().unwrap();
    let world = World::new();
    let sim = SimMcu::spawn_pty(fast_mcu(), FaultSpec::default(), world.clone(), Some(link_path(&dir))).await.unwrap();
    // This very test, in a child process, as the host.
    let mut child = std::process::Command::new(std::env::current_exe().unwrap())
        .args(["killing_the_host_leaves_the_leds_off_within_the_watchdog_time", "--exact", "--nocapture"])
        .env(HOST_PORT_ENV, link_path(&dir))
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let t = Instant::now();
    while !firings(&world).0.iter().any(|f| f.led == 7) {
        assert!(t.elapsed() < Duration::from_secs(20), "the host never lit the LED");
        assert!(child.try_wait().unwrap().is_none(), "the host exited");
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    // Alive and keeping the link up: the LED stays on well past the watchdog time.
    let watchdog = Duration::from_millis(firmware_protocol::timing::WATCHDOG_MS as u64);
    tokio::time::sleep(watchdog * 2).await;
    assert!(firings(&world).0.iter().all(|f| f.off.is_none()), "the LED went off while the host was alive");
    child.kill().unwrap();
    let killed = Instant::now();
    child.wait().unwrap();
    tokio::time::sleep(watchdog + Duration::from_millis(500)).await;
    let (fired, _) = firings(&world);
    let f = fired.iter().find(|f| f.led == 7).unwrap();
    let (off, cause) = f.off.expect("the LED is still on after the host died");
    assert_eq!(cause, OffCause::Watchdog);
    let after = off.saturating_duration_since(killed);
    assert!(after <= watchdog + Duration::from_millis(100), "off {after:?} after the kill");
    sim.stop().await.unwrap();
}
