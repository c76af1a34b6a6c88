//! Calibrations: where they are kept, and the dark and white scans that
//! produce them (`capture --calibrate dark|white`).

use std::time::Duration;

use anyhow::{Context, Result, bail};
use fit::{FitContext, FitInputs};
use rig::camera::{Camera, CameraSettings};
use rig::clock;
use rig::mcu::{Connector, Rig};
use setup::{Calibration, CapturePlan, PointGrid, RigGeometry};

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
