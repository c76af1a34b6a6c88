//! The material format: lossless round trip, atomic replacement, and clear
//! rejection of malformed or inconsistent files.

use std::collections::BTreeMap;
use std::fs;

use brdf::ndf::{Beckmann, NdfGrid, NdfTable, TableSet};
use brdf::params::AnalyticModel;
use material::{Choice, ChoiceMap, Material, MaterialError, ModelMap, NdfKind};
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
    material::write(&dir, &m).unwrap();
    let back = material::read(&dir).unwrap();
    assert_eq!(back.kd, m.kd);
    assert_eq!(back.ks, m.ks);
    assert_eq!(back.flags, m.flags);
    assert_eq!(back.models, m.models);
    assert_eq!(back.choice, m.choice);
    assert_eq!(back.ndf, m.ndf, "tables are stored as f16 and must read back bit-exact");
    assert_eq!(back.ndf_kind, NdfKind::Synthesized);
    // Writing again replaces the directory atomically.
    material::write(&dir, &back).unwrap();
    assert!(material::read(&dir).is_ok());
    let leftovers: Vec<_> = fs::read_dir(d.path()).unwrap().flatten().filter(|e| e.file_name() != "material").collect();
    assert!(leftovers.is_empty(), "temporary directories left behind");
}

#[test]
fn malformed_materials_are_rejected_with_a_reason() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("material");
    assert!(matches!(material::read(&dir), Err(MaterialError::NotAMaterial(_))));
    material::write(&dir, &sample_material()).unwrap();
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
