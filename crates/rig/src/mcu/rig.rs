//! [`Rig`]: gantry and LED control that survives faults.
//!
//! Every operation runs through one recovery loop:
//! - **MCU rebooted** (a reply with a new boot id): say hello again, clear
//!   faults, home if the rig had been homed, return to the last commanded
//!   position, then retry the operation.
//! - **Link down** (no reply after all retransmissions, port error, port
//!   gone): find the port again through its [`Connector`] (by USB ids or a
//!   stable path), reopen it, treat the MCU as rebooted, retry.
//! - **Watchdog fault latched** (the host stalled): clear it, restore, retry.
//! - **E-stop latched**: stop; only the operator clears an e-stop.
//!
//! Each recovery increments [`Rig::epoch`]. A caller that needs to know
//! whether anything physical was disturbed between two points (the
//! capture sequencer, for an exposure) compares epochs.

use std::future::Future;
use std::time::Duration;

use firmware_protocol::timing::{BOOT_WAIT_MS, HOME_TIMEOUT_MS, MOVE_DONE_SLACK_MS};
use firmware_protocol::{Command, Faults, HelloInfo, NakReason, StatusInfo};
use thiserror::Error;
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::time::Instant;

use super::client::{LinkError, LinkStats, McuClient};
use super::port::{PortLocator, open_serial};

/// How to (re)open the link to the MCU.
pub trait Connector: Send {
    type Io: AsyncRead + AsyncWrite + Unpin + Send;
    fn connect(&mut self) -> impl Future<Output = Result<Self::Io, LinkError>> + Send;
    fn describe(&self) -> String;
}

/// A real tty found by a [`PortLocator`].
#[derive(Clone, Debug)]
pub struct SerialConnector {
    pub locator: PortLocator,
    pub baud: u32,
}

impl Connector for SerialConnector {
    type Io = tokio_serial::SerialStream;
    async fn connect(&mut self) -> Result<Self::Io, LinkError> {
        let path = self.locator.resolve()?;
        open_serial(&path, self.baud)
    }
    fn describe(&self) -> String {
        self.locator.describe()
    }
}

/// A single in-memory stream (tests); it cannot reconnect.
#[derive(Debug)]
pub struct DuplexConnector(pub Option<tokio::io::DuplexStream>);

impl Connector for DuplexConnector {
    type Io = tokio::io::DuplexStream;
    async fn connect(&mut self) -> Result<Self::Io, LinkError> {
        self.0.take().ok_or(LinkError::Closed)
    }
    fn describe(&self) -> String {
        "in-memory link".into()
    }
}

#[derive(Clone, Debug)]
pub struct RigSettings {
    /// Retransmit timeout (see `firmware_protocol::timing::REPLY_TIMEOUT_MS`).
    pub reply_timeout: Duration,
    pub led_current_ma: u16,
    /// The MCU switches an LED off after this long even if the host does not.
    pub led_max_on_ms: u16,
    /// How long to keep looking for a port that disappeared.
    pub reconnect_timeout: Duration,
    /// Recoveries allowed within one operation before giving up.
    pub max_recoveries_per_op: u32,
    /// Wall time one operation may spend recovering before giving up.
    pub recovery_time_per_op: Duration,
    /// Recoveries allowed over the rig's whole session (a capture): a link
    /// that keeps failing is a fault to fix, not to ride out.
    pub max_recoveries_total: u32,
    /// Wall time the whole session may spend recovering.
    pub recovery_time_total: Duration,
    /// Expected motion, to predict when `MoveDone` is due.
    pub speed_um_s: f64,
    pub accel_um_s2: f64,
    pub settle_ms: f64,
    /// Homing speed, to predict when homing is done.
    pub homing_speed_um_s: f64,
    /// Slack after a move's predicted end before a missing `MoveDone` is
    /// checked with `Status` (see `MOVE_DONE_SLACK_MS`).
    pub move_done_slack: Duration,
}

impl RigSettings {
    /// What the driver expects of a rig with geometry `g` whose controller
    /// runs `time_scale` times real time (a simulated rig; 1.0 on hardware).
    pub fn for_geometry(g: &setup::RigGeometry, time_scale: f64, led_current_ma: u16) -> Self {
        let k = time_scale.max(1e-6);
        Self {
            led_current_ma,
            speed_um_s: g.gantry.speed_mm_s as f64 * 1000.0 / k,
            accel_um_s2: g.gantry.accel_mm_s2 as f64 * 1000.0 / (k * k),
            settle_ms: g.gantry.settle_ms as f64 * k,
            homing_speed_um_s: g.gantry.homing_speed_mm_s as f64 * 1000.0 / k,
            ..Self::default()
        }
    }
}

impl Default for RigSettings {
    fn default() -> Self {
        Self {
            reply_timeout: Duration::from_millis(firmware_protocol::timing::REPLY_TIMEOUT_MS as u64),
            led_current_ma: 200,
            led_max_on_ms: 1000,
            reconnect_timeout: Duration::from_secs(15),
            max_recoveries_per_op: 6,
            recovery_time_per_op: Duration::from_secs(60),
            max_recoveries_total: 200,
            recovery_time_total: Duration::from_secs(300),
            speed_um_s: 100_000.0,
            accel_um_s2: 1_000_000.0,
            settle_ms: 30.0,
            homing_speed_um_s: 50_000.0,
            move_done_slack: Duration::from_millis(MOVE_DONE_SLACK_MS as u64),
        }
    }
}

/// A recovery the rig went through.
#[derive(Clone, Debug, PartialEq)]
pub enum Recovery {
    Rebooted { old: u32, new: u32 },
    Reconnected { after_ms: u64 },
    WatchdogCleared,
    Rehomed,
}

#[derive(Debug, Error)]
pub enum RigError {
    #[error("could not connect to the rig at {port}: {cause}")]
    Connect { port: String, cause: LinkError },
    #[error("{op} failed: {cause}")]
    Link { op: &'static str, cause: LinkError },
    #[error(
        "{op} still failing after {n} recoveries in {secs} s; the rig answers too slowly or not at all: \
         power-cycle the controller, check its USB cable, then continue with --resume (last error: {cause})"
    )]
    GaveUp { op: &'static str, n: u32, secs: u64, cause: LinkError },
    #[error(
        "the rig's port {port} disappeared and did not come back within {secs} s (check the USB cable and the rig's power)"
    )]
    LinkLost { port: String, secs: u64 },
    #[error("the rig is e-stopped; clear the cause, then run again (the e-stop is cleared by the next connection)")]
    EStopped,
}

#[derive(Clone, Copy, Debug)]
enum Op {
    Home,
    MoveTo(i32),
    Led(u8),
    AllOff,
    Status,
    Heartbeat,
}

impl Op {
    fn name(&self) -> &'static str {
        match self {
            Op::Home => "homing",
            Op::MoveTo(_) => "moving the gantry",
            Op::Led(_) => "switching an LED on",
            Op::AllOff => "switching LEDs off",
            Op::Status => "reading rig status",
            Op::Heartbeat => "heartbeat",
        }
    }
}

/// How a recovery step ended, when it did not succeed.
enum Step {
    /// The link failed again during the step: count it and try again.
    Again(LinkError),
    /// Nothing more to try (e-stop, a refusal, a port that stayed away).
    Fatal(RigError),
}

impl Step {
    /// Link failures and reboots during a step are retried by the loop;
    /// anything else (a refusal, a version mismatch) ends the operation.
    fn again_or(op: Op) -> impl Fn(LinkError) -> Step {
        move |e| {
            if e.is_link_down() || matches!(e, LinkError::Rebooted { .. }) {
                Step::Again(e)
            } else {
                Step::Fatal(RigError::Link { op: op.name(), cause: e })
            }
        }
    }
}

enum Out {
    Done,
    Position(i32),
    Status(StatusInfo),
}

/// The rig's gantry and LEDs, with recovery.
pub struct Rig<C: Connector> {
    connector: C,
    client: Option<McuClient<C::Io>>,
    info: Option<HelloInfo>,
    was_homed: bool,
    target_um: Option<i32>,
    position_um: Option<i32>,
    epoch: u64,
    recoveries: Vec<Recovery>,
    total_recoveries: u32,
    /// Wall time spent in recovery steps this session.
    recovering: Duration,
    settings: RigSettings,
    closed_stats: LinkStats,
}

impl<C: Connector> std::fmt::Debug for Rig<C> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Rig").field("port", &self.connector.describe()).field("epoch", &self.epoch).finish()
    }
}

impl<C: Connector> Rig<C> {
    /// Connect, wait briefly for a boot announcement, say hello, and clear
    /// any latched fault left from a previous session.
    pub async fn open(mut connector: C, settings: RigSettings) -> Result<Self, RigError> {
        let port = connector.describe();
        let io = connector.connect().await.map_err(|cause| RigError::Connect { port: port.clone(), cause })?;
        let mut client = McuClient::new(io);
        client.reply_timeout = settings.reply_timeout;
        let mut rig = Self {
            connector,
            client: Some(client),
            info: None,
            was_homed: false,
            target_um: None,
            position_um: None,
            epoch: 0,
            recoveries: Vec::new(),
            total_recoveries: 0,
            recovering: Duration::ZERO,
            settings,
            closed_stats: LinkStats::default(),
        };
        let boot_wait = Duration::from_millis(BOOT_WAIT_MS as u64 / 10);
        let c = rig.client.as_mut().ok_or(RigError::Connect { port: port.clone(), cause: LinkError::Closed })?;
        c.drain_boot(boot_wait).await.map_err(|cause| RigError::Connect { port: port.clone(), cause })?;
        let info = c.hello().await.map_err(|cause| RigError::Connect { port: port.clone(), cause })?;
        c.all_off().await.map_err(|cause| RigError::Connect { port: port.clone(), cause })?;
        c.clear_fault().await.map_err(|cause| RigError::Connect { port, cause })?;
        rig.info = Some(info);
        tracing::info!(
            firmware = ?info.firmware, leds = info.n_leds, travel_min_um = info.travel_min_um,
            travel_max_um = info.travel_max_um, "connected to the rig"
        );
        Ok(rig)
    }

    pub fn info(&self) -> Option<HelloInfo> {
        self.info
    }

    /// Incremented by every recovery (see the module docs).
    pub fn epoch(&self) -> u64 {
        self.epoch
    }

    pub fn recoveries(&self) -> &[Recovery] {
        &self.recoveries
    }

    /// Link counters over every connection so far.
    pub fn link_stats(&self) -> LinkStats {
        let mut s = self.closed_stats;
        if let Some(c) = &self.client {
            let l = c.stats();
            s.commands += l.commands;
            s.retransmits += l.retransmits;
            s.replies += l.replies;
            s.stale_replies += l.stale_replies;
            s.bad_frames += l.bad_frames;
            s.rtt_total += l.rtt_total;
            s.rtt_count += l.rtt_count;
        }
        s
    }

    pub fn settings(&self) -> &RigSettings {
        &self.settings
    }

    pub fn settings_mut(&mut self) -> &mut RigSettings {
        &mut self.settings
    }

    fn heartbeat_interval(&self) -> Duration {
        let wd = self.info.map_or(firmware_protocol::timing::WATCHDOG_MS, |i| i.watchdog_ms);
        Duration::from_millis(wd as u64 / 4)
    }

    /// Homing from anywhere on the rail at the homing speed, plus slack.
    fn predicted_home(&self) -> Duration {
        let s = &self.settings;
        let rail = self.info.map_or(250_000, |i| i.travel_max_um - i.travel_min_um) as f64 * 1.1;
        Duration::from_secs_f64(rail / s.homing_speed_um_s.max(1.0) + s.settle_ms / 1000.0) + s.move_done_slack
    }

    fn predicted_move(&self, from: Option<i32>, to: i32) -> Duration {
        let s = &self.settings;
        let dist = match from {
            Some(f) => (to - f).abs() as f64,
            None => (self.info.map_or(240_000, |i| i.travel_max_um - i.travel_min_um)) as f64,
        };
        let secs = setup::trapezoid_seconds(dist, s.speed_um_s.max(1.0), s.accel_um_s2.max(1.0));
        Duration::from_secs_f64(secs + s.settle_ms / 1000.0) + s.move_done_slack
    }

    async fn attempt(&mut self, op: Op) -> Result<Out, LinkError> {
        let hb = self.heartbeat_interval();
        let settings = self.settings.clone();
        let predicted = match op {
            Op::MoveTo(x) => self.predicted_move(self.position_um, x),
            Op::Home => self.predicted_home(),
            _ => Duration::ZERO,
        };
        let home_limit = Duration::from_millis(HOME_TIMEOUT_MS as u64);
        let client = self.client.as_mut().ok_or(LinkError::Closed)?;
        match op {
            Op::Home => {
                client.start_motion(Command::Home).await?;
                let p = client.wait_motion(predicted, home_limit, hb).await?;
                self.was_homed = true;
                self.position_um = Some(p);
                Ok(Out::Position(p))
            }
            Op::MoveTo(x) => {
                client.start_motion(Command::MoveTo { position_um: x }).await?;
                let p = client.wait_motion(predicted, predicted * 4, hb).await?;
                self.position_um = Some(p);
                Ok(Out::Position(p))
            }
            Op::Led(k) => {
                client.set_led(k, settings.led_current_ma, settings.led_max_on_ms).await?;
                Ok(Out::Done)
            }
            Op::AllOff => client.all_off().await.map(|_| Out::Done),
            Op::Status => client.status().await.map(Out::Status),
            Op::Heartbeat => client.heartbeat().await.map(|_| Out::Done),
        }
    }

    /// Run `op`, recovering from faults in between attempts. Recovery is
    /// a loop, never a recursion: every failed attempt and every failed
    /// recovery step counts against the operation's budget
    /// (`max_recoveries_per_op`, `recovery_time_per_op`) and the rig's
    /// (`max_recoveries_total`), so a rig that answers too slowly or not at
    /// all ends in [`RigError::GaveUp`] instead of reconnecting forever.
    /// The session's budget counts attempts and the wall time spent
    /// recovering (`recovery_time_total`).
    async fn run(&mut self, op: Op) -> Result<Out, RigError> {
        let started = Instant::now();
        let mut n = 0;
        let mut pending: Option<LinkError> = None;
        loop {
            if let Some(err) = pending.take() {
                n += 1;
                self.total_recoveries += 1;
                let over_count = n > self.settings.max_recoveries_per_op;
                let over_time = started.elapsed() > self.settings.recovery_time_per_op;
                let over_total = self.total_recoveries > self.settings.max_recoveries_total
                    || self.recovering > self.settings.recovery_time_total;
                if over_count || over_time || over_total {
                    return Err(RigError::GaveUp {
                        op: op.name(),
                        n: n - 1,
                        secs: started.elapsed().as_secs(),
                        cause: err,
                    });
                }
                let step = Instant::now();
                let recovered = self.recover(op, err).await;
                self.recovering += step.elapsed();
                // Whatever the step achieved, the rig may have been disturbed.
                self.epoch += 1;
                match recovered {
                    Ok(()) => {}
                    Err(Step::Again(e)) => {
                        // The recovery itself failed on the link: count it, try again.
                        pending = Some(e);
                        continue;
                    }
                    Err(Step::Fatal(e)) => return Err(e),
                }
            }
            match self.attempt(op).await {
                Ok(o) => return Ok(o),
                Err(e) => pending = Some(e),
            }
        }
    }

    /// One recovery step: bring the rig back to the state the caller
    /// expects after `err`. A link failure during the step is returned as
    /// [`Step::Again`] for [`Rig::run`]'s loop to count.
    async fn recover(&mut self, op: Op, err: LinkError) -> Result<(), Step> {
        match err {
            LinkError::Rebooted { old, new } => {
                tracing::warn!(
                    old = format!("{old:#010x}"),
                    new = format!("{new:#010x}"),
                    "the rig's MCU restarted; re-homing"
                );
                self.recoveries.push(Recovery::Rebooted { old, new });
                self.restore(op).await
            }
            e if e.is_link_down() => {
                tracing::warn!(error = %e, "lost the rig's serial link; reconnecting");
                self.reconnect().await.map_err(Step::Fatal)?;
                self.restore(op).await
            }
            LinkError::Nak { reason: NakReason::EStopLatched, .. } => Err(Step::Fatal(RigError::EStopped)),
            LinkError::Nak { reason: NakReason::FaultLatched, .. } => {
                let c = self.client.as_mut().ok_or(Step::Again(LinkError::Closed))?;
                let st = c.status().await.map_err(Step::again_or(op))?;
                if st.faults.has(Faults::WATCHDOG) {
                    tracing::warn!("the rig's watchdog tripped (the host was silent too long); clearing and restoring");
                    self.recoveries.push(Recovery::WatchdogCleared);
                    self.restore(op).await
                } else {
                    Err(Step::Fatal(RigError::Link {
                        op: op.name(),
                        cause: LinkError::Nak { command: "any", reason: NakReason::FaultLatched },
                    }))
                }
            }
            LinkError::Nak { reason: NakReason::NotHomed, .. } if !matches!(op, Op::Home) => {
                tracing::warn!("the rig reports it is not homed; homing");
                self.was_homed = true;
                self.restore(op).await
            }
            cause => Err(Step::Fatal(RigError::Link { op: op.name(), cause })),
        }
    }

    /// Hello, clear faults, and (if the rig had been homed) home and return
    /// to the last target.
    async fn restore(&mut self, op: Op) -> Result<(), Step> {
        let c = self.client.as_mut().ok_or(Step::Again(LinkError::Closed))?;
        let info = c.hello().await.map_err(Step::again_or(op))?;
        c.clear_fault().await.map_err(Step::again_or(op))?;
        c.all_off().await.map_err(Step::again_or(op))?;
        self.info = Some(info);
        if self.was_homed && !matches!(op, Op::Home) {
            self.recoveries.push(Recovery::Rehomed);
            let hb = self.heartbeat_interval();
            let back = self.target_um;
            let predicted = back.map(|t| self.predicted_move(None, t));
            let home_expected = self.predicted_home();
            let c = self.client.as_mut().ok_or(Step::Again(LinkError::Closed))?;
            c.start_motion(Command::Home).await.map_err(Step::again_or(op))?;
            c.wait_motion(home_expected, Duration::from_millis(HOME_TIMEOUT_MS as u64), hb)
                .await
                .map_err(Step::again_or(op))?;
            if let (Some(t), Some(p)) = (back, predicted) {
                c.start_motion(Command::MoveTo { position_um: t }).await.map_err(Step::again_or(op))?;
                c.wait_motion(p, p * 4, hb).await.map_err(Step::again_or(op))?;
            }
            self.position_um = back;
        }
        Ok(())
    }

    async fn reconnect(&mut self) -> Result<(), RigError> {
        let last_seq = self.client.as_ref().map_or(0, |c| c.last_sequence());
        if let Some(c) = self.client.take() {
            let s = c.stats();
            self.closed_stats.commands += s.commands;
            self.closed_stats.retransmits += s.retransmits;
            self.closed_stats.replies += s.replies;
            self.closed_stats.stale_replies += s.stale_replies;
            self.closed_stats.bad_frames += s.bad_frames;
            self.closed_stats.rtt_total += s.rtt_total;
            self.closed_stats.rtt_count += s.rtt_count;
        }
        let start = Instant::now();
        let port = self.connector.describe();
        loop {
            match self.connector.connect().await {
                Ok(io) => {
                    let mut c = McuClient::new(io);
                    c.reply_timeout = self.settings.reply_timeout;
                    c.continue_sequence(last_seq);
                    let _ = c.drain_boot(Duration::from_millis(50)).await;
                    self.client = Some(c);
                    let after_ms = start.elapsed().as_millis() as u64;
                    tracing::info!(port, after_ms, "reconnected to the rig");
                    self.recoveries.push(Recovery::Reconnected { after_ms });
                    return Ok(());
                }
                Err(e) => {
                    if start.elapsed() >= self.settings.reconnect_timeout {
                        tracing::error!(error = %e, "giving up reconnecting");
                        return Err(RigError::LinkLost { port, secs: self.settings.reconnect_timeout.as_secs() });
                    }
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
            }
        }
    }

    /// Where the carriage was last reported (after a move, a homing or a
    /// recovery's return), in the controller's coordinates; `None` before
    /// the first.
    pub fn position_um(&self) -> Option<i32> {
        self.position_um
    }

    /// Home the gantry.
    pub async fn home(&mut self) -> Result<i32, RigError> {
        self.target_um = None;
        match self.run(Op::Home).await? {
            Out::Position(p) => Ok(p),
            _ => Ok(0),
        }
    }

    /// Move to an absolute position and wait until settled.
    pub async fn move_to(&mut self, position_um: i32) -> Result<i32, RigError> {
        self.target_um = Some(position_um);
        match self.run(Op::MoveTo(position_um)).await? {
            Out::Position(p) => Ok(p),
            _ => Ok(position_um),
        }
    }

    /// Light one LED (every other off). Returns the instant the `Ack`
    /// arrived: the LED was lit no later than that.
    pub async fn led_on(&mut self, led: u8) -> Result<Instant, RigError> {
        self.run(Op::Led(led)).await?;
        Ok(Instant::now())
    }

    pub async fn all_off(&mut self) -> Result<(), RigError> {
        self.run(Op::AllOff).await.map(|_| ())
    }

    pub async fn status(&mut self) -> Result<StatusInfo, RigError> {
        match self.run(Op::Status).await? {
            Out::Status(s) => Ok(s),
            _ => Err(RigError::Link { op: "reading rig status", cause: LinkError::Closed }),
        }
    }

    /// Send a heartbeat if the link has been quiet for a quarter of the
    /// watchdog (call while waiting on something else).
    pub async fn keepalive(&mut self) -> Result<(), RigError> {
        let quiet = self.client.as_ref().map_or(Duration::ZERO, |c| c.quiet_for());
        if quiet >= self.heartbeat_interval() {
            self.run(Op::Heartbeat).await?;
        }
        Ok(())
    }

    /// E-stop now: motion stops and LEDs go off; the rig stays latched.
    pub async fn estop(&mut self) -> Result<(), RigError> {
        let c = self.client.as_mut().ok_or(RigError::Link { op: "e-stop", cause: LinkError::Closed })?;
        c.estop().await.map_err(|cause| RigError::Link { op: "e-stop", cause })
    }

    /// Leave the rig safe: LEDs off. Errors are logged, not returned: this
    /// runs on every exit path, including after other errors, and the MCU's
    /// watchdog switches the LEDs off anyway if this cannot reach it.
    pub async fn shutdown(&mut self) {
        if let Some(c) = self.client.as_mut() {
            if let Err(e) = c.all_off().await {
                tracing::warn!(error = %e, "could not switch the LEDs off at exit; the rig's watchdog will");
            }
        }
    }
}
