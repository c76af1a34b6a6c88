//! The material format: lossless round trip, atomic replacement, and clear
//! rejection of malformed or inconsistent files.

use std::collections::BTreeMap;
use std::fs;

use brdf::ndf::{Beckmann, NdfGrid, NdfTable, TableSet};
use brdf::params::AnalyticModel;
use material::{Choice, ChoiceMap, Material, MaterialError, ModelMap, NdfKind, WriteMode};
use setup::{PointGrid, SampleArea};

fn sample_material() -> Material {
    let grid = PointGrid { cols: 4, rows: 3 };
    let n = grid.len();
    let g = NdfGrid::new(8, 16).unwrap();
    let mut tables = TableSet::new(g, n);
    for k in 0..n {
        let mut t = NdfTable::from_ndf(g, &Beckmann::new(0.1 + 0.05 * k as f32, 0.3, 0.1 * k as f32));
        t.normalize();
        for c in 0..g.len() {
            t.coverage_mut().set(c, c % 3 != 0);
        }
        tables.set(k, &t);
    }
    let mut models = BTreeMap::new();
    let am = AnalyticModel::WardAniso;
    models.insert(
        am.name().to_string(),
        ModelMap { model: am, params: (0..n * am.n_params()).map(|k| k as f32 * 0.01).collect(), fit_seconds: 1.5 },
    );
    Material {
        name: "test".into(),
        sample: SampleArea { width_mm: 100.0, height_mm: 80.0 },
        grid,
        kd: (0..n).map(|k| [k as f32 * 0.01, 0.2, 0.3]).collect(),
        ks: (0..n).map(|k| [0.04, 0.04 + k as f32 * 0.001, 0.05]).collect(),
        eta: vec![1.5; n],
        flags: (0..n as u32).collect(),
        ndf: Some(tables.clone()),
        ndf_kind: NdfKind::Synthesized,
        partial: Some(material::PartialFit {
            tables,
            ks: (0..n).map(|k| [0.03, 0.03 + k as f32 * 0.001, 0.04]).collect(),
            eta: vec![1.4; n],
        }),
        models,
        choice: Some(ChoiceMap {
            choice: (0..n).map(|k| Choice::from_u8((k % 4) as u8).unwrap()).collect(),
            isotropic_model: AnalyticModel::WardIso,
            anisotropic_model: AnalyticModel::WardAniso,
        }),
        provenance: serde_json::json!({"capture": "x"}),
    }
}

#[test]
fn round_trip_is_exact_up_to_f16_tables() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("material");
    let m = sample_material();
    material::write(&dir, &m, WriteMode::New).unwrap();
    let back = material::read(&dir).unwrap();
    assert_eq!(back.kd, m.kd);
    assert_eq!(back.ks, m.ks);
    assert_eq!(back.flags, m.flags);
    assert_eq!(back.models, m.models);
    assert_eq!(back.choice, m.choice);
    assert_eq!(back.ndf, m.ndf, "tables are stored as f16 and must read back bit-exact");
    assert_eq!(back.ndf_kind, NdfKind::Synthesized);
    // Writing again replaces the directory atomically, when asked to.
    let e = material::write(&dir, &back, WriteMode::New).unwrap_err();
    assert!(matches!(e, MaterialError::Exists(_)), "{e}");
    material::write(&dir, &back, WriteMode::Replace).unwrap();
    assert!(material::read(&dir).is_ok());
    let leftovers: Vec<_> = fs::read_dir(d.path()).unwrap().flatten().filter(|e| e.file_name() != "material").collect();
    assert!(leftovers.is_empty(), "temporary directories left behind");
}

#[test]
fn malformed_materials_are_rejected_with_a_reason() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("material");
    assert!(matches!(material::read(&dir), Err(MaterialError::NotAMaterial(_))));
    material::write(&dir, &sample_material(), WriteMode::New).unwrap();
    // Inconsistent grid in the JSON.
    let j = fs::read_to_string(dir.join("material.json")).unwrap();
    fs::write(dir.join("material.json"), j.replace("\"cols\": 4", "\"cols\": 5")).unwrap();
    let e = material::read(&dir).unwrap_err().to_string();
    assert!(e.contains("maps.exr") && e.contains("grid"), "{e}");
    fs::write(dir.join("material.json"), &j).unwrap();
    // A truncated EXR.
    let bytes = fs::read(dir.join("ndf.exr")).unwrap();
    fs::write(dir.join("ndf.exr"), &bytes[..bytes.len() / 2]).unwrap();
    let e = material::read(&dir).unwrap_err().to_string();
    assert!(e.contains("ndf.exr"), "{e}");
    // A future version.
    fs::write(dir.join("material.json"), j.replace("\"format_version\": 1", "\"format_version\": 9")).unwrap();
    assert!(matches!(material::read(&dir), Err(MaterialError::Version { found: 9, .. })));
}

/// Every entry under `dir` with its bytes, to show that nothing changed.
fn snapshot(dir: &std::path::Path) -> Vec<(std::path::PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p.clone());
                out.push((p, Vec::new()));
            } else {
                out.push((p.clone(), fs::read(&p).unwrap()));
            }
        }
    }
    out.sort();
    out
}

#[test]
fn writing_never_removes_what_it_did_not_write() {
    let d = tempfile::tempdir().unwrap();
    let m = sample_material();
    // A directory of someone's files (a capture, notes): refused in either
    // mode, every file left as it was.
    let busy = d.path().join("capture");
    fs::create_dir_all(busy.join("frames")).unwrap();
    fs::write(busy.join("notes.txt"), "keep me").unwrap();
    fs::write(busy.join("frames/s000.png"), [1u8, 2, 3]).unwrap();
    let before = snapshot(d.path());
    for mode in [WriteMode::New, WriteMode::Replace] {
        let e = material::write(&busy, &m, mode).unwrap_err();
        assert!(matches!(e, MaterialError::Occupied { .. }), "{e}");
    }
    assert_eq!(snapshot(d.path()), before, "a refused write changed something");
    // A regular file at the target: refused, untouched.
    let file = d.path().join("file");
    fs::write(&file, "data").unwrap();
    assert!(matches!(material::write(&file, &m, WriteMode::Replace), Err(MaterialError::Occupied { .. })));
    assert_eq!(fs::read(&file).unwrap(), b"data");
    // An empty directory takes a new material.
    let empty = d.path().join("empty");
    fs::create_dir(&empty).unwrap();
    material::write(&empty, &m, WriteMode::New).unwrap();
    assert!(material::read(&empty).is_ok());
    // A material with a file the format does not write is not replaced.
    fs::write(empty.join("README"), "mine").unwrap();
    let before = snapshot(d.path());
    let e = material::write(&empty, &m, WriteMode::Replace).unwrap_err();
    assert!(e.to_string().contains("README"), "{e}");
    assert_eq!(snapshot(d.path()), before);
}

/// `ndf_atlas.exr` is each point's table where MATERIAL.md says: the tile
/// of grid point (col, row), `x` right and `y` up, a half vector at polar
/// angle theta drawn at `sqrt(theta / (pi/2))` of the half width.
#[test]
fn the_ndf_atlas_draws_each_points_table_where_the_format_says() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("material");
    let m = sample_material();
    material::write(&dir, &m, WriteMode::New).unwrap();
    let (w, h, channels) = material::read_channels(&dir.join("ndf_atlas.exr")).unwrap();
    let tables = m.ndf.as_ref().unwrap();
    let side = 2 * tables.grid().n_theta as usize;
    assert_eq!((w, h), (4 * side, 3 * side));
    let (dv, obs) = (&channels["D"], &channels["observed"]);
    for k in 0..m.grid.len() {
        let t = tables.get(k);
        let (c, r) = (k % 4, k / 4);
        // A pixel up and to the right of the centre, and a corner outside
        // the disk.
        for (x, y) in [(side * 7 / 10, side * 3 / 10), (side / 2 + 1, side / 2 - 3), (side / 5, side * 4 / 5)] {
            let u = 2.0 * (x as f32 + 0.5) / side as f32 - 1.0;
            let v = 1.0 - 2.0 * (y as f32 + 0.5) / side as f32;
            let rr = u.hypot(v);
            let theta = rr * rr * std::f32::consts::FRAC_PI_2;
            let hv = glam::Vec3::new(theta.sin() * v.atan2(u).cos(), theta.sin() * v.atan2(u).sin(), theta.cos());
            let at = (r * side + y) * w + c * side + x;
            let want = t.eval(hv);
            assert!((dv[at] - want).abs() <= 2e-3 * want.abs() + 1e-6, "point {k} ({x},{y}): {} vs {want}", dv[at]);
            let (ti, pi) = t.grid().cell(hv).unwrap();
            assert_eq!(obs[at] > 0.5, t.coverage().get(t.grid().index(ti, pi)), "point {k} ({x},{y})");
        }
        let corner = (r * side) * w + c * side;
        assert_eq!((dv[corner], obs[corner]), (0.0, 0.0), "outside the disk");
    }
}
