//! `refl daemon`: the headless service that owns a rig PC's devices, and
//! the client `capture` uses to reach it.
//!
//! The daemon listens on a Unix socket (mode 0660: its owner and group
//! only) and runs capture jobs one at a time through the same
//! [`capture::run`] the in-process path uses. A second capture while one
//! runs is answered "busy" at once. Under systemd (`Type=notify`) it
//! reports readiness and pings the watchdog from the async runtime, so a
//! wedged runtime gets the service restarted.
//!
//! Wire format: one JSON object per line. The client sends one request:
//!
//! ```text
//! {"op":"capture","request":{...CaptureRequest...}}
//! {"op":"status"}
//! {"op":"cancel"}
//! ```
//!
//! A capture is answered with progress [`Event`] lines and a last line
//! `{"exit":CODE}` (the exit code the in-process `capture` would have
//! given: 0, 1, 2, 130, or 75 for busy). `status` answers
//! `{"busy":null,"progress":null}` or `{"busy":{"sample":..,"out":..},
//! "progress":EVENT}`, the job's latest `frames` or `fit` event; `cancel`
//! interrupts the running job (as Ctrl-C would) and answers
//! `{"cancelled":true|false}`. A client that goes away does not stop its
//! job: a capture on a rig PC outlives a dropped SSH session; `cancel`
//! stops it.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{Context, Result, anyhow, bail};
use serde::{Deserialize, Serialize};
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::{mpsc, watch};

use crate::capture::{self, CaptureRequest};
use crate::progress::{Event, Mode, Reporter};

/// Exit code of a capture refused because another is running.
pub const BUSY: i32 = crate::exit::BUSY;

/// A request to the daemon.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case")]
pub enum Request {
    Capture { request: CaptureRequest },
    Status,
    Cancel,
}

/// The job the daemon is running.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobInfo {
    pub sample: Option<String>,
    pub out: Option<PathBuf>,
}

struct Running {
    info: JobInfo,
    cancel: watch::Sender<bool>,
    /// The job's latest frame or fit progress, for `status`.
    progress: Option<Event>,
}

/// The daemon's state, shared by its socket's clients and its web page.
pub struct Daemon {
    job: Mutex<Option<Running>>,
    /// The web page's live board, when the daemon serves one.
    live: Option<Arc<crate::web::Live>>,
}

impl std::fmt::Debug for Daemon {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Daemon").field("live", &self.live).finish()
    }
}

impl Daemon {
    fn job(&self) -> std::sync::MutexGuard<'_, Option<Running>> {
        self.job.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// A job started by [`start_job`]: its progress events while it runs,
/// and its exit code.
#[derive(Debug)]
pub struct Job {
    pub events: mpsc::UnboundedReceiver<Event>,
    pub exit: tokio::task::JoinHandle<i32>,
}

/// Start a capture job unless one is running (then the answer is the
/// message for the operator). The job goes on whether or not anyone reads
/// its events.
pub fn start_job(d: &Arc<Daemon>, request: CaptureRequest) -> std::result::Result<Job, String> {
    let (cancel_tx, cancel_rx) = watch::channel(false);
    let info = JobInfo { sample: request.sample.clone(), out: request.out.clone().or(request.resume.clone()) };
    {
        let mut g = d.job();
        if let Some(r) = g.as_ref() {
            return Err(format!(
                "busy: the rig is capturing '{}' into {}; wait for it, or stop it with `refl daemon --cancel`",
                r.info.sample.as_deref().unwrap_or("?"),
                r.info.out.as_ref().map_or("?".into(), |p| p.display().to_string())
            ));
        }
        *g = Some(Running { info: info.clone(), cancel: cancel_tx, progress: None });
    }
    if let Some(live) = &d.live {
        live.started(&info);
    }
    sd_notify(&format!("STATUS=capturing {}", info.sample.as_deref().unwrap_or("?")));
    let (tx, events) = mpsc::unbounded_channel::<Event>();
    let d2 = d.clone();
    let exit = tokio::spawn(async move {
        let latest = d2.clone();
        let mut rep = Reporter::new(Mode::Plain).forward_to(move |e| {
            if matches!(e, Event::Frames { .. } | Event::Fit(_))
                && let Some(r) = latest.job().as_mut()
            {
                r.progress = Some(e.clone());
            }
            if let Some(live) = &latest.live {
                live.record(e);
            }
            let _ = tx.send(e.clone());
        });
        if let Some(live) = d2.live.clone() {
            rep = rep.frames_to(move |f| live.frame(f));
        }
        let r = capture::run(request, &mut rep, cancel_rx).await.map_err(for_the_service);
        let (code, message) = match &r {
            Ok(_) => (0, None),
            Err(e) => {
                rep.emit(Event::Error { message: format!("{e:#}") });
                (crate::exit::code(e), Some(format!("{e:#}")))
            }
        };
        // The page's board first: a job started once the slot is free
        // finds it already showing this one's end.
        if let Some(live) = d2.live.clone() {
            let dir = r.as_ref().ok().map(|s| s.dir.clone()).or(info.out.clone());
            live.ended(&info, dir.as_deref(), code, message);
            if let (0, Some(dir)) = (code, dir) {
                tokio::task::spawn_blocking(move || live.evaluate(&dir));
            }
        }
        *d2.job() = None;
        sd_notify("STATUS=idle");
        code
    });
    Ok(Job { events, exit })
}

/// A capture directory the daemon's user may not write: the operator's
/// `--out` (a home directory, say) is to change, and the message says so
/// and where the daemon may write.
fn for_the_service(e: anyhow::Error) -> anyhow::Error {
    let denied = e.chain().find_map(|c| match c.downcast_ref::<store::StoreError>() {
        Some(s @ store::StoreError::Io { source, .. }) if source.kind() == std::io::ErrorKind::PermissionDenied => {
            Some(s)
        }
        _ => None,
    });
    let Some(denied) = denied else { return e };
    let user = std::env::var("USER").unwrap_or_else(|_| "the daemon's user".into());
    let data = crate::paths::data_dir().map_or("its data directory".into(), |d| d.display().to_string());
    // The store's error names its cause itself (`{denied}`, not the chain).
    crate::usage(anyhow!(
        "{denied}: the capture daemon writes the capture as {user}; choose an --out it may write (such as \
         {data}/captures/NAME), or run this capture without the daemon (--no-daemon)"
    ))
}

/// Interrupt the running job, as Ctrl-C would; false when none runs.
pub fn cancel_job(d: &Daemon) -> bool {
    let c = d.job().as_ref().map(|r| r.cancel.clone());
    c.is_some_and(|c| c.send(true).is_ok())
}

/// The web page a daemon serves: where, and where its npm modules are.
#[derive(Clone, Debug)]
pub struct Http {
    pub addr: std::net::SocketAddr,
    pub modules: Option<PathBuf>,
}

/// Where a daemon listens: `$REFLECTOMETER_SOCKET`, else systemd's
/// `$RUNTIME_DIRECTORY/daemon.sock`, else `runtime_dir()/daemon.sock`.
pub fn default_socket() -> PathBuf {
    if let Some(p) = std::env::var_os("REFLECTOMETER_SOCKET") {
        return PathBuf::from(p);
    }
    if let Some(d) = std::env::var_os("RUNTIME_DIRECTORY") {
        return PathBuf::from(d).join("daemon.sock");
    }
    crate::paths::runtime_dir().join("daemon.sock")
}

/// Sockets a client tries, in order: `$REFLECTOMETER_SOCKET` alone when
/// set; otherwise the system service's and then the user's.
pub fn client_sockets() -> Vec<PathBuf> {
    if let Some(p) = std::env::var_os("REFLECTOMETER_SOCKET") {
        return vec![PathBuf::from(p)];
    }
    vec![PathBuf::from("/run/reflectometer/daemon.sock"), crate::paths::runtime_dir().join("daemon.sock")]
}

/// Send `state` to systemd's notification socket, if there is one.
pub fn sd_notify(state: &str) {
    use std::os::linux::net::SocketAddrExt;
    use std::os::unix::net::{SocketAddr, UnixDatagram};
    let Some(path) = std::env::var_os("NOTIFY_SOCKET") else { return };
    let path = path.to_string_lossy().into_owned();
    let addr = match path.strip_prefix('@') {
        Some(name) => SocketAddr::from_abstract_name(name.as_bytes()),
        None => SocketAddr::from_pathname(&path),
    };
    let sent = addr.and_then(|a| UnixDatagram::unbound().and_then(|s| s.send_to_addr(state.as_bytes(), &a)));
    if let Err(e) = sent {
        tracing::warn!(error = %e, "cannot notify systemd");
    }
}

/// Bind the socket: refuse if a daemon already answers there, replace a
/// stale one, and restrict it to owner and group.
fn bind(path: &Path) -> Result<UnixListener> {
    use std::os::unix::fs::PermissionsExt;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    if path.exists() {
        if std::os::unix::net::UnixStream::connect(path).is_ok() {
            bail!("a daemon is already listening on {}", path.display());
        }
        std::fs::remove_file(path).with_context(|| format!("cannot remove the stale socket {}", path.display()))?;
    }
    let l = UnixListener::bind(path).with_context(|| format!("cannot listen on {}", path.display()))?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(0o660))
        .with_context(|| format!("cannot restrict {}", path.display()))?;
    Ok(l)
}

/// Run the daemon until `stop` turns true (the process's signal watcher:
/// SIGTERM, Ctrl-C). A running job is interrupted first, whatever stage it
/// is in: LEDs off, gantry stopped, frames kept, a resumable capture left.
/// With `http`, the web page is served too (`crate::web`).
pub async fn serve(socket: &Path, http: Option<Http>, mut stop: watch::Receiver<bool>) -> Result<()> {
    let listener = bind(socket)?;
    let runtime = socket.parent().unwrap_or(Path::new(".")).to_path_buf();
    let live = http.as_ref().map(|_| Arc::new(crate::web::Live::new(runtime.join("web"))));
    let daemon = Arc::new(Daemon { job: Mutex::new(None), live: live.clone() });
    // The page's port is taken before the daemon says it is ready.
    let mut page = match (http, live) {
        (Some(h), Some(live)) => {
            let listener = tokio::net::TcpListener::bind(h.addr)
                .await
                .with_context(|| format!("cannot listen for the web page on {}", h.addr))?;
            let (d, s) = (daemon.clone(), stop.clone());
            let dir = runtime.clone();
            Some(tokio::spawn(async move { crate::web::serve(listener, d, live, &dir, h.modules, s).await }))
        }
        _ => None,
    };
    tracing::info!("daemon listening on {}", socket.display());
    sd_notify("READY=1\nSTATUS=idle");
    let watchdog = std::env::var("WATCHDOG_USEC").ok().and_then(|v| v.parse::<u64>().ok());
    let mut ping = tokio::time::interval(Duration::from_micros(watchdog.unwrap_or(10_000_000) / 2));
    let result = loop {
        tokio::select! {
            a = listener.accept() => match a {
                Ok((stream, _)) => {
                    let daemon = daemon.clone();
                    tokio::spawn(async move {
                        if let Err(e) = handle(stream, daemon).await {
                            tracing::warn!(error = %e, "client connection failed");
                        }
                    });
                }
                Err(e) => break Err(anyhow!("accept on {}: {e}", socket.display())),
            },
            _ = ping.tick() => if watchdog.is_some() { sd_notify("WATCHDOG=1") },
            r = async {
                match page.as_mut() {
                    Some(p) => p.await,
                    None => std::future::pending().await,
                }
            } => {
                page = None;
                match r {
                    Ok(Ok(())) => {}
                    Ok(Err(e)) => break Err(e),
                    Err(e) => break Err(anyhow!("the web page's task failed: {e}")),
                }
            }
            _ = stop.wait_for(|s| *s) => break Ok(()),
        }
    };
    sd_notify("STOPPING=1");
    // Stop a running job and give it time to switch the rig off.
    if cancel_job(&daemon) {
        tracing::info!("stopping the running capture");
        for _ in 0..100 {
            if daemon.job().is_none() {
                break;
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }
    // The page shuts down gracefully (its event streams end on `stop`);
    // a client that keeps a connection open must not keep the token file
    // alive past the daemon, so it is removed here too once the page has
    // had its moment.
    if let Some(p) = page {
        let _ = tokio::time::timeout(Duration::from_secs(2), p).await;
        let _ = std::fs::remove_file(runtime.join(crate::web::TOKEN_FILE));
    }
    let _ = std::fs::remove_file(socket);
    result
}

async fn send_line(w: &mut (impl AsyncWriteExt + Unpin), v: &impl Serialize) -> std::io::Result<()> {
    let mut b = serde_json::to_vec(v).map_err(std::io::Error::other)?;
    b.push(b'\n');
    w.write_all(&b).await?;
    w.flush().await
}

async fn handle(stream: UnixStream, daemon: Arc<Daemon>) -> Result<()> {
    let (r, mut w) = stream.into_split();
    let mut line = String::new();
    if BufReader::new(r).take(1 << 20).read_line(&mut line).await? == 0 {
        // Connected and went away (a client probing for the daemon).
        return Ok(());
    }
    let req: Request = match serde_json::from_str(&line) {
        Ok(r) => r,
        Err(e) => {
            send_line(&mut w, &Event::Error { message: format!("bad request: {e}") }).await?;
            send_line(&mut w, &serde_json::json!({ "exit": crate::exit::USAGE })).await?;
            return Ok(());
        }
    };
    match req {
        Request::Status => {
            let (busy, progress) = match daemon.job().as_ref() {
                Some(r) => (Some(r.info.clone()), r.progress.clone()),
                None => (None, None),
            };
            send_line(&mut w, &serde_json::json!({ "busy": busy, "progress": progress })).await?;
        }
        Request::Cancel => {
            let cancelled = cancel_job(&daemon);
            send_line(&mut w, &serde_json::json!({ "cancelled": cancelled })).await?;
        }
        Request::Capture { request } => {
            let Job { mut events, exit } = match start_job(&daemon, request) {
                Ok(j) => j,
                Err(msg) => {
                    send_line(&mut w, &Event::Error { message: msg }).await?;
                    send_line(&mut w, &serde_json::json!({ "exit": BUSY })).await?;
                    return Ok(());
                }
            };
            // Relay events while the client listens; the job goes on without it.
            let mut client = Some(w);
            while let Some(e) = events.recv().await {
                if let Some(c) = client.as_mut()
                    && send_line(c, &e).await.is_err()
                {
                    tracing::warn!("the client went away; the capture goes on");
                    client = None;
                }
            }
            let code = exit.await.unwrap_or(crate::exit::FAILED);
            if let Some(mut c) = client {
                send_line(&mut c, &serde_json::json!({ "exit": code })).await?;
            }
        }
    }
    Ok(())
}

/// A connection to a running daemon, if one answers. A daemon this user
/// may not reach (not in the service's group) is an error: running the
/// capture in-process beside it would fight it for the rig.
pub async fn connect() -> Result<Option<(PathBuf, UnixStream)>> {
    for p in client_sockets() {
        match UnixStream::connect(&p).await {
            Ok(s) => return Ok(Some((p, s))),
            Err(e) if e.kind() == std::io::ErrorKind::PermissionDenied => bail!(
                "the capture daemon's socket {} is not open to you ({e}): ask for the service's group (`sudo \
                 usermod -aG reflectometer $USER`, then log in again), or run without the daemon (--no-daemon) when \
                 no service drives the rig",
                p.display()
            ),
            Err(_) => {}
        }
    }
    Ok(None)
}

/// Make the request's paths absolute (the daemon has another working
/// directory).
fn absolute(mut req: CaptureRequest) -> Result<CaptureRequest> {
    let cwd = std::env::current_dir().context("cannot read the working directory")?;
    for p in [&mut req.out, &mut req.resume, &mut req.rig_file, &mut req.sim_material, &mut req.calib_dir]
        .into_iter()
        .flatten()
    {
        if p.is_relative() {
            *p = cwd.join(&*p);
        }
    }
    Ok(req)
}

/// Run a capture through the daemon on `stream`, relaying its progress to
/// `rep`; a stop request (Ctrl-C) asks the daemon to cancel. Returns the
/// exit code. A daemon that goes away mid-job leaves the capture to be
/// resumed: the client marks it interrupted (once the daemon's lock on it
/// is gone) and says how to continue.
pub async fn capture_via(
    socket: &Path,
    stream: UnixStream,
    req: CaptureRequest,
    rep: &mut Reporter,
    mut stop: watch::Receiver<bool>,
) -> Result<i32> {
    let req = absolute(req)?;
    let dir = req.out.clone().or(req.resume.clone());
    let (r, mut w) = stream.into_split();
    send_line(&mut w, &Request::Capture { request: req }).await?;
    let mut lines = BufReader::new(r).lines();
    let mut cancelled = false;
    loop {
        tokio::select! {
            l = lines.next_line() => {
                let l = match l {
                    Ok(Some(l)) => l,
                    Ok(None) | Err(_) => return Err(daemon_gone(socket, dir.as_deref())),
                };
                let v: serde_json::Value = serde_json::from_str(&l).context("bad line from the daemon")?;
                if let Some(code) = v.get("exit").and_then(|c| c.as_i64()) {
                    return Ok(code as i32);
                }
                match serde_json::from_value::<Event>(v) {
                    Ok(e) => rep.emit(e),
                    Err(e) => tracing::warn!(error = %e, "unknown event from the daemon"),
                }
            }
            _ = stop.wait_for(|s| *s), if !cancelled => {
                cancelled = true;
                rep.warn("asking the daemon to stop the capture");
                let mut s = UnixStream::connect(socket).await?;
                send_line(&mut s, &Request::Cancel).await?;
            }
        }
    }
}

/// The daemon closed the connection without an exit line: it died. Mark
/// the capture interrupted if it had started one (its lock died with it)
/// and say how to continue.
fn daemon_gone(socket: &Path, dir: Option<&Path>) -> anyhow::Error {
    let Some(dir) = dir.filter(|d| d.join(store::CaptureDir::INFO).exists()) else {
        return anyhow!("the daemon on {} closed the connection before the capture started", socket.display());
    };
    let marked = match store::CaptureDir::read_info(dir) {
        Ok(info) if info.status == store::CaptureStatus::InProgress => {
            store::CaptureDir::set_status_of(dir, store::CaptureStatus::Interrupted).is_ok()
        }
        _ => false,
    };
    tracing::debug!(marked, "capture status after the daemon went away");
    anyhow!(
        "the daemon on {} went away during the capture; everything stored so far is kept: restart the daemon \
         (`systemctl restart reflectometer`) or run without it, then continue with `capture --resume {}`",
        socket.display(),
        dir.display()
    )
}

/// Send `status` or `cancel` and return the daemon's answer.
pub async fn ask(socket: &Path, req: &Request) -> Result<serde_json::Value> {
    let s = UnixStream::connect(socket).await.with_context(|| format!("no daemon answers on {}", socket.display()))?;
    let (r, mut w) = s.into_split();
    send_line(&mut w, req).await?;
    let mut lines = BufReader::new(r).lines();
    let l = lines.next_line().await?.ok_or_else(|| anyhow!("the daemon closed the connection"))?;
    Ok(serde_json::from_str(&l)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn io_error(kind: std::io::ErrorKind) -> anyhow::Error {
        let cause = std::io::Error::from(kind);
        anyhow::Error::new(store::StoreError::Io { what: "creating", path: "/home/alice/mine".into(), source: cause })
            .context("starting the capture")
    }

    #[test]
    fn a_directory_the_daemon_may_not_write_is_the_operators_to_change() {
        let e = for_the_service(io_error(std::io::ErrorKind::PermissionDenied));
        assert_eq!(crate::exit::code(&e), crate::exit::USAGE);
        let m = format!("{e:#}");
        assert!(m.contains("/home/alice/mine") && m.contains("--out") && m.contains("--no-daemon"), "{m}");
        assert_eq!(m.matches("ermission denied").count(), 1, "{m}");
        // Other failures keep their own message and code.
        let e = for_the_service(io_error(std::io::ErrorKind::Other));
        assert_eq!(crate::exit::code(&e), crate::exit::FAILED);
        assert!(!format!("{e:#}").contains("--no-daemon"));
    }
}
