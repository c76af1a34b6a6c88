//! The scratch lab the end-to-end tests run the real binaries in (shared
//! by `e2e.rs` and `operator.rs`).
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

pub const CAPTURE: &str = env!("CARGO_BIN_EXE_capture");
pub const REFL: &str = env!("CARGO_BIN_EXE_refl");

/// A scratch directory with its own data directory (calibrations).
pub struct Lab {
    pub dir: tempfile::TempDir,
}

impl Lab {
    pub fn new() -> Self {
        Self { dir: tempfile::tempdir().unwrap() }
    }

    pub fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    pub fn cmd(&self, exe: &str) -> Command {
        let mut c = Command::new(exe);
        c.env("REFLECTOMETER_DATA", self.path("data")).env("RUST_LOG", "warn").stdin(Stdio::null());
        c
    }

    /// A `capture` of a small simulated sample (`steps` gantry steps) into `out`.
    pub fn capture_cmd(&self, sample: &str, out: &str, steps: u32) -> Command {
        self.capture_cmd_sized(sample, out, steps, 12, 64)
    }

    /// A `capture` of `grid` x `grid` points seen by a `px`-pixel camera.
    pub fn capture_cmd_sized(&self, sample: &str, out: &str, steps: u32, grid: u32, px: u32) -> Command {
        let mut c = self.cmd(CAPTURE);
        c.args(["--sample", sample, "--quality", "fast"])
            .args(["--grid", &grid.to_string(), "--camera-px", &px.to_string()])
            .args(["--steps", &steps.to_string()])
            .arg("--out")
            .arg(self.path(out));
        c
    }

    /// `capture` of a small simulated sample into `out`, with extra args.
    pub fn capture(&self, sample: &str, out: &str, extra: &[&str]) -> Output {
        self.capture_cmd(sample, out, 12).args(extra).output().unwrap()
    }

    /// Start `refl daemon` on `socket` and wait until it accepts connections.
    pub fn start_daemon(&self, socket: &Path, stderr: Stdio) -> std::process::Child {
        let mut d = self
            .cmd(REFL)
            .arg("daemon")
            .env("REFLECTOMETER_SOCKET", socket)
            .stdout(Stdio::null())
            .stderr(stderr)
            .spawn()
            .unwrap();
        let t = Instant::now();
        while std::os::unix::net::UnixStream::connect(socket).is_err() {
            assert!(t.elapsed() < Duration::from_secs(30), "the daemon did not start");
            assert!(d.try_wait().unwrap().is_none(), "the daemon exited");
            std::thread::sleep(Duration::from_millis(10));
        }
        d
    }

    pub fn refl(&self, args: &[&str]) -> Output {
        self.cmd(REFL).args(args).output().unwrap()
    }
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

pub fn assert_ok(o: &Output, what: &str) {
    assert!(o.status.success(), "{what} failed ({:?}):\n{}", o.status.code(), stderr(o));
}

pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

pub fn same_files(a: &Path, b: &Path, names: &[&str]) {
    for n in names {
        let (x, y) = (std::fs::read(a.join(n)).unwrap(), std::fs::read(b.join(n)).unwrap());
        assert!(x == y, "{n} differs between {} and {}", a.display(), b.display());
    }
}

pub const MATERIAL_FILES: &[&str] =
    &["maps.exr", "ndf.exr", "ndf_atlas.exr", "ndf_partial.exr", "model_ward_iso.exr", "model_ward_aniso.exr"];

/// Wait until `path` holds at least `bytes` bytes while `child` runs.
pub fn wait_for_bytes(child: &mut std::process::Child, path: &Path, bytes: u64) {
    let t = Instant::now();
    while std::fs::metadata(path).map(|m| m.len()).unwrap_or(0) < bytes {
        assert!(t.elapsed() < Duration::from_secs(120), "{} did not grow", path.display());
        assert!(child.try_wait().unwrap().is_none(), "the process ended early");
        std::thread::sleep(Duration::from_millis(10));
    }
}
