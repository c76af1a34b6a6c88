//! Faults the emulated rig can inject, configured per run with a spec
//! string such as `corrupt=0.01,drop=0.005,dup=0.02,delay-ms=3,reboot-at=500,disconnect-at=900,seed=7`.
//!
//! - `corrupt=P`: each byte in either direction has one bit flipped with probability P.
//! - `drop=P`: each byte in either direction is lost with probability P.
//! - `dup=P`: each reply frame is sent twice with probability P.
//! - `delay-ms=N`: every reply is held back N milliseconds.
//! - `reboot-at=N`: the MCU resets when the N-th valid command arrives (that command is lost).
//! - `disconnect-at=N`: the link disappears when the N-th valid command arrives, and comes back
//!   (as a freshly powered MCU on a new device node) after `reconnect-ms` (default 300).
//! - `hang-at=N`: from the N-th valid command on, the MCU never answers again, even after
//!   the host reopens the port (wedged firmware behind a live USB link).
//! - `seed=N`: seed of the fault random stream (default 1).
//!
//! Camera faults use the same spec (ignored by the MCU): `frame-timeout-at=N`,
//! `error-frame=P`, `stale-frame=P`, `camera-unplug-at=N`.

use std::fmt;

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

#[derive(Clone, Debug, Default, PartialEq)]
pub struct FaultSpec {
    pub corrupt: f64,
    pub drop: f64,
    pub dup: f64,
    pub delay_ms: u64,
    pub reboot_at: Vec<u64>,
    pub disconnect_at: Vec<u64>,
    pub reconnect_ms: u64,
    /// The MCU stops answering at this command and never answers again.
    pub hang_at: Option<u64>,
    pub seed: u64,
    /// Camera: the N-th frame request never completes (the driver must time out).
    pub frame_timeout_at: Vec<u64>,
    /// Camera: probability that a frame carries the V4L2 error flag.
    pub error_frame: f64,
    /// Camera: probability that a frame is delivered late with an old timestamp.
    pub stale_frame: f64,
    /// Camera: the device disappears at the N-th frame and comes back.
    pub camera_unplug_at: Vec<u64>,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FaultSpecError(pub String);

impl fmt::Display for FaultSpecError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for FaultSpecError {}

impl FaultSpec {
    pub fn none() -> Self {
        Self { reconnect_ms: 300, seed: 1, ..Self::default() }
    }

    /// True if no fault of the serial link is configured.
    pub fn link_is_clean(&self) -> bool {
        self.corrupt == 0.0
            && self.drop == 0.0
            && self.dup == 0.0
            && self.delay_ms == 0
            && self.reboot_at.is_empty()
            && self.disconnect_at.is_empty()
            && self.hang_at.is_none()
    }

    pub fn parse(spec: &str) -> Result<Self, FaultSpecError> {
        let mut f = Self::none();
        let spec = spec.trim();
        if spec.is_empty() || spec == "none" {
            return Ok(f);
        }
        for item in spec.split(',') {
            let (k, v) = item
                .split_once('=')
                .ok_or_else(|| FaultSpecError(format!("fault '{item}' needs a value, like corrupt=0.01")))?;
            let (k, v) = (k.trim(), v.trim());
            let prob = |v: &str| -> Result<f64, FaultSpecError> {
                let p: f64 = v.parse().map_err(|_| FaultSpecError(format!("{k}={v}: not a number")))?;
                if (0.0..=1.0).contains(&p) {
                    Ok(p)
                } else {
                    Err(FaultSpecError(format!("{k}={v}: a probability must be between 0 and 1")))
                }
            };
            let int = |v: &str| -> Result<u64, FaultSpecError> {
                v.parse().map_err(|_| FaultSpecError(format!("{k}={v}: not a whole number")))
            };
            match k {
                "corrupt" => f.corrupt = prob(v)?,
                "drop" => f.drop = prob(v)?,
                "dup" => f.dup = prob(v)?,
                "delay-ms" => f.delay_ms = int(v)?,
                "reboot-at" => f.reboot_at.push(int(v)?),
                "disconnect-at" => f.disconnect_at.push(int(v)?),
                "reconnect-ms" => f.reconnect_ms = int(v)?,
                "hang-at" => f.hang_at = Some(int(v)?),
                "seed" => f.seed = int(v)?,
                "frame-timeout-at" => f.frame_timeout_at.push(int(v)?),
                "error-frame" => f.error_frame = prob(v)?,
                "stale-frame" => f.stale_frame = prob(v)?,
                "camera-unplug-at" => f.camera_unplug_at.push(int(v)?),
                other => {
                    return Err(FaultSpecError(format!(
                        "unknown fault '{other}'; known: corrupt, drop, dup, delay-ms, reboot-at, disconnect-at, \
                         reconnect-ms, hang-at, seed, frame-timeout-at, error-frame, stale-frame, camera-unplug-at"
                    )));
                }
            }
        }
        Ok(f)
    }
}

/// Applies byte-level faults to a stream, deterministically from the seed.
#[derive(Debug)]
pub struct ByteFaults {
    corrupt: f64,
    drop: f64,
    rng: Pcg64,
    pub corrupted: u64,
    pub dropped: u64,
}

impl ByteFaults {
    pub fn new(spec: &FaultSpec, stream: u64) -> Self {
        Self {
            corrupt: spec.corrupt,
            drop: spec.drop,
            rng: Pcg64::seed_from_u64(spec.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ stream),
            corrupted: 0,
            dropped: 0,
        }
    }

    /// Pass `bytes` through the faults into `out`.
    pub fn apply(&mut self, bytes: &[u8], out: &mut Vec<u8>) {
        for &b in bytes {
            if self.drop > 0.0 && self.rng.random::<f64>() < self.drop {
                self.dropped += 1;
                continue;
            }
            if self.corrupt > 0.0 && self.rng.random::<f64>() < self.corrupt {
                self.corrupted += 1;
                out.push(b ^ (1 << self.rng.random_range(0..8)));
            } else {
                out.push(b);
            }
        }
    }

    pub fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && self.rng.random::<f64>() < p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_a_full_spec_and_rejects_nonsense() {
        let f = FaultSpec::parse("corrupt=0.01,drop=0.005,dup=0.02,delay-ms=3,reboot-at=500,disconnect-at=900,seed=7")
            .unwrap();
        assert_eq!(f.corrupt, 0.01);
        assert_eq!(f.reboot_at, vec![500]);
        assert_eq!(f.seed, 7);
        assert!(FaultSpec::parse("corrupt=2").is_err());
        assert!(FaultSpec::parse("bogus=1").is_err());
        assert!(FaultSpec::parse("drop").is_err());
        assert!(FaultSpec::parse("none").unwrap().link_is_clean());
    }
}
