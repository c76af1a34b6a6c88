//! Reading and writing the material directory (specified in `MATERIAL.md`
//! at the repository root).

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

use brdf::ndf::{NdfGrid, TableSet};
use brdf::params::AnalyticModel;
use exr::prelude::{
    AnyChannel, AnyChannels, Encoding, FlatSamples, Image, Layer, LayerAttributes, ReadChannels, ReadLayers, SmallVec,
    WritableImage, f16,
};
use serde::{Deserialize, Serialize};
use setup::{PointGrid, SampleArea};
use thiserror::Error;

use crate::data::{Choice, ChoiceMap, Material, ModelMap, NdfKind, PartialFit};

/// Version of the material format.
pub const MATERIAL_FORMAT_VERSION: u32 = 1;

#[derive(Debug, Error)]
pub enum MaterialError {
    #[error("{0} is not a material directory (no material.json)")]
    NotAMaterial(String),
    #[error("{path} cannot take a material: {reason}; nothing was changed")]
    Occupied { path: String, reason: String },
    #[error("{0} already holds a material; choose another directory, or replace it explicitly")]
    Exists(String),
    #[error("{path}: {reason}")]
    Malformed { path: String, reason: String },
    #[error("{path} is material format version {found}; this program reads version {MATERIAL_FORMAT_VERSION}")]
    Version { path: String, found: u32 },
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
}

fn malformed(path: &Path, reason: impl Into<String>) -> MaterialError {
    MaterialError::Malformed { path: path.display().to_string(), reason: reason.into() }
}

fn io(path: &Path, source: std::io::Error) -> MaterialError {
    MaterialError::Io { path: path.display().to_string(), source }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct NdfEntry {
    file: String,
    grid: NdfGrid,
    kind: NdfKind,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct ModelEntry {
    name: String,
    file: String,
    params: Vec<String>,
    fit_seconds: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct ChoiceEntry {
    legend: Vec<String>,
    isotropic_model: String,
    anisotropic_model: String,
}

/// `material.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct MaterialJson {
    format_version: u32,
    name: String,
    sample: SampleArea,
    grid: PointGrid,
    conventions: String,
    units: String,
    maps: String,
    ndf: Option<NdfEntry>,
    partial_ndf: Option<NdfEntry>,
    models: Vec<ModelEntry>,
    choice: Option<ChoiceEntry>,
    provenance: serde_json::Value,
}

const CONVENTIONS: &str = "local frame: normal +z, x along the sample's x axis (gantry travel); i toward the light, \
o toward the viewer; f = kd/pi + ks D(h) F_rel(i.h) / (4 sigma(i) sigma(o)), integral D cos = 1, F_rel(1) = 1 \
(relative dielectric Fresnel with index eta), sigma(v) = integral max(0, h.v) D(h) dw; NDF tables: ring t of \
n_theta spans theta = (t/n_theta)^2 pi/2 .. ((t+1)/n_theta)^2 pi/2, sector p spans phi = p 2pi/n_phi ..; map row 0 \
is the sample's +y edge, column 0 its -x edge";

const UNITS: &str = "kd, ks: albedo (unitless, linear RGB); eta: unitless; D: 1/sr; positions: mm";

fn write_channels(
    path: &Path,
    width: usize,
    height: usize,
    channels: Vec<(String, FlatSamples)>,
) -> Result<(), MaterialError> {
    write_encoded(path, width, height, channels, Encoding::SMALL_LOSSLESS)
}

fn write_encoded(
    path: &Path,
    width: usize,
    height: usize,
    channels: Vec<(String, FlatSamples)>,
    encoding: Encoding,
) -> Result<(), MaterialError> {
    let list: Vec<AnyChannel<FlatSamples>> =
        channels.into_iter().map(|(n, s)| AnyChannel::new(n.as_str(), s)).collect();
    let layer =
        Layer::new((width, height), LayerAttributes::default(), encoding, AnyChannels::sort(SmallVec::from_vec(list)));
    Image::from_layer(layer).write().to_file(path).map_err(|e| malformed(path, format!("writing EXR: {e}")))
}

/// Every channel of an EXR's first layer as `f32`, with its width and
/// height: how this crate reads its files, and how a test reads one back.
pub fn read_channels(path: &Path) -> Result<(usize, usize, BTreeMap<String, Vec<f32>>), MaterialError> {
    let img = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| malformed(path, format!("not a readable EXR: {e}")))?;
    let size = img.layer_data.size;
    let mut out = BTreeMap::new();
    for ch in &img.layer_data.channel_data.list {
        out.insert(ch.name.to_string(), ch.sample_data.values_as_f32().collect::<Vec<f32>>());
    }
    Ok((size.0, size.1, out))
}

fn take(path: &Path, ch: &mut BTreeMap<String, Vec<f32>>, name: &str, len: usize) -> Result<Vec<f32>, MaterialError> {
    let v = ch.remove(name).ok_or_else(|| malformed(path, format!("channel '{name}' is missing")))?;
    if v.len() != len {
        return Err(malformed(path, format!("channel '{name}' has {} values, expected {len}", v.len())));
    }
    if let Some(bad) = v.iter().position(|x| !x.is_finite()) {
        return Err(malformed(path, format!("channel '{name}' holds a non-finite value at index {bad}")));
    }
    Ok(v)
}

fn write_tables(path: &Path, t: &TableSet) -> Result<(), MaterialError> {
    let g = t.grid();
    let (values, coverage) = t.raw();
    let cells = g.len();
    let words = cells.div_ceil(64);
    let mut observed = Vec::with_capacity(values.len());
    for k in 0..t.len() {
        for c in 0..cells {
            let on = brdf::ndf::bit(&coverage[k * words..(k + 1) * words], c);
            observed.push(f16::from_f32(if on { 1.0 } else { 0.0 }));
        }
    }
    write_channels(
        path,
        g.n_phi as usize,
        g.n_theta as usize * t.len(),
        vec![("D".into(), FlatSamples::F16(values.to_vec())), ("observed".into(), FlatSamples::F16(observed))],
    )
}

/// Pixels per side of a point's tile in `ndf_atlas.exr`, per ring of its
/// table: one across each ring's width (at two, balanced satin's atlas
/// took 63 MB and most of the material's writing time).
const ATLAS_PX_PER_RING: usize = 1;

/// `ndf_atlas.exr`: every point's table as a top view of its hemisphere,
/// one square tile per point laid out as the grid (row 0 the `+y` edge, as
/// `maps.exr`), for people to look at. In a tile, `x` is right and `y` up;
/// the distance from the centre is `sqrt(theta / (pi/2))` of the tile's
/// half width (the tables' own ring spacing), so each ring is equally wide.
/// Channels `D` (the table, interpolated as it is evaluated) and
/// `observed`; 0 outside the disk.
fn write_atlas(path: &Path, t: &TableSet, grid: setup::PointGrid) -> Result<(), MaterialError> {
    let g = t.grid();
    let side = ATLAS_PX_PER_RING * 2 * g.n_theta as usize;
    let (cols, rows) = (grid.cols as usize, grid.rows as usize);
    let (w, h) = (cols * side, rows * side);
    let mut d = vec![f16::ZERO; w * h];
    let mut observed = vec![f16::ZERO; w * h];
    // Each tile pixel's interpolation (`NdfTable::eval` at its half
    // vector, which is above the horizon) and cell, once.
    let dirs: Vec<Option<(brdf::ndf::Bilinear, usize)>> = (0..side * side)
        .map(|k| {
            let (x, y) = (k % side, k / side);
            let u = 2.0 * (x as f32 + 0.5) / side as f32 - 1.0;
            let v = 1.0 - 2.0 * (y as f32 + 0.5) / side as f32;
            let r = u.hypot(v);
            if r > 1.0 {
                return None;
            }
            let theta = r * r * std::f32::consts::FRAC_PI_2;
            let phi = v.atan2(u);
            let hv = glam::Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
            let (ti, pi) = g.cell(hv)?;
            Some((g.bilinear(hv), g.index(ti, pi)))
        })
        .collect();
    for p in 0..t.len() {
        let table = t.get(p);
        let (tx, ty) = ((p % cols) * side, (p / cols) * side);
        for (k, dir) in dirs.iter().enumerate() {
            let Some((bilinear, cell)) = dir else { continue };
            let at = (ty + k / side) * w + tx + k % side;
            d[at] = f16::from_f32(table.eval_at(*bilinear));
            observed[at] = f16::from_f32(if table.coverage().get(*cell) { 1.0 } else { 0.0 });
        }
    }
    // Run-length coding: the disks' surrounds are long runs of zeros, and
    // zip would cost the material seconds of the time it is ready in.
    let channels = vec![("D".into(), FlatSamples::F16(d)), ("observed".into(), FlatSamples::F16(observed))];
    write_encoded(path, w, h, channels, Encoding::FAST_LOSSLESS)
}

fn read_tables(path: &Path, grid: NdfGrid, n: usize) -> Result<TableSet, MaterialError> {
    let (w, h, mut ch) = read_channels(path)?;
    let cells = grid.len();
    if w != grid.n_phi as usize || h != grid.n_theta as usize * n {
        return Err(malformed(path, format!("is {w}x{h}, expected {}x{}", grid.n_phi, grid.n_theta as usize * n)));
    }
    let d = take(path, &mut ch, "D", cells * n)?;
    if let Some(bad) = d.iter().position(|&x| x < 0.0) {
        return Err(malformed(path, format!("NDF value {} at index {bad} is negative", d[bad])));
    }
    let obs = take(path, &mut ch, "observed", cells * n)?;
    let words = cells.div_ceil(64);
    let mut coverage = vec![0u64; words * n];
    for k in 0..n {
        for c in 0..cells {
            if obs[k * cells + c] > 0.5 {
                coverage[k * words + c / 64] |= 1 << (c % 64);
            }
        }
    }
    let values = d.into_iter().map(f16::from_f32).collect();
    TableSet::from_raw(grid, n, values, coverage).ok_or_else(|| malformed(path, "inconsistent table sizes"))
}

/// What [`write`] may do to a directory that already exists.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WriteMode {
    /// Only a new or empty directory is written; an existing material is
    /// refused.
    New,
    /// An existing material is replaced (atomically); anything that is not
    /// a material, or a material holding files the format does not write,
    /// is still refused.
    Replace,
}

/// Is `name` a file a material directory holds (one [`write`] makes)?
fn is_material_file(name: &str) -> bool {
    matches!(name, "material.json" | "maps.exr" | "ndf.exr" | "ndf_atlas.exr" | "ndf_partial.exr")
        || (name.starts_with("model_") && name.ends_with(".exr"))
}

/// Check what is at `dir` before writing a material there: nothing, an
/// empty directory, or (with [`WriteMode::Replace`]) a material holding
/// only the format's files. Returns whether a material is to be replaced.
fn check_target(dir: &Path, mode: WriteMode) -> Result<bool, MaterialError> {
    let meta = match fs::symlink_metadata(dir) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        Err(e) => return Err(io(dir, e)),
    };
    let shown = dir.display().to_string();
    if !meta.is_dir() {
        return Err(MaterialError::Occupied { path: shown, reason: "it is a file, not a directory".into() });
    }
    let names: Vec<String> = fs::read_dir(dir)
        .map_err(|e| io(dir, e))?
        .map(|e| e.map(|e| e.file_name().to_string_lossy().into_owned()))
        .collect::<Result<_, _>>()
        .map_err(|e| io(dir, e))?;
    if names.is_empty() {
        return Ok(false);
    }
    if !names.iter().any(|n| n == "material.json") {
        return Err(MaterialError::Occupied {
            path: shown,
            reason: format!("it holds {} entries and is not a material (no material.json)", names.len()),
        });
    }
    if mode == WriteMode::New {
        return Err(MaterialError::Exists(shown));
    }
    if let Some(foreign) = names.iter().find(|n| !is_material_file(n)) {
        return Err(MaterialError::Occupied {
            path: shown,
            reason: format!("it holds '{foreign}', which a material does not; move it elsewhere first"),
        });
    }
    Ok(true)
}

/// Write a material directory. Everything goes into a new temporary
/// sibling directory first, which then takes `dir`'s place; nothing at
/// `dir` is touched unless the whole material was written. A directory
/// that is not empty is refused unless it is a material and `mode` is
/// [`WriteMode::Replace`]; then only the format's own files are removed.
pub fn write(dir: &Path, m: &Material, mode: WriteMode) -> Result<(), MaterialError> {
    let n = m.n_points();
    for (what, len) in [("kd", m.kd.len()), ("ks", m.ks.len()), ("eta", m.eta.len()), ("flags", m.flags.len())] {
        if len != n {
            return Err(malformed(dir, format!("{what} has {len} points, the grid has {n}")));
        }
    }
    let replacing = check_target(dir, mode)?;
    let parent = dir.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    fs::create_dir_all(parent).map_err(|e| io(parent, e))?;
    let name = dir.file_name().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "material".into());
    let tmp = unique_sibling(parent, &name, "tmp")?;
    if let Err(e) = write_into(&tmp, m) {
        remove_material_files(&tmp);
        return Err(e);
    }
    if replacing {
        let old = unique_sibling(parent, &name, "old")?;
        // `old` was just made empty; renaming a directory onto an empty one replaces it.
        if let Err(e) = fs::rename(dir, &old) {
            let _ = fs::remove_dir(&old);
            remove_material_files(&tmp);
            return Err(io(dir, e));
        }
        if let Err(e) = fs::rename(&tmp, dir) {
            let _ = fs::rename(&old, dir);
            remove_material_files(&tmp);
            return Err(io(dir, e));
        }
        remove_material_files(&old);
    } else {
        // An empty directory at `dir` is replaced by the rename; a
        // non-empty one (made since the check) makes it fail, untouched.
        if let Err(e) = fs::rename(&tmp, dir) {
            remove_material_files(&tmp);
            return Err(io(dir, e));
        }
    }
    Ok(())
}

/// Make a new, empty directory `parent/.NAME.WHAT-PID-K` (never an
/// existing one).
fn unique_sibling(parent: &Path, name: &str, what: &str) -> Result<PathBuf, MaterialError> {
    for k in 0..1000 {
        let p = parent.join(format!(".{name}.{what}-{}-{k}", std::process::id()));
        match fs::create_dir(&p) {
            Ok(()) => return Ok(p),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(io(&p, e)),
        }
    }
    Err(io(parent, std::io::Error::other("no free name for a temporary directory")))
}

/// Remove a directory [`write`] made or replaced: only the format's files,
/// then the directory if that left it empty.
fn remove_material_files(dir: &Path) {
    if let Ok(rd) = fs::read_dir(dir) {
        for e in rd.flatten() {
            if is_material_file(&e.file_name().to_string_lossy()) {
                let _ = fs::remove_file(e.path());
            }
        }
    }
    let _ = fs::remove_dir(dir);
}

fn write_into(dir: &Path, m: &Material) -> Result<(), MaterialError> {
    let n = m.n_points();
    let (w, h) = (m.grid.cols as usize, m.grid.rows as usize);
    let col = |c: usize, v: &[[f32; 3]]| FlatSamples::F32(v.iter().map(|x| x[c]).collect());
    let mut maps = vec![
        ("kd.R".to_string(), col(0, &m.kd)),
        ("kd.G".into(), col(1, &m.kd)),
        ("kd.B".into(), col(2, &m.kd)),
        ("ks.R".into(), col(0, &m.ks)),
        ("ks.G".into(), col(1, &m.ks)),
        ("ks.B".into(), col(2, &m.ks)),
        ("eta".into(), FlatSamples::F32(m.eta.clone())),
        ("flags".into(), FlatSamples::U32(m.flags.clone())),
    ];
    if let Some(pf) = &m.partial {
        if pf.ks.len() != n || pf.eta.len() != n || pf.tables.len() != n {
            return Err(malformed(dir, "the partial fit's maps do not cover the grid"));
        }
        maps.push(("partial_ks.R".into(), col(0, &pf.ks)));
        maps.push(("partial_ks.G".into(), col(1, &pf.ks)));
        maps.push(("partial_ks.B".into(), col(2, &pf.ks)));
        maps.push(("partial_eta".into(), FlatSamples::F32(pf.eta.clone())));
    }
    if let Some(c) = &m.choice {
        maps.push(("choice".into(), FlatSamples::U32(c.choice.iter().map(|&x| x as u32).collect())));
    }
    // The tables (the largest files, zip-compressed) and the atlas are
    // written on threads of their own while this one writes the maps and
    // the models.
    let (ndf, partial_ndf, models) = std::thread::scope(|scope| -> Result<_, MaterialError> {
        let ndf_job = m.ndf.as_ref().map(|t| scope.spawn(move || write_tables(&dir.join("ndf.exr"), t)));
        let atlas_job = m.ndf.as_ref().map(|t| scope.spawn(move || write_atlas(&dir.join("ndf_atlas.exr"), t, m.grid)));
        let partial_job =
            m.partial.as_ref().map(|pf| scope.spawn(move || write_tables(&dir.join("ndf_partial.exr"), &pf.tables)));
        write_channels(&dir.join("maps.exr"), w, h, maps)?;
        let mut models = Vec::new();
        for (name, mm) in &m.models {
            let names = mm.model.param_names();
            let np = names.len();
            if mm.params.len() != np * m.n_points() {
                return Err(malformed(
                    dir,
                    format!("model {name} has {} values, expected {}", mm.params.len(), np * m.n_points()),
                ));
            }
            let chans = names
                .iter()
                .enumerate()
                .map(|(k, n)| (n.clone(), FlatSamples::F32(mm.params.iter().skip(k).step_by(np).copied().collect())))
                .collect();
            let file = format!("model_{name}.exr");
            write_channels(&dir.join(&file), w, h, chans)?;
            models.push(ModelEntry { name: name.clone(), file, params: names, fit_seconds: mm.fit_seconds });
        }
        for job in [ndf_job, atlas_job, partial_job].into_iter().flatten() {
            job.join().map_err(|_| malformed(dir, "a thread writing its tables failed"))??;
        }
        let ndf = m.ndf.as_ref().map(|t| NdfEntry { file: "ndf.exr".into(), grid: t.grid(), kind: m.ndf_kind });
        let partial_ndf = m.partial.as_ref().map(|pf| NdfEntry {
            file: "ndf_partial.exr".into(),
            grid: pf.tables.grid(),
            kind: NdfKind::Partial,
        });
        Ok((ndf, partial_ndf, models))
    })?;
    let choice = m.choice.as_ref().map(|c| ChoiceEntry {
        legend: vec!["diffuse".into(), "isotropic".into(), "anisotropic".into(), "tabulated".into()],
        isotropic_model: c.isotropic_model.name().into(),
        anisotropic_model: c.anisotropic_model.name().into(),
    });
    let json = MaterialJson {
        format_version: MATERIAL_FORMAT_VERSION,
        name: m.name.clone(),
        sample: m.sample,
        grid: m.grid,
        conventions: CONVENTIONS.into(),
        units: UNITS.into(),
        maps: "maps.exr".into(),
        ndf,
        partial_ndf,
        models,
        choice,
        provenance: m.provenance.clone(),
    };
    let text = serde_json::to_string_pretty(&json).map_err(|e| malformed(dir, e.to_string()))?;
    fs::write(dir.join("material.json"), text).map_err(|e| io(&dir.join("material.json"), e))
}

/// Read and validate a material directory.
pub fn read(dir: &Path) -> Result<Material, MaterialError> {
    let jp = dir.join("material.json");
    if !jp.exists() {
        return Err(MaterialError::NotAMaterial(dir.display().to_string()));
    }
    let text = fs::read_to_string(&jp).map_err(|e| io(&jp, e))?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| malformed(&jp, e.to_string()))?;
    let found = v.get("format_version").and_then(|x| x.as_u64()).unwrap_or(0) as u32;
    if found != MATERIAL_FORMAT_VERSION {
        return Err(MaterialError::Version { path: jp.display().to_string(), found });
    }
    let j: MaterialJson = serde_json::from_value(v).map_err(|e| malformed(&jp, e.to_string()))?;
    if j.grid.cols == 0 || j.grid.rows == 0 || j.grid.len() > 16_000_000 {
        return Err(malformed(&jp, format!("grid {}x{} is not usable", j.grid.cols, j.grid.rows)));
    }
    let n = j.grid.len();
    let mp = dir.join(&j.maps);
    let (w, h, mut ch) = read_channels(&mp)?;
    if (w, h) != (j.grid.cols as usize, j.grid.rows as usize) {
        return Err(malformed(&mp, format!("is {w}x{h} but the grid is {}x{}", j.grid.cols, j.grid.rows)));
    }
    let tri = |ch: &mut BTreeMap<String, Vec<f32>>, p: &str| -> Result<Vec<[f32; 3]>, MaterialError> {
        let r = take(&mp, ch, &format!("{p}.R"), n)?;
        let g = take(&mp, ch, &format!("{p}.G"), n)?;
        let b = take(&mp, ch, &format!("{p}.B"), n)?;
        Ok((0..n).map(|i| [r[i], g[i], b[i]]).collect())
    };
    let kd = tri(&mut ch, "kd")?;
    let ks = tri(&mut ch, "ks")?;
    let eta = take(&mp, &mut ch, "eta", n)?;
    let flags = take(&mp, &mut ch, "flags", n)?.into_iter().map(|x| x as u32).collect();
    let ndf = match &j.ndf {
        Some(e) => Some(read_tables(&dir.join(&e.file), e.grid, n)?),
        None => None,
    };
    let partial = match &j.partial_ndf {
        Some(e) => Some(PartialFit {
            tables: read_tables(&dir.join(&e.file), e.grid, n)?,
            ks: tri(&mut ch, "partial_ks")?,
            eta: take(&mp, &mut ch, "partial_eta", n)?,
        }),
        None => None,
    };
    let mut models = BTreeMap::new();
    for e in &j.models {
        let model =
            AnalyticModel::from_name(&e.name).ok_or_else(|| malformed(&jp, format!("unknown model '{}'", e.name)))?;
        let path = dir.join(&e.file);
        let (w, h, mut ch) = read_channels(&path)?;
        if (w, h) != (j.grid.cols as usize, j.grid.rows as usize) {
            return Err(malformed(&path, "size differs from the grid"));
        }
        let names = model.param_names();
        let cols: Vec<Vec<f32>> = names.iter().map(|nm| take(&path, &mut ch, nm, n)).collect::<Result<_, _>>()?;
        let mut params = Vec::with_capacity(n * names.len());
        for p in 0..n {
            params.extend(cols.iter().map(|c| c[p]));
        }
        models.insert(e.name.clone(), ModelMap { model, params, fit_seconds: e.fit_seconds });
    }
    let choice = match &j.choice {
        Some(c) => {
            let raw = take(&mp, &mut ch, "choice", n)?;
            let choice = raw
                .iter()
                .map(|&x| {
                    Choice::from_u8(x as u8).ok_or_else(|| malformed(&mp, format!("choice value {x} is not a class")))
                })
                .collect::<Result<_, _>>()?;
            let model =
                |s: &str| AnalyticModel::from_name(s).ok_or_else(|| malformed(&jp, format!("unknown model '{s}'")));
            Some(ChoiceMap {
                choice,
                isotropic_model: model(&c.isotropic_model)?,
                anisotropic_model: model(&c.anisotropic_model)?,
            })
        }
        None => None,
    };
    let ndf_kind = j.ndf.as_ref().map_or(NdfKind::Partial, |e| e.kind);
    Ok(Material {
        name: j.name,
        sample: j.sample,
        grid: j.grid,
        kd,
        ks,
        eta,
        flags,
        ndf,
        ndf_kind,
        partial,
        models,
        choice,
        provenance: j.provenance,
    })
}

/// Total size of a material directory on disk, in bytes.
pub fn disk_bytes(dir: &Path) -> u64 {
    fs::read_dir(dir).map(|rd| rd.flatten().filter_map(|e| e.metadata().ok()).map(|m| m.len()).sum()).unwrap_or(0)
}

/// Path of the main NDF file of a material directory.
pub fn ndf_path(dir: &Path) -> PathBuf {
    dir.join("ndf.exr")
}
