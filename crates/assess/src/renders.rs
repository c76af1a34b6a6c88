//! Preview renders of a fitted material: the comparison sheets a capture
//! writes to `renders/`, the model-choice map, and `refl render`.
//!
//! A sheet puts the ground truth (simulated captures), the measured model
//! and the analytic fits side by side under one exposure, so the
//! difference the microfacet synthesis makes is visible at a glance.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, anyhow, bail};
use glam::Vec3;
use material::SvBrdf;
use material::{Choice, Material, MaterialView, ModelChoice};
use render::scene::{EnvMap, Light, dir_from};
use render::{Image, Scene};
use setup::SampleArea;

use crate::Progress;

/// Distance of the evaluation camera and lights from the sample centre.
pub const EVAL_DISTANCE_MM: f32 = 400.0;

/// How a render is lit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Lighting {
    /// A point light at `EVAL_DISTANCE_MM` in the given direction.
    Point { elevation_deg: f32, azimuth_deg: f32 },
    /// A distant light from the given direction.
    Directional { elevation_deg: f32, azimuth_deg: f32 },
    /// The procedural sky with its sun at the given direction.
    Sky { elevation_deg: f32, azimuth_deg: f32, samples: u32 },
}

impl Lighting {
    /// Parse `point:ELEV,AZ`, `directional:ELEV,AZ` or `sky:ELEV,AZ` (degrees).
    pub fn parse(s: &str) -> Result<Self> {
        let (kind, rest) = s.split_once(':').unwrap_or((s, "45,30"));
        let (e, a) = parse_pair(rest).with_context(|| format!("--light {s}"))?;
        Ok(match kind {
            "point" => Lighting::Point { elevation_deg: e, azimuth_deg: a },
            "directional" => Lighting::Directional { elevation_deg: e, azimuth_deg: a },
            "sky" | "env" => Lighting::Sky { elevation_deg: e, azimuth_deg: a, samples: 64 },
            _ => bail!("--light {s}: expected point:ELEV,AZ, directional:ELEV,AZ or sky:ELEV,AZ"),
        })
    }
}

/// Parse `A,B` as two finite numbers.
pub fn parse_pair(s: &str) -> Result<(f32, f32)> {
    let (a, b) = s.split_once(',').ok_or_else(|| anyhow!("expected two numbers 'A,B', got '{s}'"))?;
    let a: f32 = a.trim().parse().map_err(|_| anyhow!("'{a}' is not a number"))?;
    let b: f32 = b.trim().parse().map_err(|_| anyhow!("'{b}' is not a number"))?;
    if !a.is_finite() || !b.is_finite() {
        bail!("'{s}' is not finite");
    }
    Ok((a, b))
}

/// A camera at (`camera_deg` polar, azimuth) looking at the sample centre,
/// lit by `light`, `px` pixels square.
pub fn scene(camera_deg: (f32, f32), light: Lighting, px: u32) -> Scene {
    let camera = Scene::camera(camera_deg.0, camera_deg.1, EVAL_DISTANCE_MM, 18.0, px);
    let d = EVAL_DISTANCE_MM;
    match light {
        Lighting::Point { elevation_deg, azimuth_deg } => Scene {
            camera,
            lights: vec![Light::Point {
                position_mm: dir_from(elevation_deg.to_radians(), azimuth_deg.to_radians()) * d,
                intensity: Vec3::splat(d * d),
            }],
            env: None,
            env_samples: 0,
        },
        Lighting::Directional { elevation_deg, azimuth_deg } => Scene {
            camera,
            lights: vec![Light::Directional {
                direction: dir_from(elevation_deg.to_radians(), azimuth_deg.to_radians()),
                irradiance: Vec3::ONE,
            }],
            env: None,
            env_samples: 0,
        },
        Lighting::Sky { elevation_deg, azimuth_deg, samples } => Scene {
            camera,
            lights: Vec::new(),
            env: Some(Arc::new(EnvMap::sky(elevation_deg, azimuth_deg))),
            env_samples: samples,
        },
    }
}

/// The views a capture's preview sheets show.
pub fn preview_views(px: u32) -> Vec<(&'static str, Scene)> {
    vec![
        ("side-light", scene((35.0, 90.0), Lighting::Point { elevation_deg: 50.0, azimuth_deg: 250.0 }, px)),
        ("tilted", scene((40.0, 0.0), Lighting::Point { elevation_deg: 80.0, azimuth_deg: 0.0 }, px)),
        ("sky", scene((45.0, 200.0), Lighting::Sky { elevation_deg: 35.0, azimuth_deg: 20.0, samples: 32 }, px)),
    ]
}

/// The models a sheet shows, in order, with their labels: the measured
/// model first, then the per-point choice and the Ward fits.
pub fn sheet_models(m: &Material) -> Vec<(String, ModelChoice)> {
    let mut v = Vec::new();
    if m.ndf.is_some() {
        let label = if m.partial.is_some() { "synthesized" } else { "tabulated" };
        v.push((label.to_string(), ModelChoice::Tabulated));
    }
    if m.choice.is_some() {
        v.push(("auto".to_string(), ModelChoice::Auto));
    }
    for name in ["ward_iso", "ward_aniso"] {
        if let Some(mm) = m.models.get(name) {
            v.push((name.to_string(), ModelChoice::Analytic(mm.model)));
        }
    }
    v
}

/// Write `renders/`: one sheet per preview view (PNG) with every panel
/// also as EXR, and the model-choice map. Returns the files written (only
/// those finished before `stop()` turned true).
pub fn write_previews(
    out: &Path,
    m: Arc<Material>,
    truth: Option<Arc<dyn SvBrdf>>,
    px: u32,
    rep: &mut dyn Progress,
    stop: &dyn Fn() -> bool,
) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let sample = m.sample;
    let mut panels_src: Vec<(String, Arc<dyn SvBrdf>)> = Vec::new();
    if let Some(t) = truth {
        panels_src.push(("truth".to_string(), t));
    }
    for (label, choice) in sheet_models(&m) {
        let view = MaterialView::new(m.clone(), choice).ok_or_else(|| anyhow!("material lacks model {label}"))?;
        panels_src.push((label, Arc::new(view)));
    }
    let mut written = Vec::new();
    for (view_name, scene) in preview_views(px) {
        rep.stage("render", format!("{view_name}: {} panels", panels_src.len()));
        let mut images: Vec<Image> = Vec::with_capacity(panels_src.len());
        for (_, b) in &panels_src {
            // A stop request is honoured between panels (each takes well under a second).
            if stop() {
                return Ok(written);
            }
            images.push(render::render(b.as_ref(), &sample, &scene, 11));
        }
        for ((label, _), img) in panels_src.iter().zip(&images) {
            let p = out.join(format!("{view_name}-{label}.exr"));
            render::output::write_exr(&p, img)?;
            written.push(p);
        }
        let panels: Vec<(&str, &Image)> = panels_src.iter().map(|(l, _)| l.as_str()).zip(images.iter()).collect();
        let p = out.join(format!("{view_name}.png"));
        render::output::write_sheet(&p, &panels)?;
        written.push(p);
    }
    if let Some(p) = write_choice_map(out, &m)? {
        written.push(p);
    }
    Ok(written)
}

/// Colours of the model-choice map, by class.
pub const CHOICE_COLOURS: [(Choice, [u8; 3]); 4] = [
    (Choice::Diffuse, [128, 128, 128]),
    (Choice::Isotropic, [60, 110, 220]),
    (Choice::Anisotropic, [60, 180, 90]),
    (Choice::Tabulated, [220, 70, 60]),
];

/// `model_choice.png`: each point's chosen class as a colour (grey diffuse,
/// blue isotropic, green anisotropic, red tabulated), scaled up to at least
/// 256 pixels wide. `None` when the material has no choice.
pub fn write_choice_map(out: &Path, m: &Material) -> Result<Option<PathBuf>> {
    let Some(c) = &m.choice else { return Ok(None) };
    let (cols, rows) = (m.grid.cols, m.grid.rows);
    let scale = (256 / cols.max(1)).max(1);
    let (w, h) = (cols * scale, rows * scale);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    for y in 0..h {
        for x in 0..w {
            let p = ((y / scale) * cols + x / scale) as usize;
            let rgb = CHOICE_COLOURS.iter().find(|(k, _)| *k == c.choice[p]).map(|(_, c)| *c).unwrap_or([0; 3]);
            let i = ((y * w + x) * 3) as usize;
            buf[i..i + 3].copy_from_slice(&rgb);
        }
    }
    let p = out.join("model_choice.png");
    image::save_buffer(&p, &buf, w, h, image::ExtendedColorType::Rgb8)
        .with_context(|| format!("cannot write {}", p.display()))?;
    Ok(Some(p))
}

/// Resolve a model name against a material (`refl render --model`).
pub fn model_by_name(m: &Material, name: &str) -> Result<ModelChoice> {
    let choice = match name {
        "synthesized" | "tabulated" => ModelChoice::Tabulated,
        "partial" => ModelChoice::Partial,
        "auto" => ModelChoice::Auto,
        other => match m.models.get(other) {
            Some(mm) => ModelChoice::Analytic(mm.model),
            None => {
                let mut known: Vec<&str> = vec!["tabulated", "partial"];
                if m.choice.is_some() {
                    known.push("auto");
                }
                known.extend(m.models.keys().map(|s| s.as_str()));
                bail!("the material has no model '{other}'; it has {}", known.join(", "))
            }
        },
    };
    Ok(choice)
}

/// Render one model of a material to `out` (`.exr` linear, anything else
/// PNG at automatic exposure).
pub fn render_to_file(m: Arc<Material>, model: &str, scene: &Scene, out: &Path) -> Result<()> {
    let choice = model_by_name(&m, model)?;
    let sample: SampleArea = m.sample;
    let view = MaterialView::new(m, choice).ok_or_else(|| anyhow!("the material lacks what model '{model}' needs"))?;
    let img = render::render(&view, &sample, scene, 11);
    if out.extension().is_some_and(|e| e.eq_ignore_ascii_case("exr")) {
        render::output::write_exr(out, &img)?;
    } else {
        let e = render::output::auto_exposure(&img);
        render::output::write_png(out, &img, e)?;
    }
    Ok(())
}
