//! A point near the sample's edge reads pixels that see past it. On a
//! white sample laid on a dark surround, every point the fitter calls
//! measured must read the white albedo, whatever lies beyond the edge; the
//! points it cannot measure are flagged, and the material shows their
//! nearest measured neighbour.
//!
//! Tolerance: `kd` within 3% of the albedo, as in `fit_accuracy.rs` (the
//! mean of hundreds of samples with ~2% shot noise each, plus the sensor's
//! 0.5% pixel response spread). A point that mixes in pixels of the
//! simulator's surround (albedo 0.03) through the bilinear sample or the
//! demosaicing reads darker in some channel, by as much as half (as the
//! outermost points of a 48 x 48 grid did before the fitter checked).

// Shared with the NDF tests; this file does not compare tables.
#[allow(dead_code)]
#[path = "support/simfit.rs"]
mod simfit;

use std::sync::Arc;

use fit::FitSettings;
use fit::partial::point_flag;
use simfit::{Scenario, run};

#[test]
fn no_measured_point_sees_past_the_sample_and_the_rest_borrow_a_neighbour() {
    let s = Scenario {
        material: sim::materials::builtin("white").unwrap(),
        camera_px: 96,
        grid: 24,
        steps: 16,
        led_stride: 4,
        exposures_us: vec![20_000],
        seed: 5,
    };
    let f = run(&s, FitSettings::default());
    let albedo = sim::materials::WHITE_ALBEDO;
    let grid = f.ctx.inputs.grid;
    let sample = f.ctx.inputs.geometry.sample;
    let mut measured = 0;
    for p in 0..grid.len() {
        let pos = f.ctx.positions[p];
        let from_edge = (0.5 * sample.width_mm - pos.x.abs()).min(0.5 * sample.height_mm - pos.y.abs());
        if f.maps.flags[p] & point_flag::OUT_OF_VIEW != 0 {
            // 2.5 pixels of this camera are under 4 mm on the sample.
            assert!(from_edge < 4.0, "point {p}, {from_edge:.1} mm from the edge, was not measured");
            continue;
        }
        measured += 1;
        for c in 0..3 {
            let kd = f.maps.kd[p][c];
            assert!((kd - albedo).abs() <= 0.03 * albedo, "point {p} ({from_edge:.1} mm from the edge): kd {kd}");
        }
    }
    // The outermost ring (2 mm from the edge) is within reach of the edge.
    assert!(measured <= 22 * 22, "{measured} points measured");
    // What the material shows there: a measured neighbour's reflectance.
    let m = material::Material {
        name: "white".into(),
        sample,
        grid,
        kd: f.maps.kd.clone(),
        ks: f.maps.ks.clone(),
        eta: f.maps.eta.clone(),
        flags: f.maps.flags.clone(),
        ndf: Some(f.maps.tables.clone()),
        ndf_kind: material::NdfKind::Partial,
        partial: None,
        models: Default::default(),
        choice: None,
        provenance: Default::default(),
    };
    let view = material::MaterialView::new(Arc::new(m), material::ModelChoice::Tabulated).unwrap();
    let corner = glam::Vec2::new(-0.5 * sample.width_mm + 0.5, 0.5 * sample.height_mm - 0.5);
    let kd = material::SvBrdf::at(&view, corner).kd();
    assert!((kd.x - albedo).abs() <= 0.03 * albedo, "the corner shows kd {kd}");
}
