//! Turning a finished fit into the capture's outputs: `material/` and
//! `report.json`.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use material::{Material, NdfKind};
use store::CaptureInfo;

use crate::fitjob::{FitJob, FitOutcome};
use crate::presets::Quality;
use crate::progress::Reporter;
use crate::report::Report;

/// Flag counts over the grid, by name.
pub fn flag_counts(flags: &[u32]) -> serde_json::Value {
    let mut m = serde_json::Map::new();
    for &(bit, name) in fit::point_flag::NAMES {
        m.insert(name.into(), serde_json::json!(flags.iter().filter(|&&f| f & bit != 0).count()));
    }
    serde_json::Value::Object(m)
}

/// The material the fit describes.
pub fn material_from(out: &FitOutcome, info: &CaptureInfo, q: &Quality) -> Material {
    let maps = &out.maps;
    Material {
        name: info.sample.clone(),
        sample: info.geometry.sample,
        grid: info.grid,
        kd: maps.kd.clone(),
        ks: maps.ks.clone(),
        eta: maps.eta.clone(),
        flags: maps.flags.clone(),
        ndf: Some(maps.tables.clone()),
        ndf_kind: NdfKind::Partial,
        partial_ndf: None,
        models: Default::default(),
        choice: None,
        provenance: serde_json::json!({
            "capture_created_utc": info.created_utc,
            "sample": info.sample,
            "quality": q,
            "calibration": info.calibration.id,
            "simulated": info.simulated,
        }),
    }
}

/// Wait for the fitter, then write the material.
pub async fn finish_fit(
    job: FitJob,
    info: &CaptureInfo,
    q: &Quality,
    root: &Path,
    rep: &mut Reporter,
    report: &mut Report,
) -> Result<PathBuf> {
    rep.stage("fit", "per-point NDFs (diffuse, specular, masking, Fresnel)");
    let t = Instant::now();
    let out = tokio::task::block_in_place(|| job.finish())?;
    rep.stage("fit", format!("{} points in {:.1} s after the last frame", out.maps.len(), out.timings.points_s));
    let m = material_from(&out, info, q);
    let dir = root.join("material");
    tokio::task::block_in_place(|| material::write(&dir, &m)).with_context(|| format!("writing {}", dir.display()))?;
    report.time("fit_ingest_s", out.timings.ingest_s);
    report.time("fit_points_s", out.timings.points_s);
    report.time("fit_total_after_capture_s", t.elapsed().as_secs_f64());
    report.fit = serde_json::json!({
        "points": out.maps.len(),
        "flags": flag_counts(&out.maps.flags),
        "samples": out.census,
        "sample_store_mb": out.sample_bytes as f64 / 1e6,
        "ndf_tables_mb": out.maps.tables.bytes() as f64 / 1e6,
        "material_disk_mb": material::io::disk_bytes(&dir) as f64 / 1e6,
    });
    rep.stage("fit", format!("material written to {}", dir.display()));
    Ok(dir)
}

pub fn write_report(root: &Path, report: &Report) -> Result<()> {
    let p = root.join("report.json");
    let tmp = root.join(".report.json.tmp");
    std::fs::write(&tmp, serde_json::to_vec_pretty(report)?)
        .with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, &p).with_context(|| format!("cannot write {}", p.display()))?;
    Ok(())
}
