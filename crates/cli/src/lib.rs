//! The reflectometer's application, shared by the `capture` and `refl`
//! binaries and the daemon: the capture job (devices, store, streaming
//! fit) and its outputs, calibration runs, the daemon, where files go, and
//! progress. Configuration (rig files, presets) is `config`'s; evaluation,
//! renders and the tools that work on stored captures are `assess`'s.

pub mod bench;
pub mod calib;
pub mod capture;
pub mod cpu;
pub mod daemon;
pub mod fitjob;
pub mod output;
pub mod paths;
pub mod progress;
pub mod session;
pub mod tiles;
pub mod web;

/// Exit codes of the binaries, and the one place that maps an error to its
/// code (both binaries and the daemon use [`exit::code`]).
pub mod exit {
    /// Bad input: arguments, rig file, an occupied output directory, a
    /// file or directory that is not what the command reads.
    pub const USAGE: i32 = 2;
    /// A device, the disk or the capture failed.
    pub const FAILED: i32 = 1;
    /// The daemon is running another capture.
    pub const BUSY: i32 = 75;
    /// Interrupted by the operator (Ctrl-C, SIGTERM, `refl daemon --cancel`),
    /// or a benchmark stopped by one.
    pub const INTERRUPTED: i32 = 130;

    /// The exit code an error means: [`INTERRUPTED`] for an operator's
    /// stop, [`USAGE`] for input that cannot be used as given (nothing was
    /// touched), [`FAILED`] for the rest.
    pub fn code(e: &anyhow::Error) -> i32 {
        use material::MaterialError as M;
        use store::StoreError as S;
        for cause in e.chain() {
            if cause.is::<crate::Interrupted>() || cause.is::<crate::Abandoned>() {
                return INTERRUPTED;
            }
            if cause.is::<crate::Usage>()
                || cause.is::<config::ConfigError>()
                || cause.is::<material::rgl::RglError>()
                || cause.is::<material::merl::MerlError>()
            {
                return USAGE;
            }
            let bad_material = cause.downcast_ref::<M>().is_some_and(|m| {
                matches!(
                    m,
                    M::NotAMaterial(_) | M::Occupied { .. } | M::Exists(_) | M::Malformed { .. } | M::Version { .. }
                )
            });
            let bad_capture = cause.downcast_ref::<S>().is_some_and(|s| {
                matches!(
                    s,
                    S::NotACapture(_)
                        | S::NotEmpty(_)
                        | S::AnotherCapture { .. }
                        | S::BadCaptureJson { .. }
                        | S::Version { .. }
                        | S::Locked { .. }
                        | S::BadCalibration { .. }
                )
            });
            if bad_material || bad_capture {
                return USAGE;
            }
        }
        FAILED
    }
}

/// An operator's interruption (exit code 130): Ctrl-C, SIGTERM, a
/// cancelled daemon job, or `--stop-after`.
#[derive(Debug)]
pub struct Interrupted;

impl std::fmt::Display for Interrupted {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("interrupted; everything captured so far is kept (continue with capture --resume)")
    }
}

impl std::error::Error for Interrupted {}

/// An operator's stop of work that stores nothing (a benchmark, named by
/// the field): the exit code of [`Interrupted`], without its advice to
/// resume.
#[derive(Debug)]
pub struct Abandoned(pub &'static str);

impl std::fmt::Display for Abandoned {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} was stopped; it stores nothing", self.0)
    }
}

impl std::error::Error for Abandoned {}

/// A request that cannot be carried out as given (bad arguments, an
/// unknown sample, an occupied output directory): the binaries exit with
/// [`exit::USAGE`] and nothing has been touched.
#[derive(Debug)]
pub struct Usage(pub String);

impl std::fmt::Display for Usage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Usage {}

/// Mark an error as a [`Usage`] error (keeping its whole message).
pub fn usage(e: anyhow::Error) -> anyhow::Error {
    anyhow::Error::new(Usage(format!("{e:#}")))
}

/// Let a reader that stops early end the process quietly, as it ends `cat`
/// or `grep`: `refl inspect DIR | head` is killed by SIGPIPE when `head`
/// has gone. Rust's runtime ignores SIGPIPE, so that a write to a closed
/// pipe or socket fails instead, and `println!` panics on that failure,
/// backtrace and all. Only for commands whose work is what they print
/// (reports, listings, figure benchmarks): the daemon, the emulated
/// microcontroller and the rig benchmarks must see a closed peer as an
/// error they handle, and a fit or a trade-off sweep must not be killed
/// mid-way by a log line to a stderr whose reader has gone.
pub fn quiet_on_closed_stdout() {
    // SAFETY: restoring a signal's default action has no preconditions.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

/// The process's one watcher of stop signals (SIGINT, SIGTERM, SIGHUP),
/// shared by the capture, the fit, the renders and the daemon: the
/// returned receiver turns true at the first signal and every stage polls
/// or awaits it. A second signal while the first is being honoured ends
/// the process at once with [`exit::INTERRUPTED`] (what is stored stays
/// stored: frames and materials are written atomically). Call inside the
/// runtime.
pub fn stop_on_signals() -> anyhow::Result<tokio::sync::watch::Receiver<bool>> {
    use tokio::signal::unix::{SignalKind, signal};
    let (tx, rx) = tokio::sync::watch::channel(false);
    let mut int = signal(SignalKind::interrupt())?;
    let mut term = signal(SignalKind::terminate())?;
    let mut hup = signal(SignalKind::hangup())?;
    tokio::spawn(async move {
        let mut seen = 0;
        loop {
            let name = tokio::select! {
                _ = int.recv() => "SIGINT",
                _ = term.recv() => "SIGTERM",
                _ = hup.recv() => "SIGHUP",
            };
            seen += 1;
            if seen > 1 {
                eprintln!("{name} again: stopping now");
                std::process::exit(exit::INTERRUPTED);
            }
            tracing::info!("{name}: stopping (send it again to stop at once)");
            let _ = tx.send(true);
        }
    });
    Ok(rx)
}

/// How log lines are written.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum LogFormat {
    /// Human-readable lines (colour only when stderr is a terminal).
    #[default]
    Text,
    /// One JSON object per line (timestamp, level, message, fields), for
    /// the rig PC's journal or a log collector.
    Json,
}

/// Install the log subscriber: `RUST_LOG` filters, `info` by default, to
/// stderr; colour only when stderr is a terminal (a log written to a file
/// or a pipe carries no escape codes).
pub fn init_logging(format: LogFormat) {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let builder = tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_target(false);
    let _ = match format {
        LogFormat::Text => builder.with_ansi(std::io::stderr().is_terminal()).try_init(),
        LogFormat::Json => builder.json().with_ansi(false).try_init(),
    };
}
