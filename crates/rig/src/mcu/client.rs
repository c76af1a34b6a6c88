//! The host side of the protocol's reliability layer: one command in
//! flight, retransmission of the same sequence number on timeout, reply
//! matching by sequence number, stale duplicates ignored, and the boot id
//! of every reply checked against the one `Hello` returned.
//!
//! This type knows nothing about recovery: a reboot or a dead link comes
//! back as an error, and [`super::Rig`] decides what to do.

use std::io;
use std::time::Duration;

use firmware_protocol::frame::Push;
use firmware_protocol::timing::{MAX_RETRIES, REPLY_TIMEOUT_MS};
use firmware_protocol::{
    Command, CommandPacket, FrameAccumulator, HelloInfo, MAX_FRAME_LEN, NakReason, PROTOCOL_VERSION, Reply,
    ReplyPacket, StatusInfo, next_seq,
};
use thiserror::Error;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::time::Instant;

/// What went wrong on the link. Messages say what to check.
#[derive(Debug, Error)]
pub enum LinkError {
    #[error("serial port error: {0} (is the rig's USB cable connected and the port not used by another program?)")]
    Io(#[from] io::Error),
    #[error(
        "no reply to {command} after {attempts} attempts over {ms} ms (check the rig's power and USB cable; \
         the MCU may be hung)"
    )]
    Timeout { command: &'static str, attempts: u32, ms: u64 },
    #[error("the rig's microcontroller restarted (boot id {old:#010x} -> {new:#010x}); it must be homed again")]
    Rebooted { old: u32, new: u32 },
    #[error("the rig refused {command}: {reason:?}")]
    Nak { command: &'static str, reason: NakReason },
    #[error("the serial link closed")]
    Closed,
    #[error("unexpected reply to {command}: {reply:?}")]
    Unexpected { command: &'static str, reply: Reply },
    #[error(
        "the rig speaks protocol version {mcu}, this program speaks {host}: update the firmware or this program \
         so they match"
    )]
    Version { mcu: u8, host: u8 },
}

impl LinkError {
    /// The link itself failed (as opposed to the MCU answering).
    pub fn is_link_down(&self) -> bool {
        matches!(self, LinkError::Io(_) | LinkError::Timeout { .. } | LinkError::Closed)
    }
}

/// How often `Status` is polled once a move is overdue.
pub const MOTION_POLL: Duration = Duration::from_millis(20);

/// Counters for the overhead measurements and the operator's report.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LinkStats {
    pub commands: u64,
    pub retransmits: u64,
    pub replies: u64,
    pub stale_replies: u64,
    pub bad_frames: u64,
    /// Sum of round-trip times of commands answered at the first attempt.
    pub rtt_total: Duration,
    pub rtt_count: u64,
}

impl LinkStats {
    pub fn mean_rtt(&self) -> Option<Duration> {
        (self.rtt_count > 0).then(|| self.rtt_total / self.rtt_count as u32)
    }
}

pub fn command_name(c: &Command) -> &'static str {
    match c {
        Command::Hello => "Hello",
        Command::Home => "Home",
        Command::MoveTo { .. } => "MoveTo",
        Command::SetLed { .. } => "SetLed",
        Command::AllOff => "AllOff",
        Command::Status => "Status",
        Command::EStop => "EStop",
        Command::ClearFault => "ClearFault",
        Command::Heartbeat => "Heartbeat",
    }
}

/// Stop-and-wait client over any byte stream.
#[derive(Debug)]
pub struct McuClient<T> {
    io: T,
    acc: FrameAccumulator,
    inbox: Vec<ReplyPacket>,
    seq: u8,
    boot_id: Option<u32>,
    info: Option<HelloInfo>,
    motion_seq: Option<u8>,
    motion_done: Option<i32>,
    last_tx: Instant,
    stats: LinkStats,
    pub reply_timeout: Duration,
    pub max_retries: u32,
}

impl<T: AsyncRead + AsyncWrite + Unpin> McuClient<T> {
    pub fn new(io: T) -> Self {
        Self {
            io,
            acc: FrameAccumulator::new(),
            inbox: Vec::new(),
            seq: 0,
            boot_id: None,
            info: None,
            motion_seq: None,
            motion_done: None,
            last_tx: Instant::now(),
            stats: LinkStats::default(),
            reply_timeout: Duration::from_millis(REPLY_TIMEOUT_MS as u64),
            max_retries: MAX_RETRIES,
        }
    }

    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    pub fn info(&self) -> Option<HelloInfo> {
        self.info
    }

    pub fn boot_id(&self) -> Option<u32> {
        self.boot_id
    }

    /// Continue the sequence numbers of an earlier client on the same
    /// controller, so that late replies to that client's commands (still
    /// in the port's buffers after a reconnect) are recognised as stale
    /// instead of answering this client's first commands.
    pub fn continue_sequence(&mut self, after: u8) {
        self.seq = after;
    }

    /// The sequence number of the last command sent.
    pub fn last_sequence(&self) -> u8 {
        self.seq
    }

    /// Time since the last frame was sent.
    pub fn quiet_for(&self) -> Duration {
        self.last_tx.elapsed()
    }

    /// Read frames until one reply decodes or `deadline` passes.
    async fn next_reply(&mut self, deadline: Instant) -> Result<Option<ReplyPacket>, LinkError> {
        if !self.inbox.is_empty() {
            return Ok(Some(self.inbox.remove(0)));
        }
        let mut buf = [0u8; 256];
        loop {
            let n = match tokio::time::timeout_at(deadline, self.io.read(&mut buf)).await {
                Err(_) => return Ok(None),
                Ok(Ok(0)) => return Err(LinkError::Closed),
                Ok(Ok(n)) => n,
                Ok(Err(e)) => return Err(LinkError::Io(e)),
            };
            for &b in &buf[..n] {
                match self.acc.push(b) {
                    Push::Frame(f) => match ReplyPacket::decode(f) {
                        Ok(p) => self.inbox.push(p),
                        Err(_) => self.stats.bad_frames += 1,
                    },
                    Push::Dropped(_) => {}
                    Push::Pending => {}
                }
            }
            if !self.inbox.is_empty() {
                return Ok(Some(self.inbox.remove(0)));
            }
        }
    }

    /// Check the boot id of a reply; record `MoveDone` for the motion in
    /// progress. Returns the packet if it still needs handling.
    fn screen(&mut self, p: ReplyPacket) -> Result<Option<ReplyPacket>, LinkError> {
        self.stats.replies += 1;
        if let Some(old) = self.boot_id {
            if p.boot_id != old {
                self.boot_id = None;
                self.motion_seq = None;
                return Err(LinkError::Rebooted { old, new: p.boot_id });
            }
        }
        if p.reply == Reply::Boot {
            return Ok(None);
        }
        if let Reply::MoveDone { position_um } = p.reply {
            if Some(p.seq) == self.motion_seq {
                self.motion_done = Some(position_um);
                return Ok(None);
            }
        }
        Ok(Some(p))
    }

    async fn write_frame(&mut self, frame: &[u8]) -> Result<(), LinkError> {
        self.io.write_all(frame).await?;
        self.io.flush().await?;
        self.last_tx = Instant::now();
        Ok(())
    }

    /// Send a command and wait for its reply, retransmitting the same
    /// packet on timeout. A `Nak` is returned as [`LinkError::Nak`].
    pub async fn request(&mut self, command: Command) -> Result<ReplyPacket, LinkError> {
        let name = command_name(&command);
        self.seq = next_seq(self.seq);
        let seq = self.seq;
        let mut frame = [0u8; MAX_FRAME_LEN];
        let n = CommandPacket { seq, command }.encode(&mut frame).map_err(|_| LinkError::Closed)?;
        self.stats.commands += 1;
        let started = Instant::now();
        for attempt in 0..=self.max_retries {
            if attempt > 0 {
                self.stats.retransmits += 1;
                tracing::debug!(command = name, seq, attempt, "retransmitting");
            }
            self.write_frame(&frame[..n]).await?;
            let deadline = Instant::now() + self.reply_timeout;
            while let Some(p) = self.next_reply(deadline).await? {
                let Some(p) = self.screen(p)? else { continue };
                if p.seq != seq {
                    self.stats.stale_replies += 1;
                    continue;
                }
                if attempt == 0 {
                    self.stats.rtt_total += started.elapsed();
                    self.stats.rtt_count += 1;
                }
                return match p.reply {
                    Reply::Nak(NakReason::VersionMismatch) => Err(LinkError::Version {
                        mcu: self.info.map_or(0, |i| i.protocol_version),
                        host: PROTOCOL_VERSION,
                    }),
                    Reply::Nak(reason) => Err(LinkError::Nak { command: name, reason }),
                    _ => Ok(p),
                };
            }
        }
        Err(LinkError::Timeout {
            command: name,
            attempts: self.max_retries + 1,
            ms: started.elapsed().as_millis() as u64,
        })
    }

    /// Wait up to `wait` for the MCU's boot announcement (boards that reset
    /// when the port opens), discarding anything else.
    pub async fn drain_boot(&mut self, wait: Duration) -> Result<bool, LinkError> {
        let deadline = Instant::now() + wait;
        while let Some(p) = self.next_reply(deadline).await? {
            if p.reply == Reply::Boot {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// `Hello`: learn the boot id and capabilities, and check the version.
    pub async fn hello(&mut self) -> Result<HelloInfo, LinkError> {
        self.boot_id = None;
        let p = self.request(Command::Hello).await?;
        match p.reply {
            Reply::Hello(h) => {
                if h.protocol_version != PROTOCOL_VERSION {
                    return Err(LinkError::Version { mcu: h.protocol_version, host: PROTOCOL_VERSION });
                }
                self.info = Some(h);
                self.boot_id = Some(p.boot_id);
                Ok(h)
            }
            r => Err(LinkError::Unexpected { command: "Hello", reply: r }),
        }
    }

    async fn expect_ack(&mut self, command: Command) -> Result<u8, LinkError> {
        let name = command_name(&command);
        let p = self.request(command).await?;
        match p.reply {
            Reply::Ack => Ok(p.seq),
            r => Err(LinkError::Unexpected { command: name, reply: r }),
        }
    }

    /// Start a motion command; returns once the MCU accepted it.
    pub async fn start_motion(&mut self, command: Command) -> Result<(), LinkError> {
        let name = command_name(&command);
        self.motion_done = None;
        self.motion_seq = None;
        let p = self.request(command).await?;
        match p.reply {
            Reply::Ack => {
                self.motion_seq = Some(p.seq);
                Ok(())
            }
            Reply::MoveDone { position_um } => {
                // The Ack was lost and the move already finished.
                self.motion_seq = Some(p.seq);
                self.motion_done = Some(position_um);
                Ok(())
            }
            r => Err(LinkError::Unexpected { command: name, reply: r }),
        }
    }

    /// Wait for the current motion's `MoveDone`, sending heartbeats every
    /// `heartbeat` meanwhile. If it has not come by `expected` (the
    /// predicted end plus slack), the `MoveDone` may have been lost: poll
    /// `Status` every [`MOTION_POLL`] until the carriage is stopped or
    /// `hard_timeout` passes. Returns the final position.
    pub async fn wait_motion(
        &mut self,
        expected: Duration,
        hard_timeout: Duration,
        heartbeat: Duration,
    ) -> Result<i32, LinkError> {
        let start = Instant::now();
        let poll_from = start + expected;
        let give_up = start + hard_timeout.max(expected);
        loop {
            if let Some(p) = self.motion_done.take() {
                self.motion_seq = None;
                return Ok(p);
            }
            let now = Instant::now();
            if now >= poll_from {
                let s = self.status().await?;
                if self.motion_done.is_none() && !s.flags.has(firmware_protocol::StatusFlags::MOVING) {
                    tracing::debug!("MoveDone missing; Status shows the move finished");
                    self.motion_seq = None;
                    return Ok(s.position_um);
                }
                if Instant::now() >= give_up {
                    return Err(LinkError::Timeout {
                        command: "MoveDone",
                        attempts: 1,
                        ms: hard_timeout.as_millis() as u64,
                    });
                }
            }
            let beat_at = self.last_tx + heartbeat;
            let next_poll = if now >= poll_from { now + MOTION_POLL } else { poll_from };
            let deadline = next_poll.min(beat_at.max(now + Duration::from_millis(1)));
            match self.next_reply(deadline).await? {
                Some(p) => {
                    if self.screen(p)?.is_some() {
                        self.stats.stale_replies += 1;
                    }
                }
                None => {
                    if Instant::now() >= beat_at && self.motion_done.is_none() {
                        self.expect_ack(Command::Heartbeat).await?;
                    }
                }
            }
        }
    }

    pub async fn status(&mut self) -> Result<StatusInfo, LinkError> {
        match self.request(Command::Status).await?.reply {
            Reply::Status(s) => Ok(s),
            r => Err(LinkError::Unexpected { command: "Status", reply: r }),
        }
    }

    pub async fn set_led(&mut self, led: u8, current_ma: u16, max_on_ms: u16) -> Result<(), LinkError> {
        self.expect_ack(Command::SetLed { led, current_ma, max_on_ms }).await.map(|_| ())
    }

    pub async fn all_off(&mut self) -> Result<(), LinkError> {
        self.expect_ack(Command::AllOff).await.map(|_| ())
    }

    pub async fn estop(&mut self) -> Result<(), LinkError> {
        self.expect_ack(Command::EStop).await.map(|_| ())
    }

    pub async fn clear_fault(&mut self) -> Result<(), LinkError> {
        self.expect_ack(Command::ClearFault).await.map(|_| ())
    }

    pub async fn heartbeat(&mut self) -> Result<(), LinkError> {
        self.expect_ack(Command::Heartbeat).await.map(|_| ())
    }

    /// Best-effort, non-blocking write of an `AllOff` frame, for paths that
    /// cannot await (drop, signal handlers). The MCU watchdog is the
    /// backstop if even this fails.
    pub fn encode_all_off(&mut self) -> Vec<u8> {
        self.seq = next_seq(self.seq);
        let mut frame = [0u8; MAX_FRAME_LEN];
        let n = CommandPacket { seq: self.seq, command: Command::AllOff }.encode(&mut frame).unwrap_or(0);
        frame[..n].to_vec()
    }

    pub fn into_inner(self) -> T {
        self.io
    }
}
