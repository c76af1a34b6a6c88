//! Geometric calibration on the simulated rig: a camera that departs from
//! its rig file (pose, focal length, principal point, distortion, drawn as
//! a perturbed rig) is recovered from the checkerboard target, through the
//! simulated sensor (Bayer mosaic, noise, the LEDs' uneven light).

use fit::geometric::{Luma, detect_corners, grid_corners, solve_camera};
use setup::{CheckerTarget, RigGeometry};
use sim::camera::{CameraTiming, LedTruth, SensorModel, SimCamera, SimCameraConfig};

/// The views of `capture --calibrate geometry`, rendered directly: every
/// LED from each lighting position, summed per view, less the dark frames.
fn views(truth: sim::RigTruth, seed: u64) -> (Vec<Luma>, RigGeometry) {
    let filed = RigGeometry::default();
    let target = CheckerTarget::default();
    let cfg = SimCameraConfig {
        truth,
        sensor: SensorModel::default(),
        leds: LedTruth::realistic(40, seed),
        timing: CameraTiming::Fast { time_scale: 0.0 },
        seed,
        faults: sim::FaultSpec::none(),
        rest_um: 0.0,
    };
    let mut cam = SimCamera::new(cfg, std::sync::Arc::new(sim::materials::Target(target)), sim::World::new());
    cam.set_exposure_direct(20_000 * fit::geometric::EXPOSURE_FACTOR, 1.0);
    let mut out = Vec::new();
    for placement in sim::truth::target_placements() {
        cam.restage(std::sync::Arc::new(sim::materials::Target(target)), placement);
        let mut luma = Luma::new(filed.camera.width, filed.camera.height);
        let positions = fit::geometric::lighting_positions(&filed);
        let dark = fit::geometric::DARK_FRAMES_PER_VIEW;
        let lit = (positions.len() * 40) as f32;
        for _ in 0..dark {
            assert!(luma.add(&cam.render_direct(0, None), -lit / dark as f32));
        }
        for x in positions {
            for led in 0..40 {
                assert!(luma.add(&cam.render_direct((x * 1000.0) as i32, Some(led)), 1.0));
            }
        }
        out.push(luma);
    }
    (out, filed)
}

#[test]
fn the_camera_of_a_perturbed_rig_is_recovered() {
    let target = CheckerTarget::default();
    // Three drawn rigs, and one whose only faults are the sensor's and the
    // room's (hot pixels, dark current, ambient light: specks a corner
    // detector can take for corners).
    let sensor_only = sim::Tolerances::default().keeping(false, false, false, false, true);
    let filed = RigGeometry::default();
    let rigs = [
        (1u64, sim::RigTruth::perturbed(&filed, 1)),
        (3, sim::RigTruth::perturbed(&filed, 3)),
        (11, sim::RigTruth::perturbed(&filed, 11)),
        (1, sim::RigTruth::drawn(&filed, &sensor_only, 1)),
    ];
    for (seed, truth) in rigs {
        let true_cam = truth.geometry.camera;
        // The calibration measures the camera in the frame of the sample's
        // surface (where the target lay), which the perturbed rig tilts and
        // raises: compare there.
        let (to_rig, origin) = truth.sample_frame();
        let surface = |p: glam::Vec3| to_rig * p + origin;
        let true_position = to_rig.transpose() * (true_cam.position_mm - origin);
        let (lumas, filed) = views(truth, seed);
        let seen: Vec<_> = lumas
            .iter()
            .enumerate()
            .map(|(v, l)| grid_corners(v, &detect_corners(l), &target, &filed.camera).unwrap())
            .collect();
        let sol = solve_camera(&target, &seen, &filed.camera).unwrap();
        let c = sol.camera;
        let before =
            (filed.camera.project(glam::Vec3::ZERO).unwrap() - true_cam.project(glam::Vec3::ZERO).unwrap()).length();
        eprintln!(
            "seed {seed}: reprojection {:.3} px RMS ({:.3} worst); position off {:.2} mm (rig file: {:.2} mm), \
             principal point {} (true {}), fov {} (true {}), k1 {} (true {}); the rig file missed the centre by {before:.1} px",
            sol.rms_px,
            sol.max_px,
            (c.position_mm - true_position).length(),
            (filed.camera.position_mm - true_cam.position_mm).length(),
            c.principal_offset_px,
            true_cam.principal_offset_px,
            c.fov_y_deg,
            true_cam.fov_y_deg,
            c.radial_k[0],
            true_cam.radial_k[0]
        );
        // The requirement.
        assert!(sol.rms_px < 0.3, "seed {seed}: reprojection {} px", sol.rms_px);
        // What the fitter needs: where each sample point is seen, to a
        // fraction of the 2.5 px a point's value reaches over, and the
        // direction toward the camera to a fraction of a degree (2 mm at
        // 450 mm is 0.25 degrees; the LEDs' half vectors are 3-7 degrees
        // apart).
        for p in [glam::Vec3::ZERO, glam::Vec3::new(45.0, -45.0, 0.0), glam::Vec3::new(-45.0, 45.0, 0.0)] {
            let e = (c.project(p).unwrap() - true_cam.project(surface(p)).unwrap()).length();
            assert!(e < 0.3, "seed {seed}: {p} is seen {e} px from where the calibration puts it");
        }
        assert!((c.position_mm - true_position).length() < 2.0, "seed {seed}: {}", c.position_mm);
    }
}
