//! A stored capture as the fitter's input (what the fitter must know of it,
//! and its frames in the order they were stored), and the fit's result as
//! the capture's material. The capture job's fit, `refl fit` and the
//! hold-out refit of `refl eval` all go through here.

use std::path::Path;

use anyhow::{Context, Result};
use frame::Frame;
use setup::PlannedShot;

/// A frame on its way to the fitter.
#[derive(Debug)]
pub enum FrameMsg {
    Dark { exposure: u8, frame: Frame },
    Shot { shot: PlannedShot, frame: Frame },
}

impl FrameMsg {
    /// Hand this frame to a fit pipeline or an ingest.
    pub fn feed(self, sink: &mut dyn fit::FrameSink) {
        match self {
            FrameMsg::Dark { exposure, frame } => sink.push_dark(exposure, &frame),
            FrameMsg::Shot { shot, frame } => sink.push_shot(&shot, &frame),
        }
    }
}

/// Read a stored capture's frames in manifest order (dark frames were
/// stored before the shots of their exposure) and hand each to `each`.
pub fn for_each_frame(
    root: &Path,
    entries: &[store::ManifestEntry],
    each: &mut dyn FnMut(FrameMsg) -> Result<()>,
) -> Result<u64> {
    let mut n = 0;
    for e in entries {
        let frame = store::CaptureDir::read_frame(root, e).with_context(|| format!("reading {}", e.file))?;
        each(match e.frame {
            store::FrameKind::Dark { exposure, .. } => FrameMsg::Dark { exposure, frame },
            store::FrameKind::Shot(shot) => FrameMsg::Shot { shot, frame },
        })?;
        n += 1;
    }
    Ok(n)
}

/// What the fitter needs to know about a stored capture.
pub fn fit_inputs(info: &store::CaptureInfo) -> fit::FitInputs {
    fit::FitInputs {
        geometry: info.geometry.clone(),
        plan: info.plan.clone(),
        calibration: info.calibration.clone(),
        grid: info.grid,
        e_per_dn: info.sensor.e_per_dn,
        bit_depth: info.sensor.bit_depth,
        sensor_layout: info.sensor.layout,
    }
}

/// The material the fit describes.
pub fn material_from(out: &fit::FitResult, info: &store::CaptureInfo, q: &config::Quality) -> material::Material {
    let maps = &out.maps;
    material::Material {
        name: info.sample.clone(),
        sample: info.geometry.sample,
        grid: info.grid,
        kd: maps.kd.clone(),
        ks: maps.ks.clone(),
        eta: maps.eta.clone(),
        flags: maps.flags.clone(),
        ndf: Some(maps.tables.clone()),
        ndf_kind: if out.partial.is_some() { material::NdfKind::Synthesized } else { material::NdfKind::Partial },
        partial: out.partial.as_ref().map(|p| material::PartialFit {
            tables: p.tables.clone(),
            ks: p.ks.clone(),
            eta: p.eta.clone(),
        }),
        models: out
            .models
            .iter()
            .map(|f| {
                (
                    f.model.name().to_string(),
                    material::ModelMap { model: f.model, params: f.params.clone(), fit_seconds: f.seconds },
                )
            })
            .collect(),
        choice: out.selection.as_ref().map(|s| material::ChoiceMap {
            choice: s
                .choice
                .iter()
                .map(|&c| material::Choice::from_u8(c).unwrap_or(material::Choice::Tabulated))
                .collect(),
            isotropic_model: s.isotropic,
            anisotropic_model: s.anisotropic,
        }),
        provenance: serde_json::json!({
            "capture_created_utc": info.created_utc,
            "sample": info.sample,
            "quality": q,
            "calibration": info.calibration.id,
            "simulated": info.simulated,
            "model_choice": out.selection.as_ref().map(|s| &s.summary),
            "fit_seconds": {
                "partial": out.timings.ingest_s + out.timings.points_s,
                "synthesized": out.timings.ingest_s + out.timings.points_s + out.timings.synthesis_s
                    + out.timings.pool_s,
            },
        }),
    }
}
