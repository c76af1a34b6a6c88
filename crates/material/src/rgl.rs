//! Measured BRDFs from the RGL material database (Dupuy and Jakob 2018),
//! read from its "tensor file" container, and their import as a
//! homogeneous material in this project's format.
//!
//! The container and the meaning of its tables are described in
//! `../shared/data/rgl/README.md` (from the database's documentation):
//! `f_r(i, o) = rgb(i, h) D(h) / (4 sigma(i))` with `h` the half vector,
//! `D` the tabulated NDF and `sigma` the projected area; the `rgb` slice is
//! indexed by the point of the unit square that the visible-NDF warp maps
//! to `h`. Tables over directions use `u_theta = sqrt(theta / (pi/2))` and
//! `u_phi = (phi + pi) / (2 pi)`; for isotropic files `phi` of `h` is taken
//! relative to the light's azimuth.
//!
//! The warp is the usual hierarchical one over a bilinearly interpolated
//! density on a grid of vertices: a marginal over rows (`u_phi`), then a
//! conditional over the row (`u_theta`). Its inverse at `h` is therefore
//! (conditional CDF at `u_theta` given `u_phi`, marginal CDF at `u_phi`),
//! both computed here in closed form from the interpolated density (the
//! interpolation between the file's `theta_i` slices is applied to the
//! density before the CDFs are taken).
//!
//! The import keeps the measured NDF (resampled onto an [`NdfGrid`]) as the
//! reference table and fits the rest of this project's microfacet model
//! (diffuse albedo, specular albedo per channel, Fresnel index; the
//! shadowing term comes from the NDF) to the measured BRDF by linear least
//! squares per candidate index, reporting the relative residual.

use std::f32::consts::{FRAC_PI_2, PI};
use std::path::Path;
use std::sync::Arc;

use brdf::ndf::{NdfGrid, NdfTable, TableSet};
use brdf::{Brdf, Rgb};
use glam::{Vec2, Vec3};
use setup::{PointGrid, SampleArea};

use crate::data::{Material, NdfKind};
use crate::view::{MaterialView, ModelChoice};

#[derive(Debug, thiserror::Error)]
pub enum RglError {
    #[error("{0}")]
    Format(String),
    #[error("{path}: {cause}")]
    Io { path: String, cause: std::io::Error },
}

fn bad(msg: impl Into<String>) -> RglError {
    RglError::Format(msg.into())
}

/// One field of a tensor file, converted to `f32`.
#[derive(Clone, Debug, PartialEq)]
pub struct Field {
    pub name: String,
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

/// Parse a tensor file. Every offset and size is checked against the
/// buffer; malformed input is an error, never a panic.
pub fn parse_tensor_file(bytes: &[u8]) -> Result<Vec<Field>, RglError> {
    struct Cursor<'a> {
        b: &'a [u8],
        at: usize,
    }
    impl Cursor<'_> {
        fn take(&mut self, n: usize) -> Result<&[u8], RglError> {
            let end = self.at.checked_add(n).filter(|&e| e <= self.b.len()).ok_or_else(|| bad("truncated header"))?;
            let s = &self.b[self.at..end];
            self.at = end;
            Ok(s)
        }
        fn u8(&mut self) -> Result<u8, RglError> {
            Ok(self.take(1)?[0])
        }
        fn u16(&mut self) -> Result<u16, RglError> {
            Ok(u16::from_le_bytes(self.take(2)?.try_into().map_err(|_| bad("truncated"))?))
        }
        fn u32(&mut self) -> Result<u32, RglError> {
            Ok(u32::from_le_bytes(self.take(4)?.try_into().map_err(|_| bad("truncated"))?))
        }
        fn u64(&mut self) -> Result<u64, RglError> {
            Ok(u64::from_le_bytes(self.take(8)?.try_into().map_err(|_| bad("truncated"))?))
        }
    }
    let mut c = Cursor { b: bytes, at: 0 };
    if c.take(12)? != b"tensor_file\0" {
        return Err(bad("not a tensor file (bad magic)"));
    }
    let (major, minor) = (c.u8()?, c.u8()?);
    if (major, minor) != (1, 0) {
        return Err(bad(format!("tensor file version {major}.{minor}; only 1.0 is known")));
    }
    let n = c.u32()?;
    if n > 1000 {
        return Err(bad(format!("{n} fields is implausible")));
    }
    let mut fields = Vec::new();
    for _ in 0..n {
        let len = c.u16()? as usize;
        let name = String::from_utf8_lossy(c.take(len)?).into_owned();
        let ndim = c.u16()? as usize;
        if ndim > 8 {
            return Err(bad(format!("field {name}: {ndim} dimensions is implausible")));
        }
        let ty = c.u8()?;
        let offset = c.u64()? as usize;
        let mut shape = Vec::with_capacity(ndim);
        for _ in 0..ndim {
            shape.push(c.u64()? as usize);
        }
        let count = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d)).ok_or_else(|| bad("size overflow"))?;
        let width = match ty {
            1 | 2 => 1,
            3 | 4 | 9 => 2,
            5 | 6 | 10 => 4,
            7 | 8 | 11 => 8,
            _ => return Err(bad(format!("field {name}: unknown type code {ty}"))),
        };
        let end = count.checked_mul(width).and_then(|b| b.checked_add(offset)).filter(|&e| e <= bytes.len());
        let Some(end) = end else { return Err(bad(format!("field {name}: data outside the file"))) };
        let raw = &bytes[offset..end];
        let data: Vec<f32> = raw
            .chunks_exact(width)
            .map(|b| match ty {
                1 => b[0] as f32,
                2 => b[0] as i8 as f32,
                3 => u16::from_le_bytes([b[0], b[1]]) as f32,
                4 => i16::from_le_bytes([b[0], b[1]]) as f32,
                5 => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
                6 => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
                9 => half::f16::from_le_bytes([b[0], b[1]]).to_f32(),
                10 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                7 => u64::from_le_bytes(b.try_into().unwrap_or([0; 8])) as f32,
                8 => i64::from_le_bytes(b.try_into().unwrap_or([0; 8])) as f32,
                _ => f64::from_le_bytes(b.try_into().unwrap_or([0; 8])) as f32,
            })
            .collect();
        fields.push(Field { name, shape, data });
    }
    Ok(fields)
}

/// A bilinearly interpolated density on `nx` x `ny` vertices over the unit
/// square, with its hierarchical (row-marginal, then conditional) CDFs.
#[derive(Clone, Debug)]
struct Warp {
    nx: usize,
    ny: usize,
    v: Vec<f32>,
    /// Integral of each row over x (trapezoid of a linear interpolant).
    row: Vec<f64>,
    /// Cumulative marginal over y at each row vertex.
    marginal: Vec<f64>,
}

impl Warp {
    fn new(nx: usize, ny: usize, v: Vec<f32>) -> Self {
        let dx = 1.0 / (nx - 1) as f64;
        let row: Vec<f64> = (0..ny)
            .map(|j| (0..nx - 1).map(|i| 0.5 * (v[j * nx + i] as f64 + v[j * nx + i + 1] as f64) * dx).sum())
            .collect();
        let dy = if ny > 1 { 1.0 / (ny - 1) as f64 } else { 1.0 };
        let mut marginal = vec![0.0f64; ny];
        for j in 1..ny {
            marginal[j] = marginal[j - 1] + 0.5 * (row[j - 1] + row[j]) * dy;
        }
        Self { nx, ny, v, row, marginal }
    }

    /// Cell index and fraction of `u` on `n` vertices.
    fn locate(u: f32, n: usize) -> (usize, f64) {
        let x = (u.clamp(0.0, 1.0) as f64) * (n - 1) as f64;
        let i = (x.floor() as usize).min(n.saturating_sub(2));
        (i, x - i as f64)
    }

    /// The point of the unit square that the warp maps to `(x, y)`.
    fn invert(&self, x: f32, y: f32) -> Vec2 {
        // Marginal CDF at y: rows' integrals are linear in y within a cell.
        let (u1, t) = if self.ny > 1 {
            let (j, t) = Self::locate(y, self.ny);
            let dy = 1.0 / (self.ny - 1) as f64;
            let (a, b) = (self.row[j], self.row[j + 1]);
            let partial = (a * t + 0.5 * (b - a) * t * t) * dy;
            let total = self.marginal[self.ny - 1];
            (if total > 0.0 { (self.marginal[j] + partial) / total } else { y as f64 }, (j, t))
        } else {
            (0.0, (0, 0.0))
        };
        let (j, t) = t;
        let j1 = (j + 1).min(self.ny - 1);
        // The row at y, linear between the two rows' vertices.
        let at = |i: usize| (1.0 - t) * self.v[j * self.nx + i] as f64 + t * self.v[j1 * self.nx + i] as f64;
        let dx = 1.0 / (self.nx - 1) as f64;
        let (i, s) = Self::locate(x, self.nx);
        let mut before = 0.0;
        let mut total = 0.0;
        for k in 0..self.nx - 1 {
            let seg = 0.5 * (at(k) + at(k + 1)) * dx;
            if k < i {
                before += seg;
            }
            total += seg;
        }
        let (a, b) = (at(i), at(i + 1));
        before += (a * s + 0.5 * (b - a) * s * s) * dx;
        let u0 = if total > 0.0 { before / total } else { x as f64 };
        Vec2::new(u0.clamp(0.0, 1.0) as f32, u1.clamp(0.0, 1.0) as f32)
    }
}

/// Bilinear lookup of an `nx` x `ny` vertex grid over the unit square.
fn bilinear(v: &[f32], nx: usize, ny: usize, x: f32, y: f32) -> f32 {
    let (i, s) = Warp::locate(x, nx);
    let (j, t) = if ny > 1 { Warp::locate(y, ny) } else { (0, 0.0) };
    let j1 = (j + 1).min(ny - 1);
    let (s, t) = (s as f32, t as f32);
    let a = v[j * nx + i] * (1.0 - s) + v[j * nx + i + 1] * s;
    let b = v[j1 * nx + i] * (1.0 - s) + v[j1 * nx + i + 1] * s;
    a * (1.0 - t) + b * t
}

fn theta_to_u(theta: f32) -> f32 {
    (theta.max(0.0) / FRAC_PI_2).sqrt()
}

fn phi_to_u(phi: f32) -> f32 {
    let u = (phi + PI) / (2.0 * PI);
    u - u.floor()
}

/// An isotropic RGL measurement, evaluable as a BRDF.
#[derive(Clone, Debug)]
pub struct RglBrdf {
    pub description: String,
    /// Incident elevations of the slices (radians).
    theta_i: Vec<f32>,
    ndf: (usize, usize, Vec<f32>),
    sigma: (usize, usize, Vec<f32>),
    /// Per `theta_i` slice: the visible-NDF density (x = u_theta, y = u_phi).
    vndf: Vec<(usize, usize, Vec<f32>)>,
    /// Per slice and channel: the rgb table over the unit square.
    rgb: Vec<[(usize, usize, Vec<f32>); 3]>,
}

fn field<'a>(fields: &'a [Field], name: &str) -> Result<&'a Field, RglError> {
    fields.iter().find(|f| f.name == name).ok_or_else(|| bad(format!("no field '{name}'")))
}

impl RglBrdf {
    pub fn read(path: &Path) -> Result<Self, RglError> {
        let bytes = std::fs::read(path).map_err(|e| RglError::Io { path: path.display().to_string(), cause: e })?;
        Self::parse(&bytes).map_err(|e| match e {
            RglError::Format(m) => RglError::Format(format!("{}: {m}", path.display())),
            e => e,
        })
    }

    pub fn parse(bytes: &[u8]) -> Result<Self, RglError> {
        let fields = parse_tensor_file(bytes)?;
        let description = fields
            .iter()
            .find(|f| f.name == "description")
            .map(|f| f.data.iter().map(|&b| b as u8 as char).collect::<String>())
            .unwrap_or_default();
        let phi_i = field(&fields, "phi_i")?;
        if phi_i.data.len() != 1 {
            return Err(bad("only isotropic files (one phi_i) are supported"));
        }
        // Radians (the files hold 0 to pi/2, whatever their README says).
        let theta_i: Vec<f32> = field(&fields, "theta_i")?.data.clone();
        let nt = theta_i.len();
        if nt < 2 || theta_i.windows(2).any(|w| !(w[1] > w[0])) {
            return Err(bad("theta_i must hold two or more increasing elevations"));
        }
        let grid2 = |name: &str| -> Result<(usize, usize, Vec<f32>), RglError> {
            let f = field(&fields, name)?;
            let &[ny, nx] = f.shape.as_slice() else { return Err(bad(format!("{name}: expected 2 dimensions"))) };
            if nx < 2 || ny < 1 {
                return Err(bad(format!("{name}: too small")));
            }
            Ok((nx, ny, f.data.clone()))
        };
        let ndf = grid2("ndf")?;
        let sigma = grid2("sigma")?;
        let v = field(&fields, "vndf")?;
        let &[1, t, ny, nx] = v.shape.as_slice() else { return Err(bad("vndf: expected shape [1, theta_i, y, x]")) };
        if t != nt || nx < 2 || ny < 2 {
            return Err(bad("vndf: shape does not match theta_i"));
        }
        let vndf = (0..nt).map(|k| (nx, ny, v.data[k * nx * ny..(k + 1) * nx * ny].to_vec())).collect();
        let r = field(&fields, "rgb")?;
        let &[1, t, 3, ry, rx] = r.shape.as_slice() else {
            return Err(bad("rgb: expected shape [1, theta_i, 3, y, x]"));
        };
        if t != nt || rx < 2 || ry < 2 {
            return Err(bad("rgb: shape does not match theta_i"));
        }
        let rgb = (0..nt)
            .map(|k| {
                std::array::from_fn(|c| {
                    let o = (k * 3 + c) * rx * ry;
                    (rx, ry, r.data[o..o + rx * ry].to_vec())
                })
            })
            .collect();
        if [&ndf.2, &sigma.2].iter().any(|d| d.iter().any(|x| !x.is_finite())) {
            return Err(bad("non-finite table values"));
        }
        Ok(Self { description, theta_i, ndf, sigma, vndf, rgb })
    }

    /// The measured NDF at `h` (normalised as the file is).
    pub fn d(&self, h: Vec3) -> f32 {
        if h.z <= 0.0 {
            return 0.0;
        }
        let h = h.normalize();
        let (nx, ny, v) = &self.ndf;
        bilinear(v, *nx, *ny, theta_to_u(h.z.clamp(-1.0, 1.0).acos()), phi_to_u(h.y.atan2(h.x))).max(0.0)
    }

    /// The slice pair around `theta` and the weight of the upper one.
    fn slices(&self, theta: f32) -> (usize, usize, f32) {
        let n = self.theta_i.len();
        if theta <= self.theta_i[0] {
            return (0, 0, 0.0);
        }
        if theta >= self.theta_i[n - 1] {
            return (n - 1, n - 1, 0.0);
        }
        let k = self.theta_i.windows(2).position(|w| theta < w[1]).unwrap_or(n - 2);
        (k, k + 1, (theta - self.theta_i[k]) / (self.theta_i[k + 1] - self.theta_i[k]))
    }
}

impl Brdf for RglBrdf {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        if i.z <= 0.0 || o.z <= 0.0 {
            return Rgb::ZERO;
        }
        let (i, o) = (i.normalize(), o.normalize());
        let h = (i + o).normalize();
        let theta_i = i.z.clamp(-1.0, 1.0).acos();
        let phi_i = i.y.atan2(i.x);
        let (uth, uph) = (theta_to_u(h.z.clamp(-1.0, 1.0).acos()), phi_to_u(h.y.atan2(h.x) - phi_i));
        let (a, b, w) = self.slices(theta_i);
        // The density between the two slices, then its inverse warp.
        let (nx, ny, va) = &self.vndf[a];
        let vb = &self.vndf[b].2;
        let mixed: Vec<f32> = va.iter().zip(vb).map(|(x, y)| x * (1.0 - w) + y * w).collect();
        let u = Warp::new(*nx, *ny, mixed).invert(uth, uph);
        let rgb = Vec3::from_array(std::array::from_fn(|c| {
            let (rx, ry, ta) = &self.rgb[a][c];
            let tb = &self.rgb[b][c].2;
            bilinear(ta, *rx, *ry, u.x, u.y) * (1.0 - w) + bilinear(tb, *rx, *ry, u.x, u.y) * w
        }));
        let (sx, sy, sv) = &self.sigma;
        let sigma = bilinear(sv, *sx, *sy, theta_to_u(theta_i), phi_to_u(phi_i)).max(1e-6);
        let f = rgb.max(Vec3::ZERO) * self.d(h) / (4.0 * sigma);
        if f.is_finite() { f } else { Rgb::ZERO }
    }
}

/// What the import did.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ImportSummary {
    pub description: String,
    pub kd: [f32; 3],
    pub ks: [f32; 3],
    pub eta: f32,
    /// Relative RMS difference of the imported model from the measured
    /// BRDF (cosine-weighted, over the directions it was fitted on).
    pub residual: f32,
}

/// Directions for the fit: lights and views over the hemisphere up to 80
/// degrees, in one azimuthal plane and out of it.
fn fit_directions() -> Vec<(Vec3, Vec3)> {
    let dir = |t: f32, p: f32| Vec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos());
    let mut v = Vec::new();
    for ti in 0..9 {
        for to in 0..9 {
            for po in 0..12 {
                let (t1, t2) = ((ti as f32 * 10.0).to_radians(), (to as f32 * 10.0).to_radians());
                v.push((dir(t1, 0.0), dir(t2, (po as f32 * 30.0).to_radians())));
            }
        }
    }
    v
}

/// Import `brdf` as a homogeneous material on a `width_mm` square sample.
pub fn import(brdf: &RglBrdf, name: &str, grid: NdfGrid, width_mm: f32) -> (Material, ImportSummary) {
    let table = NdfTable::from_fn(grid, 4, |h| brdf.d(h));
    let provenance = serde_json::json!({ "imported_from": "rgl", "description": brdf.description });
    fit_homogeneous(brdf, table, name, width_mm, brdf.description.clone(), provenance)
}

/// A homogeneous material with NDF `table` (normalised here, marked fully
/// observed) whose diffuse albedo, specular albedo and Fresnel index are
/// fitted to `brdf`.
pub fn fit_homogeneous(
    brdf: &dyn Brdf,
    mut table: NdfTable,
    name: &str,
    width_mm: f32,
    description: String,
    provenance: serde_json::Value,
) -> (Material, ImportSummary) {
    let grid = table.grid();
    table.normalize();
    for c in 0..grid.len() {
        table.coverage_mut().set(c, true);
    }
    let mut tables = TableSet::new(grid, 1);
    tables.set(0, &table);
    let base = |eta: f32, ks: [f32; 3], kd: [f32; 3]| Material {
        name: name.to_string(),
        sample: SampleArea { width_mm, height_mm: width_mm },
        grid: PointGrid { cols: 1, rows: 1 },
        kd: vec![kd],
        ks: vec![ks],
        eta: vec![eta],
        flags: vec![0],
        ndf: Some(tables.clone()),
        ndf_kind: NdfKind::Reference,
        partial: None,
        models: Default::default(),
        choice: None,
        provenance: provenance.clone(),
    };
    let dirs = fit_directions();
    let truth: Vec<Rgb> = dirs.iter().map(|&(i, o)| brdf.eval(i, o)).collect();
    // Per candidate eta: the specular basis (ks = 1, kd = 0), then a
    // non-negative two-term least squares per channel (weighted by cos_i).
    let mut best: Option<(f64, f32, [f32; 3], [f32; 3])> = None;
    let etas: Vec<f32> = (0..40).map(|k| 1.05 * (30.0f32 / 1.05).powf(k as f32 / 39.0)).collect();
    for &eta in &etas {
        let m = Arc::new(base(eta, [1.0; 3], [0.0; 3]));
        let Some(view) = MaterialView::new(m, ModelChoice::Tabulated) else { continue };
        let pm = crate::point::SvBrdf::at(&view, Vec2::ZERO);
        let spec: Vec<f32> = dirs.iter().map(|&(i, o)| pm.eval(i, o).x).collect();
        let (mut kd, mut ks, mut err, mut den) = ([0.0f32; 3], [0.0f32; 3], 0.0f64, 0.0f64);
        for c in 0..3 {
            // Normal equations for y = a / pi + b s, weights w = cos_i.
            let (mut s11, mut s12, mut s22, mut t1, mut t2) = (0.0f64, 0.0, 0.0, 0.0, 0.0);
            for ((&(i, _), &s), y) in dirs.iter().zip(&spec).zip(&truth) {
                let (w, d, s, y) = (i.z as f64, 1.0 / std::f64::consts::PI, s as f64, y[c] as f64);
                s11 += w * d * d;
                s12 += w * d * s;
                s22 += w * s * s;
                t1 += w * d * y;
                t2 += w * s * y;
            }
            let det = s11 * s22 - s12 * s12;
            let (mut a, mut b) = if det.abs() > 1e-12 {
                ((t1 * s22 - t2 * s12) / det, (s11 * t2 - s12 * t1) / det)
            } else {
                (t1 / s11.max(1e-12), 0.0)
            };
            if a < 0.0 {
                a = 0.0;
                b = (t2 / s22.max(1e-12)).max(0.0);
            }
            if b < 0.0 {
                b = 0.0;
                a = (t1 / s11.max(1e-12)).max(0.0);
            }
            kd[c] = a as f32;
            ks[c] = b as f32;
            for ((&(i, _), &s), y) in dirs.iter().zip(&spec).zip(&truth) {
                let p = a / std::f64::consts::PI + b * s as f64;
                err += i.z as f64 * (p - y[c] as f64).powi(2);
                den += i.z as f64 * (y[c] as f64).powi(2);
            }
        }
        let rel = (err / den.max(1e-30)).sqrt();
        if best.as_ref().is_none_or(|b| rel < b.0) {
            best = Some((rel, eta, kd, ks));
        }
    }
    let (residual, eta, kd, ks) = best.unwrap_or((f64::NAN, 1.5, [0.0; 3], [0.0; 3]));
    let m = base(eta, ks, kd);
    let s = ImportSummary { description, kd, ks, eta, residual: residual as f32 };
    (m, s)
}
