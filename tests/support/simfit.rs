//! A simulated capture rendered directly (no MCU, no timing) and fitted:
//! the fastest way to test the fitter against ground truth.

use std::sync::Arc;

use brdf::ndf::NdfTable;
use fit::{FitContext, FitInputs, FitSettings, Pipeline, PointMaps, SampleStore, Stages};
use material::SvBrdf;
use setup::{Calibration, CameraModel, CapturePlan, PointGrid, RigGeometry};
use sim::camera::{CameraTiming, LedTruth, SensorModel, SimCamera, SimCameraConfig};

pub struct Scenario {
    pub material: Arc<dyn SvBrdf>,
    pub camera_px: u32,
    pub grid: u32,
    pub steps: u32,
    pub led_stride: u8,
    pub exposures_us: Vec<u32>,
    pub seed: u64,
}

pub struct Fitted {
    pub ctx: FitContext,
    pub store: SampleStore,
    pub maps: PointMaps,
    pub settings: FitSettings,
}

pub fn run(s: &Scenario, settings: FitSettings) -> Fitted {
    let mut geometry = RigGeometry::default();
    geometry.camera = CameraModel::oblique(45.0, 450.0, 15.0, s.camera_px, s.camera_px);
    let plan = CapturePlan {
        steps: s.steps,
        first_mm: -120.0,
        last_mm: 120.0,
        leds: (0..40).step_by(s.led_stride as usize).collect(),
        exposures_us: s.exposures_us.clone(),
        gain: 1.0,
        dark_frames: 4,
        bracket: setup::Bracket::Every,
    };
    let sensor = SensorModel::default();
    let leds = LedTruth { scale: vec![1.0; 40], profile_exponent: 1.0, nominal_current_ma: 200 };
    let cfg = SimCameraConfig {
        truth: sim::RigTruth::ideal(&geometry),
        sensor: sensor.clone(),
        leds,
        timing: CameraTiming::Fast { time_scale: 0.0 },
        seed: s.seed,
        faults: sim::FaultSpec::none(),
        rest_um: 0.0,
    };
    let mut cam = SimCamera::new(cfg, s.material.clone(), sim::World::new());
    // The true calibration: LED intensity in DN per second per unit
    // reflectance (sensitivity / electrons per DN), the true profile.
    let mut cal = Calibration::nominal(40, 1.0, sensor.black_level_dn);
    cal.led_scale = vec![sensor.sensitivity / sensor.e_per_dn(); 40];
    // The lens's vignetting as the flat field (a white scan measures it).
    let grid = PointGrid { cols: s.grid, rows: s.grid };
    cal.flat_field = (0..grid.len())
        .map(|i| {
            let p = grid.position_of(&geometry.sample, i).extend(0.0);
            geometry.camera.project(p).map_or(1.0, |px| geometry.camera.vignetting(px))
        })
        .collect();
    cal.flat_field_grid = Some(grid);
    cal.read_noise_dn = [sensor.read_noise_e / sensor.e_per_dn(); 3];
    let inputs = FitInputs {
        geometry,
        plan: plan.clone(),
        calibration: cal,
        grid: PointGrid { cols: s.grid, rows: s.grid },
        e_per_dn: sensor.e_per_dn(),
        bit_depth: sensor.bit_depth,
        sensor_layout: Some(frame::Layout::Bayer { pattern: sensor.pattern }),
    };
    let ctx = FitContext::new(inputs);
    let stages = Stages { keep_samples: true, ..Stages::default() };
    let mut pipeline = Pipeline::new(&ctx, settings.clone(), stages);
    for (e, &us) in plan.exposures_us.iter().enumerate() {
        cam.set_exposure_direct(us, plan.gain);
        for _ in 0..plan.dark_frames {
            let f = cam.render_direct(0, None);
            pipeline.push_dark(e as u8, &f);
        }
    }
    for shot in plan.shots() {
        cam.set_exposure_direct(plan.exposures_us[shot.exposure as usize], plan.gain);
        let f = cam.render_direct(shot.position_um, Some(shot.led));
        pipeline.push_shot(&shot, &f);
    }
    let r = pipeline.finish(&|| false).expect("the scenario has usable samples");
    let store = r.samples.expect("kept");
    Fitted { ctx, store, maps: r.maps, settings }
}

/// The true NDF table of a point, normalised.
pub fn true_table(material: &dyn SvBrdf, f: &Fitted, p: usize) -> Option<NdfTable> {
    let pos = f.ctx.positions[p].truncate();
    let pm = material.at(pos);
    let ndf = pm.ndf()?.clone();
    let mut t = NdfTable::from_ndf(f.settings.grid, &ndf);
    t.normalize();
    Some(t)
}
