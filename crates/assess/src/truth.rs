//! Ground truth: the material a simulated capture scanned.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result, anyhow};
use brdf::ndf::{NdfGrid, NdfTable};
use glam::{Vec2, Vec3};
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

/// How the true lobe compares with the rig's sampling of it, each the
/// median over the points (every [`REACH_STRIDE`]th) with a specular lobe.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct LobeReach {
    /// Half-angle of the cone whose solid angle equals that of the smallest
    /// set of directions holding half the NDF's projected mass (the
    /// densest cells first): a width that does not assume the lobe's shape,
    /// centre or symmetry.
    pub half_mass_deg: f64,
    /// Angle from the NDF's densest direction to the nearest half vector
    /// the plan's lights give the point.
    pub nearest_deg: f64,
    /// The half vectors' spacing at that light
    /// (`fit::FitContext::half_vector_spacing`).
    pub spacing_deg: f64,
}

/// Every how many points [`lobe_reach`] looks at.
const REACH_STRIDE: usize = 37;

/// The grid the true NDF is read on for [`lobe_reach`]: its rings shrink
/// toward the pole (0.02 degrees first), fine enough for a mirror-like
/// lobe.
const REACH_GRID: NdfGrid = NdfGrid { n_theta: 64, n_phi: 128 };

/// `ndf`'s [`NdfTable::half_mass_cone`] on [`REACH_GRID`].
fn half_mass_cone(ndf: &dyn brdf::ndf::Ndf) -> Option<(f64, Vec3)> {
    NdfTable::from_fn(REACH_GRID, 2, |h| ndf.d(h)).half_mass_cone().map(|(a, peak)| (a as f64, peak))
}

/// [`LobeReach`] of the true `material` under the rig and plan of `ctx`;
/// `None` when no point has a specular lobe.
pub fn lobe_reach(ctx: &fit::FitContext, material: &dyn SvBrdf) -> Option<LobeReach> {
    let mut found: Vec<[f64; 3]> = Vec::new();
    for p in (0..ctx.n_points()).step_by(REACH_STRIDE) {
        let x = ctx.positions[p];
        let Some(ndf) = material.at(Vec2::new(x.x, x.y)).ndf().cloned() else { continue };
        let Some((half_mass, peak)) = half_mass_cone(ndf.as_ref()) else { continue };
        let Some((angle, spacing)) = nearest_half_vector(ctx, p, peak) else { continue };
        found.push([half_mass.to_degrees(), (angle as f64).to_degrees(), (spacing as f64).to_degrees()]);
    }
    let median = |i: usize| {
        let mut v: Vec<f64> = found.iter().map(|f| f[i]).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    (!found.is_empty()).then(|| LobeReach { half_mass_deg: median(0), nearest_deg: median(1), spacing_deg: median(2) })
}

/// The angle from `h` to the nearest half vector of point `p`'s lights
/// above its horizon, and the half vectors' spacing there
/// (`fit::FitContext::half_vector_spacing`), radians.
fn nearest_half_vector(ctx: &fit::FitContext, p: usize, h: Vec3) -> Option<(f32, f32)> {
    let o = ctx.view[p];
    (0..ctx.n_lights())
        .filter_map(|q| ctx.sample(p, q).map(|sg| (q, (sg.i + o).normalize_or_zero().dot(h).clamp(-1.0, 1.0).acos())))
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .map(|(q, angle)| (angle, ctx.half_vector_spacing(p, q)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use brdf::ndf::Beckmann;

    /// Half the width, in radians, of the ring of [`REACH_GRID`] at polar
    /// angle `theta`: how far a cap's edge can fall from a ring's edge.
    fn half_ring(theta: f64) -> f64 {
        let u = (2.0 * theta / std::f64::consts::PI).sqrt();
        0.5 * std::f64::consts::PI * u / REACH_GRID.n_theta as f64
    }

    #[test]
    fn the_half_mass_cone_of_a_beckmann_lobe_is_its_median_slope() {
        // Beckmann's slopes are Gaussian, `exp(-t^2 / a^2) / (pi a^2)`:
        // half of them lie within `tan(theta) = a sqrt(ln 2)`, a cap about
        // the normal, which is the densest set of that mass.
        for alpha in [0.02f32, 0.1, 0.4] {
            let (cone, peak) = half_mass_cone(&Beckmann::isotropic(alpha)).unwrap();
            let expected = (alpha as f64 * std::f64::consts::LN_2.sqrt()).atan();
            let tol = half_ring(expected);
            assert!((cone - expected).abs() < tol, "alpha {alpha}: {cone} against {expected} (+- {tol})");
            assert!(peak.z > REACH_GRID.theta_edge(1).cos(), "alpha {alpha}: peak {peak}");
        }
    }

    #[test]
    fn the_half_mass_cone_of_an_anisotropic_lobe_is_the_ellipse_s_area() {
        // Half the slopes lie in an ellipse of area `pi ax ay ln 2`; for
        // slopes this small a solid angle is nearly a slope area (within
        // `cos^3` of the ellipse's far end, 4% here, on the area), so the
        // cone's half-angle is near `sqrt(ax ay ln 2)`, whichever way the
        // lobe is turned.
        let (ax, ay) = (0.05f32, 0.2f32);
        let expected = ((ax * ay) as f64 * std::f64::consts::LN_2).sqrt();
        let (straight, _) = half_mass_cone(&Beckmann::new(ax, ay, 0.0)).unwrap();
        let (turned, _) = half_mass_cone(&Beckmann::new(ax, ay, 0.7)).unwrap();
        for cone in [straight, turned] {
            assert!((cone / expected - 1.0).abs() < 0.03, "{cone} against {expected}");
        }
        assert!((straight - turned).abs() < half_ring(expected), "{straight} turned to {turned}");
    }
}
