//! MERL BRDF database files (`.binary`; Matusik et al., "A Data-Driven
//! Reflectance Model", SIGGRAPH 2003): isotropic BRDFs tabulated over the
//! half/difference angles of Rusinkiewicz (1998).
//!
//! Layout (little-endian): three `i32` dimensions (90, 90, 180) then
//! `3 x 90 x 90 x 180` `f64` values, red block then green then blue, each
//! indexed `[theta_h][theta_d][phi_d]` with `theta_h` warped as
//! `sqrt(theta_h / (pi/2)) * 90`, `theta_d` linear over `[0, pi/2)` and
//! `phi_d` over `[0, pi)` (reciprocity folds the other half). Channel
//! scales are the published ones: 1/1500, 1.15/1500 and 1.66/1500; a
//! negative value marks a cell that was not measured.

use std::f32::consts::{FRAC_PI_2, PI};
use std::path::Path;

use brdf::{Brdf, Rgb};
use glam::Vec3;

pub const THETA_H: usize = 90;
pub const THETA_D: usize = 90;
pub const PHI_D: usize = 180;
pub const SCALE: [f64; 3] = [1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0];
const N: usize = THETA_H * THETA_D * PHI_D;

#[derive(Debug, thiserror::Error)]
pub enum MerlError {
    #[error("{0}")]
    Format(String),
    #[error("{path}: {cause}")]
    Io { path: String, cause: std::io::Error },
}

/// A MERL measurement, evaluable as a BRDF.
#[derive(Clone, Debug)]
pub struct MerlBrdf {
    /// `[channel][theta_h][theta_d][phi_d]`, already scaled.
    values: Vec<f32>,
}

/// The table cell of a light and view direction (local frame).
pub fn cell(i: Vec3, o: Vec3) -> Option<usize> {
    if i.z <= 0.0 || o.z <= 0.0 {
        return None;
    }
    let (i, o) = (i.normalize(), o.normalize());
    let h = (i + o).normalize();
    let theta_h = h.z.clamp(-1.0, 1.0).acos();
    let phi_h = h.y.atan2(h.x);
    // The difference vector: i in the frame where h is the pole.
    let d = rotate_y(rotate_z(i, -phi_h), -theta_h);
    let theta_d = d.z.clamp(-1.0, 1.0).acos();
    let mut phi_d = d.y.atan2(d.x);
    if phi_d < 0.0 {
        phi_d += PI;
    }
    let th = ((theta_h / FRAC_PI_2).max(0.0).sqrt() * THETA_H as f32) as usize;
    let td = (theta_d / FRAC_PI_2 * THETA_D as f32) as usize;
    let pd = (phi_d / PI * PHI_D as f32) as usize;
    Some((th.min(THETA_H - 1) * THETA_D + td.min(THETA_D - 1)) * PHI_D + pd.min(PHI_D - 1))
}

fn rotate_z(v: Vec3, a: f32) -> Vec3 {
    let (s, c) = a.sin_cos();
    Vec3::new(c * v.x - s * v.y, s * v.x + c * v.y, v.z)
}

fn rotate_y(v: Vec3, a: f32) -> Vec3 {
    let (s, c) = a.sin_cos();
    Vec3::new(c * v.x + s * v.z, v.y, -s * v.x + c * v.z)
}

impl MerlBrdf {
    pub fn read(path: &Path) -> Result<Self, MerlError> {
        let b = std::fs::read(path).map_err(|e| MerlError::Io { path: path.display().to_string(), cause: e })?;
        Self::parse(&b).map_err(|e| match e {
            MerlError::Format(m) => MerlError::Format(format!("{}: {m}", path.display())),
            e => e,
        })
    }

    pub fn parse(b: &[u8]) -> Result<Self, MerlError> {
        if b.len() < 12 {
            return Err(MerlError::Format("shorter than the header".into()));
        }
        let dim = |k: usize| i32::from_le_bytes([b[4 * k], b[4 * k + 1], b[4 * k + 2], b[4 * k + 3]]);
        let dims = [dim(0), dim(1), dim(2)];
        if dims != [THETA_H as i32, THETA_D as i32, PHI_D as i32] {
            return Err(MerlError::Format(format!("dimensions {dims:?}, expected [90, 90, 180]")));
        }
        if b.len() != 12 + 3 * N * 8 {
            return Err(MerlError::Format(format!("{} bytes, expected {}", b.len(), 12 + 3 * N * 8)));
        }
        let values = b[12..]
            .chunks_exact(8)
            .enumerate()
            .map(|(k, c)| {
                let v = f64::from_le_bytes(c.try_into().unwrap_or([0; 8])) * SCALE[k / N];
                if v.is_finite() { v.max(0.0) as f32 } else { 0.0 }
            })
            .collect();
        Ok(Self { values })
    }

    /// Encode a BRDF in the format (for tests and for exporting analytic
    /// references): each cell holds the BRDF at its centre.
    pub fn encode(brdf: &dyn Brdf) -> Vec<u8> {
        let mut out = Vec::with_capacity(12 + 3 * N * 8);
        for d in [THETA_H, THETA_D, PHI_D] {
            out.extend_from_slice(&(d as i32).to_le_bytes());
        }
        let mut vals = vec![0.0f64; 3 * N];
        for th in 0..THETA_H {
            let u = (th as f32 + 0.5) / THETA_H as f32;
            let theta_h = u * u * FRAC_PI_2;
            for td in 0..THETA_D {
                let theta_d = (td as f32 + 0.5) / THETA_D as f32 * FRAC_PI_2;
                for pd in 0..PHI_D {
                    let phi_d = (pd as f32 + 0.5) / PHI_D as f32 * PI;
                    let d = Vec3::new(theta_d.sin() * phi_d.cos(), theta_d.sin() * phi_d.sin(), theta_d.cos());
                    // Back from the half/difference frame (phi_h = 0).
                    let i = rotate_y(d, theta_h);
                    let h = Vec3::new(theta_h.sin(), 0.0, theta_h.cos());
                    let o = 2.0 * i.dot(h) * h - i;
                    let f = brdf.eval(i, o);
                    let k = (th * THETA_D + td) * PHI_D + pd;
                    for c in 0..3 {
                        vals[c * N + k] = if i.z > 0.0 && o.z > 0.0 { f[c] as f64 / SCALE[c] } else { -1.0 };
                    }
                }
            }
        }
        for v in vals {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }
}

impl Brdf for MerlBrdf {
    fn eval(&self, i: Vec3, o: Vec3) -> Rgb {
        match cell(i, o) {
            Some(k) => Vec3::new(self.values[k], self.values[N + k], self.values[2 * N + k]),
            None => Rgb::ZERO,
        }
    }
}

/// The NDF a MERL measurement implies, from its retro-reflection slice
/// (`i = o = h`, where `f = kd/pi + ks D(h) S(h)^2 / (4 cos^2 theta_h)` in
/// this project's microfacet model with `F_rel = 1`): the diffuse part is
/// the slice's lower quartile, and the shadowing term is recomputed from
/// the table twice (it depends on `D`).
pub fn ndf_from_retro(brdf: &MerlBrdf, grid: brdf::ndf::NdfGrid) -> brdf::ndf::NdfTable {
    use brdf::ndf::{MaskingOperator, NdfTable};
    let retro = |h: Vec3| brdf.eval(h, h).dot(Vec3::splat(1.0 / 3.0));
    let mut slice: Vec<f32> = (0..90)
        .map(|k| {
            let t = (k as f32 + 0.5) / 90.0 * 80f32.to_radians();
            retro(Vec3::new(t.sin(), 0.0, t.cos()))
        })
        .collect();
    slice.sort_by(f32::total_cmp);
    let diffuse = slice[slice.len() / 4];
    let op = MaskingOperator::new(grid);
    let mut table = NdfTable::from_fn(grid, 2, |h| (retro(h) - diffuse).max(0.0) * 4.0 * h.z * h.z);
    for _ in 0..2 {
        table.normalize();
        let m = op.projected_areas(&table);
        let prev = table.clone();
        table = NdfTable::from_fn(grid, 2, |h| {
            let g = m.g1(h).max(0.05);
            (retro(h) - diffuse).max(0.0) * 4.0 * h.z * h.z / (g * g)
        });
        if table.values().iter().all(|v| *v == 0.0) {
            return prev;
        }
    }
    table
}

/// Import a MERL measurement as a homogeneous material.
pub fn import(
    brdf: &MerlBrdf,
    name: &str,
    grid: brdf::ndf::NdfGrid,
    width_mm: f32,
) -> (crate::Material, crate::rgl::ImportSummary) {
    let table = ndf_from_retro(brdf, grid);
    let provenance = serde_json::json!({ "imported_from": "merl", "ndf": "from the retro-reflection slice" });
    crate::rgl::fit_homogeneous(brdf, table, name, width_mm, format!("MERL {name}"), provenance)
}
