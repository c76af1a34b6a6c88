//! Calibrations: where they are kept, and the scans that produce them
//! (`capture --calibrate dark|white|geometry|all`).

use std::time::Duration;

use anyhow::{Context, Result, bail};
use fit::{FitContext, FitInputs};
use rig::camera::{Camera, CameraSettings};
use rig::clock;
use rig::mcu::{Connector, Rig};
use setup::{Calibration, CapturePlan, CheckerTarget, PointGrid, RigGeometry};

use crate::progress::{Event, Reporter};

/// Number of dark frames a dark calibration averages.
pub const DARK_FRAMES: u32 = 16;

/// Dark scan: every LED off, frames at the default exposure; the black
/// level and read noise per colour.
pub async fn dark<K: Connector, C: Camera>(
    rig: &mut Rig<K>,
    camera: &mut C,
    base: Calibration,
    settings: &CameraSettings,
    rep: &mut Reporter,
) -> Result<Calibration> {
    rep.stage("calibrate", "dark scan: all LEDs off");
    crate::session::configure_camera(camera, settings, rep).await?;
    rig.all_off().await?;
    let off_at = clock::to_mono(tokio::time::Instant::now());
    let mut frames = Vec::new();
    for _ in 0..DARK_FRAMES {
        frames.push(camera.frame_after(off_at, Duration::from_secs(5)).await?);
        rig.keepalive().await?;
    }
    let Some(stats) = fit::calibrate::dark_statistics(&frames) else { bail!("the dark scan gave no pixels") };
    rep.stage("calibrate", format!("black level {:.1?} DN, read noise {:.2?} DN", stats.black_level, stats.read_noise));
    if let Some(why) = stats.light_leak() {
        rep.warn(why);
    }
    Ok(Calibration {
        id: crate::paths::utc_stamp(),
        black_level: stats.black_level,
        read_noise_dn: stats.read_noise,
        ..base
    })
}

/// White scan: the white reference under every LED at every step of a
/// plan; solves LED intensities, emission profile and flat field.
#[allow(clippy::too_many_arguments)]
pub async fn white<K: Connector, C: Camera>(
    rig: &mut Rig<K>,
    camera: &mut C,
    geometry: &RigGeometry,
    base: Calibration,
    albedo: f32,
    settings: &CameraSettings,
    e_per_dn: f32,
    rep: &mut Reporter,
) -> Result<Calibration> {
    rep.stage("calibrate", format!("white scan of a reference of albedo {albedo}"));
    crate::session::configure_camera(camera, settings, rep).await?;
    let plan = CapturePlan {
        steps: 48,
        first_mm: geometry.gantry.travel_min_mm,
        last_mm: geometry.gantry.travel_max_mm,
        leds: (0..geometry.bar.n_leds).collect(),
        exposures_us: vec![settings.exposure_us],
        gain: settings.gain,
        dark_frames: 0,
    };
    plan.validate(geometry)?;
    // Solve relative to a nominal calibration: unit LEDs, no flat field,
    // Lambertian profile, the dark scan's black level.
    let nominal = Calibration {
        led_scale: vec![1.0; geometry.bar.n_leds as usize],
        profile_exponent: 1.0,
        flat_field: Vec::new(),
        flat_field_grid: None,
        ..base.clone()
    };
    let inputs = FitInputs {
        geometry: geometry.clone(),
        plan: plan.clone(),
        calibration: nominal.clone(),
        grid: PointGrid { cols: 24, rows: 24 },
        e_per_dn,
        bit_depth: 12,
    };
    let ctx = FitContext::new(inputs);
    let mut acc = fit::calibrate::WhiteAccumulator::new(&ctx, albedo);
    let shots = plan.shots();
    let total = shots.len() as u64;
    let started = std::time::Instant::now();
    let mut at = None;
    for (k, s) in shots.iter().enumerate() {
        if at != Some(s.position_um) {
            rig.all_off().await?;
            rig.move_to(s.position_um).await?;
            at = Some(s.position_um);
        }
        let lit = rig.led_on(s.led).await?;
        let f = camera.frame_after(clock::to_mono(lit), Duration::from_secs(5)).await?;
        tokio::task::block_in_place(|| acc.push_shot(s, &f));
        let done = k as u64 + 1;
        let rate = done as f64 / started.elapsed().as_secs_f64().max(1e-9);
        rep.emit(Event::Frames { done, total, rate_hz: rate, eta_s: (total - done) as f64 / rate.max(1e-9) });
    }
    rig.all_off().await?;
    let solved = tokio::task::block_in_place(|| acc.solve(&nominal, crate::paths::utc_stamp()))
        .context("the white scan had too few usable samples (is the reference in place and lit?)")?;
    rep.stage(
        "calibrate",
        format!(
            "LED intensities spread {:.1}%, emission profile cos^{:.2}, fit residual {:.1}%",
            100.0 * spread(&solved.led_scale),
            solved.profile_exponent,
            100.0 * solved.residual_rms
        ),
    );
    Ok(solved)
}

fn spread(v: &[f32]) -> f32 {
    let m = v.iter().sum::<f32>() / v.len().max(1) as f32;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f32>() / v.len().max(1) as f32).sqrt() / m.max(1e-30)
}

/// What the operator is asked to do for each view of the geometric scan
/// (the simulated operator does it as `sim::truth::target_placements`).
pub const TARGET_VIEWS: [&str; 4] = [
    "lay the checkerboard target flat in the sample holder, centred, its rows along the gantry's travel",
    "prop the target up about 20 degrees, tilted toward the camera",
    "prop the target up about 20 degrees, tilted toward the first LED's end of the bar",
    "prop the target up about 20 degrees, tilted toward the last LED's end of the bar",
];

/// Geometric scan: the checkerboard target in each of the
/// [`TARGET_VIEWS`], lit by every LED from the carriage positions where the
/// bar hides nothing (`fit::geometric::lighting_positions`), the frames of
/// each view summed less its dark frames; the camera solved from the
/// corners (`fit::geometric`).
pub async fn geometry<K: Connector>(
    rig: &mut Rig<K>,
    camera: &mut crate::session::RigCamera,
    filed: &RigGeometry,
    base: Calibration,
    settings: &CameraSettings,
    rep: &mut Reporter,
) -> Result<Calibration> {
    use fit::geometric::{Luma, detect_corners, grid_corners, solve_camera};
    let target = CheckerTarget::default();
    rep.stage(
        "calibrate",
        format!(
            "geometric scan: a {n} x {n} checkerboard of {} mm squares in {} views",
            target.square_mm,
            TARGET_VIEWS.len(),
            n = target.squares
        ),
    );
    let settings = CameraSettings {
        exposure_us: settings.exposure_us.saturating_mul(fit::geometric::EXPOSURE_FACTOR),
        ..settings.clone()
    };
    crate::session::configure_camera(camera, &settings, rep).await?;
    let positions_mm = fit::geometric::lighting_positions(filed);
    if positions_mm.is_empty() {
        bail!("the rig file's bar hides part of the sample from the camera at every carriage position");
    }
    let leds: Vec<u8> = (0..filed.bar.n_leds).collect();
    let dark = fit::geometric::DARK_FRAMES_PER_VIEW;
    let lit = positions_mm.len() * leds.len();
    let total = (TARGET_VIEWS.len() * (lit + dark as usize)) as u64;
    let started = std::time::Instant::now();
    let mut done = 0u64;
    let mut views = Vec::new();
    for (v, ask) in TARGET_VIEWS.iter().enumerate() {
        place_target(camera, v, ask, &target, rep).await?;
        let mut luma = Luma::new(filed.camera.width, filed.camera.height);
        rig.all_off().await?;
        let off = clock::to_mono(tokio::time::Instant::now());
        for _ in 0..dark {
            let f = camera.frame_after(off, Duration::from_secs(5)).await?;
            if !luma.add(&f, -(lit as f32) / dark as f32) {
                bail!("the camera delivered {}x{} frames, not {}x{}", f.width, f.height, luma.width, luma.height);
            }
            done += 1;
            rig.keepalive().await?;
        }
        for &x in &positions_mm {
            rig.all_off().await?;
            rig.move_to((x * 1000.0).round() as i32).await?;
            for &led in &leds {
                let lit = rig.led_on(led).await?;
                let f = camera.frame_after(clock::to_mono(lit), Duration::from_secs(5)).await?;
                if !luma.add(&f, 1.0) {
                    bail!("the camera delivered {}x{} frames, not {}x{}", f.width, f.height, luma.width, luma.height);
                }
                done += 1;
                let rate = done as f64 / started.elapsed().as_secs_f64().max(1e-9);
                rep.emit(Event::Frames { done, total, rate_hz: rate, eta_s: (total - done) as f64 / rate.max(1e-9) });
            }
        }
        rig.all_off().await?;
        let seen = tokio::task::block_in_place(|| grid_corners(v, &detect_corners(&luma), &target, &filed.camera))?;
        rep.stage("calibrate", format!("view {}: all {} corners found", v + 1, seen.len()));
        views.push(seen);
    }
    let sol = tokio::task::block_in_place(|| solve_camera(&target, &views, &filed.camera))?;
    let c = sol.camera;
    let moved = (c.position_mm - filed.camera.position_mm).length();
    rep.stage(
        "calibrate",
        format!(
            "camera: reprojection {:.2} px RMS ({:.2} px worst, {} corners); {:.1} mm from the rig file's position, \
             field of view {:.2} degrees (filed {:.2}), principal point {:+.1}, {:+.1} px off centre, distortion k1 {:+.3}",
            sol.rms_px,
            sol.max_px,
            sol.corners,
            moved,
            c.fov_y_deg,
            filed.camera.fov_y_deg,
            c.principal_offset_px.x,
            c.principal_offset_px.y,
            c.radial_k[0]
        ),
    );
    if sol.rms_px > 0.3 {
        rep.warn(format!(
            "the target's corners fit the camera to {:.2} px RMS (expected below 0.3): check that the target is flat \
             and was still during each view",
            sol.rms_px
        ));
    }
    if moved > 20.0 {
        rep.warn(format!("the camera is {moved:.0} mm from where the rig file puts it: correct the rig file"));
    }
    let id = crate::paths::utc_stamp();
    Ok(Calibration {
        id: id.clone(),
        camera: Some(setup::calibration::CameraCalibration {
            id,
            camera: c,
            rms_px: sol.rms_px,
            max_px: sol.max_px,
            corners: sol.corners as u32,
            views: views.len() as u32,
        }),
        ..base
    })
}

/// Put the target in view `v`'s placement: the simulated operator does it;
/// on hardware the operator is asked and confirms.
async fn place_target(
    camera: &mut crate::session::RigCamera,
    v: usize,
    ask: &str,
    target: &CheckerTarget,
    rep: &mut Reporter,
) -> Result<()> {
    match camera {
        crate::session::RigCamera::Sim(c) => {
            rep.stage("calibrate", format!("view {}: the simulated operator will {ask}", v + 1));
            let placement = sim::truth::target_placements().get(v).copied().flatten();
            tokio::task::block_in_place(|| c.restage(std::sync::Arc::new(sim::materials::Target(*target)), placement));
            Ok(())
        }
        #[cfg(target_os = "linux")]
        crate::session::RigCamera::V4l2(_) => operator_confirms(&format!("view {}: {ask}", v + 1)).await,
    }
}

/// Ask the operator to do something and wait for Enter; refused without a
/// terminal (nobody is there to do it).
#[cfg(target_os = "linux")]
async fn operator_confirms(what: &str) -> Result<()> {
    use std::io::IsTerminal;
    if !std::io::stdin().is_terminal() {
        bail!("the geometric calibration needs an operator to place the target ({what}): run it in a terminal");
    }
    let prompt = format!("{what}; then press Enter");
    tokio::task::spawn_blocking(move || {
        eprintln!("{prompt}");
        let mut line = String::new();
        std::io::stdin().read_line(&mut line).map(|_| ())
    })
    .await
    .context("the prompt's thread failed")?
    .context("cannot read the operator's answer")
}
