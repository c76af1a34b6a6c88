//! The instrument in the hands of a careless or hostile operator: every
//! defect of issue 14, each run through the real binaries on the simulated
//! rig. Nothing the operator owns is ever removed; every stop request is
//! honoured at every stage and leaves a resumable capture; a rig that
//! stops answering ends in bounded time with advice; impossible rigs,
//! calibrations and half captures are refused with the usage code.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::Vec3;

#[path = "support/lab.rs"]
mod lab;
use lab::*;

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn status(dir: &Path) -> String {
    json(&dir.join("capture.json"))["status"].as_str().unwrap().to_string()
}

/// Every entry under `dir` with its bytes (directories with none).
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p.clone());
                out.push((p, Vec::new()));
            } else {
                out.push((p.clone(), std::fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

/// Read JSON progress lines until one satisfies `pred` (the rest stay in
/// `lines`). Fails if the process ends first.
fn wait_for_event(
    lines: &mut impl Iterator<Item = std::io::Result<String>>,
    what: &str,
    pred: impl Fn(&serde_json::Value) -> bool,
) {
    for l in lines.by_ref() {
        let l = l.unwrap();
        if serde_json::from_str::<serde_json::Value>(&l).is_ok_and(|v| pred(&v)) {
            return;
        }
    }
    panic!("the process ended before {what}");
}

fn is_stage(v: &serde_json::Value, stage: &str, detail_starts: &str) -> bool {
    v["event"] == "stage" && v["stage"] == stage && v["detail"].as_str().is_some_and(|d| d.starts_with(detail_starts))
}

fn signal(child: &Child, sig: i32) {
    // SAFETY: plain kill(2) on our own child's pid.
    unsafe { libc::kill(child.id() as i32, sig) };
}

/// A child that must end by itself; killed (and the test failed) if it
/// runs on far past any bound the rig's recovery budget allows.
fn wait_bounded(mut child: Child, limit: Duration, what: &str) -> std::process::Output {
    let t = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if t.elapsed() > limit {
            child.kill().unwrap();
            panic!("{what} was still running after {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    child.wait_with_output().unwrap()
}

/// Defect 1: writing a material never removes what it did not write.
#[test]
fn importing_never_removes_what_it_did_not_write() {
    let lab = Lab::new();
    let t = material::PointMaterial::microfacet(
        Vec3::new(0.3, 0.2, 0.1),
        Vec3::ONE,
        Arc::new(brdf::ndf::Beckmann::new(0.2, 0.2, 0.0)),
        brdf::fresnel::Fresnel::Dielectric { eta: 1.5 },
    );
    let merl = lab.path("gold.binary");
    std::fs::write(&merl, material::merl::MerlBrdf::encode(&t)).unwrap();

    // A capture directory (what the issue saw emptied) and a notes folder.
    assert_ok(&lab.capture("satin", "capture", &["--no-fit"]), "capture");
    std::fs::create_dir(lab.path("notes")).unwrap();
    std::fs::write(lab.path("notes/todo.txt"), "keep").unwrap();
    let before = (snapshot(&lab.path("capture")), snapshot(&lab.path("notes")));
    for out in ["capture", "notes"] {
        for extra in [&[][..], &["--replace"][..]] {
            let o = lab.refl(&[&["import-merl", s(&merl), "--out", s(&lab.path(out))][..], extra].concat());
            assert_eq!(o.status.code(), Some(2), "{out} {extra:?}: {}", stderr(&o));
            assert!(stderr(&o).contains("nothing was changed"), "{}", stderr(&o));
        }
    }
    assert_eq!((snapshot(&lab.path("capture")), snapshot(&lab.path("notes"))), before, "a refusal changed files");

    // A new directory takes the material; a second import needs --replace,
    // which swaps in the new material.
    let gold = lab.path("gold");
    assert_ok(&lab.refl(&["import-merl", s(&merl), "--out", s(&gold)]), "import");
    let o = lab.refl(&["import-merl", s(&merl), "--out", s(&gold)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("already holds a material"), "{}", stderr(&o));
    assert_ok(&lab.refl(&["import-merl", s(&merl), "--out", s(&gold), "--replace"]), "import --replace");
    assert!(gold.join("material.json").is_file());
    let siblings: Vec<String> =
        std::fs::read_dir(lab.dir.path()).unwrap().flatten().map(|e| e.file_name().to_string_lossy().into()).collect();
    assert!(!siblings.iter().any(|n| n.starts_with(".gold.")), "temporary directories left: {siblings:?}");
}

/// Defect 2: a controller that answers slowly within the protocol's
/// timeout works; one that stops answering (its port still opens) ends the
/// capture, and a resume of it, with advice instead of reconnecting forever.
#[test]
fn a_rig_that_stops_answering_ends_with_advice_not_forever() {
    let lab = Lab::new();
    // The reproducer: 15 ms replies are within the 50 ms timeout.
    let o = lab.capture_cmd("satin", "slow", 4).args(["--no-fit", "--sim-faults", "delay-ms=15"]).output().unwrap();
    assert_ok(&o, "capture with 15 ms replies");

    let hung = |args: &[&str]| {
        let child = lab.cmd(CAPTURE).args(args).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
        // The recovery budget is 6 recoveries or 60 s per operation; each
        // recovery here costs one reply timeout series (0.45 s).
        wait_bounded(child, Duration::from_secs(120), "a capture of a hung rig")
    };
    // Enough shots that the resume, too, sends the wedged controller more
    // than `hang-at` commands (the count restarts with each connection).
    let base = ["--sample", "satin", "--quality", "fast", "--grid", "12", "--camera-px", "64", "--steps", "48"];
    let out = lab.path("hung");
    let o = hung(&[&base[..], &["--out", s(&out), "--sim-faults", "hang-at=150"]].concat());
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("power-cycle the controller"), "{}", stderr(&o));
    assert_eq!(status(&out), "interrupted");
    let o = hung(&["--resume", s(&out)]);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("power-cycle the controller"), "{}", stderr(&o));
}

/// Defect 3: a stop request during the fit (SIGINT) or the renders (SIGHUP,
/// a closed terminal) ends the process with 130 and leaves a capture that
/// resumes to its material.
#[test]
fn a_stop_during_the_fit_or_the_renders_is_honoured() {
    let lab = Lab::new();
    for (out, stage, detail, sig) in
        [("in-fit", "fit", "per-point", libc::SIGINT), ("in-render", "render", "", libc::SIGHUP)]
    {
        let mut child = lab
            .capture_cmd_sized("satin", out, 12, 40, 96)
            .arg("--json")
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
        wait_for_event(&mut lines, "the stage", |v| is_stage(v, stage, detail));
        signal(&child, sig);
        let t = Instant::now();
        let code = child.wait().unwrap().code();
        let after = t.elapsed();
        assert_eq!(code, Some(130), "{out}");
        // Well under the stage's own length (seconds): the stop was honoured
        // at once, not after the stage finished.
        eprintln!("{out}: exited {after:?} after signal {sig}");
        let dir = lab.path(out);
        assert_eq!(status(&dir), "captured", "{out}: every frame is stored, the outputs are not");
        assert!(!dir.join("report.json").exists(), "{out}");
        let o = lab.cmd(CAPTURE).arg("--resume").arg(&dir).output().unwrap();
        assert_ok(&o, "resume after a stop in the fit");
        assert_eq!(status(&dir), "complete");
        assert!(dir.join("material/maps.exr").is_file() && dir.join("renders/sky.png").is_file());
    }
}

/// Defect 3 through the daemon: `--cancel` during the fit is honoured
/// (it answered `{"cancelled":false}` there); defect 6: a daemon that dies
/// leaves the capture interrupted and its client says how to resume.
#[test]
fn the_daemon_cancels_any_stage_and_its_death_is_explained() {
    let lab = Lab::new();
    let socket = lab.path("daemon.sock");
    let mut daemon = lab.start_daemon(&socket, Stdio::null());
    let mut client = lab
        .capture_cmd_sized("satin", "cancelled", 12, 40, 96)
        .arg("--json")
        .env("REFLECTOMETER_SOCKET", &socket)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(client.stdout.take().unwrap()).lines();
    wait_for_event(&mut lines, "the fit", |v| is_stage(v, "fit", "per-point"));
    let o = lab.cmd(REFL).args(["daemon", "--cancel", "--socket", s(&socket)]).output().unwrap();
    assert_ok(&o, "daemon --cancel");
    assert!(String::from_utf8_lossy(&o.stdout).contains("\"cancelled\":true"), "{o:?}");
    assert_eq!(client.wait().unwrap().code(), Some(130));
    assert_eq!(status(&lab.path("cancelled")), "captured");
    // Every frame is there: `refl fit` finishes it.
    assert_ok(&lab.refl(&["fit", s(&lab.path("cancelled"))]), "refl fit after the cancel");
    assert_eq!(status(&lab.path("cancelled")), "complete");

    // The daemon dies mid-capture (kill -9): the client explains, the
    // capture is marked interrupted and resumes without the daemon.
    let mut client = lab
        .capture_cmd("satin", "orphan", 48)
        .env("REFLECTOMETER_SOCKET", &socket)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    wait_for_bytes(&mut client, &lab.path("orphan/manifest.jsonl"), 2000);
    daemon.kill().unwrap();
    daemon.wait().unwrap();
    let o = client.wait_with_output().unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("--resume"), "{}", stderr(&o));
    assert_eq!(status(&lab.path("orphan")), "interrupted");
    let o = lab.cmd(CAPTURE).args(["--no-daemon", "--resume", s(&lab.path("orphan"))]).output().unwrap();
    assert_ok(&o, "resume after the daemon died");
}

/// Write a rig file into the lab.
fn rig_file(lab: &Lab, name: &str, body: &str) -> PathBuf {
    let p = lab.path(name);
    std::fs::write(&p, body).unwrap();
    p
}

const SIM_RIG: &str = "name = \"sim\"\nkind = \"sim\"\nwhite_reference_albedo = 0.95\nled_current_ma = 200\n";

/// Defect 4: impossible rigs and calibrations are refused naming the field;
/// nothing is created.
#[test]
fn impossible_rigs_and_calibrations_are_refused() {
    let lab = Lab::new();
    let geometry_camera = "[geometry.sample]\nwidth_mm = 100.0\nheight_mm = 100.0\n[geometry.bar]\nn_leds = 40\n\
        pitch_mm = 5.0\nfirst_led_y_mm = -97.5\nheight_mm = 40.0\nwidth_mm = 10.0\nthickness_mm = 12.0\n\
        [geometry.gantry]\ntravel_min_mm = -120.0\ntravel_max_mm = 120.0\nspeed_mm_s = SPEED\naccel_mm_s2 = 1000.0\n\
        settle_ms = 30.0\nhoming_speed_mm_s = 50.0\n[geometry.emission]\nprofile_exponent = 1.0\ncurrent_ma = 200\n\
        [geometry.camera]\nposition_mm = [-318.2, 0.0, 318.2]\nlook_at_mm = [0.0, 0.0, 0.0]\nup = [0.0, 0.0, 1.0]\n\
        fov_y_deg = FOV\nwidth = 256\nheight = 256\n";
    let good = geometry_camera.replace("SPEED", "100.0").replace("FOV", "15.0");
    let cases = [
        (format!("{SIM_RIG}{}", geometry_camera.replace("SPEED", "100.0").replace("FOV", "nan")), "fov_y_deg"),
        (format!("{SIM_RIG}{}", geometry_camera.replace("SPEED", "0.0").replace("FOV", "15.0")), "speed_mm_s"),
        (format!("{SIM_RIG}{}", good.replace("height_mm = 40.0", "height_mm = -40.0")), "bar.height_mm"),
        (format!("{SIM_RIG}{}", good.replace("width_mm = 100.0", "width_mm = -1.0")), "sample.width_mm"),
        (format!("{SIM_RIG}[sim]\ntime_scale = nan\n"), "time_scale"),
        (format!("{SIM_RIG}[sim]\nfps = -30.0\n"), "fps"),
    ];
    for (k, (body, field)) in cases.iter().enumerate() {
        let rig = rig_file(&lab, &format!("rig{k}.toml"), body);
        let out = lab.path(&format!("out{k}"));
        let o = lab.capture("satin", &format!("out{k}"), &["--rig", s(&rig)]);
        assert_eq!(o.status.code(), Some(2), "{field}: {}", stderr(&o));
        assert!(stderr(&o).contains(field) && stderr(&o).contains("must be"), "{field}: {}", stderr(&o));
        assert!(!out.exists(), "{field}: nothing is created");
    }
    // The good rig file is accepted (the cases differ from it in one field).
    let rig = rig_file(&lab, "good.toml", &format!("{SIM_RIG}{good}"));
    let o = lab.capture_cmd("satin", "good", 4).args(["--rig", s(&rig), "--no-fit"]).output().unwrap();
    assert_ok(&o, "the good rig");

    // A calibration whose LEDs gave no light is refused before capturing.
    let cal_dir = lab.path("data/calibration/sim-perturbed-1");
    let newest = std::fs::read_dir(&cal_dir).unwrap().flatten().map(|e| e.path()).max().unwrap();
    let mut cal = json(&newest);
    for v in cal["led_scale"].as_array_mut().unwrap() {
        *v = serde_json::json!(0.0);
    }
    std::fs::write(cal_dir.join("99991231T235959Z.json"), serde_json::to_vec(&cal).unwrap()).unwrap();
    let o = lab.capture("satin", "dark-leds", &[]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("led_scale[0]"), "{}", stderr(&o));
    assert!(!lab.path("dark-leds").exists());
}

/// Defect 5: `refl fit` on an interrupted capture refuses, or with
/// `--partial` fits it and says so in the report and the material.
#[test]
fn fitting_a_half_capture_needs_partial_and_is_marked() {
    let lab = Lab::new();
    let o = lab.capture("satin", "half", &["--stop-after", "100"]);
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    let dir = lab.path("half");
    let o = lab.refl(&["fit", s(&dir)]);
    assert_eq!(o.status.code(), Some(2), "{}", stderr(&o));
    assert!(stderr(&o).contains("--partial") && stderr(&o).contains("--resume"), "{}", stderr(&o));
    assert!(!dir.join("material").exists());
    assert_ok(&lab.refl(&["fit", "--partial", s(&dir)]), "refl fit --partial");
    let report = json(&dir.join("report.json"));
    assert_eq!(report["partial"]["stored_shots"], 100, "{}", report["partial"]);
    let m = json(&dir.join("material/material.json"));
    assert_eq!(m["provenance"]["partial_capture"]["stored_shots"], 100);
}

/// Defect 6: two writers of one capture directory; the second is refused
/// with the usage code while the first runs, and the first is unharmed.
#[test]
fn one_writer_per_capture_directory() {
    let lab = Lab::new();
    let o = lab.capture_cmd("satin", "shared", 64).args(["--stop-after", "50"]).output().unwrap();
    assert_eq!(o.status.code(), Some(130), "{}", stderr(&o));
    let dir = lab.path("shared");
    let mut first =
        lab.cmd(CAPTURE).arg("--resume").arg(&dir).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let manifest = dir.join("manifest.jsonl");
    let len = std::fs::metadata(&manifest).unwrap().len();
    wait_for_bytes(&mut first, &manifest, len + 2000);
    let second = lab.cmd(CAPTURE).arg("--resume").arg(&dir).output().unwrap();
    assert_eq!(second.status.code(), Some(2), "{}", stderr(&second));
    assert!(stderr(&second).contains("in use"), "{}", stderr(&second));
    let fit = lab.refl(&["fit", "--partial", s(&dir)]);
    assert_eq!(fit.status.code(), Some(2), "{}", stderr(&fit));
    let o = first.wait_with_output().unwrap();
    assert_ok(&o, "the first resume");
    assert_eq!(status(&dir), "complete");
}

/// Defect 6: without HOME, calibrations follow the XDG rules (never a
/// directory relative to where the command ran); stale emulator links of
/// dead processes are cleaned up at start.
#[test]
fn data_and_runtime_directories_are_absolute_and_clean() {
    let lab = Lab::new();
    let runtime = lab.path("run");
    let links = runtime.join("reflectometer");
    std::fs::create_dir_all(&links).unwrap();
    // A pid that certainly ended: our own finished child's.
    let mut dead = std::process::Command::new("true").spawn().unwrap();
    let pid = dead.id();
    dead.wait().unwrap();
    let stale = links.join(format!("sim-mcu-{pid}-0"));
    std::os::unix::fs::symlink("/dev/pts/nonexistent", &stale).unwrap();
    let work = lab.path("cwd");
    std::fs::create_dir(&work).unwrap();
    let o = lab
        .capture_cmd("satin", "xdg-capture", 4)
        .arg("--no-fit")
        .current_dir(&work)
        .env_remove("REFLECTOMETER_DATA")
        .env_remove("HOME")
        .env("XDG_DATA_HOME", lab.path("xdg"))
        .env("XDG_RUNTIME_DIR", &runtime)
        .output()
        .unwrap();
    assert_ok(&o, "capture without HOME");
    assert!(lab.path("xdg/reflectometer/calibration/sim-perturbed-1").is_dir(), "calibration kept under XDG_DATA_HOME");
    assert_eq!(std::fs::read_dir(&work).unwrap().count(), 0, "nothing written relative to the working directory");
    assert!(std::fs::symlink_metadata(&stale).is_err(), "the stale link is removed");
    let info = json(&lab.path("xdg-capture/capture.json"));
    let source = info["calibration_source"].as_str().unwrap();
    assert!(Path::new(source).is_absolute(), "{source}");
}
