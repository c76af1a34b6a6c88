//! The emulated rig microcontroller: the firmware side of
//! `firmware-protocol`, written as a state machine driven by received
//! frames and by time (no IO here; [`crate::link`] moves the bytes).
//!
//! It homes against a limit switch, moves with a trapezoidal profile and
//! settles, enforces soft limits and refuses moves until homed, lights one
//! LED at a time with a maximum on-time, trips a watchdog when the host goes
//! silent while something is active, latches e-stop, answers duplicate
//! sequence numbers from its reply cache without executing them, and can be
//! rebooted (new boot id, position lost). Every physical effect goes into
//! the shared [`World`] timeline.

use firmware_protocol::frame::FrameError;
use firmware_protocol::message::NO_LED;
use firmware_protocol::{
    Command, CommandPacket, DecodeError, Faults, HelloInfo, NakReason, PROTOCOL_VERSION, Reply, ReplyPacket,
    StatusFlags, StatusInfo, UNSOLICITED_SEQ,
};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use tokio::time::{Duration, Instant};

use crate::world::{Effect, MotionProfile, OffCause, World};

/// Mechanical and electrical parameters of the emulated rig.
#[derive(Clone, Debug, PartialEq)]
pub struct McuConfig {
    pub firmware: [u8; 3],
    pub n_leds: u8,
    /// Soft limits, in the homed coordinate (= physical position).
    pub travel_min_um: i32,
    pub travel_max_um: i32,
    /// Physical position of the minimum limit switch (home).
    pub switch_min_um: i32,
    pub max_current_ma: u16,
    pub watchdog_ms: u16,
    pub profile: MotionProfile,
    pub homing_speed_um_s: f64,
    /// Time the carriage needs to stop ringing after a move.
    pub settle_ms: f64,
    /// Multiplies every mechanical duration (moves, homing, settling):
    /// 1 for real time, smaller for fast tests. Protocol timeouts (the
    /// watchdog, LED on-time) are not scaled.
    pub time_scale: f64,
    /// Physical carriage position at power-up.
    pub rest_um: f64,
}

impl Default for McuConfig {
    fn default() -> Self {
        Self {
            firmware: [1, 0, 0],
            n_leds: 40,
            travel_min_um: -120_000,
            travel_max_um: 120_000,
            switch_min_um: -125_000,
            max_current_ma: 350,
            watchdog_ms: firmware_protocol::timing::WATCHDOG_MS,
            profile: MotionProfile { speed_um_s: 100_000.0, accel_um_s2: 1_000_000.0 },
            homing_speed_um_s: 50_000.0,
            settle_ms: 30.0,
            time_scale: 1.0,
            rest_um: 10_000.0,
        }
    }
}

impl McuConfig {
    /// The emulated controller of a rig with geometry `g`, its clock running
    /// `time_scale` times real time (0.001: a thousand times faster).
    pub fn for_geometry(g: &setup::RigGeometry, time_scale: f64) -> Self {
        let um = |mm: f32| (mm * 1000.0).round() as i32;
        Self {
            n_leds: g.bar.n_leds,
            travel_min_um: um(g.gantry.travel_min_mm),
            travel_max_um: um(g.gantry.travel_max_mm),
            // The home switch sits 5 mm beyond the soft limit.
            switch_min_um: um(g.gantry.travel_min_mm) - 5_000,
            profile: MotionProfile {
                speed_um_s: g.gantry.speed_mm_s as f64 * 1000.0,
                accel_um_s2: g.gantry.accel_mm_s2 as f64 * 1000.0,
            },
            homing_speed_um_s: g.gantry.homing_speed_mm_s as f64 * 1000.0,
            settle_ms: g.gantry.settle_ms as f64,
            time_scale,
            ..Self::default()
        }
    }
}

#[derive(Clone, Copy, Debug)]
struct Motion {
    seq: u8,
    from_um: f64,
    to_um: f64,
    start: Instant,
    /// End of motion plus settling.
    done_at: Instant,
    profile: MotionProfile,
    homing: bool,
}

#[derive(Clone, Copy, Debug)]
struct Lit {
    led: u8,
    off_deadline: Instant,
}

/// Counters of what the MCU saw, for tests and overhead measurements.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct McuStats {
    pub frames_ok: u64,
    pub frames_rejected: u64,
    pub duplicates: u64,
    pub commands_executed: u64,
    pub naks: u64,
}

pub struct Mcu {
    cfg: McuConfig,
    world: World,
    rng: Pcg64,
    boot_id: u32,
    homed: bool,
    /// Reported position = physical + offset (0 once homed).
    offset_um: f64,
    /// Physical position when not moving.
    rest_um: f64,
    motion: Option<Motion>,
    lit: Option<Lit>,
    faults: u8,
    last: Option<(u8, Reply)>,
    last_rx: Instant,
    stats: McuStats,
}

impl std::fmt::Debug for Mcu {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Mcu").field("boot_id", &self.boot_id).field("homed", &self.homed).finish_non_exhaustive()
    }
}

impl Mcu {
    /// Power up at `now`: returns the MCU and its `Boot` announcement.
    pub fn power_up(cfg: McuConfig, world: World, seed: u64, now: Instant) -> (Self, ReplyPacket) {
        let rest = cfg.rest_um;
        let mut m = Self {
            cfg,
            world,
            rng: Pcg64::seed_from_u64(seed),
            boot_id: 0,
            homed: false,
            offset_um: 0.0,
            rest_um: rest,
            motion: None,
            lit: None,
            faults: 0,
            last: None,
            last_rx: now,
            stats: McuStats::default(),
        };
        let boot = m.reset(now);
        (m, boot)
    }

    /// Reset as after a power glitch: LEDs off, motion stopped, position
    /// lost, new boot id. Returns the `Boot` announcement.
    pub fn reset(&mut self, now: Instant) -> ReplyPacket {
        self.halt(now);
        if let Some(l) = self.lit.take() {
            self.world.record(now, Effect::LedOff { led: l.led, cause: OffCause::Reboot });
        }
        self.boot_id = self.rng.random::<u32>() | 1;
        self.homed = false;
        // The step counter restarts at 0 wherever the carriage is.
        self.offset_um = -self.rest_um;
        self.faults = 0;
        self.last = None;
        self.last_rx = now;
        self.world.record(now, Effect::Reboot { boot_id: self.boot_id });
        ReplyPacket { seq: UNSOLICITED_SEQ, boot_id: self.boot_id, reply: Reply::Boot }
    }

    pub fn boot_id(&self) -> u32 {
        self.boot_id
    }

    pub fn stats(&self) -> McuStats {
        self.stats
    }

    pub fn world(&self) -> &World {
        &self.world
    }

    pub fn config(&self) -> &McuConfig {
        &self.cfg
    }

    fn reply(&self, seq: u8, reply: Reply) -> ReplyPacket {
        ReplyPacket { seq, boot_id: self.boot_id, reply }
    }

    fn scaled(&self, seconds: f64) -> Duration {
        Duration::from_secs_f64((seconds * self.cfg.time_scale).max(0.0))
    }

    /// A profile in real (scaled) time: distances unchanged, durations
    /// multiplied by `time_scale`.
    fn real_time(&self, p: MotionProfile) -> MotionProfile {
        let k = self.cfg.time_scale.max(1e-12);
        MotionProfile { speed_um_s: p.speed_um_s / k, accel_um_s2: p.accel_um_s2 / (k * k) }
    }

    /// Physical position at `now`.
    pub fn physical_position(&self, now: Instant) -> f64 {
        match self.motion {
            Some(m) => self.position_along(now, m),
            None => self.rest_um,
        }
    }

    fn position_along(&self, now: Instant, m: Motion) -> f64 {
        let t = (now - m.start).as_secs_f64();
        let d = m.profile.distance_at(m.to_um - m.from_um, t);
        m.from_um + d * (m.to_um - m.from_um).signum()
    }

    fn reported_position(&self, now: Instant) -> i32 {
        (self.physical_position(now) + self.offset_um).round() as i32
    }

    /// Stop any motion where it is.
    fn halt(&mut self, now: Instant) {
        if let Some(m) = self.motion.take() {
            let at = self.position_along(now, m);
            self.rest_um = at;
            self.world.record(now, Effect::Halt { at_um: at });
        }
    }

    fn led_off(&mut self, now: Instant, cause: OffCause) {
        if let Some(l) = self.lit.take() {
            self.world.record(now, Effect::LedOff { led: l.led, cause });
        }
    }

    fn start_motion(&mut self, now: Instant, seq: u8, to_um: f64, profile: MotionProfile, homing: bool) {
        let from = self.physical_position(now);
        if self.motion.is_some() {
            self.halt(now);
        }
        let profile = self.real_time(profile);
        let dur = profile.duration_s(to_um - from) + self.scaled(self.cfg.settle_ms / 1000.0).as_secs_f64();
        self.motion = Some(Motion {
            seq,
            from_um: from,
            to_um,
            start: now,
            done_at: now + Duration::from_secs_f64(dur),
            profile,
            homing,
        });
        self.world.record(now, Effect::MoveStart { from_um: from, to_um, profile });
    }

    fn status(&self, now: Instant) -> StatusInfo {
        let mut flags = 0;
        if self.homed {
            flags |= StatusFlags::HOMED;
        }
        if let Some(m) = self.motion {
            flags |= StatusFlags::MOVING;
            if m.homing {
                flags |= StatusFlags::HOMING;
            }
        }
        let phys = self.physical_position(now);
        if phys <= self.cfg.switch_min_um as f64 + 1.0 {
            flags |= StatusFlags::LIMIT_MIN;
        }
        if self.lit.is_some() {
            flags |= StatusFlags::LED_ON;
        }
        StatusInfo {
            position_um: self.reported_position(now),
            flags: StatusFlags(flags),
            lit_led: self.lit.map_or(NO_LED, |l| l.led),
            faults: Faults(self.faults),
        }
    }

    /// Handle one frame's COBS bytes received at `now`.
    pub fn on_frame(&mut self, now: Instant, encoded: &[u8]) -> Vec<ReplyPacket> {
        let packet = match CommandPacket::decode(encoded) {
            Ok(p) => p,
            Err(DecodeError::Frame(_)) => {
                // Corrupt frames are dropped without an answer.
                self.stats.frames_rejected += 1;
                return Vec::new();
            }
            Err(e) => {
                self.stats.frames_ok += 1;
                self.last_rx = now;
                let seq = CommandPacket::peek_seq(encoded).unwrap_or(UNSOLICITED_SEQ);
                let reason = match e {
                    DecodeError::Version(_) => NakReason::VersionMismatch,
                    DecodeError::UnknownId(_) => NakReason::UnknownCommand,
                    DecodeError::Length { .. } => NakReason::BadLength,
                    DecodeError::Frame(FrameError::TooShort) | DecodeError::Frame(_) => NakReason::BadLength,
                };
                self.stats.naks += 1;
                return vec![self.reply(seq, Reply::Nak(reason))];
            }
        };
        self.stats.frames_ok += 1;
        self.last_rx = now;
        // E-stop is executed even if it repeats the last sequence number.
        if packet.command != Command::EStop {
            if let Some((seq, cached)) = self.last {
                if seq == packet.seq {
                    self.stats.duplicates += 1;
                    return vec![self.reply(seq, cached)];
                }
            }
        }
        let reply = self.execute(now, packet);
        self.last = Some((packet.seq, reply));
        self.stats.commands_executed += 1;
        if matches!(reply, Reply::Nak(_)) {
            self.stats.naks += 1;
        }
        vec![self.reply(packet.seq, reply)]
    }

    fn blocked(&self) -> Option<NakReason> {
        if self.faults & Faults::E_STOP != 0 {
            Some(NakReason::EStopLatched)
        } else if Faults(self.faults).blocking() {
            Some(NakReason::FaultLatched)
        } else {
            None
        }
    }

    fn execute(&mut self, now: Instant, p: CommandPacket) -> Reply {
        match p.command {
            Command::Hello => Reply::Hello(HelloInfo {
                protocol_version: PROTOCOL_VERSION,
                firmware: self.cfg.firmware,
                n_leds: self.cfg.n_leds,
                travel_min_um: self.cfg.travel_min_um,
                travel_max_um: self.cfg.travel_max_um,
                max_current_ma: self.cfg.max_current_ma,
                watchdog_ms: self.cfg.watchdog_ms,
            }),
            Command::Heartbeat => Reply::Ack,
            Command::Status => Reply::Status(self.status(now)),
            Command::AllOff => {
                self.led_off(now, OffCause::Command);
                Reply::Ack
            }
            Command::EStop => {
                self.halt(now);
                self.led_off(now, OffCause::EStop);
                self.faults |= Faults::E_STOP;
                self.homed = false;
                Reply::Ack
            }
            Command::ClearFault => {
                self.faults = 0;
                Reply::Ack
            }
            Command::Home => {
                if let Some(r) = self.blocked() {
                    return Reply::Nak(r);
                }
                if self.motion.is_some_and(|m| m.homing) {
                    // Already homing: the same command again changes nothing.
                    if let Some(m) = self.motion.as_mut() {
                        m.seq = p.seq;
                    }
                    return Reply::Ack;
                }
                let prof = MotionProfile { speed_um_s: self.cfg.homing_speed_um_s, ..self.cfg.profile };
                self.start_motion(now, p.seq, self.cfg.switch_min_um as f64, prof, true);
                Reply::Ack
            }
            Command::MoveTo { position_um } => {
                if let Some(r) = self.blocked() {
                    return Reply::Nak(r);
                }
                if !self.homed || self.motion.is_some_and(|m| m.homing) {
                    return Reply::Nak(NakReason::NotHomed);
                }
                if position_um < self.cfg.travel_min_um || position_um > self.cfg.travel_max_um {
                    return Reply::Nak(NakReason::OutOfRange);
                }
                let target_phys = position_um as f64 - self.offset_um;
                self.start_motion(now, p.seq, target_phys, self.cfg.profile, false);
                Reply::Ack
            }
            Command::SetLed { led, current_ma, max_on_ms } => {
                if let Some(r) = self.blocked() {
                    return Reply::Nak(r);
                }
                if led >= self.cfg.n_leds {
                    return Reply::Nak(NakReason::LedOutOfRange);
                }
                if current_ma > self.cfg.max_current_ma {
                    return Reply::Nak(NakReason::CurrentTooHigh);
                }
                self.led_off(now, OffCause::Command);
                self.world.record(now, Effect::LedOn { led, current_ma });
                self.lit = Some(Lit { led, off_deadline: now + Duration::from_millis(max_on_ms as u64) });
                Reply::Ack
            }
        }
    }

    /// When [`Mcu::tick`] must run next (motion end, LED deadline, watchdog).
    pub fn next_deadline(&self) -> Option<Instant> {
        let active = self.motion.is_some() || self.lit.is_some();
        let wd = active.then(|| self.last_rx + Duration::from_millis(self.cfg.watchdog_ms as u64));
        [self.motion.map(|m| m.done_at), self.lit.map(|l| l.off_deadline), wd].into_iter().flatten().min()
    }

    /// Advance time to `now`: finish moves, enforce LED on-time and the
    /// watchdog. Returns replies to send (`MoveDone`).
    pub fn tick(&mut self, now: Instant) -> Vec<ReplyPacket> {
        let mut out = Vec::new();
        let wd_deadline = self.last_rx + Duration::from_millis(self.cfg.watchdog_ms as u64);
        if now >= wd_deadline && (self.motion.is_some() || self.lit.is_some()) {
            self.halt(now);
            self.led_off(now, OffCause::Watchdog);
            self.faults |= Faults::WATCHDOG;
        }
        if let Some(l) = self.lit {
            if now >= l.off_deadline {
                self.led_off(l.off_deadline, OffCause::MaxOnTime);
                self.faults |= Faults::LED_OVERTIME;
            }
        }
        if let Some(m) = self.motion {
            if now >= m.done_at {
                self.motion = None;
                self.rest_um = m.to_um;
                if m.homing {
                    self.homed = true;
                    self.offset_um = 0.0;
                    self.world.record(m.done_at, Effect::Homed);
                }
                let done = Reply::MoveDone { position_um: self.reported_position(now) };
                if self.last.is_some_and(|(s, _)| s == m.seq) {
                    self.last = Some((m.seq, done));
                }
                out.push(self.reply(m.seq, done));
            }
        }
        out
    }
}

/// Version of the emulated firmware, as reported by `Hello`.
pub fn firmware_version(cfg: &McuConfig) -> String {
    format!("{}.{}.{}", cfg.firmware[0], cfg.firmware[1], cfg.firmware[2])
}
