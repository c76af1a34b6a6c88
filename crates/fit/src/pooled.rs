//! Pooled estimation: points that share a material share its NDF.
//!
//! One point's lights are 3 to 7 degrees apart in half-vector space, so a
//! glossy lobe is undersampled at any single point, and the splatting
//! kernel that bridges those gaps blurs the lobe (`refl bench budget`
//! measures this as the largest term of the fitter's error). Points at
//! other places on the sample see the same lights at other half vectors:
//! pooled, the samples of a few hundred points interleave far more densely
//! than one point's.
//!
//! 1. **Clusters.** The points with specular are clustered by their partial
//!    tables, unrotated (k-means on the descriptors of the synthesis, over
//!    the cells most points observe), so a cluster holds one material in
//!    one orientation. More clusters than materials only pools less.
//! 2. **Pooled table.** Every sample of every member becomes a value of
//!    the normalised NDF at its half vector, through its own point's
//!    diffuse, specular colour and scale, masking and Fresnel:
//!    `D_q = 4 s_q sigma(i) sigma(o) / (F_rel k_s)` (the per-point
//!    relation of `partial.rs` divided by the point's `k_s`). They are
//!    splatted into one table with kernels `sqrt(members)` times narrower
//!    than one point's (the pooled density), never below half a cell, and
//!    weighted by their inverse variance. The observed region, closing and
//!    push-pull are the per-point rules on the pooled weights.
//! 3. **Scale and masking.** With the pooled table fixed, each member's
//!    `k_s` is the weighted least-squares scale of the pooled model to its
//!    own samples; masking is recomputed from the pooled table; two rounds.
//! 4. **Who keeps its own table.** A member keeps its per-point table when
//!    that explains its samples better than the pooled one by more than
//!    its extra parameters can (Akaike's criterion on the noise model's
//!    chi-square: `chi2_own + 2 k_own < chi2_pooled + 2`, with `k_own` the
//!    cells its own samples observed, at most its sample count, and `1`
//!    for the pooled scale): a point that differs from its cluster beyond
//!    the noise is not forced into it. `k_own` is an upper bound of the own
//!    table's free parameters (a kernel wider than a cell ties neighbouring
//!    cells together), so the test leans toward pooling.
//!
//! The stage runs after synthesis: a pooled point's table is the pooled
//! one on the cells the pool observed, joined with its own completed table
//! beyond them (scaled to agree in mass over the pool's region), and its
//! `k_s` the least-squares scale of that table to its samples. Pooled
//! points carry [`point_flag::POOLED`].

use brdf::fresnel;
use brdf::ndf::{Coverage, MaskingOperator, MaskingTable, NdfTable, TableSet};
use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::context::FitContext;
use crate::partial::{PointSamples, SplatLayout, Splatted, close, join, kernel_cells, lum, point_flag};
use crate::points::{PointMaps, gather};
use crate::pushpull::push_pull;
use crate::samples::SampleStore;
use crate::settings::FitSettings;

/// The pooled stage's knobs.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PoolSettings {
    /// Clusters of the k-means (more than the sample has materials only
    /// pools fewer points together).
    pub clusters: u32,
    pub seed: u64,
}

impl Default for PoolSettings {
    fn default() -> Self {
        Self { clusters: 16, seed: 1 }
    }
}

/// What the pooled stage did.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PoolStats {
    pub clusters: usize,
    /// Points that took their cluster's table.
    pub pooled: usize,
    /// Points that kept their own (they differ from the cluster beyond noise).
    pub kept_own: usize,
}

/// Rounds of (pooled table, per-point scale, masking).
const ROUNDS: usize = 2;
/// Descriptor length for the clustering (as the analytic stage's).
const DESCRIPTOR: usize = 32;
/// Smallest kernel as a fraction of the cell's angular size at `h`.
const MIN_KERNEL_CELLS: f32 = 0.5;

/// One member's samples and the per-point quantities that turn them into
/// NDF values.
struct Member {
    p: usize,
    ps: PointSamples,
    /// Scalar specular of each sample and its half vector.
    spec: Vec<f32>,
    h: Vec<Vec3>,
    /// Fresnel relative to normal incidence, per sample.
    fresnel: Vec<f32>,
    k_s: f32,
}

/// Cluster, pool and choose; replaces the pooled points' tables and
/// specular scales in `maps`. `observed` holds the points' tables before
/// synthesis (whose coverage is what their own samples observed) when
/// `maps` holds completed ones.
pub fn pool(
    ctx: &FitContext,
    store: &SampleStore,
    maps: &mut PointMaps,
    settings: &FitSettings,
    pool: &PoolSettings,
    op: &MaskingOperator,
    observed: Option<&TableSet>,
) -> PoolStats {
    let eligible: Vec<usize> = (0..maps.len()).filter(|&p| maps.flags[p] & point_flag::NO_SPECULAR == 0).collect();
    if eligible.len() < 2 {
        return PoolStats::default();
    }
    let k = (pool.clusters as usize).clamp(1, eligible.len());
    let assign = crate::synth::cluster::by_table(&maps.tables, &eligible, DESCRIPTOR, k, pool.seed);
    let mut members: Vec<Vec<usize>> = vec![Vec::new(); k];
    for (j, &p) in eligible.iter().enumerate() {
        members[assign[j] as usize].push(p);
    }
    let maps_ref = &*maps;
    let pooled_points = members.iter().filter(|m| m.len() >= 2).map(Vec::len).sum::<usize>();
    ctx.progress.begin(crate::FitStage::Pooling, pooled_points as u64);
    let results: Vec<Vec<(usize, NdfTable, f32)>> = members
        .par_iter()
        .filter(|m| m.len() >= 2)
        .map(|m| {
            let r = pool_cluster(ctx, store, maps_ref, settings, op, m, observed);
            ctx.progress.advance(m.len() as u64);
            r
        })
        .collect();
    let mut stats = PoolStats { clusters: results.len(), ..PoolStats::default() };
    for (p, table, k_s) in results.into_iter().flatten() {
        let colour_lum = lum(maps.ks[p]);
        let colour = maps.ks[p].map(|c| if colour_lum > 0.0 { c / colour_lum } else { 1.0 });
        maps.ks[p] = colour.map(|c| c * k_s);
        maps.tables.set(p, &table);
        maps.flags[p] |= point_flag::POOLED;
        stats.pooled += 1;
    }
    stats.kept_own = eligible.len() - stats.pooled;
    stats
}

/// The angular size of the table's cell around `h` (the larger of its
/// extents in theta and in phi).
fn cell_angle(grid: brdf::ndf::NdfGrid, h: Vec3) -> f32 {
    let Some((t, _)) = grid.cell(h) else { return grid.theta_edge(1) };
    let dt = grid.theta_edge(t + 1) - grid.theta_edge(t);
    let dp = grid.dphi() * grid.theta_center(t).sin();
    dt.max(dp)
}

/// Pool one cluster; returns, for every member that takes the pooled
/// table, the table and its new `k_s`.
fn pool_cluster(
    ctx: &FitContext,
    store: &SampleStore,
    maps: &PointMaps,
    settings: &FitSettings,
    op: &MaskingOperator,
    m: &[usize],
    own_observed: Option<&TableSet>,
) -> Vec<(usize, NdfTable, f32)> {
    let grid = settings.grid;
    let cells = grid.len();
    let centres: Vec<Vec3> =
        (0..cells).map(|c| grid.direction(c / grid.n_phi as usize, c % grid.n_phi as usize)).collect();
    let members: Vec<Member> = m
        .iter()
        .map(|&p| Member::new(p, gather(ctx, store, p, settings), maps.kd[p], maps.ks[p], maps.eta[p]))
        .collect();
    let shrink = 1.0 / (members.len() as f32).sqrt();
    // Kernel cells of every sample, once.
    let mut kcells: Vec<(u32, f32)> = Vec::new();
    let mut offsets: Vec<usize> = vec![0];
    let mut corners: Vec<[(u32, f32); 4]> = Vec::new();
    let mut sum_k = vec![0.0f32; cells];
    for mb in &members {
        for (x, &h) in mb.ps.samples.iter().zip(&mb.h) {
            corners.push(crate::partial::corners(grid, h));
            let r = (x.kernel_rad * shrink).max(MIN_KERNEL_CELLS * cell_angle(grid, h)).max(crate::tol::MIN_KERNEL_RAD);
            let start = kcells.len();
            kernel_cells(grid, &centres, h, r, &mut kcells);
            for &(c, w) in &kcells[start..] {
                sum_k[c as usize] += w;
            }
            offsets.push(kcells.len());
        }
    }
    let observed: Vec<bool> = sum_k.iter().map(|&w| w >= settings.observed_weight).collect();
    let covered = close(grid, &observed);
    let confidence: Vec<f32> = sum_k.iter().map(|&w| (w / settings.observed_weight).min(1.0)).collect();
    // Masking: each member's own to start, then the pooled table's.
    let own_masking: Vec<MaskingTable> = members.iter().map(|mb| op.projected_areas(&maps.tables.get(mb.p))).collect();
    let mut shared: Option<MaskingTable> = None;
    let mut k_s: Vec<f32> = members.iter().map(|mb| mb.k_s).collect();
    let mut table = NdfTable::zeros(grid);
    let layout = SplatLayout {
        grid,
        cells: &kcells,
        offsets: &offsets,
        corners: &corners,
        confidence: &confidence,
        covered: &covered,
    };
    let mut d_all: Vec<f32> = Vec::with_capacity(corners.len());
    let mut weight: Vec<f64> = Vec::with_capacity(corners.len());
    for _ in 0..ROUNDS {
        let mut sum_w = vec![0.0f64; cells];
        let mut sum_wd = vec![0.0f64; cells];
        d_all.clear();
        weight.clear();
        let mut s = 0;
        for (j, mb) in members.iter().enumerate() {
            let m = shared.as_ref().unwrap_or(&own_masking[j]);
            let sigma_o = m.projected_area(mb.ps.o);
            for (k, x) in mb.ps.samples.iter().enumerate() {
                let g = 4.0 * m.projected_area(x.i) * sigma_o / (mb.fresnel[k] * k_s[j]);
                let d = mb.spec[k] * g;
                let var_d = (x.var * g * g) as f64;
                d_all.push(d);
                if d.is_finite() && var_d > 0.0 && var_d.is_finite() {
                    weight.push(1.0 / var_d);
                    for &(c, w) in &kcells[offsets[s]..offsets[s + 1]] {
                        sum_w[c as usize] += w as f64 / var_d;
                        sum_wd[c as usize] += w as f64 * d as f64 / var_d;
                    }
                } else {
                    weight.push(0.0);
                }
                s += 1;
            }
        }
        let mut values: Vec<f32> =
            sum_w.iter().zip(&sum_wd).map(|(&w, &wd)| if w > 0.0 { (wd / w) as f32 } else { 0.0 }).collect();
        push_pull(grid.n_theta as usize, grid.n_phi as usize, &mut values, &confidence, &covered);
        layout.twice(&mut values, &d_all, Some(&weight), settings.bias_passes);
        let mut cov = Coverage::empty(cells);
        for (c, v) in values.iter_mut().enumerate() {
            if covered[c] && v.is_finite() {
                cov.set(c, true);
                *v = v.max(0.0);
            } else {
                *v = 0.0;
            }
        }
        table = NdfTable::from_values(grid, values, cov).unwrap_or_else(|_| NdfTable::zeros(grid));
        if !(table.normalize() > 0.0) {
            return Vec::new();
        }
        let m = op.projected_areas(&table);
        for (j, mb) in members.iter().enumerate() {
            if let Some(s) = Fit::of(mb, &table, &m).scale() {
                k_s[j] = s;
            }
        }
        shared = Some(m);
    }
    members
        .iter()
        .zip(&own_masking)
        .filter_map(|(mb, own_masking)| {
            let own = maps.tables.get(mb.p);
            // The pooled table where the pool observed, the point's own
            // completed table beyond, agreeing in mass over the pool's region.
            let pooled = Splatted { table: table.clone(), k_s: 1.0 };
            let joined = join(&pooled, &own).map_or_else(|| table.clone(), |j| j.table);
            let joined_masking = op.projected_areas(&joined);
            let pooled_fit = Fit::of(mb, &joined, &joined_masking);
            let k_joined = pooled_fit.scale()?;
            let chi2_pooled = pooled_fit.chi2(k_joined);
            let chi2_own = Fit::of(mb, &own, own_masking).chi2(mb.k_s);
            let cells = own_observed.map_or_else(|| own.coverage().count(), |o| o.get(mb.p).coverage().count());
            let k_own = cells.min(mb.ps.samples.len()) as f64;
            (chi2_pooled + 2.0 <= chi2_own + 2.0 * k_own).then_some((mb.p, joined, k_joined))
        })
        .collect()
}

impl Member {
    fn new(p: usize, ps: PointSamples, kd: [f32; 3], ks: [f32; 3], eta: f32) -> Self {
        let rho_d = kd.map(|kd| kd / std::f32::consts::PI);
        let f0 = fresnel::dielectric_f0(eta).max(crate::tol::MIN_DIVISOR);
        let h: Vec<Vec3> = ps.samples.iter().map(|x| (x.i + ps.o).normalize_or(Vec3::Z)).collect();
        let fresnel = ps
            .samples
            .iter()
            .zip(&h)
            .map(|(x, h)| (fresnel::dielectric(x.i.dot(*h), eta) / f0).max(crate::tol::MIN_FRESNEL_RATIO))
            .collect();
        let spec =
            ps.samples.iter().map(|x| lum([x.rho[0] - rho_d[0], x.rho[1] - rho_d[1], x.rho[2] - rho_d[2]])).collect();
        Member { p, spec, h, fresnel, k_s: lum(ks), ps }
    }
}

/// Sums over a member's samples of the noise model's weights times
/// `s^2`, `s g` and `g^2`, with `s` the scalar specular and `g` the
/// model's prediction per unit `k_s`: the least-squares scale is
/// `sg / gg` and the chi-square at scale `k` is `ss - 2 k sg + k^2 gg`,
/// both from one pass.
#[derive(Clone, Copy, Debug, Default)]
struct Fit {
    ss: f64,
    sg: f64,
    gg: f64,
}

impl Fit {
    fn of(mb: &Member, table: &NdfTable, m: &MaskingTable) -> Self {
        let sigma_o = m.projected_area(mb.ps.o);
        let mut f = Fit::default();
        for (k, x) in mb.ps.samples.iter().enumerate() {
            let denom = 4.0 * m.projected_area(x.i) * sigma_o;
            let g = if denom > 0.0 { (table.eval(mb.h[k]) * mb.fresnel[k] / denom) as f64 } else { 0.0 };
            let (s, w) = (mb.spec[k] as f64, 1.0 / x.var as f64);
            f.ss += w * s * s;
            f.sg += w * s * g;
            f.gg += w * g * g;
        }
        f
    }

    /// Weighted least-squares `k_s`.
    fn scale(&self) -> Option<f32> {
        let s = (self.sg / self.gg) as f32;
        (self.gg > 0.0 && s.is_finite() && s > 0.0).then_some(s)
    }

    fn chi2(&self, k: f32) -> f64 {
        let k = k as f64;
        (self.ss - 2.0 * k * self.sg + k * k * self.gg).max(0.0)
    }
}
