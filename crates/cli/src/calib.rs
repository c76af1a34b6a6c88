//! Calibrations: where they are kept, and the scans that produce them
//! (`capture --calibrate dark|white|geometry|all`).

use std::time::Duration;

use anyhow::{Context, Result, bail};
use fit::{FitContext, FitInputs};
use frame::Frame;
use rig::camera::{Camera, CameraSettings};
use rig::clock;
use rig::mcu::{Connector, Rig};
use setup::{Calibration, CheckerTarget, RigGeometry};

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
    let frames = dark_frames(rig, camera, DARK_FRAMES).await?;
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

/// White scan: dark frames, then the white reference under every LED at
/// every step of a plan; solves LED intensities, emission profile and flat
/// field (and the scale of a mirror scan's LEDs, `fit::calibrate`).
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
    let plan = fit::calibrate::white_plan(geometry, settings.exposure_us, settings.gain);
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
        grid: fit::calibrate::WHITE_GRID,
        e_per_dn,
        bit_depth: 12,
        sensor_layout: None,
    };
    let ctx = FitContext::new(inputs);
    let mut acc = fit::calibrate::WhiteAccumulator::new(&ctx, albedo);
    // Dark frames at the scan's exposure: the room's light and the
    // sensor's dark current, pixel by pixel, which the white frames carry
    // and a black level does not remove.
    for f in dark_frames(rig, camera, DARK_FRAMES).await? {
        acc.push_dark(&f);
    }
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
        let f = lit_frame(rig, camera, s.led).await?;
        tokio::task::block_in_place(|| acc.push_shot(s, &f));
        frames_done(rep, k as u64 + 1, total, started);
    }
    rig.all_off().await?;
    let solved = tokio::task::block_in_place(|| acc.solve(&nominal, crate::paths::utc_stamp()))
        .context("the white scan had too few usable samples (is the reference in place and lit?)")?;
    if let Some(l) = &solved.lights {
        let off = l.white_scale / base_scale(&base) - 1.0;
        rep.stage(
            "calibrate",
            format!(
                "the light's fall-off across the white scales the LEDs' distances from the camera's mirror image by \
                 {:+.3}% (the mirror left them +-{:.3}%)",
                100.0 * off,
                100.0 * l.scale_sd
            ),
        );
        let unmeasured = l.led_mm.len().saturating_sub(l.measured.len());
        if unmeasured > 0 {
            rep.stage(
                "calibrate",
                format!(
                    "placed {} of the {unmeasured} LEDs the mirror did not see by how their light falls off across \
                     the white (the rest stay on the line through the measured ones)",
                    l.white_placed.len()
                ),
            );
        }
        if off.abs() > 0.95 * fit::calibrate::SCALE_SEARCH_SDS as f32 * l.scale_sd {
            rep.warn(
                "the white scan and the mirror scan disagree about the LEDs' distances by more than the build's \
                 tolerances allow: check that the white reference lay where the mirror did, and the rig file's LED \
                 pitch",
            );
        }
    }
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

/// How long a scan waits for a frame before it gives up on the camera.
const FRAME_TIMEOUT: Duration = Duration::from_secs(5);

/// `n` frames with every LED off.
async fn dark_frames<K: Connector, C: Camera>(rig: &mut Rig<K>, camera: &mut C, n: u32) -> Result<Vec<Frame>> {
    rig.all_off().await?;
    let off = clock::to_mono(tokio::time::Instant::now());
    let mut frames = Vec::with_capacity(n as usize);
    for _ in 0..n {
        frames.push(camera.frame_after(off, FRAME_TIMEOUT).await?);
        rig.keepalive().await?;
    }
    Ok(frames)
}

/// The frame taken with LED `led` lit (the carriage where it is).
async fn lit_frame<K: Connector, C: Camera>(rig: &mut Rig<K>, camera: &mut C, led: u8) -> Result<Frame> {
    let lit = rig.led_on(led).await?;
    Ok(camera.frame_after(clock::to_mono(lit), FRAME_TIMEOUT).await?)
}

/// Add `weight` times `f` to `luma`; a frame of another size than the
/// camera's is refused.
fn add_frame(luma: &mut fit::geometric::Luma, f: &Frame, weight: f32) -> Result<()> {
    if !luma.add(f, weight) {
        bail!("the camera delivered {}x{} frames, not {}x{}", f.width, f.height, luma.width, luma.height);
    }
    Ok(())
}

/// Report `done` of a scan's `total` frames, taken since `started`.
fn frames_done(rep: &mut Reporter, done: u64, total: u64, started: std::time::Instant) {
    let rate = done as f64 / started.elapsed().as_secs_f64().max(1e-9);
    rep.emit(Event::Frames { done, total, rate_hz: rate, eta_s: total.saturating_sub(done) as f64 / rate.max(1e-9) });
}

/// The white scale `base`'s LEDs already had (a white scan after another
/// starts from the last one's LEDs).
fn base_scale(base: &Calibration) -> f32 {
    base.lights.as_ref().map_or(1.0, |l| l.white_scale)
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
/// corners (`fit::geometric`); then the mirror scan ([`MIRROR_VIEW`]), the
/// LEDs and the carriage's travel solved with that camera (`fit::mirror`).
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
    let default = settings.clone();
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
        place(camera, Holder::Target { v, ask, target: &target }, rep).await?;
        let mut luma = Luma::new(filed.camera.width, filed.camera.height);
        for f in dark_frames(rig, camera, dark).await? {
            add_frame(&mut luma, &f, -(lit as f32) / dark as f32)?;
            done += 1;
        }
        for &x in &positions_mm {
            rig.all_off().await?;
            rig.move_to((x * 1000.0).round() as i32).await?;
            for &led in &leds {
                add_frame(&mut luma, &lit_frame(rig, camera, led).await?, 1.0)?;
                done += 1;
                frames_done(rep, done, total, started);
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
    let lights = mirror_scan(rig, camera, filed, &c, &default, rep).await?;
    Ok(Calibration {
        id: id.clone(),
        camera: Some(setup::calibration::CameraCalibration {
            id: id.clone(),
            camera: c,
            rms_px: sol.rms_px,
            max_px: sol.max_px,
            corners: sol.corners as u32,
            views: views.len() as u32,
        }),
        lights: Some(setup::calibration::LightCalibration { id, ..lights }),
        ..base
    })
}

/// What the operator is asked to do before the mirror scan.
pub const MIRROR_VIEW: &str =
    "lay the front-surface mirror flat in the sample holder, mirror side up, in place of the target";

/// The mirror scan: every LED at every carriage position of
/// `fit::mirror::scan_positions`, each frame less the mean of the dark
/// frames, its highlight found; the LEDs and the carriage's travel solved
/// from them with the calibrated `camera` (`fit::mirror`).
async fn mirror_scan<K: Connector>(
    rig: &mut Rig<K>,
    camera: &mut crate::session::RigCamera,
    filed: &RigGeometry,
    measured: &setup::CameraModel,
    default: &CameraSettings,
    rep: &mut Reporter,
) -> Result<setup::calibration::LightCalibration> {
    use fit::geometric::Luma;
    use fit::mirror::{
        DARK_FRAMES, EXPOSURE_DIVISOR, Highlight, backlash, find_highlight, return_positions, scan_positions,
        solve_lights,
    };
    place(camera, Holder::Mirror, rep).await?;
    let settings = CameraSettings { exposure_us: (default.exposure_us / EXPOSURE_DIVISOR).max(1), ..default.clone() };
    crate::session::configure_camera(camera, &settings, rep).await?;
    let positions = scan_positions(filed);
    if positions.len() < 3 {
        bail!("the rig file's geometry leaves fewer than 3 carriage positions whose highlights land on the mirror");
    }
    let (w, h) = (filed.camera.width, filed.camera.height);
    let mut dark = Luma::new(w, h);
    let mut top = 0.0f32;
    for f in dark_frames(rig, camera, DARK_FRAMES).await? {
        top = ((1u64 << f.bit_depth.min(32)) - 1) as f32;
        add_frame(&mut dark, &f, -1.0 / DARK_FRAMES as f32)?;
    }
    // Saturated pixels (within a few read-noise widths of the top code,
    // less the black level the dark frames removed) carry no shape.
    let black = -dark.data.iter().sum::<f32>() / dark.data.len().max(1) as f32;
    let ceiling = 0.98 * (top - black);
    let leds: Vec<u8> = (0..filed.bar.n_leds).collect();
    let back = return_positions(&positions);
    let total = ((positions.len() + back.len()) * leds.len()) as u64;
    let started = std::time::Instant::now();
    let mut done = 0u64;
    let (mut found, mut down) = (Vec::new(), Vec::new());
    // Every position approached from below, as a capture's are, so the
    // gantry's backlash is taken up the same way. Then a few again from
    // above (`back`): the lead screw's backlash, which the scans and
    // captures design out by approaching from below, but which a worn nut
    // shows.
    rig.move_to(((positions[0] - 5.0).max(filed.gantry.travel_min_mm) * 1000.0).round() as i32).await?;
    let last = positions[positions.len() - 1];
    let visits = positions.iter().map(|&x| (x, true)).chain(back.iter().map(|&x| (x, false)));
    for (x, up) in visits {
        rig.all_off().await?;
        if !up && x == back[0] {
            // Past the top, to come down onto the first return position.
            rig.move_to(((last + 5.0).min(filed.gantry.travel_max_mm) * 1000.0).round() as i32).await?;
        }
        rig.move_to((x * 1000.0).round() as i32).await?;
        for &led in &leds {
            let mut img = dark.clone();
            add_frame(&mut img, &lit_frame(rig, camera, led).await?, 1.0)?;
            if let Some(pixel) = tokio::task::block_in_place(|| find_highlight(&img, ceiling)) {
                (if up { &mut found } else { &mut down }).push(Highlight { led, commanded_mm: x, pixel });
            }
            done += 1;
            frames_done(rep, done, total, started);
        }
    }
    rig.all_off().await?;
    let sol = tokio::task::block_in_place(|| solve_lights(&found, measured, filed))?;
    let play = backlash(&found, &down);
    if let Some(b) = play {
        rep.stage(
            "calibrate",
            format!(
                "the gantry's backlash {:.3} mm (+-{:.4}, {} highlights seen from both directions); every scan and \
                 capture approaches its positions from below, so it does not enter a fit",
                b.mm, b.sd_mm, b.pairs
            ),
        );
        if b.mm.abs() > BACKLASH_WARN_MM {
            rep.warn(format!(
                "the gantry's backlash is {:.2} mm, more than a lead screw's {BACKLASH_WARN_MM} mm: check the \
                 carriage's nut and coupling (a loose carriage also wanders between frames)",
                b.mm
            ));
        }
    }
    let nominal_mid = filed.bar.led_position(0.0, filed.bar.n_leds / 2);
    let mid = sol.led_mm[(filed.bar.n_leds / 2) as usize];
    rep.stage(
        "calibrate",
        format!(
            "LEDs: {} measured from {} highlights (the others on the line through them until the white scan places \
             them), {:.3} mm RMS from their rays ({:.3} mm worst); the middle LED {:.2} mm from the rig file's place, at height {:.2} mm \
             (filed {:.2}); the gantry's scale {:+.2}% (+-{:.2}% from the build's tolerances: a mirror cannot see it)",
            sol.measured.len(),
            sol.used,
            sol.rms_mm,
            sol.max_mm,
            (mid - nominal_mid).length(),
            mid.z,
            nominal_mid.z,
            100.0 * (sol.travel_mm.length() - 1.0),
            100.0 * sol.scale_sd
        ),
    );
    if sol.rms_mm > 0.1 {
        rep.warn(format!(
            "the LEDs fit their highlights to {:.2} mm RMS (expected below 0.1): check that the mirror is flat and \
             clean and lay where the target did",
            sol.rms_mm
        ));
    }
    Ok(setup::calibration::LightCalibration {
        id: String::new(),
        led_mm: sol.led_mm,
        travel_mm: sol.travel_mm,
        measured: sol.measured,
        highlights: sol.used as u32,
        rms_mm: sol.rms_mm,
        max_mm: sol.max_mm,
        scale_sd: sol.scale_sd,
        white_scale: 1.0,
        white_placed: Vec::new(),
        backlash_mm: play.map(|b| b.mm),
    })
}

/// A backlash beyond this is reported as a mechanical fault: twice the
/// largest a bench rig's lead screw is taken to have (RIGFILE.md's
/// tolerances, 0.1 mm).
const BACKLASH_WARN_MM: f32 = 0.2;

/// What the geometric scan has the operator put in the sample holder.
enum Holder<'a> {
    /// The checkerboard in view `v`'s placement, as `ask` says.
    Target { v: usize, ask: &'a str, target: &'a CheckerTarget },
    /// The front-surface mirror, flat ([`MIRROR_VIEW`]).
    Mirror,
}

/// Put `what` in the sample holder: the simulated operator does it; on
/// hardware the operator is asked and confirms.
async fn place(camera: &mut crate::session::RigCamera, what: Holder<'_>, rep: &mut Reporter) -> Result<()> {
    let (ask, step) = match &what {
        Holder::Target { v, ask, .. } => (*ask, format!("view {}", v + 1)),
        Holder::Mirror => (MIRROR_VIEW, "mirror".to_string()),
    };
    match camera {
        crate::session::RigCamera::Sim(c) => {
            rep.stage("calibrate", format!("{step}: the simulated operator will {ask}"));
            let (material, placement): (std::sync::Arc<dyn material::SvBrdf>, _) = match what {
                Holder::Target { v, target, .. } => (
                    std::sync::Arc::new(sim::materials::Target(*target)),
                    sim::truth::target_placements().get(v).copied().flatten(),
                ),
                Holder::Mirror => (std::sync::Arc::new(sim::materials::Mirror), None),
            };
            tokio::task::block_in_place(|| c.restage(material, placement));
            Ok(())
        }
        #[cfg(target_os = "linux")]
        crate::session::RigCamera::V4l2(_) => operator_confirms(&format!("{step}: {ask}")).await,
    }
}

/// Ask the operator to do something and wait for Enter; refused without a
/// terminal (nobody is there to do it).
#[cfg(target_os = "linux")]
async fn operator_confirms(what: &str) -> Result<()> {
    use std::io::IsTerminal;
    if !std::io::stdin().is_terminal() {
        bail!("the geometric calibration needs an operator at the rig ({what}): run it in a terminal");
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
