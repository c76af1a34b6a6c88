//! `refl export-gltf`: a fitted material as a glTF 2.0 asset (the flat
//! sample as one textured quad) that ordinary renderers and engines load.
//!
//! The material is the per-point anisotropic GGX fit (`ggx_aniso`; the
//! anisotropic Ward fit stands in when GGX was not fitted, its alphas read
//! as GGX alphas) mapped onto glTF's metallic-roughness model with
//! `KHR_materials_anisotropy`, `KHR_materials_specular` and
//! `KHR_materials_ior`:
//!
//! - base colour = the diffuse albedo `kd` (sRGB texture), metallic 0;
//!   a point the camera did not measure shows its nearest measured one;
//! - glTF's anisotropic GGX has `alpha_b = r^2` and
//!   `alpha_t = mix(r^2, 1, strength^2)` along the anisotropy direction
//!   (the extension's specification), so `r = sqrt(min alpha)`,
//!   `strength = sqrt((max alpha - min alpha) / (1 - min alpha))` and the
//!   direction is the axis of the larger alpha;
//! - the dielectric `F0` comes from `ior` (= the fitted eta); the specular
//!   colour scales it to the fitted `ks` (`specular colour = ks / F0`).
//!
//! Texture `v` runs down the sample's `-y`, as the material's grid rows do;
//! the tangent is the sample's `+x`. glTF is `+y` up: sample `(x, y, z)`
//! maps to glTF `(x, z, -y)`, in metres.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow, bail};
use brdf::params::AnalyticModel;
use glam::Vec2;
use material::Material;
use render::output::srgb;

fn linear8(x: f32) -> u8 {
    (x.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Export `m` to `out` (`NAME.gltf`, with `NAME.bin` and `NAME_*.png`
/// beside it). Returns the files written.
pub fn export(m: &Material, out: &Path) -> Result<Vec<PathBuf>> {
    let (model, mm) = [AnalyticModel::GgxAniso, AnalyticModel::WardAniso]
        .iter()
        .find_map(|am| m.models.get(am.name()).map(|mm| (*am, mm)))
        .ok_or_else(|| anyhow!("the material has neither a ggx_aniso nor a ward_aniso fit to export"))?;
    let np = model.n_params();
    let n = m.n_points();
    if mm.params.len() != n * np {
        bail!("the {} parameters do not match the grid", model.name());
    }
    let stem =
        out.file_stem().map(|s| s.to_string_lossy().into_owned()).ok_or_else(|| anyhow!("--out needs a file name"))?;
    let dir = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let (w, h) = (m.grid.cols, m.grid.rows);
    let mut base = vec![0u8; n * 3];
    let mut mr = vec![0u8; n * 3];
    let mut aniso = vec![0u8; n * 3];
    let mut spec = vec![0u8; n * 3];
    // eta: one ior for the asset (glTF has no ior texture): the median.
    let mut etas: Vec<f32> = match model {
        AnalyticModel::GgxAniso => (0..n).map(|p| mm.params[p * np + 9]).filter(|e| e.is_finite()).collect(),
        _ => m.eta.clone(),
    };
    etas.sort_by(f32::total_cmp);
    let ior = etas.get(etas.len() / 2).copied().unwrap_or(1.5).clamp(1.01, 10.0);
    let f0 = ((ior - 1.0) / (ior + 1.0)).powi(2);
    let ks_max = (0..n).flat_map(|p| mm.params[p * np + 3..p * np + 6].to_vec()).fold(0.0f32, f32::max);
    let spec_factor = (ks_max / f0).max(1e-6);
    // Points the camera did not measure show their nearest measured one.
    let stand_in = m.stand_ins();
    for p in 0..n {
        let s = stand_in[p] as usize;
        let q = &mm.params[s * np..(s + 1) * np];
        for c in 0..3 {
            base[p * 3 + c] = srgb(q[c]);
            spec[p * 3 + c] = srgb(q[3 + c] / f0 / spec_factor);
        }
        let (ax, ay, angle) = (q[6].clamp(1e-4, 1.0), q[7].clamp(1e-4, 1.0), q[8]);
        let (lo, hi) = (ax.min(ay), ax.max(ay));
        let dir = if ax >= ay { angle } else { angle + std::f32::consts::FRAC_PI_2 };
        let strength = ((hi - lo) / (1.0 - lo).max(1e-6)).clamp(0.0, 1.0).sqrt();
        mr[p * 3 + 1] = linear8(lo.sqrt());
        aniso[p * 3] = linear8(0.5 + 0.5 * dir.cos());
        aniso[p * 3 + 1] = linear8(0.5 + 0.5 * dir.sin());
        aniso[p * 3 + 2] = linear8(strength);
    }
    let mut written = Vec::new();
    let mut textures = Vec::new();
    for (name, data) in [("basecolor", &base), ("metallicroughness", &mr), ("anisotropy", &aniso), ("specular", &spec)]
    {
        let file = format!("{stem}_{name}.png");
        let p = dir.join(&file);
        image::save_buffer(&p, data, w, h, image::ExtendedColorType::Rgb8)
            .with_context(|| format!("cannot write {}", p.display()))?;
        written.push(p);
        textures.push(file);
    }
    // The quad: positions (m), normals, tangents, uvs; two triangles.
    let (sw, sh) = (m.sample.width_mm / 1000.0, m.sample.height_mm / 1000.0);
    let corners = [Vec2::new(-0.5, -0.5), Vec2::new(0.5, -0.5), Vec2::new(0.5, 0.5), Vec2::new(-0.5, 0.5)];
    let mut bin: Vec<u8> = Vec::new();
    let push = |bin: &mut Vec<u8>, v: &[f32]| v.iter().for_each(|x| bin.extend_from_slice(&x.to_le_bytes()));
    for c in corners {
        push(&mut bin, &[c.x * sw, 0.0, -c.y * sh]);
    }
    for _ in corners {
        push(&mut bin, &[0.0, 1.0, 0.0]);
    }
    for _ in corners {
        push(&mut bin, &[1.0, 0.0, 0.0, 1.0]);
    }
    for c in corners {
        let uv = m.grid.coords(&m.sample, Vec2::new(c.x * m.sample.width_mm, c.y * m.sample.height_mm));
        push(&mut bin, &[uv.x / w as f32, uv.y / h as f32]);
    }
    for i in [0u16, 1, 2, 0, 2, 3] {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    let bin_file = format!("{stem}.bin");
    let bin_path = dir.join(&bin_file);
    std::fs::write(&bin_path, &bin).with_context(|| format!("cannot write {}", bin_path.display()))?;
    written.push(bin_path);
    let view = |offset: usize, len: usize| serde_json::json!({ "buffer": 0, "byteOffset": offset, "byteLength": len });
    let doc = serde_json::json!({
        "asset": { "version": "2.0", "generator": "reflectometer refl export-gltf" },
        "extensionsUsed": ["KHR_materials_anisotropy", "KHR_materials_specular", "KHR_materials_ior"],
        "scene": 0,
        "scenes": [{ "nodes": [0] }],
        "nodes": [{ "mesh": 0, "name": m.name }],
        "meshes": [{ "name": m.name, "primitives": [{
            "attributes": { "POSITION": 0, "NORMAL": 1, "TANGENT": 2, "TEXCOORD_0": 3 },
            "indices": 4, "material": 0 }] }],
        "buffers": [{ "uri": bin_file, "byteLength": bin.len() }],
        "bufferViews": [view(0, 48), view(48, 48), view(96, 64), view(160, 32), view(192, 12)],
        "accessors": [
            { "bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
              "min": [-0.5 * sw, 0.0, -0.5 * sh], "max": [0.5 * sw, 0.0, 0.5 * sh] },
            { "bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3" },
            { "bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC4" },
            { "bufferView": 3, "componentType": 5126, "count": 4, "type": "VEC2" },
            { "bufferView": 4, "componentType": 5123, "count": 6, "type": "SCALAR" }
        ],
        "samplers": [{ "magFilter": 9728, "minFilter": 9728 }],
        "images": textures.iter().map(|t| serde_json::json!({ "uri": t })).collect::<Vec<_>>(),
        "textures": (0..textures.len()).map(|k| serde_json::json!({ "source": k, "sampler": 0 })).collect::<Vec<_>>(),
        "materials": [{
            "name": m.name,
            "pbrMetallicRoughness": {
                "baseColorTexture": { "index": 0 },
                "metallicFactor": 0.0,
                "roughnessFactor": 1.0,
                "metallicRoughnessTexture": { "index": 1 }
            },
            "extensions": {
                "KHR_materials_anisotropy": { "anisotropyStrength": 1.0, "anisotropyRotation": 0.0, "anisotropyTexture": { "index": 2 } },
                "KHR_materials_specular": { "specularFactor": 1.0, "specularColorFactor": [spec_factor, spec_factor, spec_factor], "specularColorTexture": { "index": 3 } },
                "KHR_materials_ior": { "ior": ior }
            },
            "extras": { "reflectometer_model": model.name() }
        }]
    });
    std::fs::write(out, serde_json::to_vec_pretty(&doc)?).with_context(|| format!("cannot write {}", out.display()))?;
    written.push(out.to_path_buf());
    Ok(written)
}
