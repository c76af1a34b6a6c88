//! The one place that converts between clocks.
//!
//! - Host events (a command sent, a reply received) are `tokio::time::Instant`,
//!   which on Linux is `CLOCK_MONOTONIC` (and virtual under paused test time).
//! - V4L2 buffers carry `CLOCK_MONOTONIC` timestamps as `timeval`s.
//! - Frame metadata on disk stores nanoseconds of `CLOCK_MONOTONIC`
//!   ([`MonoNs`]), comparable across both.
//!
//! `Instant` is opaque, so the conversion is anchored once: the pair
//! (`Instant::now()`, `clock_gettime(CLOCK_MONOTONIC)`) read back to back.
//! Both read the same clock, so the offset is exact up to the few hundred
//! nanoseconds between the two calls.

use std::sync::OnceLock;
use std::time::Duration;

pub use frame::MonoNs;
use tokio::time::Instant;

/// `CLOCK_MONOTONIC` from a V4L2 buffer's `timeval`.
pub fn from_timeval(sec: i64, usec: i64) -> MonoNs {
    MonoNs((sec.max(0) as u64) * 1_000_000_000 + (usec.max(0) as u64) * 1_000)
}

/// `a - b`, zero if negative.
pub fn elapsed(a: MonoNs, b: MonoNs) -> Duration {
    Duration::from_nanos(a.0.saturating_sub(b.0))
}

fn clock_monotonic_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes into the timespec we pass.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

struct Anchor {
    instant: std::time::Instant,
    mono: u64,
}

fn anchor() -> &'static Anchor {
    static A: OnceLock<Anchor> = OnceLock::new();
    A.get_or_init(|| {
        let instant = std::time::Instant::now();
        let mono = clock_monotonic_ns();
        Anchor { instant, mono }
    })
}

/// `CLOCK_MONOTONIC` now.
pub fn now_mono() -> MonoNs {
    MonoNs(clock_monotonic_ns())
}

/// Convert a host instant to monotonic nanoseconds.
pub fn to_mono(t: Instant) -> MonoNs {
    let a = anchor();
    let t = t.into_std();
    if t >= a.instant {
        MonoNs(a.mono + (t - a.instant).as_nanos() as u64)
    } else {
        MonoNs(a.mono.saturating_sub((a.instant - t).as_nanos() as u64))
    }
}

/// Convert monotonic nanoseconds to a host instant.
pub fn to_instant(m: MonoNs) -> Instant {
    let a = anchor();
    let t = if m.0 >= a.mono {
        a.instant + Duration::from_nanos(m.0 - a.mono)
    } else {
        a.instant - Duration::from_nanos(a.mono - m.0)
    };
    Instant::from_std(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_agreement_with_clock_gettime() {
        let t = Instant::now();
        let m = to_mono(t);
        let back = to_instant(m);
        let d = if back > t { back - t } else { t - back };
        assert!(d < Duration::from_micros(1));
        let direct = now_mono();
        let diff = direct.0.abs_diff(to_mono(Instant::now()).0);
        assert!(diff < 1_000_000, "instant and CLOCK_MONOTONIC disagree by {diff} ns");
    }
}
