//! Example-based microfacet synthesis (Wang et al. 2008): one oblique view
//! observes only part of each point's NDF; the rest is taken from other
//! points whose NDF, rotated about the normal, matches on the overlap.
//!
//! **Matching** ([`score`]): normalised cross-correlation of the two NDFs
//! over the overlap of their observed regions, cosine-weighted, so equal
//! shapes match at any scale; a match needs `min_overlap` of the query's
//! observed measure and must cover some of what the query is missing. All
//! rotations of a candidate are scored at once by FFT along phi, at
//! `rotations` angles.
//!
//! **Blending** ([`fill`]): each missing cell takes the distance-weighted
//! mean of the best `blend` matches that cover it; observed cells are kept.
//! The completed table is renormalised and its added mass multiplies `k_s`.
//! A second pass matches against the completed tables, so coverage grows
//! from points that can borrow from points that already did.
//!
//! **Tail** ([`tail`]): after the passes, the cells no match covered take a
//! lobe fitted to the rest of the table (`SynthSettings::tail`), so that
//! normalising does not move their mass onto the observed cells.
//!
//! **Search modes** (the talk's speed-ups, each measured by
//! `refl bench synthesis`):
//! - [`SearchMode::BruteForce`]: every other point at every rotation, `N^2 M`.
//! - [`SearchMode::Clustered`]: k-means on NDF descriptors ([`cluster`]);
//!   every query against every cluster's mean NDF at every rotation, `N K M`.
//! - [`SearchMode::Accelerated`]: clustering, then a k-d tree over the
//!   descriptors of every cluster at every rotation ([`descriptor`]): each
//!   query looks up its nearest (cluster, rotation) pairs, prunes those whose
//!   coarse coverage cannot overlap or add anything, and scores the rest
//!   exactly at that one rotation. Where the rotations are finer than the
//!   table's sectors, the tree holds whole sectors and each cluster found
//!   takes its nearest finer angle within a sector.

pub mod cluster;
pub mod descriptor;
pub mod fill;
pub mod score;
pub mod tail;

use std::num::NonZero;
use std::time::Instant;

use brdf::ndf::{NdfTable, TableSet, TableSlot};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use descriptor::{CoarseMask, Core, coarse_mask, coarse_overlap_gain, rotate_mask};
use score::{CandidateSpectra, Flat, Match, Plans, QuerySpectra, ScoreScratch, best_rotation, score_at};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SearchMode {
    BruteForce,
    Clustered,
    Accelerated,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SynthSettings {
    pub mode: SearchMode,
    /// k-means clusters (the talk: about N / 100).
    pub clusters: u32,
    /// Descriptor length (16 or 32).
    pub descriptor: u32,
    /// Rotation angles searched (at least `n_phi`).
    pub rotations: u32,
    /// Matches blended per query.
    pub blend: u32,
    /// Overlap required, as a fraction of the query's observed measure.
    pub min_overlap: f32,
    /// Nearest (cluster, rotation) pairs looked up per query (rotations
    /// at whole sectors where `rotations` is at least twice `n_phi`).
    pub neighbours: u32,
    /// Passes (the second matches against completed tables).
    pub passes: u32,
    pub seed: u64,
    /// Fill the cells no match covered from a lobe fitted to the rest
    /// ([`tail`]); off, they stay empty (0).
    #[serde(default = "filled_tail")]
    pub tail: bool,
}

fn filled_tail() -> bool {
    true
}

impl Default for SynthSettings {
    fn default() -> Self {
        Self {
            mode: SearchMode::Accelerated,
            clusters: 96,
            descriptor: 32,
            rotations: 96,
            blend: 4,
            min_overlap: 0.5,
            neighbours: 48,
            passes: 2,
            seed: 1,
            tail: true,
        }
    }
}

/// What a synthesis run did.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SynthStats {
    pub points: usize,
    pub completed: usize,
    /// Mean fraction of the hemisphere's cosine measure added per point.
    pub mean_added_coverage: f64,
    /// Exact scores computed (FFT: all rotations of one candidate count once).
    pub candidates_scored: u64,
    /// Candidates dropped by the coarse-mask test before scoring.
    pub pruned: u64,
    pub cluster_seconds: f64,
    pub search_seconds: f64,
    pub fill_seconds: f64,
    /// Points whose empty cells took a fitted tail ([`tail`]), and the mean
    /// share of their table's mass the tails hold.
    #[serde(default)]
    pub tail_filled: usize,
    #[serde(default)]
    pub mean_tail_mass: f64,
}

#[derive(Clone, Debug)]
pub struct SynthOutput {
    /// Completed tables, normalised.
    pub tables: TableSet,
    /// Per point: integral of the completed table relative to the partial one
    /// (1 where nothing was added); multiply `k_s` by it.
    pub mass_factor: Vec<f32>,
    pub stats: SynthStats,
}

/// The share of the hemisphere's cosine measure that table `p` of `set`
/// observed.
/// `measures` holds the grid's [`brdf::ndf::NdfGrid::cos_measures`].
fn coverage_measure(set: &TableSet, p: usize, measures: &[f32]) -> f64 {
    let np = set.grid().n_phi as usize;
    let words = set.coverage_words(p);
    (0..set.grid().len()).filter(|&c| brdf::ndf::bit(words, c)).map(|c| measures[c / np] as f64).sum::<f64>()
        / std::f64::consts::PI
}

/// Cluster mean tables: per cell the mean over members that observed it;
/// observed where at least half of the members did. Each cluster's sums
/// run over its members in the order of `points`.
fn cluster_tables(tables: &TableSet, points: &[usize], assign: &[u32], k: usize) -> Vec<NdfTable> {
    let g = tables.grid();
    let cells = g.len();
    let mut members = vec![Vec::new(); k];
    for (i, &p) in points.iter().enumerate() {
        members[assign[i] as usize].push(p);
    }
    members
        .par_iter()
        .map(|members| {
            let mut sum = vec![0.0f64; cells];
            let mut cnt = vec![0u32; cells];
            let mut values = vec![0.0f32; cells];
            for &p in members {
                tables.values_into(p, &mut values);
                let words = tables.coverage_words(p);
                for cell in 0..cells {
                    if brdf::ndf::bit(words, cell) {
                        sum[cell] += values[cell] as f64;
                        cnt[cell] += 1;
                    }
                }
            }
            let n = members.len() as u32;
            let mut t = NdfTable::zeros(g);
            for cell in 0..cells {
                if n > 0 && 2 * cnt[cell] >= n && cnt[cell] > 0 {
                    t.values_mut()[cell] = (sum[cell] / cnt[cell] as f64) as f32;
                    t.coverage_mut().set(cell, true);
                }
            }
            t
        })
        .collect()
}

fn top(mut v: Vec<Match>, k: usize) -> Vec<Match> {
    v.sort_by(|a, b| a.distance.total_cmp(&b.distance).then(a.candidate.cmp(&b.candidate)));
    v.truncate(k);
    v
}

/// Complete the tables of the `eligible` points.
pub fn synthesize(input: &TableSet, eligible: &[bool], s: &SynthSettings) -> SynthOutput {
    synthesize_watched(input, eligible, s, &crate::FitProgress::new())
}

/// [`synthesize`], counting each point's search of each pass in `progress`.
pub fn synthesize_watched(
    input: &TableSet,
    eligible: &[bool],
    s: &SynthSettings,
    progress: &crate::FitProgress,
) -> SynthOutput {
    let grid = input.grid();
    let points: Vec<usize> = (0..input.len()).filter(|&p| eligible.get(p).copied().unwrap_or(false)).collect();
    progress.begin(crate::FitStage::Synthesis, (points.len() * s.passes.max(1) as usize) as u64);
    // Synthesis writes only the eligible points' tables; a blank one (a
    // point the choice's refit skips) stays unwritten.
    let mut tables = input.clone_written();
    let mut mass = vec![1.0f32; input.len()];
    let mut stats = SynthStats { points: points.len(), ..SynthStats::default() };
    if points.len() < 2 {
        return SynthOutput { tables, mass_factor: mass, stats };
    }
    let plans = Plans::new(grid, s.rotations as usize);
    let measures = grid.cos_measures();
    let before: Vec<f64> = points.par_iter().map(|&p| coverage_measure(input, p, &measures)).collect();
    let blend = s.blend.max(1) as usize;
    for _pass in 0..s.passes.max(1) {
        // Candidates: other points, or cluster means.
        let t0 = Instant::now();
        let core = Core::find(&tables, &points, s.descriptor as usize);
        let dlen = core.len();
        let descriptors = core.describe_all(&tables, &points);
        let candidates: Vec<NdfTable> = match s.mode {
            SearchMode::BruteForce => points.iter().map(|&p| tables.get(p)).collect(),
            _ => {
                let k = (s.clusters as usize).clamp(1, points.len());
                let assign = cluster::kmeans(&descriptors, dlen, k, s.seed);
                cluster_tables(&tables, &points, &assign, k)
            }
        };
        stats.cluster_seconds += t0.elapsed().as_secs_f64();
        let t1 = Instant::now();
        let scored = std::sync::atomic::AtomicU64::new(0);
        let pruned = std::sync::atomic::AtomicU64::new(0);
        let matches: Vec<Vec<Match>> = match s.mode {
            SearchMode::BruteForce | SearchMode::Clustered => {
                let spectra: Vec<CandidateSpectra> =
                    candidates.par_iter().map(|t| CandidateSpectra::new(&plans, t)).collect();
                points
                    .par_iter()
                    .enumerate()
                    .map_init(ScoreScratch::default, |scratch, (qi, &p)| {
                        let q = tables.get(p);
                        let qs = QuerySpectra::new(&plans, &q);
                        let mut found = Vec::new();
                        for (ci, cs) in spectra.iter().enumerate() {
                            if s.mode == SearchMode::BruteForce && ci == qi {
                                continue;
                            }
                            scored.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                            if let Some(m) = best_rotation(&plans, &qs, cs, ci, s.min_overlap, scratch) {
                                found.push(m);
                            }
                        }
                        progress.advance(1);
                        top(found, blend)
                    })
                    .collect()
            }
            SearchMode::Accelerated => {
                let m_rot = plans.rotations;
                let np = grid.n_phi as f32;
                let masks: Vec<CoarseMask> =
                    candidates.iter().map(|t| coarse_mask(grid, t.coverage().words())).collect();
                // Descriptor database: every cluster at every rotation.
                let mut db = vec![0.0f32; candidates.len() * m_rot * dlen];
                db.par_chunks_mut(dlen.max(1)).enumerate().for_each(|(e, d)| {
                    let (c, r) = (e / m_rot, e % m_rot);
                    core.describe(&candidates[c], r as f32 * np / m_rot as f32, d);
                });
                // With two or more angles per sector, the nearest-neighbour
                // search runs over each cluster at whole sectors only
                // (`coarse`), and each cluster it finds is then turned to its
                // nearest angle within a sector either side
                // ([`finest_rotation`]). A cluster's neighbouring angles
                // crowded the search over every angle: at 1,000 angles its
                // 48 neighbours held a few clusters, ten or so angles each,
                // and the k-d tree over a million entries took the largest
                // part of the search's time. Below two angles per sector (the presets'
                // `fast` and `balanced`) every angle is searched, as before.
                let coarse = grid.n_phi as usize;
                let step = m_rot / coarse;
                let coarse_db: Vec<f32> = if step == 1 {
                    Vec::new()
                } else {
                    (0..candidates.len() * coarse)
                        .flat_map(|e| {
                            let fine = (e / coarse) * m_rot + (e % coarse) * m_rot / coarse;
                            db[fine * dlen..(fine + 1) * dlen].iter().copied()
                        })
                        .collect()
                };
                let (tree_db, tree_rot) = if step == 1 { (&db, m_rot) } else { (&coarse_db, coarse) };
                let nn = (s.neighbours.max(1) as usize).min(candidates.len() * tree_rot);
                let lookups = nearest(tree_db, &descriptors, dlen, nn);
                let flats: Vec<Flat> = candidates.iter().map(Flat::new).collect();
                points
                    .par_iter()
                    .enumerate()
                    .map(|(qi, &p)| {
                        let qf = Flat::query(&tables, p);
                        let qm = coarse_mask(grid, tables.coverage_words(p));
                        let need = (s.min_overlap * qm.iter().map(|r| r.count_ones()).sum::<u32>() as f32 * 0.8) as u32;
                        let mut found: Vec<Match> = Vec::new();
                        let mut seen: Vec<usize> = Vec::new();
                        for &e in &lookups[qi] {
                            let (c, r) = (e / tree_rot, e % tree_rot);
                            // Neighbouring rotations of one cluster crowd the
                            // list; its nearest rotation stands for it.
                            if seen.contains(&c) {
                                continue;
                            }
                            seen.push(c);
                            let r = if step == 1 {
                                r
                            } else {
                                let query = &descriptors[qi * dlen..(qi + 1) * dlen];
                                finest_rotation(
                                    &db[c * m_rot * dlen..(c + 1) * m_rot * dlen],
                                    dlen,
                                    query,
                                    r * m_rot / coarse,
                                    m_rot.div_ceil(coarse),
                                )
                            };
                            let shift = r as f32 * np / m_rot as f32;
                            let (ov, gain) = coarse_overlap_gain(&qm, &rotate_mask(&masks[c], shift, grid.n_phi));
                            if ov < need || gain == 0 {
                                pruned.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                                continue;
                            }
                            scored.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                            if let Some(m) = score_at(&measures, &qf, &flats[c], shift, c, s.min_overlap) {
                                found.push(m);
                            }
                        }
                        progress.advance(1);
                        top(found, blend)
                    })
                    .collect()
            }
        };
        stats.candidates_scored += scored.into_inner();
        stats.pruned += pruned.into_inner();
        stats.search_seconds += t1.elapsed().as_secs_f64();
        let t2 = Instant::now();
        slots_of(&mut tables, &mut mass, &points).into_par_iter().zip(matches.par_iter()).for_each(
            |((mut slot, mass), ms)| {
                if ms.is_empty() {
                    return;
                }
                let with: Vec<(Match, &NdfTable)> = ms.iter().map(|m| (*m, &candidates[m.candidate])).collect();
                if let Some(mut t) = fill::complete(&slot.get(), &with) {
                    let k = t.normalize();
                    if k > 0.0 {
                        *mass *= k;
                        slot.set(&t);
                    }
                }
            },
        );
        stats.fill_seconds += t2.elapsed().as_secs_f64();
    }
    let after: Vec<f64> = points.par_iter().map(|&p| coverage_measure(&tables, p, &measures)).collect();
    stats.completed = before.iter().zip(&after).filter(|(b, a)| a > b).count();
    stats.mean_added_coverage = before.iter().zip(&after).map(|(b, a)| a - b).sum::<f64>() / points.len() as f64;
    if s.tail {
        let t = Instant::now();
        let slopes = tail::Slopes::new(grid);
        let factors: Vec<Option<f32>> = slots_of(&mut tables, &mut mass, &points)
            .into_par_iter()
            .map(|(mut slot, mass)| {
                let mut f = tail::fill_with(&slot.get(), &slopes)?;
                let k = f.normalize();
                (k > 0.0).then(|| {
                    *mass *= k;
                    slot.set(&f);
                    k
                })
            })
            .collect();
        let mut tail_mass = 0.0;
        for k in factors.into_iter().flatten() {
            tail_mass += f64::from(1.0 - 1.0 / k);
            stats.tail_filled += 1;
        }
        stats.mean_tail_mass = if stats.tail_filled > 0 { tail_mass / stats.tail_filled as f64 } else { 0.0 };
        stats.fill_seconds += t.elapsed().as_secs_f64();
    }
    SynthOutput { tables, mass_factor: mass, stats }
}

/// The tables of `points` (ascending, as `synthesize` takes them) in
/// `tables`, each with its entry of `mass`, to change in parallel.
fn slots_of<'a>(tables: &'a mut TableSet, mass: &'a mut [f32], points: &[usize]) -> Vec<(TableSlot<'a>, &'a mut f32)> {
    let mut next = points.iter().peekable();
    tables.slots().zip(mass.iter_mut()).enumerate().filter_map(|(p, slot)| next.next_if_eq(&&p).map(|_| slot)).collect()
}

/// Of one cluster's descriptors at `rotations` angles (`db`, row-major,
/// `dim` long), the angle nearest to `query` within `reach` angles either
/// side of `around` (the lowest distance; the first such angle counting
/// from `around - reach`).
fn finest_rotation(db: &[f32], dim: usize, query: &[f32], around: usize, reach: usize) -> usize {
    let rotations = db.len() / dim;
    let mut best = (around, f32::INFINITY);
    for k in 0..=2 * reach {
        let r = (around + rotations + k - reach) % rotations;
        let d = cluster::d2(&db[r * dim..(r + 1) * dim], query);
        if d < best.1 {
            best = (r, d);
        }
    }
    best.0
}

/// Database size above which nearest neighbours use the k-d tree.
const TREE_ENTRIES: usize = 50_000;

/// For every query descriptor, the indices of its `n` nearest database
/// entries (k-d tree for the descriptor lengths it is compiled for,
/// brute force otherwise).
fn nearest(db: &[f32], queries: &[f32], dim: usize, n: usize) -> Vec<Vec<usize>> {
    fn tree<const D: usize>(db: &[f32], queries: &[f32], n: usize) -> Option<Vec<Vec<usize>>> {
        let t = cluster::tree::<D>(db)?;
        let k = NonZero::new(n)?;
        Some(
            queries
                .par_chunks_exact(D)
                .map(|q| {
                    let q: [f32; D] = std::array::from_fn(|j| q[j]);
                    t.query(&q)
                        .nearest_n::<kiddo::SquaredEuclidean<f32>>(k)
                        .execute()
                        .into_iter()
                        .map(|r| r.item as usize)
                        .collect()
                })
                .collect(),
        )
    }
    // In 32 dimensions a k-d tree only pays off for large databases:
    // synthesising the balanced satin capture (9,216 entries) took 12.1 s
    // with the scan and 14.7 s with the tree; `refl bench synthesis` prints
    // both at larger sizes.
    let entries = db.len() / dim.max(1);
    let fast = match dim {
        16 if entries > TREE_ENTRIES => tree::<16>(db, queries, n),
        32 if entries > TREE_ENTRIES => tree::<32>(db, queries, n),
        _ => None,
    };
    fast.unwrap_or_else(|| {
        queries
            .par_chunks_exact(dim.max(1))
            .map(|q| {
                let mut d: Vec<(f32, usize)> = db
                    .chunks_exact(dim.max(1))
                    .enumerate()
                    .map(|(i, x)| (x.iter().zip(q).map(|(a, b)| (a - b) * (a - b)).sum::<f32>(), i))
                    .collect();
                let k = n.min(d.len());
                if k > 0 && k < d.len() {
                    d.select_nth_unstable_by(k - 1, |a, b| a.0.total_cmp(&b.0));
                }
                d.truncate(k);
                d.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                // A fresh vector: `into_iter().collect()` would reuse (and
                // keep) the scan buffer of every entry, for every query,
                // which made memory grow as N x clusters x rotations.
                let mut out = Vec::with_capacity(k);
                out.extend(d.iter().map(|x| x.1));
                out
            })
            .collect()
    })
}

#[cfg(test)]
mod tests {
    use super::finest_rotation;

    #[test]
    fn the_finest_rotation_is_the_nearest_within_reach_around_the_ring() {
        // One cluster at 12 angles, 2-long descriptors: angle r sits at
        // (r, 0); the query nearest angle 11, then angle 0.
        let db: Vec<f32> = (0..12).flat_map(|r| [r as f32, 0.0]).collect();
        let query = [11.2, 0.0];
        // Around 0, one angle either side reaches 11 across the wrap.
        assert_eq!(finest_rotation(&db, 2, &query, 0, 1), 11);
        // Around 3, the nearest within reach is the edge nearest the query.
        assert_eq!(finest_rotation(&db, 2, &query, 3, 2), 5);
        // No reach: the angle it starts from.
        assert_eq!(finest_rotation(&db, 2, &query, 7, 0), 7);
        // Equal distances: the first counting from `around - reach`.
        assert_eq!(finest_rotation(&db, 2, &[5.5, 0.0], 5, 1), 5);
    }
}
