//! The reflectometer's application layer, shared by the `capture` and
//! `refl` binaries and the daemon: rig files, quality presets, calibration,
//! the capture job (devices, store, streaming fit) and its outputs.

pub mod bench;
pub mod calib;
pub mod capture;
pub mod daemon;
pub mod eval;
pub mod fitjob;
pub mod gltf;
pub mod inspect;
pub mod output;
pub mod paths;
pub mod presets;
pub mod progress;
pub mod renders;
pub mod report;
pub mod rigfile;
pub mod session;
pub mod tradeoff;

/// Exit codes of the binaries.
pub mod exit {
    /// Bad input: arguments, rig file, an occupied output directory.
    pub const USAGE: i32 = 2;
    /// A device or the capture failed.
    pub const FAILED: i32 = 1;
    /// Interrupted by the operator (Ctrl-C, SIGTERM).
    pub const INTERRUPTED: i32 = 130;
}

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

/// Install the log subscriber: `RUST_LOG` filters, `info` by default, to stderr.
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ =
        tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_target(false).try_init();
}
