//! A fitted material in memory.

use std::collections::BTreeMap;

use brdf::ndf::TableSet;
use brdf::params::AnalyticModel;
use serde::{Deserialize, Serialize};
use setup::{PointGrid, SampleArea};

/// The flag bit (`fit::point_flag::OUT_OF_VIEW`, `out_of_view` in
/// MATERIAL.md) of a point the camera did not measure: out of its view, or
/// so near the sample's edge that its pixels saw past it. Its maps hold no
/// fit; a [`crate::MaterialView`] shows its nearest measured neighbour.
pub const UNMEASURED: u32 = 0x40;

/// What produced the main NDF tables.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NdfKind {
    /// Only what the camera observed, normalised over it.
    Partial,
    /// Completed by example-based microfacet synthesis.
    Synthesized,
    /// Ground truth (imported measurements, resampled analytic NDFs).
    Reference,
}

/// Per-point parameters of one analytic model.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelMap {
    pub model: AnalyticModel,
    /// `n_points x model.n_params()`, row-major by point.
    pub params: Vec<f32>,
    /// Wall time of the fit that produced it.
    pub fit_seconds: f64,
}

impl ModelMap {
    pub fn point(&self, p: usize) -> &[f32] {
        let n = self.model.n_params();
        &self.params[p * n..(p + 1) * n]
    }
}

/// The model chosen per region by "model only what the sample needs".
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum Choice {
    Diffuse = 0,
    Isotropic = 1,
    Anisotropic = 2,
    Tabulated = 3,
}

impl Choice {
    pub fn from_u8(v: u8) -> Option<Self> {
        Some(match v {
            0 => Choice::Diffuse,
            1 => Choice::Isotropic,
            2 => Choice::Anisotropic,
            3 => Choice::Tabulated,
            _ => return None,
        })
    }
}

/// The per-point model choice, with the analytic models used for the
/// isotropic and anisotropic classes.
#[derive(Clone, Debug, PartialEq)]
pub struct ChoiceMap {
    pub choice: Vec<Choice>,
    pub isotropic_model: AnalyticModel,
    pub anisotropic_model: AnalyticModel,
}

/// A point fit before synthesis: its partial tables, normalised over the
/// observed region, with the `ks` and `eta` that belong to them.
#[derive(Clone, Debug, PartialEq)]
pub struct PartialFit {
    pub tables: TableSet,
    pub ks: Vec<[f32; 3]>,
    pub eta: Vec<f32>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: String,
    pub sample: SampleArea,
    pub grid: PointGrid,
    /// Diffuse albedo per point.
    pub kd: Vec<[f32; 3]>,
    /// Specular albedo at normal incidence per point (with `F_rel(1) = 1`).
    pub ks: Vec<[f32; 3]>,
    /// Index of refraction of the relative dielectric Fresnel term.
    pub eta: Vec<f32>,
    /// Fit flags per point (`fit::point_flag`).
    pub flags: Vec<u32>,
    pub ndf: Option<TableSet>,
    pub ndf_kind: NdfKind,
    /// The fit before synthesis, kept beside a synthesized one.
    pub partial: Option<PartialFit>,
    pub models: BTreeMap<String, ModelMap>,
    pub choice: Option<ChoiceMap>,
    /// Where it came from: capture, settings, timings.
    pub provenance: serde_json::Value,
}

impl Material {
    pub fn n_points(&self) -> usize {
        self.grid.len()
    }

    /// Whether the camera measured point `p` (a material without flags
    /// counts every point measured).
    pub fn is_measured(&self, p: usize) -> bool {
        self.flags.get(p).is_none_or(|f| f & UNMEASURED == 0)
    }

    /// The point shown for each grid point: itself, or for an
    /// [`UNMEASURED`] one its nearest measured neighbour (renders and
    /// exports extend the measurement to the sample's edges this way).
    pub fn stand_ins(&self) -> Vec<u32> {
        if self.flags.len() != self.n_points() {
            return (0..self.n_points() as u32).collect();
        }
        let measured: Vec<bool> = (0..self.n_points()).map(|p| self.is_measured(p)).collect();
        self.grid.stand_ins(&measured)
    }

    /// Nearest grid point to a sample position.
    pub fn point_at(&self, p_mm: glam::Vec2) -> Option<usize> {
        let c = self.grid.coords(&self.sample, p_mm);
        let (col, row) = (c.x.floor(), c.y.floor());
        if col < 0.0 || row < 0.0 || col >= self.grid.cols as f32 || row >= self.grid.rows as f32 {
            return None;
        }
        Some(row as usize * self.grid.cols as usize + col as usize)
    }
}
