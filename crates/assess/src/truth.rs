//! Ground truth: the material a simulated capture scanned.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result, anyhow};
use material::SvBrdf;

/// The material a simulated capture scanned (its ground truth); `None` for
/// a capture made on hardware.
pub fn ground_truth(info: &store::CaptureInfo) -> Result<Option<Arc<dyn SvBrdf>>> {
    match &info.simulated {
        Some(s) => Ok(Some(sim_material(
            s.material.as_deref().unwrap_or(&info.sample),
            s.material_dir.as_deref().map(Path::new),
        )?)),
        None => Ok(None),
    }
}

/// The simulated sample: a built-in material or a stored one.
pub fn sim_material(name: &str, dir: Option<&Path>) -> Result<Arc<dyn SvBrdf>> {
    if let Some(d) = dir {
        let m = material::read(d).with_context(|| format!("--sim-material {}", d.display()))?;
        let choice = if m.ndf.is_some() { material::ModelChoice::Tabulated } else { material::ModelChoice::Partial };
        let view = material::MaterialView::new(Arc::new(m), choice)
            .ok_or_else(|| anyhow!("{} has no NDF tables to render", d.display()))?;
        return Ok(Arc::new(view));
    }
    sim::materials::builtin(name).ok_or_else(|| {
        anyhow!(
            "unknown sample '{name}': the simulated rig knows {} (or use --sim-material DIR)",
            sim::materials::builtin_names()
        )
    })
}
