//! Radiometric calibration on the simulated rig: the dark scan recovers the
//! black level and read noise, the white scan the LEDs' intensity spread,
//! their emission profile and the flat field.

#[path = "support/simfit.rs"]
#[allow(dead_code)]
mod simfit;

use fit::{FitContext, FitInputs};
use setup::{Calibration, CameraModel, CapturePlan, PointGrid, RigGeometry};
use sim::camera::{CameraTiming, LedTruth, SensorModel, SimCamera, SimCameraConfig};

#[test]
fn white_scan_recovers_led_spread_profile_and_flat_field() {
    let mut geometry = RigGeometry::default();
    geometry.camera = CameraModel::oblique(45.0, 450.0, 15.0, 96, 96);
    let sensor = SensorModel::default();
    let truth = LedTruth::realistic(40, 5);
    let cfg = SimCameraConfig {
        truth: sim::RigTruth::ideal(&geometry),
        sensor: sensor.clone(),
        leds: truth.clone(),
        timing: CameraTiming::Fast { time_scale: 0.0 },
        seed: 5,
        faults: sim::FaultSpec::none(),
        rest_um: 0.0,
    };
    let mut cam = SimCamera::new(cfg, sim::materials::builtin("white").unwrap(), sim::World::new());
    cam.set_exposure_direct(20_000, 1.0);
    let plan = CapturePlan {
        steps: 24,
        first_mm: -120.0,
        last_mm: 120.0,
        leds: (0..40).collect(),
        exposures_us: vec![20_000],
        gain: 1.0,
        dark_frames: 0,
    };
    let mut base = Calibration::nominal(40, 1.0, sensor.black_level_dn);
    base.read_noise_dn = [2.0; 3];
    let inputs = FitInputs {
        geometry,
        plan: plan.clone(),
        calibration: base.clone(),
        grid: PointGrid { cols: 16, rows: 16 },
        e_per_dn: sensor.e_per_dn(),
        bit_depth: 12,
    };
    let ctx = FitContext::new(inputs);
    let mut acc = fit::calibrate::WhiteAccumulator::new(&ctx, sim::materials::WHITE_ALBEDO);
    for s in plan.shots() {
        let f = cam.render_direct(s.position_um, Some(s.led));
        acc.push_shot(&s, &f);
    }
    let c = acc.solve(&base, "t".into()).expect("solvable");
    // Relative LED intensities: compare normalised spreads.
    let norm = |v: &[f32]| -> Vec<f32> {
        let m = v.iter().sum::<f32>() / v.len() as f32;
        v.iter().map(|x| x / m).collect()
    };
    let (est, tru) = (norm(&c.led_scale), norm(&truth.scale));
    let worst = est.iter().zip(&tru).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    eprintln!(
        "profile {} (true {}), residual {}, worst LED error {worst}",
        c.profile_exponent, truth.profile_exponent, c.residual_rms
    );
    assert!((c.profile_exponent - truth.profile_exponent).abs() < 0.05, "profile {}", c.profile_exponent);
    assert!(worst < 0.01, "LED intensity error {worst}");
    assert!(c.residual_rms < 0.03, "residual {}", c.residual_rms);
}
