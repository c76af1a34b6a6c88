//! `refl bench budget`: where the fitter's error comes from. The same
//! synthetic capture (a built-in or imported material evaluated at every
//! light and point of a quality preset's plan, written straight into the
//! sample store, see [`crate::bench::synthetic`]) is fitted as the preset would
//! (per point, then pooled; synthesis and the analytic fits are not part of
//! the budget), then per point alone, then with its noise removed, then
//! with each of the fitter's resolution knobs loosened. The noiseless rows
//! are the method's own bias on this sampling; the rows after them say
//! which knob that bias is in. The pooled rows pool as the preset does,
//! each member turned to its cluster's lobe axis where that predicts
//! held-out samples better (`fit::pooled::PoolSettings::turn`); the
//! "members not turned" rows pool without turning.
//!
//! The row "through camera pixels" gives each point, without noise,
//! the samples of the mean BRDF over its footprint in the preset's
//! simulated camera (its Bayer demosaic and bilinear read,
//! `crate::footprint`), still scored against the point's centre: the part of
//! `refl eval`'s error that is the camera's resolution.
//!
//! What this budget does not cover otherwise: the camera (its
//! quantisation, clipping, pixel response), the LEDs' true intensities and
//! emission profile, and the calibration that estimates them. Those sit
//! between the simulated rig and the sample store; `refl eval` on a full
//! simulated capture includes them, so the difference between its figures
//! and this table's first row is their share.
//!
//! Before the rows, [`crate::truth::lobe_reach`] sets the true lobe's
//! width against the plan's spacing of half vectors: where the lobe is far
//! narrower, the error is the sampling's, whatever the fitter does.
//!
//! Figures per row, pooled over the points with specular in both truth and
//! fit:
//! - `ndf_obs`: relative L2 of the fitted NDF table against the true one
//!   over the cells the fit observed, in the table's cosine measure.
//! - `shape_obs`: the same after the best scale of the fitted table on
//!   those cells (its shape alone); `scale` is the pooled best scale. A
//!   table normalised over the hemisphere whose unobserved part is
//!   extrapolated has a scale error that is not a shape error.
//! - `ndf_full`: over the whole hemisphere.
//! - `brdf`: relative RMS error of the fitted BRDF (diffuse, specular,
//!   masking, Fresnel together) against the truth, with view and light at
//!   `refl eval`'s conditions, distant (directions only).

use std::time::Instant;

use anyhow::Result;
use brdf::Brdf;
use brdf::ndf::{MaskingOperator, NdfGrid, NdfTable};
use glam::{Vec2, Vec3};

use crate::bench::{Synthetic, synthetic_through};

/// One row of the budget.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Row {
    pub name: String,
    pub points: usize,
    pub ndf_obs: f64,
    pub shape_obs: f64,
    pub scale: f64,
    pub ndf_full: f64,
    pub brdf: f64,
    pub fit_s: f64,
}

/// A variant of the preset's capture or fit.
struct Variant {
    name: &'static str,
    noise: bool,
    /// Steps and LED stride relative to the preset: (steps x, stride /).
    denser: bool,
    /// Pool each material's points (`fit::pooled`) as the preset does.
    pooled: bool,
    /// Pool without turning members to their cluster's axis
    /// (`fit::pooled::PoolSettings::turn` off).
    unturned: bool,
    /// Each point's samples through the preset's simulated camera's pixel
    /// footprint (`crate::bench::synthetic_through`).
    footprint: bool,
    settings: fn(&mut fit::FitSettings),
}

/// The preset's capture (with its noise) fitted per point alone: what
/// each variant departs from.
const AS_CAPTURED: Variant = Variant {
    name: "",
    noise: true,
    denser: false,
    pooled: false,
    unturned: false,
    footprint: false,
    settings: |_| {},
};

fn variants() -> Vec<Variant> {
    vec![
        Variant { name: "as captured, pooled (the preset's fit)", pooled: true, ..AS_CAPTURED },
        Variant { name: "no noise, pooled", noise: false, pooled: true, ..AS_CAPTURED },
        Variant {
            name: "no noise, pooled, through camera pixels",
            noise: false,
            pooled: true,
            footprint: true,
            ..AS_CAPTURED
        },
        Variant { name: "as captured, pooled, members not turned", pooled: true, unturned: true, ..AS_CAPTURED },
        Variant {
            name: "no noise, pooled, members not turned",
            noise: false,
            pooled: true,
            unturned: true,
            ..AS_CAPTURED
        },
        Variant {
            name: "no noise, pooled, NDF table twice as fine",
            noise: false,
            pooled: true,
            settings: |s| s.grid = NdfGrid { n_theta: 2 * s.grid.n_theta, n_phi: 2 * s.grid.n_phi },
            ..AS_CAPTURED
        },
        Variant { name: "as captured, per point (no pooling)", ..AS_CAPTURED },
        Variant { name: "no noise, per point (the method's own bias)", noise: false, ..AS_CAPTURED },
        Variant {
            name: "no noise, per point, no bias correction",
            noise: false,
            settings: |s| s.bias_passes = 0,
            ..AS_CAPTURED
        },
        Variant {
            name: "no noise, per point, two bias corrections",
            noise: false,
            settings: |s| s.bias_passes = 2,
            ..AS_CAPTURED
        },
        Variant { name: "as captured, per point, no bias correction", settings: |s| s.bias_passes = 0, ..AS_CAPTURED },
        Variant {
            name: "no noise, NDF table twice as fine",
            noise: false,
            settings: |s| s.grid = NdfGrid { n_theta: 2 * s.grid.n_theta, n_phi: 2 * s.grid.n_phi },
            ..AS_CAPTURED
        },
        Variant {
            name: "no noise, splat kernel half as wide",
            noise: false,
            settings: |s| s.kernel_scale *= 0.5,
            ..AS_CAPTURED
        },
        Variant {
            name: "no noise, masking iterated to convergence",
            noise: false,
            settings: |s| {
                s.max_masking_iterations = 12;
                s.masking_tolerance = 1e-4;
            },
            ..AS_CAPTURED
        },
        Variant { name: "as captured, splat kernel half as wide", settings: |s| s.kernel_scale *= 0.5, ..AS_CAPTURED },
        Variant { name: "as captured, splat kernel 0.7 as wide", settings: |s| s.kernel_scale *= 0.7, ..AS_CAPTURED },
        Variant {
            name: "no noise, Fresnel not fitted",
            noise: false,
            settings: |s| s.fit_fresnel = false,
            ..AS_CAPTURED
        },
        Variant { name: "no noise, twice the steps and every LED", noise: false, denser: true, ..AS_CAPTURED },
    ]
}

/// The budget of `sample` (the stored material in `dir` where given, as
/// `capture --sim-material` scans it) at the quality preset `q`: every row,
/// or those whose name contains `only`.
pub fn run(sample: &str, dir: Option<&std::path::Path>, q: &config::Quality, only: Option<&str>) -> Result<Vec<Row>> {
    let material = crate::truth::sim_material(sample, dir)?;
    println!(
        "error budget: '{sample}' at the {} preset: {} x {} points, {} steps x every {} LED, NDF {} x {} cells",
        q.name, q.grid, q.grid, q.steps, q.led_stride, q.fit.grid.n_theta, q.fit.grid.n_phi
    );
    let ctx = crate::bench::synthetic_context(q.grid, q.steps, q.led_stride as u32)?;
    match crate::truth::lobe_reach(&ctx, material.as_ref()) {
        Some(r) => println!(
            "truth against the rig (median over points): half the NDF's mass within a cone of {:.2} degrees; the \
             light whose half vector comes nearest the NDF's peak lands {:.2} degrees from it, and the preset's half \
             vectors there are {:.2} degrees apart",
            r.half_mass_deg, r.nearest_deg, r.spacing_deg
        ),
        None => println!("truth against the rig: no point of the sample has a specular lobe"),
    }
    println!(
        "{:<44} {:>7} {:>9} {:>9} {:>7} {:>9} {:>8} {:>7}",
        "row", "points", "ndf_obs", "shape_obs", "scale", "ndf_full", "brdf", "fit_s"
    );
    let mut rows = Vec::new();
    for v in variants().into_iter().filter(|v| only.is_none_or(|o| v.name.contains(o))) {
        let (steps, stride) = if v.denser { (2 * q.steps, 1) } else { (q.steps, q.led_stride as u32) };
        let s = synthetic_through(material.clone(), q.grid, steps, stride, v.noise, v.footprint.then(|| camera(q)))?;
        let mut settings = q.fit.clone();
        (v.settings)(&mut settings);
        let t = Instant::now();
        let pool =
            q.pool.clone().filter(|_| v.pooled).map(|p| fit::pooled::PoolSettings { turn: p.turn && !v.unturned, ..p });
        let stages = fit::Stages { pool, ..fit::Stages::default() };
        let maps = fit::pipeline::run_stages(&s.ctx, s.store.clone(), settings.clone(), &stages, &|| false)?.maps;
        let fit_s = t.elapsed().as_secs_f64();
        let row = score(v.name, &s, &maps, settings.grid, fit_s);
        println!(
            "{:<44} {:>7} {:>9.4} {:>9.4} {:>7.3} {:>9.4} {:>8.4} {:>7.1}",
            row.name, row.points, row.ndf_obs, row.shape_obs, row.scale, row.ndf_full, row.brdf, row.fit_s
        );
        rows.push(row);
    }
    Ok(rows)
}

/// The preset's simulated camera (the rig file's, read at the preset's
/// size, as `capture` reads it) and its Bayer sensor.
fn camera(q: &config::Quality) -> (setup::CameraModel, frame::Layout) {
    let rig = config::RigFile::parse(config::rigfile::DEFAULT_RIG, "embedded simulated rig");
    let mut cam = rig.map(|r| r.geometry()).unwrap_or_default().camera;
    (cam.width, cam.height) = (q.sim_camera_px, q.sim_camera_px);
    (cam, frame::Layout::Bayer { pattern: sim::camera::SensorModel::default().pattern })
}

fn score(name: &str, s: &Synthetic, maps: &fit::points::PointMaps, grid: NdfGrid, fit_s: f64) -> Row {
    let op = MaskingOperator::new(grid);
    let dirs: Vec<(Vec3, Vec3)> = crate::eval::conditions()
        .iter()
        .map(|c| {
            let o =
                render::scene::dir_from((90.0 - c.camera_polar_deg).to_radians(), c.camera_azimuth_deg.to_radians());
            let i = render::scene::dir_from(c.light_elevation_deg.to_radians(), c.light_azimuth_deg.to_radians());
            (i, o)
        })
        .collect();
    // Sums: (obs num, obs den, shape num, full num, full den, a.b, a.a, brdf num, brdf den)
    let mut acc = [0.0f64; 9];
    let mut points = 0;
    for p in 0..maps.len() {
        if maps.flags[p] & fit::point_flag::NO_SPECULAR != 0 {
            continue;
        }
        let x = s.ctx.positions[p];
        let truth = s.material.at(Vec2::new(x.x, x.y));
        let Some(ndf) = truth.ndf() else { continue };
        let mut t = NdfTable::from_fn(grid, 3, |h| ndf.d(h));
        if t.normalize() <= 0.0 {
            continue;
        }
        points += 1;
        let est = maps.tables.get(p);
        let cov = est.coverage();
        let (mut ab, mut aa, mut bb) = (0.0f64, 0.0f64, 0.0f64);
        let np = grid.n_phi as usize;
        for (k, (&a, &b)) in est.values().iter().zip(t.values()).enumerate() {
            let w = grid.cos_measure(k / np) as f64;
            let (a, b) = (a as f64, b as f64);
            acc[3] += w * (a - b) * (a - b);
            acc[4] += w * b * b;
            if cov.get(k) {
                acc[0] += w * (a - b) * (a - b);
                ab += w * a * b;
                aa += w * a * a;
                bb += w * b * b;
            }
        }
        acc[1] += bb;
        // Best scale for this point: min over k of |k a - b|^2 = bb - ab^2/aa.
        acc[2] += if aa > 0.0 { (bb - ab * ab / aa).max(0.0) } else { bb };
        acc[5] += ab;
        acc[6] += aa;
        let fitted = material::PointMaterial::fitted(
            Vec3::from(maps.kd[p]),
            Vec3::from(maps.ks[p]),
            maps.eta[p],
            material::PointMaterial::table_ndf(est, &op),
        );
        for &(i, o) in &dirs {
            let (f, g) = (fitted.eval(i, o), truth.eval(i, o));
            acc[7] += (f - g).length_squared() as f64;
            acc[8] += g.length_squared() as f64;
        }
    }
    let rel = |n: f64, d: f64| if d > 0.0 { (n / d).sqrt() } else { f64::NAN };
    Row {
        name: name.to_string(),
        points,
        ndf_obs: rel(acc[0], acc[1]),
        shape_obs: rel(acc[2], acc[1]),
        scale: if acc[6] > 0.0 { acc[5] / acc[6] } else { f64::NAN },
        ndf_full: rel(acc[3], acc[4]),
        brdf: rel(acc[7], acc[8]),
        fit_s,
    }
}
