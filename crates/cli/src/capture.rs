//! The capture job: everything `capture --sample NAME --out DIR` does, shared
//! by the operator's command (in-process) and the daemon.
//!
//! 1. Resolve the rig, the quality preset, the sample and the calibration
//!    (on the simulated rig a missing calibration is made first; on
//!    hardware the operator is told to run the dark and white scans).
//! 2. Create the capture directory (or reopen it with `--resume`, verifying
//!    every stored frame) and start the fitter thread; stored frames of a
//!    resumed capture are replayed into it.
//! 3. Home, take the dark frames, then every shot of the plan through the
//!    confirming sequencer (`rig::sequence`): each confirmed frame is
//!    written to disk and streamed to the fitter as it arrives.
//! 4. Ctrl-C or SIGTERM e-stops the rig (LEDs off, motion stopped) and keeps
//!    everything stored; `--resume DIR` continues.
//! 5. Fit, write `material/`, renders and `report.json`.

use std::collections::{HashMap, HashSet};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use frame::Frame;
use rig::camera::{Camera, CameraError, CameraSettings};
use rig::clock;
use rig::mcu::{Connector, Rig, RigError};
use rig::sequence::{self, Exposer, Shot};
use serde::{Deserialize, Serialize};
use setup::{Calibration, CapturePlan, PointGrid, RigGeometry};
use sim::FaultSpec;
use store::{CaptureDir, CaptureInfo, CaptureStatus, FrameKind, SensorInfo, SimInfo};
use tokio::sync::watch;

use crate::Interrupted;
use crate::calib;
use crate::fitjob::{FitJob, FrameMsg};
use crate::output;
use crate::progress::{Event, Reporter};
use crate::session;
use assess::report::{self, Report};
use assess::truth::{ground_truth, sim_material};
use config::presets::{self, Overrides, Quality};
use config::{RigFile, RigKind};
use store::CalibrationStore;

/// What to capture (also the daemon's job request).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CaptureRequest {
    pub sample: Option<String>,
    pub out: Option<PathBuf>,
    pub resume: Option<PathBuf>,
    pub quality: Option<String>,
    #[serde(default)]
    pub overrides: Overrides,
    pub rig_file: Option<PathBuf>,
    pub sim_material: Option<PathBuf>,
    #[serde(default)]
    pub sim_faults: String,
    /// Simulated rig: which physical rig (`ideal`, `perturbed:SEED`) in
    /// place of the rig file's `[sim] rig`.
    #[serde(default)]
    pub sim_rig: Option<String>,
    pub calib_dir: Option<PathBuf>,
    /// Capture only, no fit.
    #[serde(default)]
    pub no_fit: bool,
    /// Stop after this many shots (tests and demonstrations of resume).
    pub stop_after: Option<u64>,
}

pub fn camera_settings(g: &RigGeometry, exposure_us: u32, gain: f32, fps: f32) -> CameraSettings {
    CameraSettings { width: g.camera.width, height: g.camera.height, exposure_us, gain, fps, settle_frames: 2 }
}

fn quality(req: &CaptureRequest) -> Result<Quality> {
    let name = req.quality.as_deref().unwrap_or("balanced");
    let q = presets::preset(name)
        .ok_or_else(|| anyhow!("unknown quality '{name}': use one of {}", presets::PRESETS.join(", ")))?;
    Ok(q.apply(&req.overrides)?)
}

/// The plan a quality preset asks for on a rig.
pub fn plan_for(q: &Quality, g: &RigGeometry) -> Result<CapturePlan> {
    let plan = CapturePlan {
        steps: q.steps,
        first_mm: g.gantry.travel_min_mm,
        last_mm: g.gantry.travel_max_mm,
        leds: (0..g.bar.n_leds).step_by(q.led_stride as usize).collect(),
        exposures_us: q.exposures_us.clone(),
        gain: 1.0,
        dark_frames: q.dark_frames,
        bracket: q.bracket,
    };
    plan.validate(g)?;
    Ok(plan)
}

/// Geometry of a rig, with the preset's simulated camera resolution.
pub fn geometry_for(rf: &RigFile, q: &Quality) -> RigGeometry {
    let mut g = rf.geometry();
    if rf.kind == RigKind::Sim {
        g.camera.width = q.sim_camera_px;
        g.camera.height = q.sim_camera_px;
    }
    g
}

/// A geometric calibration older than this is reported at every capture.
const GEOMETRY_MAX_AGE_DAYS: i64 = 90;

/// Find the calibration to use; on the simulated rig, make one if missing.
async fn calibration_for(
    rf: &RigFile,
    geometry: &RigGeometry,
    store: &CalibrationStore,
    rep: &mut Reporter,
) -> Result<(Calibration, String)> {
    let newest = store.newest()?;
    let measured_geometry = newest.as_ref().is_some_and(|(_, c)| c.camera.is_some() && c.lights.is_some());
    if let Some((path, c)) = newest {
        let usable = c.led_scale.len() == geometry.bar.n_leds as usize && !c.flat_field.is_empty();
        // A rig may run without a geometric calibration (the rig file's
        // camera), with a warning; the simulated rig makes one only when it
        // has no calibration at all.
        if usable {
            match &c.camera {
                None => rep.warn(
                    "this rig has no geometric calibration: the camera's pose and lens are taken from the rig file \
                     (run `capture --calibrate geometry`, then `capture --calibrate white`; see CALIBRATION.md)",
                ),
                Some(g) => {
                    if c.lights.is_none() {
                        rep.warn(
                            "this rig's geometric calibration has no mirror scan: the LEDs are placed by the rig file \
                             (run `capture --calibrate geometry` again, then `capture --calibrate white`; see \
                             CALIBRATION.md)",
                        );
                    }
                    let now = crate::paths::stamp_days(&crate::paths::utc_stamp());
                    let age = now.zip(crate::paths::stamp_days(&g.id)).map(|(n, t)| n - t);
                    if let Some(days) = age.filter(|&a| a > GEOMETRY_MAX_AGE_DAYS) {
                        rep.warn(format!(
                            "the geometric calibration is {days} days old: a knocked camera or bar moves the rig's \
                             geometry; run `capture --calibrate geometry` and `capture --calibrate white` again"
                        ));
                    }
                }
            }
            if !geometry.references.is_empty()
                && c.drift_reference.as_ref().is_none_or(|d| d.patches != geometry.references)
            {
                rep.warn(
                    "the white calibration has no readings of the rig file's reference patches (it predates them, or \
                     they moved): the LEDs' drift during the capture is not corrected (run `capture --calibrate \
                     white`; see CALIBRATION.md)",
                );
            }
            c.validate().map_err(|e| {
                crate::usage(anyhow!(
                    "{}: {e}; run `capture --calibrate dark` and `capture --calibrate white` again",
                    path.display()
                ))
            })?;
            return Ok((c, path.display().to_string()));
        }
    }
    if rf.kind == RigKind::Hardware {
        bail!(
            "no calibration for rig '{}' in {}: place the lens cap and run `capture --calibrate dark`, then place the \
             white reference and run `capture --calibrate white`",
            rf.name,
            store.dir().display()
        );
    }
    let scan = if measured_geometry { Scan::White } else { Scan::All };
    rep.stage(
        "calibrate",
        match scan {
            Scan::White => {
                "no radiometric calibration of the simulated rig yet: running the dark and white scans first"
            }
            _ => "no calibration of the simulated rig yet: running the geometric, dark and white scans first",
        },
    );
    let c = calibrate(rf, geometry, store, rep, scan).await?;
    let path = store.dir().join(format!("{}.json", c.id));
    Ok((c, path.display().to_string()))
}

/// Open the rig for a calibration scan; on the simulated rig with the
/// white reference in the holder (the geometric scan puts its target there
/// itself, `calib::geometry`).
async fn open_for_scan(rf: &RigFile, geometry: &RigGeometry) -> Result<session::Session> {
    Ok(match rf.kind {
        RigKind::Sim => session::open_sim(rf, geometry, sim_material("white", None)?, &FaultSpec::none()).await?,
        RigKind::Hardware => session::open_hardware(rf, geometry).await?,
    })
}

/// Which calibration scans to run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scan {
    /// Lens capped: black level and read noise.
    Dark,
    /// Dark, then the white reference: LED intensities, emission profile,
    /// flat field.
    White,
    /// The checkerboard target, then a flat mirror: the camera's
    /// intrinsics and pose, then where the LEDs are.
    Geometry,
    /// Geometry, dark and white, in that order (the white scan's flat
    /// field is mapped with the measured camera).
    All,
}

impl std::str::FromStr for Scan {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> Result<Self> {
        Ok(match s {
            "dark" => Scan::Dark,
            "white" => Scan::White,
            "geometry" => Scan::Geometry,
            "all" => Scan::All,
            o => bail!("unknown calibration '{o}': dark, white, geometry or all"),
        })
    }
}

/// Run the scans `scan` asks for, each building on the newest stored
/// calibration, and store the result. `geometry` is the rig file's. On
/// the simulated rig the target or the white reference is put in place for
/// each scan; on hardware the operator places them (or the lens cap).
pub async fn calibrate(
    rf: &RigFile,
    geometry: &RigGeometry,
    store: &CalibrationStore,
    rep: &mut Reporter,
    scan: Scan,
) -> Result<Calibration> {
    let mut c = match store.newest()? {
        Some((_, c)) if c.led_scale.len() == geometry.bar.n_leds as usize => c,
        _ => Calibration::nominal(geometry.bar.n_leds, 1.0, 0.0),
    };
    if matches!(scan, Scan::Geometry | Scan::All) {
        // At the camera's own resolution, the rig file's (the simulated
        // rig's presets read it coarser; `Calibration::geometry_of` scales
        // the result to them).
        let full = rf.geometry();
        let mut s = open_for_scan(rf, &full).await?;
        let cs = camera_settings(&full, 20_000, 1.0, s.fps);
        let result = async {
            s.rig.home().await?;
            calib::geometry(&mut s.rig, &mut s.camera, &full, c.clone(), &cs, rep).await
        }
        .await;
        s.close().await;
        c = result?;
        if scan == Scan::Geometry && !c.flat_field.is_empty() {
            rep.warn("the white calibration was mapped with the old camera: run `capture --calibrate white` again");
        }
    }
    let result = if scan == Scan::Geometry {
        Ok(c)
    } else {
        let mut s = open_for_scan(rf, geometry).await?;
        let cs = camera_settings(geometry, 20_000, 1.0, s.fps);
        let result = async {
            s.rig.home().await?;
            let mut c = calib::dark(&mut s.rig, &mut s.camera, c, &cs, rep).await?;
            if matches!(scan, Scan::White | Scan::All) {
                let measured = c.geometry_of(geometry);
                c = calib::white(
                    &mut s.rig,
                    &mut s.camera,
                    &measured,
                    c,
                    rf.white_reference_albedo,
                    &cs,
                    s.e_per_dn,
                    rep,
                )
                .await?;
            }
            anyhow::Ok(c)
        }
        .await;
        s.close().await;
        result
    };
    let c = result?;
    c.validate().map_err(|e| {
        anyhow!(
            "the scan gave a calibration that cannot be used ({e}); nothing was saved: check that every LED lights \
             and that the {} is in place",
            match scan {
                Scan::Dark => "lens cap",
                Scan::Geometry => "target",
                Scan::White | Scan::All => "white reference",
            }
        )
    })?;
    let path = store.save(&c)?;
    rep.stage("calibrate", format!("saved {}", path.display()));
    Ok(c)
}

struct Shooter<'a, C: Camera> {
    camera: &'a mut C,
    store: &'a mut CaptureDir,
    fit: Option<&'a FitJob>,
    plan: &'a CapturePlan,
    exposure: Option<u8>,
    rep: &'a mut Reporter,
    done: u64,
    total: u64,
    started: Instant,
    stop_after: Option<u64>,
    taken: u64,
    led_max_on: Duration,
    discarded: u64,
    /// Consecutive frames that ended after their LED's maximum on-time.
    late: u32,
    /// The frame's window over the sample's points, where clipping counts.
    window: [u32; 4],
    /// Whether each shot taken (by plan index) clipped in the window.
    clipped: HashMap<u32, bool>,
    /// Shots passed over (an adaptive bracket's shorter exposures nobody
    /// needs), which leave the total.
    passed: HashSet<u32>,
    /// When the link's counters were last reported.
    link_shown: Option<Instant>,
}

/// The frame's window (x0, y0, x1, y1, pixels) that holds everything the
/// fit reads for the sample's points: each point's pixel with the reach of
/// its bilinear sample and of the demosaicing (`fit::context::PIXEL_REACH`).
fn points_window(g: &RigGeometry, grid: &PointGrid) -> [u32; 4] {
    let (mut lo, mut hi) = (glam::Vec2::splat(f32::INFINITY), glam::Vec2::splat(f32::NEG_INFINITY));
    for i in 0..grid.len() {
        if let Some(px) = g.camera.project(grid.position_of(&g.sample, i).extend(0.0)) {
            lo = lo.min(px);
            hi = hi.max(px);
        }
    }
    let reach = fit::context::PIXEL_REACH + 1.0;
    if lo.x > hi.x {
        return [0; 4];
    }
    let (lo, hi) = ((lo - reach).floor().max(glam::Vec2::ZERO), (hi + reach).ceil());
    [lo.x as u32, lo.y as u32, (hi.x as u32).min(g.camera.width), (hi.y as u32).min(g.camera.height)]
}

/// Frames in a row that may arrive too late for their LED before the
/// capture gives up.
const LATE_RETAKES: u32 = 3;
/// A camera that does not deliver is asked again this many times.
const FRAME_RETRIES: u32 = 3;
/// How long a camera that disappeared may take to come back.
const CAMERA_RETURN: Duration = Duration::from_secs(10);

impl<C: Camera> Shooter<'_, C> {
    async fn frame(&mut self, after: tokio::time::Instant, exposure_us: u32) -> Result<Frame> {
        let timeout = Duration::from_micros(exposure_us as u64) + Duration::from_secs(2);
        let mut tries = 0;
        let gone_since = Instant::now();
        loop {
            match self.camera.frame_after(clock::to_mono(after), timeout).await {
                Ok(f) => return Ok(f),
                Err(CameraError::Timeout { waited_ms }) if tries < FRAME_RETRIES => {
                    tries += 1;
                    self.rep.warn(format!(
                        "no frame within {waited_ms} ms; asking the camera again ({tries}/{FRAME_RETRIES})"
                    ));
                }
                Err(CameraError::Gone(why)) if gone_since.elapsed() < CAMERA_RETURN => {
                    self.rep.warn(format!("the camera went away ({why}); waiting for it to come back"));
                    tokio::time::sleep(Duration::from_millis(200)).await;
                }
                Err(e) => return Err(e.into()),
            }
        }
    }
}

impl<C: Camera> Exposer for Shooter<'_, C> {
    type Item = (Frame, tokio::time::Instant, u32);
    type Error = anyhow::Error;

    async fn expose(&mut self, shot: &Shot, lit_at: tokio::time::Instant) -> Result<Option<Self::Item>> {
        if self.stop_after.is_some_and(|n| self.taken >= n) {
            return Err(Interrupted.into());
        }
        let exposure_us = self.plan.exposures_us[shot.exposure as usize];
        if self.exposure != Some(shot.exposure) {
            self.camera.set_exposure(exposure_us, self.plan.gain).await?;
            self.exposure = Some(shot.exposure);
        }
        let f = self.frame(lit_at, exposure_us).await?;
        let deadline = clock::to_mono(lit_at + self.led_max_on);
        if f.meta.exposure_end > deadline {
            // The LED may have gone off during this exposure.
            if Duration::from_micros(exposure_us as u64) >= self.led_max_on {
                bail!(
                    "the exposure ({exposure_us} us) outlasts the LEDs' maximum on-time ({} ms); shorten the exposure",
                    self.led_max_on.as_millis()
                );
            }
            self.late += 1;
            if self.late > LATE_RETAKES {
                bail!(
                    "the camera delivered {} frames in a row after the LED's maximum on-time ({} ms); check the \
                     camera's frame rate and trigger settings",
                    self.late,
                    self.led_max_on.as_millis()
                );
            }
            self.rep.warn(format!(
                "step {} LED {}: the frame ended after the LED's maximum on-time; taking it again",
                shot.step, shot.led
            ));
            return Ok(None);
        }
        self.late = 0;
        self.taken += 1;
        let [x0, y0, x1, y1] = self.window;
        let clipped = f.clipped_in(x0, y0, x1, y1);
        // Known at once (not at commit), for the shorter exposure of this
        // light; a retake of this shot records it again.
        self.clipped.insert(shot.index, clipped > 0);
        Ok(Some((f, lit_at, clipped)))
    }

    fn wants(&mut self, shot: &Shot) -> bool {
        let wanted = self.plan.wants(shot, |k| self.clipped.get(&k).copied());
        if !wanted {
            self.passed.insert(shot.index);
        }
        wanted
    }

    async fn commit(&mut self, shot: &Shot, item: Self::Item) -> Result<()> {
        let (frame, lit_at, clipped) = item;
        let kind = FrameKind::Shot(*shot);
        tokio::task::block_in_place(|| {
            self.store.write_frame(kind, &frame, Some(clock::to_mono(lit_at)), Some(clipped))
        })?;
        self.rep.frame(&frame);
        if let Some(fit) = self.fit {
            // Waits (without holding a runtime worker) while the fitter is
            // 32 frames behind.
            fit.send(FrameMsg::Shot { shot: *shot, frame }).await?;
        }
        self.done += 1;
        let total = self.total.saturating_sub(self.passed.len() as u64);
        let rate = self.done as f64 / self.started.elapsed().as_secs_f64().max(1e-9);
        let left = total.saturating_sub(self.done) as f64;
        self.rep.emit(Event::Frames { done: self.done, total, rate_hz: rate, eta_s: left / rate.max(1e-9) });
        Ok(())
    }

    fn link(&mut self, l: &rig::mcu::LinkStats) {
        if self.link_shown.is_some_and(|t| t.elapsed() < Duration::from_secs(1)) {
            return;
        }
        self.link_shown = Some(Instant::now());
        self.rep.emit(Event::Link(link_report(l)));
    }

    fn discarded(&mut self, shot: &Shot) {
        self.discarded += 1;
        self.rep.warn(format!("retaking step {} LED {}: the rig recovered while it was exposed", shot.step, shot.led));
    }
}

fn link_report(l: &rig::mcu::LinkStats) -> report::LinkReport {
    report::LinkReport {
        commands: l.commands,
        retransmits: l.retransmits,
        stale_replies: l.stale_replies,
        bad_frames: l.bad_frames,
        mean_rtt_us: l.mean_rtt().map(|d| d.as_secs_f64() * 1e6),
    }
}

/// What a finished capture produced.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    pub dir: PathBuf,
    pub material: Option<PathBuf>,
    pub report: Report,
}

/// Run a capture request to the end (or to an interruption).
/// `cancel` turning true is a stop request, honoured at every stage: the
/// frames (e-stop, everything stored kept), the fit and the renders.
pub async fn run(req: CaptureRequest, rep: &mut Reporter, cancel: watch::Receiver<bool>) -> Result<Summary> {
    let started = Instant::now();
    let (mut rf, rig_source) = RigFile::load(req.rig_file.as_deref())?;
    if let Some(r) = &req.sim_rig {
        rf.sim.rig = r.parse().map_err(|e| crate::usage(anyhow!("--sim-rig: {e}")))?;
    }
    let faults = FaultSpec::parse(&req.sim_faults).map_err(|e| crate::usage(anyhow!("--sim-faults: {e}")))?;
    let resume = req.resume.is_some();
    // Everything about the capture comes from the request, or from
    // capture.json when resuming.
    let (root, info, q, done) = if let Some(dir) = &req.resume {
        let (cd, state) = CaptureDir::resume(dir)?;
        if cd.info().status == CaptureStatus::Complete && !state.damaged.is_empty() {
            rep.warn("the capture was complete but some frames were damaged; retaking them");
        }
        for d in &state.damaged {
            rep.warn(format!("dropped damaged frame {d} (it will be taken again)"));
        }
        let q: Quality = serde_json::from_value(cd.info().settings.clone())
            .with_context(|| format!("{}: capture.json does not record its quality settings", dir.display()))?;
        let info = cd.info().clone();
        if let Some(s) = &info.simulated {
            // The same physical rig as the frames already taken.
            rf.sim.rig = s.rig.parse().map_err(|e| anyhow!("{}: {e}", CaptureDir::INFO))?;
        }
        let done: HashSet<u32> = state.done_shots;
        let wanted = store::wanted_shots(&info.plan, cd.entries()).len();
        rep.stage("resume", format!("{} of {wanted} shots already stored and verified", done.len()));
        (Some(cd), info, q, done)
    } else {
        let q = quality(&req).map_err(crate::usage)?;
        let sample = req.sample.clone().ok_or_else(|| crate::usage(anyhow!("name the sample with --sample NAME")))?;
        let out =
            req.out.clone().ok_or_else(|| crate::usage(anyhow!("choose the capture directory with --out DIR")))?;
        // Before devices and calibrations: a refused --out touches nothing.
        CaptureDir::check_new(&out)?;
        if rf.kind == RigKind::Sim {
            sim_material(&sample, req.sim_material.as_deref()).map_err(crate::usage)?;
        }
        let geometry = geometry_for(&rf, &q);
        let plan = plan_for(&q, &geometry).map_err(crate::usage)?;
        let info = CaptureInfo {
            format_version: store::CAPTURE_FORMAT_VERSION,
            sample: sample.clone(),
            created_utc: crate::paths::utc_stamp(),
            status: CaptureStatus::InProgress,
            geometry,
            plan,
            calibration: Calibration::nominal(40, 1.0, 0.0),
            calibration_source: None,
            sensor: SensorInfo { bit_depth: 12, e_per_dn: 1.0, layout: None },
            camera: None,
            grid: PointGrid { cols: q.grid, rows: q.grid },
            settings: serde_json::to_value(&q)?,
            simulated: (rf.kind == RigKind::Sim).then(|| SimInfo {
                material: req.sim_material.is_none().then(|| sample.clone()),
                material_dir: req.sim_material.as_ref().map(|p| p.display().to_string()),
                faults: req.sim_faults.clone(),
                seed: rf.sim.seed,
                rig: rf.sim.rig.to_string(),
            }),
        };
        let _ = out;
        (None, info, q, HashSet::new())
    };
    // The rig file's geometry (what the simulated rig is built to) and the
    // geometry the fit uses: the file's with the calibrated camera, as
    // capture.json records it.
    let filed = geometry_for(&rf, &q);
    let cal_store = crate::paths::calibrations(req.calib_dir.as_deref(), &rf.calibration_key())?;
    let (calibration, cal_source) = if resume {
        info.calibration.validate().map_err(|e| {
            crate::usage(anyhow!("{}: the calibration it records is not usable: {e}", CaptureDir::INFO))
        })?;
        (info.calibration.clone(), info.calibration_source.clone().unwrap_or_default())
    } else {
        calibration_for(&rf, &info.geometry, &cal_store, rep).await?
    };
    let mut info = info;
    if !resume {
        info.geometry = calibration.geometry_of(&info.geometry);
    }
    let geometry = info.geometry.clone();
    let sample = info.sample.clone();
    let faults = if resume {
        FaultSpec::parse(info.simulated.as_ref().map_or("", |s| s.faults.as_str())).unwrap_or(faults)
    } else {
        faults
    };
    rep.stage("rig", format!("{} ({rig_source}); sample '{sample}', quality {}", rf.name, q.name));
    let mut s = match (rf.kind, ground_truth(&info)?) {
        (RigKind::Sim, Some(material)) => session::open_sim(&rf, &filed, material, &faults).await?,
        (RigKind::Hardware, None) => session::open_hardware(&rf, &geometry).await?,
        (RigKind::Sim, None) => {
            bail!("this capture was made on hardware; resume it with the same hardware rig (--rig)")
        }
        (RigKind::Hardware, Some(_)) => {
            bail!("this capture was made on the simulated rig; resume it without a hardware --rig")
        }
    };
    info.calibration = calibration.clone();
    info.calibration_source = Some(cal_source.clone());
    let cs = camera_settings(&geometry, info.plan.exposures_us[0], info.plan.gain, s.fps);
    let configured = async {
        let applied = session::configure_camera(&mut s.camera, &cs, rep).await?;
        if resume && info.sensor.bit_depth != applied.bit_depth {
            bail!(
                "the capture's frames are {}-bit but the camera now delivers {}-bit ({}); resume with the format it \
                 was made with",
                info.sensor.bit_depth,
                applied.bit_depth,
                applied.format
            );
        }
        anyhow::Ok(applied)
    }
    .await;
    let applied = match configured {
        Ok(a) => a,
        Err(e) => {
            s.close().await;
            return Err(e);
        }
    };
    info.sensor = SensorInfo { bit_depth: applied.bit_depth, e_per_dn: s.e_per_dn, layout: applied.layout };
    let mut cd = match root {
        Some(cd) => cd,
        None => {
            let out = req.out.clone().unwrap_or_default();
            CaptureDir::create(&out, info.clone())?
        }
    };
    cd.set_camera(applied.clone())?;
    cd.set_status(CaptureStatus::InProgress)?;
    let root = cd.root().to_path_buf();
    rep.stage("capture", format!("writing to {}", root.display()));

    let fit_inputs = fit::FitInputs {
        geometry: geometry.clone(),
        plan: info.plan.clone(),
        calibration: calibration.clone(),
        grid: info.grid,
        e_per_dn: s.e_per_dn,
        bit_depth: info.sensor.bit_depth,
        sensor_layout: info.sensor.layout,
    };
    let job = (!req.no_fit).then(|| FitJob::start(fit_inputs, q.fit.clone(), q.stages(&req.overrides)));
    if let Some(job) = &job {
        if resume {
            let stop = output::stop_requested(&cancel);
            let n = tokio::task::block_in_place(|| crate::fitjob::replay(&root, cd.entries(), job, &stop))?;
            rep.stage("fit", format!("replayed {n} stored frames into the fitter"));
        }
    }

    let mut report = Report {
        sample: sample.clone(),
        quality: q.name.clone(),
        rig: rf.name.clone(),
        calibration: cal_source,
        simulated: rf.kind == RigKind::Sim,
        ..Report::default()
    };
    let capture_started = Instant::now();
    let outcome =
        capture_frames(&mut s.rig, &mut s.camera, &mut cd, job.as_ref(), &done, rep, req.stop_after, cancel.clone())
            .await;
    s.close().await;
    report.time("capture_s", capture_started.elapsed().as_secs_f64());
    let link = link_report(&s.rig.link_stats());
    rep.emit(Event::Link(link.clone()));
    report.link = Some(link);
    report.recoveries = s.rig.recoveries().iter().map(|r| format!("{r:?}")).collect();
    let (stats, discards) = match outcome {
        Ok(x) => x,
        Err(e) => {
            let _ = cd.set_status(CaptureStatus::Interrupted);
            drop(job);
            return Err(e);
        }
    };
    // Every frame is stored; the capture is complete once its outputs are.
    cd.set_status(if job.is_some() { CaptureStatus::Captured } else { CaptureStatus::Complete })?;
    cd.sync()?;
    let shorter = cd.entries().iter().filter(|e| matches!(e.frame, FrameKind::Shot(s) if s.exposure > 0)).count();
    report.frames = Some(report::FramesReport {
        committed: stats.committed,
        retakes: stats.retakes,
        moves: stats.moves,
        camera_discards: discards,
        shorter_exposures: shorter as u64,
    });
    if info.plan.bracket == setup::Bracket::Clipped && info.plan.exposures_us.len() > 1 {
        rep.stage(
            "capture",
            format!(
                "{shorter} shots at the bracket's shorter exposures, where the longer one clipped on the sample ({} lights)",
                info.plan.n_lights()
            ),
        );
    }
    if discards.error_flagged + discards.stale + discards.short > 0 {
        rep.warn(format!(
            "the camera delivered {} frames flagged as damaged, {} stale frames (exposed before their LED was lit) \
             and {} short frames; each was discarded and taken again",
            discards.error_flagged, discards.stale, discards.short
        ));
    }
    rep.stage(
        "capture",
        format!("{} frames stored in {:.1} s", cd.entries().len(), capture_started.elapsed().as_secs_f64()),
    );

    let material_dir = match job {
        Some(job) => match output::finish_fit(job, &info, &q, &root, rep, &mut report, &cancel).await {
            Ok(dir) => Some(dir),
            Err(e) => {
                if e.downcast_ref::<Interrupted>().is_some() {
                    rep.warn(format!(
                        "stopped during the fit; every frame is stored: `capture --resume {0}` or `refl fit {0}` \
                         fits it",
                        root.display()
                    ));
                }
                return Err(e);
            }
        },
        None => None,
    };
    report.time("total_s", started.elapsed().as_secs_f64());
    report.peak_memory_mb = report::peak_memory_mb();
    report.material = material_dir.as_ref().map(|p| p.display().to_string());
    output::write_report(&root, &report)?;
    cd.set_status(CaptureStatus::Complete)?;
    rep.emit(Event::Done { summary: serde_json::to_value(&report)? });
    Ok(Summary { dir: root, material: material_dir, report })
}

/// Dark frames, then every shot not yet stored.
#[allow(clippy::too_many_arguments)]
async fn capture_frames<K: Connector, C: Camera>(
    rig: &mut Rig<K>,
    camera: &mut C,
    cd: &mut CaptureDir,
    job: Option<&FitJob>,
    done: &HashSet<u32>,
    rep: &mut Reporter,
    stop_after: Option<u64>,
    mut cancel: watch::Receiver<bool>,
) -> Result<(sequence::SequenceStats, rig::camera::Discards)> {
    let plan = cd.info().plan.clone();
    let work = async {
        rep.stage("rig", "homing");
        rig.home().await?;
        // Dark frames per exposure, all LEDs off.
        let have: HashSet<FrameKind> = cd.entries().iter().map(|e| e.frame).collect();
        for (e, &us) in plan.exposures_us.iter().enumerate() {
            let missing: Vec<u32> =
                (0..plan.dark_frames).filter(|&n| !have.contains(&FrameKind::Dark { exposure: e as u8, n })).collect();
            if missing.is_empty() {
                continue;
            }
            camera.set_exposure(us, plan.gain).await?;
            rig.all_off().await?;
            let off_at = tokio::time::Instant::now();
            for n in missing {
                let f = camera.frame_after(clock::to_mono(off_at), Duration::from_secs(5)).await?;
                tokio::task::block_in_place(|| {
                    cd.write_frame(FrameKind::Dark { exposure: e as u8, n }, &f, None, None)
                })?;
                if let Some(job) = job {
                    job.send(FrameMsg::Dark { exposure: e as u8, frame: f }).await?;
                }
                rig.keepalive().await?;
            }
        }
        // An adaptive bracket's shorter exposures are decided as the
        // capture goes (`Shooter::wants`), from the counts stored so far
        // and those it takes.
        let clipped = store::clipped_shots(cd.entries());
        let todo: Vec<Shot> = plan.shots().into_iter().filter(|s| !done.contains(&s.index)).collect();
        let at_most = todo.iter().filter(|s| plan.wants(s, |k| clipped.get(&k).copied())).count();
        rep.stage(
            "capture",
            match plan.bracket {
                setup::Bracket::Every => format!("{at_most} shots to take"),
                setup::Bracket::Clipped => format!(
                    "{at_most} shots to take at most (a shorter exposure only where the longer one clipped on the \
                     sample)"
                ),
            },
        );
        let window = points_window(&cd.info().geometry, &cd.info().grid);
        let led_max_on = Duration::from_millis(rig.settings().led_max_on_ms as u64);
        let mut shooter = Shooter {
            camera,
            store: cd,
            fit: job,
            plan: &plan,
            exposure: None,
            rep,
            done: done.len() as u64,
            total: (done.len() + at_most) as u64,
            started: Instant::now(),
            stop_after,
            taken: 0,
            led_max_on,
            discarded: 0,
            late: 0,
            window,
            clipped,
            passed: HashSet::new(),
            link_shown: None,
        };
        let stats = sequence::run(rig, &todo, &mut shooter).await?;
        let discards = shooter.camera.discards().await;
        anyhow::Ok((stats, discards))
    };
    // Stop requests (Ctrl-C, SIGTERM, a cancelled daemon job) all arrive
    // through `cancel`: the binaries' one signal watcher sets it.
    let r = tokio::select! {
        r = work => r,
        _ = cancel.wait_for(|c| *c) => Err(anyhow!(Interrupted)),
    };
    if let Err(e) = &r {
        if e.downcast_ref::<Interrupted>().is_some() {
            // Operator's stop: e-stop (motion stops, LEDs off); the next
            // connection clears it.
            if let Err(x) = rig.estop().await {
                tracing::warn!(error = %x, "e-stop did not reach the rig; its watchdog will switch the LEDs off");
            }
        }
        if let Some(RigError::EStopped) = e.downcast_ref::<RigError>() {
            tracing::error!("the rig was e-stopped during the capture");
        }
    }
    r
}
