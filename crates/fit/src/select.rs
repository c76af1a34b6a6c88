//! Model only what the sample needs: per region (an NDF cluster), the
//! simplest model that explains the data within the noise.
//!
//! Classes, simplest first: diffuse only (no measurable specular), an
//! isotropic analytic lobe, an anisotropic analytic lobe, the synthesized
//! tabulated NDF. For each cluster the mean over its points of
//! `residual / noise` is computed for each candidate, where `residual` is
//! the RMS cosine-weighted error of the model on the point's samples and
//! `noise` the RMS of the samples' own noise (what a perfect model leaves).
//! A class is accepted when its ratio is at most [`ACCEPT_RATIO`], or when
//! it is within [`AS_GOOD_AS`] of the tabulated model's ratio (nothing
//! better is available from the data); the first accepted class wins.

use brdf::params::AnalyticModel;
use serde::{Deserialize, Serialize};

use crate::analytic::{Evidence, ModelFit};
use crate::partial::point_flag;
use crate::points::PointMaps;

/// A model whose residual is within 30% of the noise floor explains the
/// data: with ~256 samples per point, a correct model's ratio scatters by a
/// few per cent around 1, and the fitter's own tabulated model reaches
/// about 1.1 on simulated captures.
pub const ACCEPT_RATIO: f32 = 1.3;
/// ... or when it is no more than 5% worse than the tabulated model.
pub const AS_GOOD_AS: f32 = 1.05;

/// Smallest noise level a residual is divided by (a point whose samples
/// carry no noise at all, as in noiseless tests, is not divided by zero).
const NOISE_FLOOR: f32 = 1e-12;

/// Class codes as stored in the material (`material::Choice`).
pub const DIFFUSE: u8 = 0;
pub const ISOTROPIC: u8 = 1;
pub const ANISOTROPIC: u8 = 2;
pub const TABULATED: u8 = 3;

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SelectionSummary {
    pub isotropic_model: String,
    pub anisotropic_model: String,
    /// Points per class: diffuse, isotropic, anisotropic, tabulated.
    pub points: [usize; 4],
    /// Mean residual/noise ratio per class over the points that chose it.
    pub ratio: [f32; 4],
    /// Bytes per point of each representation.
    pub bytes_per_point: [usize; 4],
    /// Storage if every point kept its tabulated NDF, and with the choice.
    pub bytes_all_tabulated: usize,
    pub bytes_chosen: usize,
}

#[derive(Clone, Debug)]
pub struct Selection {
    pub choice: Vec<u8>,
    pub isotropic: AnalyticModel,
    pub anisotropic: AnalyticModel,
    pub summary: SelectionSummary,
}

/// Mean of the finite values; `None` when there are none.
fn mean(v: impl Iterator<Item = Option<f32>>) -> Option<f32> {
    let (mut s, mut n) = (0.0f64, 0usize);
    for x in v.flatten() {
        if x.is_finite() {
            s += x as f64;
            n += 1;
        }
    }
    (n > 0).then(|| (s / n as f64) as f32)
}

/// Orders means with a missing one (no point fitted) last.
fn worst_last(m: Option<f32>) -> f32 {
    m.unwrap_or(f32::MAX)
}

/// Choose per cluster; `None` if neither an isotropic nor an anisotropic
/// analytic fit is available.
pub fn select(maps: &PointMaps, ev: &Evidence, fits: &[ModelFit]) -> Option<Selection> {
    let n = maps.len();
    let total = |f: &ModelFit| worst_last(mean(f.residual.iter().copied()));
    let pick = |cands: &[AnalyticModel]| -> Option<&ModelFit> {
        fits.iter().filter(|f| cands.contains(&f.model)).min_by(|a, b| total(a).total_cmp(&total(b)))
    };
    let iso = pick(&[AnalyticModel::WardIso, AnalyticModel::CookTorrance, AnalyticModel::Phong])?;
    let aniso = pick(&[AnalyticModel::WardAniso, AnalyticModel::GgxAniso, AnalyticModel::AshikhminShirley])?;
    let ratio = |r: Option<f32>, p: usize| r.map(|r| r / ev.noise[p].max(NOISE_FLOOR));
    let mut choice = vec![DIFFUSE; n];
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); ev.clusters];
    for p in 0..n {
        let c = ev.cluster[p] as usize;
        if c < ev.clusters && maps.flags[p] & point_flag::NO_SPECULAR == 0 {
            members[c].push(p);
        }
    }
    for m in &members {
        if m.is_empty() {
            continue;
        }
        let r_iso = mean(m.iter().map(|&p| ratio(iso.residual[p], p)));
        let r_aniso = mean(m.iter().map(|&p| ratio(aniso.residual[p], p)));
        let r_tab = mean(m.iter().map(|&p| ratio(Some(ev.tabulated[p]), p)));
        let ok = |r: Option<f32>| r.is_some_and(|r| r <= ACCEPT_RATIO || r_tab.is_none_or(|t| r <= t * AS_GOOD_AS));
        let class = if ok(r_iso) {
            ISOTROPIC
        } else if ok(r_aniso) {
            ANISOTROPIC
        } else {
            TABULATED
        };
        for &p in m {
            choice[p] = class;
        }
    }
    let g = maps.tables.grid();
    let bytes = [12, 4 * iso.model.n_params(), 4 * aniso.model.n_params(), 2 * g.len() + g.len().div_ceil(8) + 28];
    let mut summary = SelectionSummary {
        isotropic_model: iso.model.name().into(),
        anisotropic_model: aniso.model.name().into(),
        bytes_per_point: bytes,
        bytes_all_tabulated: n * bytes[3],
        ..SelectionSummary::default()
    };
    let mut sums = [0.0f64; 4];
    for p in 0..n {
        let c = choice[p] as usize;
        summary.points[c] += 1;
        summary.bytes_chosen += bytes[c];
        let r = match choice[p] {
            DIFFUSE => None,
            ISOTROPIC => ratio(iso.residual[p], p),
            ANISOTROPIC => ratio(aniso.residual[p], p),
            _ => ratio(Some(ev.tabulated[p]), p),
        };
        if let Some(r) = r.filter(|r| r.is_finite()) {
            sums[c] += r as f64;
        }
    }
    for c in 0..4 {
        summary.ratio[c] = if summary.points[c] > 0 { (sums[c] / summary.points[c] as f64) as f32 } else { 0.0 };
    }
    Some(Selection { choice, isotropic: iso.model, anisotropic: aniso.model, summary })
}
