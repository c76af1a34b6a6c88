//! Which frames a capture may use.

use frame::{FrameMeta, MonoNs};

/// Why a frame was or was not accepted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    Accept,
    /// The driver flagged the buffer as damaged.
    ErrorFlag,
    /// Its exposure began before the LED was known to be lit.
    TooEarly,
    /// It is within the settle window after a control change.
    Settling,
}

/// The acceptance rule, with the state it needs (the settle window).
#[derive(Clone, Debug, Default)]
pub struct FrameFilter {
    settle_frames: u32,
    /// Sequence number of the first frame after the last control change.
    settle_from: Option<u64>,
    pub dropped_error: u64,
    pub dropped_early: u64,
    pub dropped_settling: u64,
}

impl FrameFilter {
    pub fn new(settle_frames: u32) -> Self {
        Self { settle_frames, ..Self::default() }
    }

    /// A control was changed: the next `settle_frames` frames are unusable.
    /// `next_sequence` is the sequence number the next frame will carry (or
    /// `None` if unknown: then the next frames seen start the window).
    pub fn control_changed(&mut self, next_sequence: Option<u64>) {
        self.settle_from = Some(next_sequence.unwrap_or(u64::MAX));
    }

    pub fn judge(&mut self, meta: &FrameMeta, after: MonoNs) -> Verdict {
        if meta.flags.error {
            self.dropped_error += 1;
            return Verdict::ErrorFlag;
        }
        if let Some(from) = self.settle_from {
            let from = if from == u64::MAX {
                self.settle_from = Some(meta.sequence);
                meta.sequence
            } else {
                from
            };
            if meta.sequence < from + self.settle_frames as u64 {
                self.dropped_settling += 1;
                return Verdict::Settling;
            }
            self.settle_from = None;
        }
        if meta.exposure_start < after {
            self.dropped_early += 1;
            return Verdict::TooEarly;
        }
        Verdict::Accept
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use frame::FrameFlags;

    fn meta(seq: u64, start: u64, error: bool) -> FrameMeta {
        FrameMeta {
            sequence: seq,
            exposure_start: MonoNs(start),
            exposure_end: MonoNs(start + 10),
            exposure_us: 10,
            gain: 1.0,
            flags: FrameFlags { error },
        }
    }

    #[test]
    fn timestamps_not_order_decide() {
        let mut f = FrameFilter::new(2);
        // A frame delivered late but exposed before the LED came on.
        assert_eq!(f.judge(&meta(7, 90, false), MonoNs(100)), Verdict::TooEarly);
        assert_eq!(f.judge(&meta(8, 100, true), MonoNs(100)), Verdict::ErrorFlag);
        assert_eq!(f.judge(&meta(9, 110, false), MonoNs(100)), Verdict::Accept);
        f.control_changed(Some(10));
        assert_eq!(f.judge(&meta(10, 200, false), MonoNs(100)), Verdict::Settling);
        assert_eq!(f.judge(&meta(11, 210, false), MonoNs(100)), Verdict::Settling);
        assert_eq!(f.judge(&meta(12, 220, false), MonoNs(100)), Verdict::Accept);
        f.control_changed(None);
        assert_eq!(f.judge(&meta(20, 300, false), MonoNs(100)), Verdict::Settling);
        assert_eq!(f.judge(&meta(21, 310, false), MonoNs(100)), Verdict::Settling);
        assert_eq!(f.judge(&meta(22, 320, false), MonoNs(100)), Verdict::Accept);
    }
}
