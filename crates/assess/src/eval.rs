//! `refl eval DIR`: how good is the fitted material?
//!
//! - **Renders against ground truth** (simulated captures only): every
//!   model the material holds and the true material are rendered under
//!   novel conditions, none of them a capture configuration: views from
//!   overhead to 70 degrees on every side, point lights from 20 to 80
//!   degrees elevation all around. Several put the half vector where the
//!   capture's camera never looked (it sat on the `-x` side, so half
//!   vectors tilted far toward `+x` were never observed); the fraction of
//!   pixels whose half vector lies outside the point's observed region is
//!   reported per condition. `render_rel_rmse = sqrt(sum (model - truth)^2 /
//!   sum truth^2)` over all pixels and channels of all conditions. Each
//!   pixel is one ray through its centre unless `render_subpixels` asks for
//!   the mean of more: a highlight narrower than a pixel, or detail finer
//!   than the material's points, then counts by its share of the pixel
//!   instead of by whether a centre fell on it.
//! - **NDF errors** against the true NDF, the same relative L2 in the
//!   table's cosine measure, over the observed cells and the whole
//!   hemisphere, pooled over up to 1,024 points spread over the sample
//!   (those the camera measured: the others hold no fit).
//! - **The camera's resolution apart** (simulated captures): a point
//!   measures the mean BRDF over its footprint (`crate::footprint`), so
//!   the NDF errors are given again against that truth (`*_footprint`),
//!   each model's renders are scored against renders of it as well
//!   (`render_rel_rmse_resolved`), and that truth's own render error is the
//!   resolution floor (`render_resolution_floor`).
//! - **Hold-out**: for any capture, real or simulated, the material is
//!   refitted without every 8th light and predicts those lights' samples;
//!   `frame_rel_rmse` is the same relative error in reflectance over every
//!   usable held-out sample. This is the figure a lab gets without ground
//!   truth.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail};
use brdf::Brdf;
use brdf::ndf::{NdfTable, TableSet};
use config::Quality;
use material::{Material, MaterialView, ModelChoice, NdfKind, SvBrdf};
use rayon::prelude::*;
use render::{Image, Light, Scene};
use serde::Serialize;
use setup::SampleArea;
use store::CaptureDir;

use crate::Progress;
use crate::renders::Lighting;
use crate::truth::ground_truth;

/// One novel viewing and lighting condition.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Condition {
    pub name: String,
    /// Angle of the view from the sample normal.
    pub camera_polar_deg: f32,
    pub camera_azimuth_deg: f32,
    /// Elevation of the light above the sample plane.
    pub light_elevation_deg: f32,
    pub light_azimuth_deg: f32,
}

/// The evaluation conditions (views and point lights, degrees).
pub fn conditions() -> Vec<Condition> {
    let c = |name: &str, ce, ca, le, la| Condition {
        name: name.into(),
        camera_polar_deg: ce,
        camera_azimuth_deg: ca,
        light_elevation_deg: le,
        light_azimuth_deg: la,
    };
    vec![
        c("overhead, light low", 0.0, 0.0, 25.0, 30.0),
        c("side view across the weave", 35.0, 90.0, 50.0, 250.0),
        c("far side, low light", 55.0, 200.0, 20.0, 20.0),
        c("opposite the capture camera", 45.0, 180.0, 60.0, 0.0),
        c("grazing from +x, light +x", 70.0, 0.0, 20.0, 10.0),
        c("from +x, light high +x", 60.0, 20.0, 80.0, 350.0),
        c("+x view, light +y", 50.0, 330.0, 45.0, 60.0),
        c("near normal, light high", 20.0, 45.0, 80.0, 135.0),
        c("from -y, light +y", 50.0, 270.0, 40.0, 90.0),
        // Half vector about 25 degrees toward +x: just beyond the observed
        // region (which ends near 13 degrees on that side), where the
        // lobes still carry mass.
        c("tilted +x, light overhead", 40.0, 0.0, 80.0, 0.0),
    ]
}

pub fn scene_for(c: &Condition, px: u32) -> Scene {
    let light = Lighting::Point { elevation_deg: c.light_elevation_deg, azimuth_deg: c.light_azimuth_deg };
    crate::renders::scene((c.camera_polar_deg, c.camera_azimuth_deg), light, px)
}

/// Per-model figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ModelScore {
    pub render_rel_rmse: Option<f64>,
    /// The same renders against the truth as the material's points measure
    /// it ([`Evaluation::render_resolution_floor`]'s renders): the model's
    /// error with the camera's and the point grid's resolution left out.
    pub render_rel_rmse_resolved: Option<f64>,
    /// Relative L2 of the fitted NDF against the true one on the cells the
    /// fit observed, both as stored (each normalised over the hemisphere).
    pub ndf_rel_l2_observed: Option<f64>,
    pub ndf_rel_l2_full: Option<f64>,
    /// The same on the observed cells after the best scale of the fitted
    /// table per point: the error of its shape alone. `ndf_scale_observed`
    /// is the pooled best scale (1 when the normalisation agrees; a table
    /// whose unobserved part was extrapolated with too much or too little
    /// mass is off by it).
    pub ndf_shape_observed: Option<f64>,
    pub ndf_scale_observed: Option<f64>,
    /// Where the normalisation offset comes from: the share of the true
    /// NDF's mass (its integral against `cos theta_h`, 1 over the
    /// hemisphere) on the cells the fit did not observe, and the fitted
    /// table's share there (what synthesis added). The table's observed
    /// cells are too high by about the shortfall of the second.
    pub ndf_true_mass_unobserved: Option<f64>,
    pub ndf_mass_unobserved: Option<f64>,
    /// The true NDF's share on the cells the fitted table leaves empty
    /// (neither observed nor completed).
    pub ndf_true_mass_uncovered: Option<f64>,
    /// The same three against the truth the point's samples measure: the
    /// true NDFs of every sensor pixel its value is read from, weighted as
    /// the demosaic and the bilinear read weight them (its footprint on the
    /// sample, about 1 mm at the balanced preset; see [`crate::footprint`]).
    /// Where the material varies within that footprint (satin's weave
    /// cells are 2.5 mm), no fit of these samples can reach the centre's
    /// NDF; the difference between the two sets of figures is the camera's
    /// resolution, the rest is the fitter's.
    pub ndf_rel_l2_observed_footprint: Option<f64>,
    pub ndf_rel_l2_full_footprint: Option<f64>,
    pub ndf_shape_observed_footprint: Option<f64>,
    pub fit_seconds: Option<f64>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Holdout {
    /// Relative RMS error of the model's prediction of the held-out samples.
    pub frame_rel_rmse: Option<f64>,
    /// The true material's error on the same samples (simulated captures):
    /// what a perfect model scores against these noisy, calibrated samples.
    /// A fitted model can score below it by absorbing a calibration bias.
    pub noise_floor: Option<f64>,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ConditionDetail {
    pub name: String,
    /// Fraction of lit sample pixels whose half vector lies outside the
    /// point's observed region.
    pub unobserved_fraction: f64,
    /// Per model: the relative RMS render error under this condition alone.
    pub render_rel_rmse: BTreeMap<String, f64>,
}

/// The output of `refl eval --json`.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Evaluation {
    pub sample: String,
    pub ground_truth: bool,
    pub conditions: usize,
    pub models: BTreeMap<String, ModelScore>,
    pub holdout: BTreeMap<String, Holdout>,
    pub condition_detail: Vec<ConditionDetail>,
    /// The render error of the truth as the material's points measure it
    /// (each point the mean BRDF of its footprint, [`crate::footprint`])
    /// against the truth: what a perfect fit of every point's samples would
    /// score, the camera's and the point grid's resolution. Simulated
    /// captures only.
    pub render_resolution_floor: Option<f64>,
    /// The true lobe's width against the capture's spacing of half vectors
    /// ([`crate::truth::lobe_reach`]): where the lobe is far narrower than
    /// the spacing, it falls between the lights and no fit recovers it.
    /// Simulated captures of a material with a specular lobe only.
    pub lobe_reach: Option<crate::truth::LobeReach>,
    /// The other capture whose observed cells the NDF errors on observed
    /// cells were also restricted to ([`EvalOptions::observed_like`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ndf_observed_like: Option<String>,
}

#[derive(Clone, Debug)]
pub struct EvalOptions {
    pub render_px: u32,
    /// Rays per pixel side in the renders ([`render::render_subpixels`]).
    pub render_subpixels: u32,
    pub holdout: bool,
    pub max_ndf_points: usize,
    /// Score the NDF errors on observed cells only on the cells that this
    /// capture's fit and another's (a capture directory) both observed:
    /// two rigs or settings see different sets of half vectors, and an
    /// error over each one's own set mixes the sets' difficulty with the
    /// fits' accuracy. The other capture must have the same point grid and
    /// table grid.
    pub observed_like: Option<std::path::PathBuf>,
}

impl Default for EvalOptions {
    fn default() -> Self {
        Self {
            render_px: 128,
            render_subpixels: RENDER_SUBPIXELS,
            holdout: true,
            max_ndf_points: 1024,
            observed_like: None,
        }
    }
}

/// The models a material holds, as eval names them.
pub fn model_names(m: &Material) -> Vec<(String, ModelChoice)> {
    let mut v = Vec::new();
    match m.ndf_kind {
        NdfKind::Synthesized => {
            v.push(("synthesized".to_string(), ModelChoice::Tabulated));
            if m.partial.is_some() {
                v.push(("partial".to_string(), ModelChoice::Partial));
            }
        }
        _ if m.ndf.is_some() => v.push(("partial".to_string(), ModelChoice::Tabulated)),
        _ => {}
    }
    for (name, mm) in &m.models {
        v.push((name.clone(), ModelChoice::Analytic(mm.model)));
    }
    if m.choice.is_some() {
        v.push(("auto".to_string(), ModelChoice::Auto));
    }
    v
}

/// Fraction of lit pixels whose half vector is outside the observed region.
fn unobserved_fraction(m: &Material, c: &Condition, sample: &SampleArea) -> f64 {
    let Some(partial) = m.partial.as_ref().map(|pf| &pf.tables).or(m.ndf.as_ref()) else { return 0.0 };
    let scene = scene_for(c, 48);
    let Light::Point { position_mm, .. } = scene.lights[0] else { return 0.0 };
    let stand_in = m.stand_ins();
    let (mut out, mut n) = (0usize, 0usize);
    for y in 0..48 {
        for x in 0..48 {
            let Some(q) = scene.camera.pixel_to_plane(glam::Vec2::new(x as f32 + 0.5, y as f32 + 0.5)) else {
                continue;
            };
            if !sample.contains(q) {
                continue;
            }
            let Some(pi) = m.point_at(q).map(|pi| stand_in[pi] as usize) else { continue };
            let p = q.extend(0.0);
            let (o, i) = (scene.camera.view_dir(p), (position_mm - p).normalize());
            if o.z <= 0.0 || i.z <= 0.0 {
                continue;
            }
            let h = (i + o).normalize();
            let grid = partial.grid();
            let Some((t, s)) = grid.cell(h) else { continue };
            let words = partial.coverage_words(pi);
            let cell = grid.index(t, s);
            n += 1;
            if !brdf::ndf::bit(words, cell) {
                out += 1;
            }
        }
    }
    if n == 0 { 0.0 } else { out as f64 / n as f64 }
}

/// NDF errors of one model against the truth, pooled over points.
#[derive(Clone, Copy, Debug, Default)]
struct NdfErrors {
    observed: Option<f64>,
    full: Option<f64>,
    shape_observed: Option<f64>,
    scale_observed: Option<f64>,
    true_mass_unobserved: Option<f64>,
    mass_unobserved: Option<f64>,
    true_mass_uncovered: Option<f64>,
}

/// The true NDF tables the NDF errors compare with, per scored point (up
/// to `max_points` measured points spread over the sample), normalised over
/// the hemisphere: the truth at the point's centre, and the truth over its
/// footprint where the capture's camera is known.
struct TruthTables {
    points: Vec<usize>,
    centre: Vec<Option<NdfTable>>,
    footprint: Vec<Option<NdfTable>>,
}

impl TruthTables {
    fn new(m: &Material, info: &store::CaptureInfo, truth: &dyn SvBrdf, max_points: usize) -> Option<Self> {
        let grid = m.ndf.as_ref().or(m.partial.as_ref().map(|pf| &pf.tables))?.grid();
        let n = m.n_points();
        let stride = n.div_ceil(max_points.max(1)).max(1);
        let points: Vec<usize> = (0..n).step_by(stride).filter(|&p| m.is_measured(p)).collect();
        let tables: Vec<(Option<NdfTable>, Option<NdfTable>)> = points
            .par_iter()
            .map(|&p| {
                let pos = m.grid.position_of(&m.sample, p);
                let centre = truth.at(pos).ndf().map(|ndf| {
                    let mut t = NdfTable::from_fn(grid, 3, |h| ndf.d(h));
                    t.normalize();
                    t
                });
                (centre, crate::footprint::ndf(&info.geometry.camera, info.sensor.layout, &m.sample, truth, pos, grid))
            })
            .collect();
        let (centre, footprint) = tables.into_iter().unzip();
        Some(Self { points, centre, footprint })
    }
}

fn ndf_errors(
    m: &Material,
    which: ModelChoice,
    truth: &TruthTables,
    footprint: bool,
    also_observed: Option<&TableSet>,
) -> NdfErrors {
    let set = match which {
        ModelChoice::Tabulated => m.ndf.as_ref(),
        ModelChoice::Partial => m.partial.as_ref().map(|pf| &pf.tables).or(m.ndf.as_ref()),
        _ => None,
    };
    let Some(set) = set else { return NdfErrors::default() };
    let observed_set = m.partial.as_ref().map_or(set, |pf| &pf.tables);
    let grid = set.grid();
    let np = grid.n_phi as usize;
    let tables = if footprint { &truth.footprint } else { &truth.centre };
    // Per point, in the table's cosine measure: on the observed cells
    // sum (a-b)^2, sum b^2, the best-scale residual, sum ab, sum aa; then
    // over the hemisphere sum (a-b)^2, sum b^2; then the masses sum b and
    // sum a off the observed cells, sum b off the table's coverage.
    let sums: Vec<[f64; 10]> = truth
        .points
        .iter()
        .zip(tables)
        .filter_map(|(&p, t)| {
            let t = t.as_ref().filter(|t| t.grid() == grid)?;
            let est = set.get(p);
            let obs = observed_set.get(p);
            let also = also_observed.map(|o| o.get(p));
            let mut x = [0.0f64; 10];
            for (k, (&a, &b)) in est.values().iter().zip(t.values()).enumerate() {
                let w = grid.cos_measure(k / np) as f64;
                let (a, b) = (a as f64, b as f64);
                x[5] += w * (a - b) * (a - b);
                x[6] += w * b * b;
                if !obs.coverage().get(k) {
                    x[7] += w * b;
                    x[8] += w * a;
                }
                if !est.coverage().get(k) {
                    x[9] += w * b;
                }
                if obs.coverage().get(k) && also.as_ref().is_none_or(|o| o.coverage().get(k)) {
                    x[0] += w * (a - b) * (a - b);
                    x[1] += w * b * b;
                    x[3] += w * a * b;
                    x[4] += w * a * a;
                }
            }
            // min over s of sum w (s a - b)^2 = sum b^2 - (sum ab)^2 / sum a^2.
            x[2] = if x[4] > 0.0 { (x[1] - x[3] * x[3] / x[4]).max(0.0) } else { x[1] };
            Some(x)
        })
        .collect();
    let mut tot = [0.0f64; 10];
    let n = sums.len();
    for x in &sums {
        tot.iter_mut().zip(x).for_each(|(t, v)| *t += v);
    }
    let rel = |num: f64, den: f64| (den > 0.0).then(|| (num / den).sqrt());
    NdfErrors {
        observed: rel(tot[0], tot[1]),
        full: rel(tot[5], tot[6]),
        shape_observed: rel(tot[2], tot[1]),
        scale_observed: (tot[4] > 0.0).then(|| tot[3] / tot[4]),
        true_mass_unobserved: (n > 0).then(|| tot[7] / n as f64),
        mass_unobserved: (n > 0).then(|| tot[8] / n as f64),
        true_mass_uncovered: (n > 0).then(|| tot[9] / n as f64),
    }
}

/// Refit without every [`HOLDOUT_EVERY`]-th gantry step (all its lights)
/// and predict the held-out samples with every model of the refitted
/// material. For a simulated capture the true material predicts them too:
/// its error is the noise floor, what a perfect model scores against these
/// noisy, calibrated samples.
fn holdout(dir: &Path, rep: &mut dyn Progress) -> Result<BTreeMap<String, Holdout>> {
    rep.stage("eval", format!("hold-out: refitting without every {HOLDOUT_EVERY}th gantry step"));
    let info = CaptureDir::read_info(dir)?;
    let (entries, _) = CaptureDir::read_manifest(dir)?;
    let q: Quality =
        serde_json::from_value(info.settings.clone()).context("capture.json lacks its quality settings")?;
    let mut settings = q.fit.clone();
    settings.holdout_every = Some(HOLDOUT_EVERY);
    let ctx = fit::FitContext::new(crate::replay::fit_inputs(&info));
    // Ingest everything, keep the samples, fit without the held-out lights.
    let stages = fit::Stages { keep_samples: true, ..q.stages(&config::Overrides::default()) };
    let mut pipeline = fit::Pipeline::new(&ctx, settings, stages);
    crate::replay::for_each_frame(dir, &entries, &mut |msg| {
        msg.feed(&mut pipeline);
        Ok(())
    })?;
    let mut fitted = pipeline.finish(&|| false)?;
    let store = fitted.samples.take().ok_or_else(|| anyhow!("the fit kept no samples"))?;
    let m = Arc::new(crate::replay::material_from(&fitted, &info, &q));
    let mut predictors: Vec<(String, Arc<dyn SvBrdf>)> = Vec::new();
    for (name, choice) in model_names(&m) {
        let view = MaterialView::new(m.clone(), choice).ok_or_else(|| anyhow!("material lacks model {name}"))?;
        predictors.push((name, Arc::new(view)));
    }
    // The truth, for a simulated capture, predicts last: its error is the floor.
    let truth = ground_truth(&info)?;
    let n_models = predictors.len();
    predictors.extend(truth.map(|t| ("truth".to_string(), t)));
    let held: Vec<usize> = (0..ctx.n_lights()).filter(|&q| fitted.settings.holds_out(&ctx.inputs.plan, q)).collect();
    // (sum (pred - rho)^2, sum rho^2) per predictor.
    let mut sums = vec![(0.0f64, 0.0f64); predictors.len()];
    for p in 0..ctx.n_points() {
        let x = ctx.positions[p];
        let pos = glam::Vec2::new(x.x, x.y);
        let at: Vec<material::PointMaterial> = predictors.iter().map(|(_, v)| v.at(pos)).collect();
        for &q in &held {
            let (rho, fl) = store.get(q, p);
            if fl & fit::samples::flag::UNUSABLE != 0 {
                continue;
            }
            let Some(g) = ctx.sample(p, q) else { continue };
            for (s, model) in sums.iter_mut().zip(&at) {
                let pred = model.eval(g.i, ctx.view[p]);
                for c in 0..3 {
                    s.0 += ((pred[c] - rho[c]) as f64).powi(2);
                    s.1 += (rho[c] as f64).powi(2);
                }
            }
        }
    }
    let rel = |s: (f64, f64)| (s.1 > 0.0).then(|| (s.0 / s.1).sqrt());
    let floor = sums.get(n_models).and_then(|&s| rel(s));
    Ok(predictors[..n_models]
        .iter()
        .zip(&sums)
        .map(|((name, _), &s)| (name.clone(), Holdout { frame_rel_rmse: rel(s), noise_floor: floor }))
        .collect())
}

/// Every k-th gantry step is held out.
pub const HOLDOUT_EVERY: u32 = 8;

/// Rays per pixel side in the evaluation's renders.
pub const RENDER_SUBPIXELS: u32 = 1;

/// Evaluate a capture directory.
pub fn evaluate(dir: &Path, opts: &EvalOptions, rep: &mut dyn Progress) -> Result<Evaluation> {
    let info = CaptureDir::read_info(dir)?;
    let mdir = dir.join("material");
    let m = Arc::new(material::read(&mdir).with_context(|| format!("{} has no fitted material", dir.display()))?);
    let truth: Option<Arc<dyn SvBrdf>> = ground_truth(&info)?;
    let conds = conditions();
    let mut ev = Evaluation {
        sample: info.sample.clone(),
        ground_truth: truth.is_some(),
        conditions: conds.len(),
        ..Evaluation::default()
    };
    ev.condition_detail = conds
        .iter()
        .map(|c| ConditionDetail {
            name: c.name.clone(),
            unobserved_fraction: unobserved_fraction(&m, c, &info.geometry.sample),
            render_rel_rmse: BTreeMap::new(),
        })
        .collect();
    let sample = info.geometry.sample;
    // A material's renders under every condition.
    let draw = |m: &dyn SvBrdf| -> Vec<Image> {
        conds
            .iter()
            .map(|c| render::render_subpixels(m, &sample, &scene_for(c, opts.render_px), 7, opts.render_subpixels))
            .collect()
    };
    let truth_renders: Option<Vec<Image>> = truth.as_ref().map(|t| {
        rep.stage("eval", format!("rendering the ground truth under {} conditions", conds.len()));
        draw(t.as_ref())
    });
    let resolved_renders: Option<Vec<Image>> = truth.as_ref().zip(truth_renders.as_ref()).map(|(t, tr)| {
        rep.stage("eval", "rendering the truth as the points measure it (the resolution floor)".to_string());
        let resolved = crate::footprint::Resolved {
            material: m.clone(),
            camera: info.geometry.camera,
            layout: info.sensor.layout,
            truth: t.clone(),
        };
        let renders = draw(&resolved);
        let pairs: Vec<(&Image, &Image)> = renders.iter().zip(tr.iter()).collect();
        ev.render_resolution_floor = render::rel_rmse(&pairs);
        renders
    });
    // The other capture's observed cells, where asked.
    let other = match &opts.observed_like {
        Some(o) => {
            let om = material::read(&o.join("material"))
                .with_context(|| format!("--observed-like: {} has no fitted material", o.display()))?;
            let tables = om.partial.map(|pf| pf.tables).or(om.ndf);
            let ours = m.partial.as_ref().map(|pf| &pf.tables).or(m.ndf.as_ref());
            let same = |a: &TableSet, b: &TableSet| a.grid() == b.grid() && a.len() == b.len();
            match (tables, ours) {
                (Some(t), Some(u)) if same(&t, u) => {
                    ev.ndf_observed_like = Some(o.display().to_string());
                    Some(t)
                }
                (Some(_), Some(_)) => bail!(
                    "--observed-like: {} has another point grid or NDF table grid than {}",
                    o.display(),
                    dir.display()
                ),
                _ => bail!("--observed-like: {} or {} has no NDF tables", o.display(), dir.display()),
            }
        }
        None => None,
    };
    ev.lobe_reach = truth
        .as_ref()
        .and_then(|t| crate::truth::lobe_reach(&fit::FitContext::new(crate::replay::fit_inputs(&info)), t.as_ref()));
    let truth_tables = truth.as_ref().and_then(|t| {
        rep.stage("eval", "the true NDFs at the scored points and over their footprints".to_string());
        TruthTables::new(&m, &info, t.as_ref(), opts.max_ndf_points)
    });
    for (name, choice) in model_names(&m) {
        let t0 = Instant::now();
        let view = MaterialView::new(m.clone(), choice).ok_or_else(|| anyhow!("material lacks model {name}"))?;
        let mut score = ModelScore {
            fit_seconds: m
                .models
                .get(&name)
                .map(|mm| mm.fit_seconds)
                .or_else(|| m.provenance.get("fit_seconds").and_then(|v| v.get(&name)).and_then(|v| v.as_f64())),
            ..ModelScore::default()
        };
        if let Some(tr) = &truth_renders {
            let renders = draw(&view);
            let pairs: Vec<(&Image, &Image)> = renders.iter().zip(tr.iter()).collect();
            score.render_rel_rmse = render::rel_rmse(&pairs);
            if let Some(rr) = &resolved_renders {
                let pairs: Vec<(&Image, &Image)> = renders.iter().zip(rr.iter()).collect();
                score.render_rel_rmse_resolved = render::rel_rmse(&pairs);
            }
            for (d, pair) in ev.condition_detail.iter_mut().zip(&pairs) {
                if let Some(e) = render::rel_rmse(std::slice::from_ref(pair)) {
                    d.render_rel_rmse.insert(name.clone(), e);
                }
            }
            if let Some(tt) = &truth_tables {
                let e = ndf_errors(&m, choice, tt, false, other.as_ref());
                score.ndf_rel_l2_observed = e.observed;
                score.ndf_rel_l2_full = e.full;
                score.ndf_shape_observed = e.shape_observed;
                score.ndf_scale_observed = e.scale_observed;
                score.ndf_true_mass_unobserved = e.true_mass_unobserved;
                score.ndf_mass_unobserved = e.mass_unobserved;
                score.ndf_true_mass_uncovered = e.true_mass_uncovered;
                let e = ndf_errors(&m, choice, tt, true, other.as_ref());
                score.ndf_rel_l2_observed_footprint = e.observed;
                score.ndf_rel_l2_full_footprint = e.full;
                score.ndf_shape_observed_footprint = e.shape_observed;
            }
        }
        rep.stage("eval", format!("{name}: {:?} ({:.1} s)", score.render_rel_rmse, t0.elapsed().as_secs_f64()));
        ev.models.insert(name, score);
    }
    if opts.holdout {
        ev.holdout = holdout(dir, rep)?;
    }
    Ok(ev)
}
