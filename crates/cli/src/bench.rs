//! `refl bench realtime`: the one benchmark that runs the whole capture job
//! (the others, which need only the fitter or the simulator, are in
//! `assess::bench`).

use std::sync::Arc;
use std::time::Instant;

use anyhow::{Result, anyhow};
use config::{RigFile, RigKind};

use crate::progress::{Event, Mode, Reporter};

/// `refl bench realtime`: a capture of `sample` on the simulated rig in
/// real time (the camera at `fps`, exposure and readout within the frame
/// period; the gantry at the rig's speed, acceleration and settling), its
/// wall time from the first shot to the last stored frame against the
/// physical limit: frames x frame period + the gantry's moves and settling
/// between steps. Homing is outside both. The streaming fit runs alongside,
/// as in a real capture.
pub async fn realtime(sample: &str, steps: u32, led_stride: u8, fps: f32) -> Result<()> {
    let dir = std::env::temp_dir().join(format!("refl-bench-realtime-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let (mut rf, _) = RigFile::load(None)?;
    anyhow::ensure!(rf.kind == RigKind::Sim, "this benchmark runs the simulated rig");
    let q = config::preset("fast").ok_or_else(|| anyhow!("no fast preset"))?;
    let o = config::Overrides { steps: Some(steps), led_stride: Some(led_stride), ..Default::default() };
    let q = q.apply(&o)?;
    let g = crate::capture::geometry_for(&rf, &q);
    // Calibrate at simulation speed first (a real-time one would take minutes).
    let calib = dir.join("calibration");
    let store = store::CalibrationStore::new(&calib, &rf.calibration_key());
    let mut quiet = Reporter::new(Mode::Silent);
    crate::capture::calibrate(&rf, &g, &store, &mut quiet, crate::capture::Scan::All).await?;
    rf.sim.realtime = true;
    rf.sim.fps = fps;
    let rig_path = dir.join("rig.toml");
    std::fs::write(&rig_path, toml::to_string(&rf)?)?;
    let events: Arc<std::sync::Mutex<Vec<(Instant, Event)>>> = Arc::default();
    let ev = events.clone();
    let mut rep = Reporter::new(Mode::Silent).forward_to(move |e| {
        ev.lock().unwrap_or_else(|p| p.into_inner()).push((Instant::now(), e.clone()));
    });
    let req = crate::capture::CaptureRequest {
        sample: Some(sample.to_string()),
        out: Some(dir.join("capture")),
        quality: Some("fast".into()),
        overrides: o,
        rig_file: Some(rig_path),
        calib_dir: Some(calib),
        ..Default::default()
    };
    println!(
        "real-time capture: '{sample}', {steps} steps x {} LEDs at {fps} frames/s (this takes about {:.0} s)",
        g.bar.n_leds.div_ceil(led_stride.max(1)),
        (steps * g.bar.n_leds.div_ceil(led_stride.max(1)) as u32) as f32 / fps
    );
    let (_tx, rx) = tokio::sync::watch::channel(false);
    let summary = crate::capture::run(req, &mut rep, rx).await?;
    let events = events.lock().unwrap_or_else(|p| p.into_inner()).clone();
    let at = |pred: &dyn Fn(&Event) -> bool| events.iter().find(|(_, e)| pred(e)).map(|(t, _)| *t);
    let start =
        at(&|e| matches!(e, Event::Stage { stage, detail } if stage == "capture" && detail.contains("shots to take")));
    let end =
        at(&|e| matches!(e, Event::Stage { stage, detail } if stage == "capture" && detail.contains("frames stored")));
    let (Some(start), Some(end)) = (start, end) else { anyhow::bail!("the capture did not report its stages") };
    let info = store::CaptureDir::read_info(&summary.dir)?;
    let plan = &info.plan;
    let frames = plan.shots().len() + plan.dark_frames as usize * plan.exposures_us.len();
    let limit = plan.physical_seconds(&info.geometry, fps);
    let frames_s = frames as f64 / fps as f64;
    let wall = (end - start).as_secs_f64();
    println!("  frames: {frames} ({frames_s:.2} s at {fps}/s); moves and settling: {:.2} s", limit - frames_s);
    println!("  physical limit {limit:.2} s; wall time {wall:.2} s; ratio {:.3} (target 1.05 or less)", wall / limit);
    let _ = std::fs::remove_dir_all(&dir);
    Ok(())
}
