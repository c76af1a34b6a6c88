//! The physical truth of the simulated rig: where the carriage is and which
//! LED is lit at every instant, recorded as an append-only timeline.
//!
//! The emulated MCU writes it; the simulated camera reads it to render the
//! frame a real camera would have exposed; tests read it to assert what
//! really happened (every LED fired once, at the right position, never two
//! at once, all off at the end). Positions here are physical (micrometres
//! on the gantry axis), independent of what the MCU's step counter believes
//! before homing.

use std::sync::{Arc, Mutex, MutexGuard};

use tokio::time::Instant;

/// Why an LED went off.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OffCause {
    /// `SetLed` for another LED or `AllOff`.
    Command,
    /// Its maximum on-time elapsed.
    MaxOnTime,
    /// The host went silent for longer than the watchdog.
    Watchdog,
    /// E-stop.
    EStop,
    /// The MCU reset (power loss, reboot fault).
    Reboot,
}

/// One physical effect.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Effect {
    LedOn {
        led: u8,
        current_ma: u16,
    },
    LedOff {
        led: u8,
        cause: OffCause,
    },
    /// The carriage starts a trapezoidal move.
    MoveStart {
        from_um: f64,
        to_um: f64,
        profile: MotionProfile,
    },
    /// The carriage stopped before finishing its move (e-stop, watchdog, reset).
    Halt {
        at_um: f64,
    },
    /// The MCU rebooted with a new boot id.
    Reboot {
        boot_id: u32,
    },
    /// Homing finished: the MCU's counter now matches physical position.
    Homed,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Event {
    pub t: Instant,
    pub effect: Effect,
}

/// Speed and acceleration of a move, and the settling time after it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionProfile {
    pub speed_um_s: f64,
    pub accel_um_s2: f64,
}

impl MotionProfile {
    /// Duration of a trapezoidal (or triangular) move over `dist_um`.
    pub fn duration_s(&self, dist_um: f64) -> f64 {
        setup::trapezoid_seconds(dist_um, self.speed_um_s, self.accel_um_s2)
    }

    /// Distance covered `t_s` into a move of `dist_um` (clamped to the end).
    pub fn distance_at(&self, dist_um: f64, t_s: f64) -> f64 {
        let d = dist_um.abs();
        let (v, a) = (self.speed_um_s.max(1e-9), self.accel_um_s2.max(1e-9));
        let total = self.duration_s(d);
        let t = t_s.clamp(0.0, total);
        let (t_ramp, v_peak) = if d >= v * v / a { (v / a, v) } else { ((d / a).sqrt(), (d * a).sqrt()) };
        if t <= t_ramp {
            0.5 * a * t * t
        } else if t <= total - t_ramp {
            0.5 * a * t_ramp * t_ramp + v_peak * (t - t_ramp)
        } else {
            let tr = total - t;
            d - 0.5 * a * tr * tr
        }
    }
}

/// The timeline, shared between the MCU task, the camera and tests.
#[derive(Clone, Debug, Default)]
pub struct World {
    inner: Arc<Mutex<Vec<Event>>>,
}

impl World {
    pub fn new() -> Self {
        Self::default()
    }

    fn lock(&self) -> MutexGuard<'_, Vec<Event>> {
        // A panic elsewhere while holding the lock leaves a valid Vec.
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    pub fn record(&self, t: Instant, effect: Effect) {
        self.lock().push(Event { t, effect });
    }

    /// A copy of every event so far.
    pub fn events(&self) -> Vec<Event> {
        self.lock().clone()
    }

    /// Physical carriage position at `t`, from the start position `home_um`
    /// (where the carriage rests before any move).
    pub fn position_at(&self, t: Instant, rest_um: f64) -> f64 {
        position_in(&self.lock(), t, rest_um)
    }

    /// Whether the carriage's last move that started by `t` went toward
    /// `+x` (true before any move: homing approaches from `-x`).
    pub fn forward_at(&self, t: Instant) -> bool {
        self.lock()
            .iter()
            .take_while(|e| e.t <= t)
            .filter_map(|e| match e.effect {
                Effect::MoveStart { from_um, to_um, .. } if to_um != from_um => Some(to_um > from_um),
                _ => None,
            })
            .last()
            .unwrap_or(true)
    }

    /// The LED lit at `t` (with its current), if any.
    pub fn led_at(&self, t: Instant) -> Option<(u8, u16)> {
        led_in(&self.lock(), t)
    }

    /// Every interval during `[t0, t1)` in which one LED was lit, with the
    /// LED, its current and the overlap (for rendering a frame's exposure).
    pub fn led_intervals(&self, t0: Instant, t1: Instant) -> Vec<(u8, u16, Instant, Instant)> {
        let ev = self.lock();
        let mut out = Vec::new();
        let mut cur = led_in(&ev, t0);
        let mut start = t0;
        for e in ev.iter().filter(|e| e.t > t0 && e.t < t1) {
            let next = match e.effect {
                Effect::LedOn { led, current_ma } => Some(Some((led, current_ma))),
                Effect::LedOff { .. } | Effect::Reboot { .. } => Some(None),
                _ => None,
            };
            if let Some(n) = next {
                if let Some((led, c)) = cur {
                    out.push((led, c, start, e.t));
                }
                cur = n;
                start = e.t;
            }
        }
        if let Some((led, c)) = cur {
            out.push((led, c, start, t1));
        }
        out
    }
}

fn led_in(ev: &[Event], t: Instant) -> Option<(u8, u16)> {
    let mut cur = None;
    for e in ev.iter().take_while(|e| e.t <= t) {
        match e.effect {
            Effect::LedOn { led, current_ma } => cur = Some((led, current_ma)),
            Effect::LedOff { .. } | Effect::Reboot { .. } => cur = None,
            _ => {}
        }
    }
    cur
}

fn position_in(ev: &[Event], t: Instant, rest_um: f64) -> f64 {
    let mut pos = rest_um;
    let mut moving: Option<(Instant, f64, f64, MotionProfile)> = None;
    for e in ev.iter().take_while(|e| e.t <= t) {
        match e.effect {
            Effect::MoveStart { from_um, to_um, profile } => {
                pos = from_um;
                moving = Some((e.t, from_um, to_um, profile));
            }
            Effect::Halt { at_um } => {
                pos = at_um;
                moving = None;
            }
            _ => {}
        }
    }
    if let Some((t0, from, to, prof)) = moving {
        let d = prof.distance_at(to - from, (t - t0).as_secs_f64());
        pos = from + d * (to - from).signum();
    }
    pos
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trapezoid_reaches_the_target_at_its_duration() {
        let p = MotionProfile { speed_um_s: 100_000.0, accel_um_s2: 1_000_000.0 };
        for d in [10.0, 1000.0, 3750.0, 240_000.0] {
            let t = p.duration_s(d);
            assert!((p.distance_at(d, t) - d).abs() < 1e-6, "{d}");
            assert!((p.distance_at(d, t / 2.0) - d / 2.0).abs() < 1e-6 * d, "{d} midpoint");
        }
    }
}
