//! End-to-end runs of the real binaries on the simulated rig: `capture`
//! through the emulated MCU on a pseudo-terminal, the streaming fit,
//! renders, then `refl fit`, `refl eval`, `refl inspect` and `refl render`
//! on what it wrote. Small captures (12 steps, 12x12 points, 64-pixel
//! camera) keep each run to seconds; the simulation is seeded, so two runs
//! of one capture give the same frames.

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

const CAPTURE: &str = env!("CARGO_BIN_EXE_capture");
const REFL: &str = env!("CARGO_BIN_EXE_refl");

/// A scratch directory with its own data directory (calibrations).
struct Lab {
    dir: tempfile::TempDir,
}

impl Lab {
    fn new() -> Self {
        Self { dir: tempfile::tempdir().unwrap() }
    }

    fn path(&self, name: &str) -> PathBuf {
        self.dir.path().join(name)
    }

    fn cmd(&self, exe: &str) -> Command {
        let mut c = Command::new(exe);
        c.env("REFLECTOMETER_DATA", self.path("data")).env("RUST_LOG", "warn").stdin(Stdio::null());
        c
    }

    /// `capture` of a small simulated sample into `out`, with extra args.
    fn capture(&self, sample: &str, out: &str, extra: &[&str]) -> Output {
        let mut c = self.cmd(CAPTURE);
        c.args(["--sample", sample, "--quality", "fast", "--steps", "12", "--grid", "12", "--camera-px", "64"])
            .arg("--out")
            .arg(self.path(out))
            .args(extra);
        c.output().unwrap()
    }

    fn refl(&self, args: &[&str]) -> Output {
        self.cmd(REFL).args(args).output().unwrap()
    }
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn assert_ok(o: &Output, what: &str) {
    assert!(o.status.success(), "{what} failed ({:?}):\n{}", o.status.code(), stderr(o));
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn same_files(a: &Path, b: &Path, names: &[&str]) {
    for n in names {
        let (x, y) = (std::fs::read(a.join(n)).unwrap(), std::fs::read(b.join(n)).unwrap());
        assert!(x == y, "{n} differs between {} and {}", a.display(), b.display());
    }
}

const MATERIAL_FILES: &[&str] =
    &["maps.exr", "ndf.exr", "ndf_partial.exr", "model_ward_iso.exr", "model_ward_aniso.exr"];

#[test]
fn capture_fits_renders_and_every_refl_tool_reads_it() {
    let lab = Lab::new();
    let o = lab.capture("satin", "satin", &[]);
    assert_ok(&o, "capture");
    let dir = lab.path("satin");
    for f in ["capture.json", "manifest.jsonl", "report.json", "material/material.json", "material/maps.exr"] {
        assert!(dir.join(f).is_file(), "{f} missing");
    }
    for f in ["side-light.png", "sky.png", "tilted.png", "model_choice.png", "sky-truth.exr", "sky-synthesized.exr"] {
        assert!(dir.join("renders").join(f).is_file(), "renders/{f} missing");
    }
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    assert_eq!(report["fit"]["points"], 144);

    // Streaming (during the capture) and batch (`refl fit`) give the same material.
    let streamed = lab.path("streamed");
    std::fs::create_dir(&streamed).unwrap();
    for n in MATERIAL_FILES {
        std::fs::copy(dir.join("material").join(n), streamed.join(n)).unwrap();
    }
    assert_ok(&lab.refl(&["fit", s(&dir)]), "refl fit");
    same_files(&streamed, &dir.join("material"), MATERIAL_FILES);

    let o = lab.refl(&["eval", s(&dir), "--json", "--no-holdout", "--px", "48"]);
    assert_ok(&o, "refl eval");
    let ev: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(ev["ground_truth"], true);
    for m in ["synthesized", "partial", "ward_iso", "ward_aniso", "auto"] {
        let e = ev["models"][m]["render_rel_rmse"].as_f64();
        assert!(e.is_some_and(|e| e.is_finite() && e > 0.0 && e < 2.0), "{m}: {e:?}");
    }

    let o = lab.refl(&["inspect", s(&dir), "--json"]);
    assert_ok(&o, "refl inspect");
    let i: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(i.is_object());

    let png = lab.path("ward.png");
    let o =
        lab.refl(&["render", s(&dir), "--model", "ward_aniso", "--light", "sky:30,40", "--px", "32", "-o", s(&png)]);
    assert_ok(&o, "refl render");
    assert!(std::fs::metadata(&png).unwrap().len() > 100);
    let o = lab.refl(&["render", s(&dir), "--model", "nonesuch", "-o", s(&png)]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("ward_iso"), "the error lists the models it has: {}", stderr(&o));
}

#[test]
fn an_interrupted_capture_resumes_to_the_same_material() {
    let lab = Lab::new();
    assert_ok(&lab.capture("satin", "clean", &[]), "clean capture");
    let o = lab.capture("satin", "cut", &["--stop-after", "100"]);
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    assert!(!lab.path("cut/material").exists(), "no material from a partial capture");
    let o = lab.cmd(CAPTURE).arg("--resume").arg(lab.path("cut")).output().unwrap();
    assert_ok(&o, "resume");
    same_files(&lab.path("clean/material"), &lab.path("cut/material"), MATERIAL_FILES);
}

#[test]
fn sigint_stops_the_capture_and_keeps_what_was_taken() {
    let lab = Lab::new();
    // Calibrate first so the signal lands in the capture itself.
    assert_ok(&lab.capture("satin", "warmup", &["--no-fit"]), "warm-up capture");
    let mut c = lab.cmd(CAPTURE);
    c.args(["--sample", "satin", "--quality", "fast", "--steps", "64", "--grid", "12", "--camera-px", "64"])
        .arg("--out")
        .arg(lab.path("sig"))
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let mut child = c.spawn().unwrap();
    let manifest = lab.path("sig/manifest.jsonl");
    let t = Instant::now();
    while std::fs::metadata(&manifest).map(|m| m.len()).unwrap_or(0) < 2000 {
        assert!(t.elapsed() < Duration::from_secs(120), "no frames arrived");
        assert!(child.try_wait().unwrap().is_none(), "capture ended before the signal");
        std::thread::sleep(Duration::from_millis(20));
    }
    // SAFETY: plain kill(2) on our own child's pid.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let o = child.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    let info: serde_json::Value =
        serde_json::from_slice(&std::fs::read(lab.path("sig/capture.json")).unwrap()).unwrap();
    assert_eq!(info["status"], "interrupted", "{info}");
    let o = lab.cmd(CAPTURE).arg("--resume").arg(lab.path("sig")).output().unwrap();
    assert_ok(&o, "resume after SIGINT");
    assert!(lab.path("sig/material/maps.exr").is_file());
}

#[test]
fn injected_faults_are_survived_and_reported() {
    let lab = Lab::new();
    assert_ok(&lab.capture("satin", "clean", &[]), "clean capture");
    let o = lab.capture("satin", "faulty", &["--sim-faults", "corrupt=0.01,drop=0.005,dup=0.005,reboot-at=120"]);
    assert_ok(&o, "capture with faults");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(lab.path("faulty/report.json")).unwrap()).unwrap();
    assert!(report["link"]["retransmits"].as_u64().unwrap() > 0, "{}", report["link"]);
    assert!(!report["recoveries"].as_array().unwrap().is_empty(), "the reboot is recorded");
    // Every shot was taken once the link recovered: the same material.
    same_files(&lab.path("clean/material"), &lab.path("faulty/material"), MATERIAL_FILES);
}

#[test]
fn bad_input_is_refused_clearly_and_nothing_is_lost() {
    let lab = Lab::new();
    let o = lab.capture("nosuch", "x", &[]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("satin"), "lists the known samples: {}", stderr(&o));
    assert!(!lab.path("x").exists());

    let o = lab.capture("satin", "y", &["--sim-faults", "bogus=1"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("corrupt"), "lists the known faults: {}", stderr(&o));

    let o = lab.capture("satin", "y", &["--steps", "0"]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));

    // An occupied output directory is refused and left as it was.
    assert_ok(&lab.capture("satin", "kept", &["--no-fit"]), "capture");
    let before = std::fs::read(lab.path("kept/manifest.jsonl")).unwrap();
    let o = lab.capture("satin", "kept", &[]);
    assert_eq!(o.status.code(), Some(2));
    assert!(stderr(&o).contains("--resume"), "suggests --resume: {}", stderr(&o));
    assert_eq!(std::fs::read(lab.path("kept/manifest.jsonl")).unwrap(), before);

    let o = lab.refl(&["fit", s(lab.dir.path())]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("not a capture directory"), "{}", stderr(&o));
    let o = lab.refl(&["render", s(&lab.path("nothing")), "-o", s(&lab.path("r.png"))]);
    assert!(!o.status.success());
}
