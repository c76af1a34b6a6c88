//! Capture directories: refusing to overwrite, lossless round trips, and
//! resuming after a crash with a torn manifest line and a damaged frame.

use std::fs;

use frame::{BayerPattern, Frame, FrameFlags, FrameMeta, Layout, MonoNs};
use setup::{Calibration, CapturePlan, PointGrid, RigGeometry};
use store::{CAPTURE_FORMAT_VERSION, CaptureDir, CaptureInfo, CaptureStatus, FrameKind, SensorInfo, StoreError};

fn info() -> CaptureInfo {
    let g = RigGeometry::default();
    CaptureInfo {
        format_version: CAPTURE_FORMAT_VERSION,
        sample: "satin".into(),
        created_utc: "20261122T000000Z".into(),
        status: CaptureStatus::InProgress,
        plan: CapturePlan::full(&g),
        calibration: Calibration::nominal(40, 1.0, 64.0),
        calibration_source: None,
        geometry: g,
        sensor: SensorInfo { bit_depth: 12, e_per_dn: 3.0, layout: None },
        camera: None,
        grid: PointGrid { cols: 8, rows: 8 },
        settings: serde_json::json!({}),
        simulated: None,
    }
}

fn frame(seed: u16) -> Frame {
    Frame {
        width: 6,
        height: 4,
        layout: Layout::Bayer { pattern: BayerPattern::Rggb },
        bit_depth: 12,
        data: (0..24).map(|k| (k * 37 + seed) % 4096).collect(),
        meta: FrameMeta {
            sequence: seed as u64,
            exposure_start: MonoNs(1000),
            exposure_end: MonoNs(2000),
            exposure_us: 1,
            gain: 1.0,
            flags: FrameFlags::default(),
        },
    }
}

fn shot(i: u32) -> FrameKind {
    FrameKind::Shot(setup::PlannedShot { index: i, step: i / 2, led: (i % 2) as u8, exposure: 0, position_um: 0 })
}

#[test]
fn frames_round_trip_losslessly() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("cap");
    let mut c = CaptureDir::create(&root, info()).unwrap();
    let f = frame(5);
    let e = c.write_frame(shot(0), &f, Some(MonoNs(900)), Some(0)).unwrap();
    let back = CaptureDir::read_frame(&root, &e).unwrap();
    assert_eq!(back, f);
}

#[test]
fn refuses_to_overwrite_another_capture_or_a_foreign_directory() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("cap");
    CaptureDir::create(&root, info()).unwrap();
    assert!(matches!(CaptureDir::create(&root, info()), Err(StoreError::AnotherCapture { .. })));
    let other = d.path().join("photos");
    fs::create_dir_all(&other).unwrap();
    fs::write(other.join("holiday.jpg"), b"x").unwrap();
    assert!(matches!(CaptureDir::create(&other, info()), Err(StoreError::NotEmpty(_))));
    assert_eq!(fs::read(other.join("holiday.jpg")).unwrap(), b"x");
    assert!(matches!(CaptureDir::resume(&other), Err(StoreError::NotACapture(_))));
}

#[test]
fn resume_keeps_verified_frames_and_drops_damaged_ones() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("cap");
    let mut c = CaptureDir::create(&root, info()).unwrap();
    let mut entries = Vec::new();
    for i in 0..5 {
        entries.push(c.write_frame(shot(i), &frame(i as u16), None, None).unwrap());
    }
    drop(c);
    // A crash: a torn manifest line, a damaged frame, a leftover temp file.
    let mut m = fs::read_to_string(root.join(CaptureDir::MANIFEST)).unwrap();
    m.push_str("{\"frame\":{\"kind\":\"shot\",\"ind");
    fs::write(root.join(CaptureDir::MANIFEST), m).unwrap();
    let bad = root.join(&entries[2].file);
    let mut bytes = fs::read(&bad).unwrap();
    let n = bytes.len();
    bytes[n / 2] ^= 0xff;
    fs::write(&bad, bytes).unwrap();
    fs::write(root.join("frames/.s099_l00_e0.png.tmp"), b"partial").unwrap();

    let (c, state) = CaptureDir::resume(&root).unwrap();
    assert!(state.torn_tail);
    assert_eq!(state.damaged, vec![entries[2].file.clone()]);
    let mut done: Vec<_> = state.done_shots.iter().copied().collect();
    done.sort();
    assert_eq!(done, vec![0, 1, 3, 4]);
    assert_eq!(c.entries().len(), 4);
    assert!(!root.join("frames/.s099_l00_e0.png.tmp").exists());
    // The rewritten manifest reads back cleanly.
    let (again, torn) = CaptureDir::read_manifest(&root).unwrap();
    assert_eq!((again.len(), torn), (4, false));
}

#[test]
fn a_corrupted_capture_json_is_a_clear_error() {
    let d = tempfile::tempdir().unwrap();
    let root = d.path().join("cap");
    CaptureDir::create(&root, info()).unwrap();
    fs::write(root.join(CaptureDir::INFO), b"{ not json").unwrap();
    let e = CaptureDir::resume(&root).unwrap_err();
    assert!(matches!(e, StoreError::BadCaptureJson { .. }), "{e}");
}

/// An adaptive bracket's complete capture holds a light's shorter exposure
/// only where its longer one recorded clipped pixels, or recorded no count
/// (a frame from before the counts, which decides nothing).
#[test]
fn the_wanted_shots_follow_the_recorded_clipping() {
    let d = tempfile::tempdir().unwrap();
    let mut i = info();
    i.plan.steps = 1;
    i.plan.leds = vec![0, 1, 2];
    i.plan.exposures_us = vec![20_000, 2_500];
    i.plan.bracket = setup::Bracket::Clipped;
    let plan = i.plan.clone();
    let shots = plan.shots();
    let mut c = CaptureDir::create(&d.path().join("cap"), i).unwrap();
    let indices = |v: Vec<setup::PlannedShot>| v.iter().map(|s| s.index).collect::<Vec<_>>();
    assert_eq!(indices(store::wanted_shots(&plan, c.entries())), vec![0, 1, 2, 3, 4, 5]);
    for (k, clipped) in [(0, Some(12)), (1, Some(0)), (2, None)] {
        c.write_frame(FrameKind::Shot(shots[k]), &frame(k as u16), None, clipped).unwrap();
    }
    assert_eq!(indices(store::wanted_shots(&plan, c.entries())), vec![0, 1, 2, 3, 5]);
    let mut every = plan.clone();
    every.bracket = setup::Bracket::Every;
    assert_eq!(store::wanted_shots(&every, c.entries()).len(), 6);
}
