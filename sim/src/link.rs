//! Byte transport for the emulated MCU: the task that reads frames, applies
//! injected faults, runs the [`Mcu`] state machine, and writes replies; over
//! an in-memory duplex or a real pseudo-terminal whose slave end is a tty
//! that the host opens like any serial port.

use std::io;
use std::os::fd::{AsFd, AsRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll, ready};

use firmware_protocol::frame::Push;
use firmware_protocol::{CommandPacket, FrameAccumulator, MAX_FRAME_LEN, ReplyPacket};
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt, ReadBuf};
use tokio::sync::watch;
use tokio::task::JoinHandle;
use tokio::time::{Duration, Instant};

use crate::faults::{ByteFaults, FaultSpec};
use crate::mcu::{Mcu, McuConfig, McuStats};
use crate::world::World;

/// Why [`serve`] returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkEnd {
    Shutdown,
    /// An injected disconnect.
    Disconnect,
    /// The other end closed (in-memory duplex).
    PeerClosed,
}

/// Fault state that persists across reconnects.
#[derive(Debug)]
pub struct LinkFaults {
    spec: FaultSpec,
    input: ByteFaults,
    output: ByteFaults,
    commands_seen: u64,
}

impl LinkFaults {
    pub fn new(spec: FaultSpec) -> Self {
        Self { input: ByteFaults::new(&spec, 1), output: ByteFaults::new(&spec, 2), spec, commands_seen: 0 }
    }
}

async fn send<W: AsyncWrite + Unpin>(w: &mut W, faults: &mut LinkFaults, replies: Vec<ReplyPacket>) -> io::Result<()> {
    for r in replies {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = r.encode(&mut buf).map_err(|e| io::Error::other(format!("{e:?}")))?;
        if faults.spec.delay_ms > 0 {
            tokio::time::sleep(Duration::from_millis(faults.spec.delay_ms)).await;
        }
        let mut out = Vec::with_capacity(n * 2);
        faults.output.apply(&buf[..n], &mut out);
        let dup = faults.output.chance(faults.spec.dup);
        if dup {
            let copy = out.clone();
            faults.output.apply(&copy[..0], &mut out);
            out.extend_from_slice(&copy);
        }
        w.write_all(&out).await?;
    }
    w.flush().await
}

/// Run the MCU over one transport until shutdown, an injected disconnect,
/// or the peer closing it.
pub async fn serve<T: AsyncRead + AsyncWrite + Unpin>(
    mcu: &mut Mcu,
    io: T,
    faults: &mut LinkFaults,
    shutdown: &mut watch::Receiver<bool>,
    stats: &Arc<Mutex<McuStats>>,
) -> io::Result<LinkEnd> {
    let (mut rd, mut wr) = tokio::io::split(io);
    let mut acc = FrameAccumulator::new();
    let mut buf = [0u8; 512];
    let mut bytes = Vec::with_capacity(512);
    loop {
        let deadline = mcu.next_deadline();
        tokio::select! {
            _ = shutdown.changed() => return Ok(LinkEnd::Shutdown),
            r = rd.read(&mut buf) => {
                let n = match r {
                    Ok(0) => return Ok(LinkEnd::PeerClosed),
                    Ok(n) => n,
                    // A pty master reads EIO while no slave is open.
                    Err(e) if e.raw_os_error() == Some(libc::EIO) => {
                        tokio::time::sleep(Duration::from_millis(5)).await;
                        continue;
                    }
                    Err(e) => return Err(e),
                };
                bytes.clear();
                faults.input.apply(&buf[..n], &mut bytes);
                let mut frames = Vec::new();
                for &b in &bytes {
                    if let Push::Frame(f) = acc.push(b) {
                        frames.push(f.to_vec());
                    }
                }
                for f in frames {
                    let now = Instant::now();
                    if CommandPacket::decode(&f).is_ok() {
                        faults.commands_seen += 1;
                        let k = faults.commands_seen;
                        if faults.spec.hang_at.is_some_and(|h| k >= h) {
                            continue;
                        }
                        if faults.spec.disconnect_at.contains(&k) {
                            tracing::info!(command = k, "injected fault: link disconnect");
                            return Ok(LinkEnd::Disconnect);
                        }
                        if faults.spec.reboot_at.contains(&k) {
                            tracing::info!(command = k, "injected fault: MCU reboot");
                            let boot = mcu.reset(now);
                            send(&mut wr, faults, vec![boot]).await?;
                            continue;
                        }
                    }
                    let mut replies = mcu.tick(now);
                    replies.extend(mcu.on_frame(now, &f));
                    send(&mut wr, faults, replies).await?;
                }
                *stats.lock().unwrap_or_else(|p| p.into_inner()) = mcu.stats();
            }
            _ = sleep_until_opt(deadline) => {
                let replies = mcu.tick(Instant::now());
                send(&mut wr, faults, replies).await?;
            }
        }
    }
}

async fn sleep_until_opt(t: Option<Instant>) {
    match t {
        Some(t) => tokio::time::sleep_until(t).await,
        None => std::future::pending().await,
    }
}

/// The master side of a pseudo-terminal, with async IO.
#[derive(Debug)]
pub struct PtyMaster {
    fd: AsyncFd<OwnedFd>,
}

/// A pseudo-terminal pair. The slave stays open here too, so the master
/// never sees a hang-up while the host closes and reopens the tty, and its
/// termios stays raw (no echo, no line editing, 8-bit clean).
#[derive(Debug)]
pub struct Pty {
    pub master: PtyMaster,
    _slave: OwnedFd,
    pub slave_path: PathBuf,
}

impl Pty {
    pub fn open() -> io::Result<Self> {
        use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
        let r = nix::pty::openpty(None, None).map_err(io::Error::from)?;
        let mut t = tcgetattr(&r.slave).map_err(io::Error::from)?;
        cfmakeraw(&mut t);
        tcsetattr(&r.slave, SetArg::TCSANOW, &t).map_err(io::Error::from)?;
        let slave_path = nix::unistd::ttyname(r.slave.as_fd()).map_err(io::Error::from)?;
        set_nonblocking(&r.master)?;
        // SAFETY: `r.master` is an open descriptor owned by the OwnedFd that
        // the AsyncFd takes over; it stays open and unchanged until dropped.
        let fd = unsafe { AsyncFd::register(r.master) }.map_err(|e| e.into_parts().1)?;
        Ok(Self { master: PtyMaster { fd }, _slave: r.slave, slave_path })
    }
}

/// Open an existing tty (a USB gadget's `/dev/ttyGS0`, the device side of
/// the serial link a real rig's microcontroller enumerates as) for the
/// emulator: raw, 8-bit clean, non-blocking, not the controlling terminal.
pub fn open_tty(path: &Path) -> io::Result<PtyMaster> {
    use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};
    use std::os::unix::fs::OpenOptionsExt;
    let f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_NOCTTY | libc::O_NONBLOCK)
        .open(path)
        .map_err(|e| io::Error::new(e.kind(), format!("cannot open {}: {e}", path.display())))?;
    let fd = OwnedFd::from(f);
    let mut t = tcgetattr(&fd).map_err(io::Error::from)?;
    cfmakeraw(&mut t);
    tcsetattr(&fd, SetArg::TCSANOW, &t).map_err(io::Error::from)?;
    // SAFETY: `fd` is an open descriptor owned by the OwnedFd that the
    // AsyncFd takes over; it stays open and unchanged until dropped.
    let fd = unsafe { AsyncFd::register(fd) }.map_err(|e| e.into_parts().1)?;
    Ok(PtyMaster { fd })
}

impl PtyMaster {
    /// Whether the tty has hung up (its reads would end at once).
    fn hung_up(&self) -> bool {
        let mut p = libc::pollfd { fd: self.fd.get_ref().as_raw_fd(), events: libc::POLLIN, revents: 0 };
        // SAFETY: poll on one pollfd we own, with no wait.
        let n = unsafe { libc::poll(&mut p, 1, 0) };
        n > 0 && p.revents & libc::POLLHUP != 0
    }
}

fn set_nonblocking(fd: &OwnedFd) -> io::Result<()> {
    // SAFETY: fcntl on a file descriptor we own; no memory is passed.
    let flags = unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_GETFL) };
    if flags < 0 {
        return Err(io::Error::last_os_error());
    }
    // SAFETY: as above.
    if unsafe { libc::fcntl(fd.as_raw_fd(), libc::F_SETFL, flags | libc::O_NONBLOCK) } < 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(())
}

impl AsyncRead for PtyMaster {
    fn poll_read(self: Pin<&mut Self>, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.fd.poll_read_ready(cx))?;
            let unfilled = buf.initialize_unfilled();
            match guard.try_io(|inner| {
                // SAFETY: reading into a live, initialised buffer of the given length.
                let n = unsafe { libc::read(inner.as_raw_fd(), unfilled.as_mut_ptr().cast(), unfilled.len()) };
                if n < 0 { Err(io::Error::last_os_error()) } else { Ok(n as usize) }
            }) {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                Err(_would_block) => continue,
            }
        }
    }
}

impl AsyncWrite for PtyMaster {
    fn poll_write(self: Pin<&mut Self>, cx: &mut Context<'_>, data: &[u8]) -> Poll<io::Result<usize>> {
        loop {
            let mut guard = ready!(self.fd.poll_write_ready(cx))?;
            match guard.try_io(|inner| {
                // SAFETY: writing from a live buffer of the given length.
                let n = unsafe { libc::write(inner.as_raw_fd(), data.as_ptr().cast(), data.len()) };
                if n < 0 { Err(io::Error::last_os_error()) } else { Ok(n as usize) }
            }) {
                Ok(r) => return Poll::Ready(r),
                Err(_would_block) => continue,
            }
        }
    }

    fn poll_flush(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }
}

/// A running emulated MCU.
#[derive(Debug)]
pub struct SimMcu {
    pub world: World,
    stats: Arc<Mutex<McuStats>>,
    current_path: Arc<Mutex<Option<PathBuf>>>,
    /// Stable name of the device (a symlink re-pointed after every
    /// reconnect, like the udev rule's `/dev/reflectometer/mcu`).
    pub link_path: Option<PathBuf>,
    shutdown: watch::Sender<bool>,
    task: Option<JoinHandle<io::Result<()>>>,
}

impl SimMcu {
    /// Start the emulator on a pseudo-terminal. If `link_path` is given, a
    /// symlink there always points at the current slave tty.
    pub async fn spawn_pty(
        cfg: McuConfig,
        faults: FaultSpec,
        world: World,
        link_path: Option<PathBuf>,
    ) -> io::Result<Self> {
        let (tx, mut rx) = watch::channel(false);
        let stats = Arc::new(Mutex::new(McuStats::default()));
        let current_path = Arc::new(Mutex::new(None));
        let pty = Pty::open()?;
        publish(&current_path, link_path.as_deref(), &pty.slave_path)?;
        let (stats2, path2, link2, world2) = (stats.clone(), current_path.clone(), link_path.clone(), world.clone());
        let task = tokio::spawn(async move {
            let reconnect = Duration::from_millis(faults.reconnect_ms);
            let mut lf = LinkFaults::new(faults);
            let (mut mcu, boot) = Mcu::power_up(cfg, world2, lf.spec.seed, Instant::now());
            let mut pty = pty;
            let mut pending_boot = Some(boot);
            loop {
                if let Some(b) = pending_boot.take() {
                    send(&mut pty.master, &mut lf, vec![b]).await?;
                }
                match serve(&mut mcu, &mut pty.master, &mut lf, &mut rx, &stats2).await? {
                    LinkEnd::Shutdown => return Ok(()),
                    LinkEnd::PeerClosed => continue,
                    LinkEnd::Disconnect => {
                        // Unplugged: the device node goes away, the board
                        // loses power (LEDs off, motion stopped, position lost).
                        let boot = mcu.reset(Instant::now());
                        drop(pty);
                        if let Some(l) = &link2 {
                            let _ = std::fs::remove_file(l);
                        }
                        *path2.lock().unwrap_or_else(|p| p.into_inner()) = None;
                        tokio::select! {
                            _ = tokio::time::sleep(reconnect) => {}
                            _ = rx.changed() => return Ok(()),
                        }
                        pending_boot = Some(boot);
                        pty = Pty::open()?;
                        publish(&path2, link2.as_deref(), &pty.slave_path)?;
                    }
                }
            }
        });
        Ok(Self { world, stats, current_path, link_path, shutdown: tx, task: Some(task) })
    }

    /// Start the emulator on an existing tty `path` (`open_tty`), as the
    /// microcontroller's side of a real serial link: the host opens the
    /// other side (for a USB gadget, the `/dev/ttyACM*` the kernel's
    /// CDC-ACM driver makes). When the device hangs up (a USB gadget's
    /// does when it is unplugged: its reads end) the board has lost its
    /// power, as a bus-powered one does: it is reset (LEDs off, position
    /// lost) and waits for the device to come back, then boots again.
    pub async fn spawn_device(cfg: McuConfig, faults: FaultSpec, world: World, path: &Path) -> io::Result<Self> {
        let (tx, mut rx) = watch::channel(false);
        let stats = Arc::new(Mutex::new(McuStats::default()));
        let dev = open_tty(path)?;
        let (stats2, world2, path2) = (stats.clone(), world.clone(), path.to_path_buf());
        let task = tokio::spawn(async move {
            let mut lf = LinkFaults::new(faults);
            let (mut mcu, mut boot) = Mcu::power_up(cfg, world2, lf.spec.seed, Instant::now());
            let mut dev = dev;
            loop {
                // A hung-up tty may refuse the boot message: it is lost
                // as on a wire, and the host's driver does without it.
                let _ = send(&mut dev, &mut lf, vec![boot]).await;
                match serve(&mut mcu, &mut dev, &mut lf, &mut rx, &stats2).await {
                    Ok(LinkEnd::Shutdown) => return Ok(()),
                    Ok(LinkEnd::PeerClosed | LinkEnd::Disconnect) | Err(_) => {}
                }
                drop(dev);
                boot = mcu.reset(Instant::now());
                tracing::info!("{} hung up: the board is reset and waits for it", path2.display());
                dev = loop {
                    tokio::select! {
                        _ = tokio::time::sleep(Duration::from_millis(50)) => {}
                        _ = rx.changed() => return Ok(()),
                    }
                    // The old node can linger a moment: a hung-up tty's
                    // reads end at once, so only a fresh one is kept.
                    if let Ok(d) = open_tty(&path2)
                        && !d.hung_up()
                    {
                        break d;
                    }
                };
                tracing::info!("{} is back", path2.display());
            }
        });
        let current_path = Arc::new(Mutex::new(Some(path.to_path_buf())));
        Ok(Self { world, stats, current_path, link_path: None, shutdown: tx, task: Some(task) })
    }

    /// Start the emulator on an in-memory duplex; returns the host's end.
    pub fn spawn_duplex(cfg: McuConfig, faults: FaultSpec, world: World) -> (Self, tokio::io::DuplexStream) {
        let (host, dev) = tokio::io::duplex(4096);
        let (tx, mut rx) = watch::channel(false);
        let stats = Arc::new(Mutex::new(McuStats::default()));
        let stats2 = stats.clone();
        let world2 = world.clone();
        let task = tokio::spawn(async move {
            let mut lf = LinkFaults::new(faults);
            let (mut mcu, boot) = Mcu::power_up(cfg, world2, lf.spec.seed, Instant::now());
            let mut dev = dev;
            send(&mut dev, &mut lf, vec![boot]).await?;
            serve(&mut mcu, dev, &mut lf, &mut rx, &stats2).await.map(|_| ())
        });
        (
            Self {
                world,
                stats,
                current_path: Arc::new(Mutex::new(None)),
                link_path: None,
                shutdown: tx,
                task: Some(task),
            },
            host,
        )
    }

    /// The tty the host should open now (`None` while unplugged).
    pub fn device_path(&self) -> Option<PathBuf> {
        self.link_path.clone().or_else(|| self.current_path.lock().unwrap_or_else(|p| p.into_inner()).clone())
    }

    pub fn stats(&self) -> McuStats {
        *self.stats.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Stop the emulator and wait for it.
    pub async fn stop(mut self) -> io::Result<()> {
        let _ = self.shutdown.send(true);
        match self.task.take() {
            Some(t) => t.await.map_err(io::Error::other)?,
            None => Ok(()),
        }
    }
}

impl Drop for SimMcu {
    fn drop(&mut self) {
        let _ = self.shutdown.send(true);
        if let Some(l) = &self.link_path {
            let _ = std::fs::remove_file(l);
        }
    }
}

fn publish(current: &Mutex<Option<PathBuf>>, link: Option<&Path>, slave: &Path) -> io::Result<()> {
    *current.lock().unwrap_or_else(|p| p.into_inner()) = Some(slave.to_path_buf());
    if let Some(l) = link {
        let tmp = l.with_extension("new");
        let _ = std::fs::remove_file(&tmp);
        std::os::unix::fs::symlink(slave, &tmp)?;
        std::fs::rename(&tmp, l)?;
    }
    Ok(())
}
