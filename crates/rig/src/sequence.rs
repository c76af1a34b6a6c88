//! The capture sequence: for every shot (a gantry position and one LED),
//! move if needed, light the LED, take the exposure, and commit it only once
//! the rig has confirmed that nothing was disturbed while it was taken.
//!
//! Confirmation works by [`Rig::epoch`]: every recovery (MCU reboot, link
//! loss, watchdog) increments it. An exposure taken at epoch `e` is held as
//! *pending*; the next command to the rig (the next `SetLed`, a move, or the
//! final `AllOff`) is answered by the MCU with its boot id, and if the epoch
//! is still `e` afterwards the LED provably stayed lit and the carriage
//! provably stayed put for the whole exposure, so the pending exposure is
//! committed. Otherwise it is discarded and the shot is taken again. So a
//! reboot mid-capture never leaves a silent gap and never assigns a frame
//! to the wrong LED; it costs at most one retake per recovery.
//!
//! Every gantry position is approached moving toward `+x`, the plan's
//! direction: a move toward `-x` (a retake after the sequence moved on)
//! first goes [`APPROACH_UM`] past its target, or home at the travel's
//! end. So the carriage's backlash lies the same way for every shot, and a
//! retake sees the light from where the first take would have.

use std::future::Future;

use serde::{Deserialize, Serialize};
use tokio::time::Instant;

use crate::mcu::{Connector, Rig, RigError};

/// One exposure of the plan: the plan's own shot type, carried unchanged
/// from the plan through the sequencer to the store.
pub use setup::PlannedShot as Shot;

/// Takes exposures and receives the confirmed ones.
pub trait Exposer {
    type Item: Send;
    type Error: From<RigError>;
    /// Take the exposure for `shot`; the LED has been lit since `lit_at`.
    /// `None` asks for the shot again with the LED lit afresh (the exposure
    /// is unusable, e.g. it ended after the LED's maximum on-time because
    /// the camera was late); the exposer bounds how often it asks.
    fn expose(&mut self, shot: &Shot, lit_at: Instant)
    -> impl Future<Output = Result<Option<Self::Item>, Self::Error>>;
    /// Whether `shot` is to be taken, asked just before it would be (an
    /// adaptive bracket's shorter exposure depends on what the longer one
    /// saw: `setup::CapturePlan::wants`). A shot not wanted is passed over.
    fn wants(&mut self, _shot: &Shot) -> bool {
        true
    }
    /// An exposure the rig confirmed.
    fn commit(&mut self, shot: &Shot, item: Self::Item) -> impl Future<Output = Result<(), Self::Error>>;
    /// The link's counters after a commit (the capture shows them live).
    fn link(&mut self, _stats: &crate::mcu::LinkStats) {}
    /// An exposure discarded because the rig recovered while it was taken.
    fn discarded(&mut self, shot: &Shot) {
        tracing::info!(step = shot.step, led = shot.led, "retaking a shot: the rig recovered while it was exposed");
    }
}

/// How far past its target a move toward `-x` goes before it turns back:
/// more than any lead screw's backlash (the simulated rig's is at most
/// 0.1 mm, RIGFILE.md).
pub const APPROACH_UM: i32 = 1_000;

/// Move to `to` arriving toward `+x` (module docs). Where no move can pass
/// the target (within [`APPROACH_UM`] of the travel's low end), the
/// carriage is homed first: the home switch lies below the travel.
async fn approach<C: Connector>(rig: &mut Rig<C>, to: i32) -> Result<(), RigError> {
    if rig.position_um().is_none_or(|from| to < from) {
        let floor = rig.info().map_or(i32::MIN, |i| i.travel_min_um);
        match to.checked_sub(APPROACH_UM) {
            Some(before) if before >= floor => rig.move_to(before).await.map(|_| ())?,
            _ => rig.home().await.map(|_| ())?,
        }
    }
    rig.move_to(to).await?;
    Ok(())
}

/// Counters of a sequence run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct SequenceStats {
    pub committed: u64,
    pub retakes: u64,
    pub moves: u64,
}

/// Run `shots` in order (they should be sorted by position so the gantry
/// moves once per step). On error the LEDs are switched off before
/// returning; everything committed before the error stays committed.
pub async fn run<C: Connector, E: Exposer>(
    rig: &mut Rig<C>,
    shots: &[Shot],
    exposer: &mut E,
) -> Result<SequenceStats, E::Error> {
    let result = run_inner(rig, shots, exposer).await;
    if result.is_err() {
        rig.shutdown().await;
    }
    result
}

async fn run_inner<C: Connector, E: Exposer>(
    rig: &mut Rig<C>,
    shots: &[Shot],
    exposer: &mut E,
) -> Result<SequenceStats, E::Error> {
    let mut stats = SequenceStats::default();
    let mut pending: Option<(usize, E::Item, u64)> = None;
    let mut at: Option<i32> = None;
    let mut epoch_at_move = rig.epoch();
    let mut i = 0;
    loop {
        while i < shots.len() {
            let shot = shots[i];
            if !exposer.wants(&shot) {
                i += 1;
                continue;
            }
            if at != Some(shot.position_um) || rig.epoch() != epoch_at_move {
                rig.all_off().await?;
                approach(rig, shot.position_um).await?;
                stats.moves += 1;
                at = Some(shot.position_um);
                epoch_at_move = rig.epoch();
            }
            let lit_at = rig.led_on(shot.led).await?;
            if let Some((k, item, e)) = pending.take() {
                if rig.epoch() == e {
                    exposer.commit(&shots[k], item).await?;
                    exposer.link(&rig.link_stats());
                    stats.committed += 1;
                } else {
                    exposer.discarded(&shots[k]);
                    stats.retakes += 1;
                    at = None;
                    i = k;
                    continue;
                }
            }
            let e = rig.epoch();
            let Some(item) = exposer.expose(&shot, lit_at).await? else {
                // Unusable: light it again (the next pass re-fires the LED).
                stats.retakes += 1;
                continue;
            };
            pending = Some((i, item, e));
            i += 1;
        }
        // The last exposure is confirmed by switching everything off.
        let Some((k, item, e)) = pending.take() else { break };
        rig.all_off().await?;
        if rig.epoch() == e {
            exposer.commit(&shots[k], item).await?;
            exposer.link(&rig.link_stats());
            stats.committed += 1;
            break;
        }
        exposer.discarded(&shots[k]);
        stats.retakes += 1;
        at = None;
        i = k;
    }
    Ok(stats)
}
