//! k-means on NDF descriptors: seeded k-means++ (Arthur and Vassilvitskii
//! 2007) and Lloyd iterations with a fixed-order reduction, so a run repeats
//! exactly. The design notes measured `linfa-clustering` 10-19x slower than
//! this approach (assignment as a brute-force distance scan) and pinned to
//! older dependencies, which is why it is written here. Above a few hundred
//! clusters the assignment step uses a k-d tree (`kiddo`) instead of the scan.

use brdf::ndf::TableSet;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use std::num::NonZero;

/// Lloyd iterations (assignments stop changing by then on every capture
/// measured; the loop also stops as soon as they do).
const MAX_ITERATIONS: usize = 20;

/// The seeding's triangle-inequality skip holds its bound with this
/// factor to spare (see [`kmeans`]).
const SKIP_MARGIN: f32 = 1.001;

/// Squared Euclidean distance between two descriptors.
pub(crate) fn d2(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// Cluster `points` by their tables as they stand (unrotated): k-means
/// with `k` clusters on the synthesis's descriptors over the cells most of
/// them observe (`descriptor` cells). Returns each point's cluster, in the
/// order of `points`. The analytic fits share shape parameters per
/// cluster; pooled estimation halves clusters with [`kmeans`] on the same
/// descriptors, as often as its test takes the halves.
pub fn by_table(tables: &TableSet, points: &[usize], descriptor: usize, k: usize, seed: u64) -> Vec<u32> {
    let core = super::descriptor::Core::find(tables, points, descriptor);
    kmeans(&core.describe_all(tables, points), core.len(), k, seed)
}

/// Cluster `n` vectors of length `dim` (row-major in `data`) into `k`
/// clusters. Returns the assignment of each vector.
pub fn kmeans(data: &[f32], dim: usize, k: usize, seed: u64) -> Vec<u32> {
    lloyd(data, dim, k, seed, true)
}

/// [`kmeans`]; with `bounds`, each pass after the first looks for a
/// vector's nearest centre only where Hamerly's bounds (Hamerly 2010,
/// "Making k-means even faster") leave it in doubt. Per vector they keep
/// an upper bound `u` on its distance to its centre and a lower bound `l`
/// on its distance to every other; when the centres move, `u` grows by its
/// centre's move and `l` shrinks by the largest move (the triangle
/// inequality). A vector stays with its centre while `u` is below both `l`
/// and half the distance from its centre to the nearest other (no other
/// centre can be nearer then), with [`SKIP_MARGIN`] to spare for
/// rounding, so the assignments, and the centres, are those of the passes
/// without bounds.
fn lloyd(data: &[f32], dim: usize, k: usize, seed: u64, bounds: bool) -> Vec<u32> {
    let n = if dim == 0 { 0 } else { data.len() / dim };
    if n == 0 {
        return Vec::new();
    }
    let k = k.clamp(1, n);
    let row = |i: usize| &data[i * dim..(i + 1) * dim];
    let mut centres = seeds(data, dim, k, seed, true);
    let mut assign = vec![u32::MAX; n];
    let (mut upper, mut lower) = (vec![f32::INFINITY; n], vec![0.0f32; n]);
    for pass in 0..MAX_ITERATIONS {
        let nearest = Nearest::new(&centres, dim, k);
        let half_gap: Vec<f32> = if bounds && pass > 0 { nearest.half_gaps() } else { Vec::new() };
        let next: Vec<u32> = (0..n)
            .into_par_iter()
            .zip(upper.par_iter_mut().zip(lower.par_iter_mut()))
            .map(|(i, (u, l))| {
                let a = assign[i];
                if !half_gap.is_empty() {
                    let m = half_gap[a as usize].max(*l);
                    if SKIP_MARGIN * *u <= m {
                        return a;
                    }
                    *u = d2(row(i), &centres[a as usize * dim..(a as usize + 1) * dim]).sqrt();
                    if SKIP_MARGIN * *u <= m {
                        return a;
                    }
                }
                let (best, d_best, d_second) = nearest.two(row(i));
                (*u, *l) = (d_best.sqrt(), d_second.sqrt());
                best
            })
            .collect();
        let changed = next.iter().zip(&assign).any(|(a, b)| a != b);
        assign = next;
        if !changed {
            break;
        }
        // Fixed-order reduction: sums in index order.
        let mut sums = vec![0.0f64; k * dim];
        let mut counts = vec![0usize; k];
        for (i, &a) in assign.iter().enumerate() {
            counts[a as usize] += 1;
            for (s, v) in sums[a as usize * dim..(a as usize + 1) * dim].iter_mut().zip(row(i)) {
                *s += *v as f64;
            }
        }
        let mut moved = vec![0.0f32; k];
        for c in 0..k {
            if counts[c] > 0 {
                let mut move2 = 0.0f32;
                for j in 0..dim {
                    let (old, new) = (centres[c * dim + j], (sums[c * dim + j] / counts[c] as f64) as f32);
                    move2 += (old - new) * (old - new);
                    centres[c * dim + j] = new;
                }
                moved[c] = move2.sqrt();
            }
        }
        let most = moved.iter().copied().fold(0.0f32, f32::max);
        upper.par_iter_mut().zip(&assign).for_each(|(u, &a)| *u += moved[a as usize]);
        lower.par_iter_mut().for_each(|l| *l = (*l - most).max(0.0));
    }
    assign
}

/// k-means++ seeding: `k` centres of the `n` vectors of length `dim`,
/// row-major. With `skip`, the distances the triangle inequality shows
/// cannot matter are not computed; the centres are the same either way.
fn seeds(data: &[f32], dim: usize, k: usize, seed: u64, skip: bool) -> Vec<f32> {
    let n = data.len() / dim;
    let row = |i: usize| &data[i * dim..(i + 1) * dim];
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut centres: Vec<f32> = Vec::with_capacity(k * dim);
    centres.extend_from_slice(row(rng.random_range(0..n)));
    let mut nearest: Vec<f32> = (0..n).into_par_iter().map(|i| d2(row(i), &centres[0..dim])).collect();
    // Each vector's nearest centre so far, to skip the distances that
    // cannot lower `nearest` (below).
    let mut owner = vec![0u32; n];
    while centres.len() < k * dim {
        let total: f64 = nearest.iter().map(|&v| v as f64).sum();
        let pick = if total > 0.0 {
            let mut x = rng.random::<f64>() * total;
            let mut j = n - 1;
            for (i, &v) in nearest.iter().enumerate() {
                x -= v as f64;
                if x <= 0.0 {
                    j = i;
                    break;
                }
            }
            j
        } else {
            rng.random_range(0..n)
        };
        let c0 = centres.len();
        centres.extend_from_slice(row(pick));
        let c = centres[c0..c0 + dim].to_vec();
        let j = (c0 / dim) as u32;
        // By the triangle inequality, a vector at squared distance `v`
        // from its nearest centre `o` is no nearer the new centre when
        // that is at least twice as far from `o`: squared, `4 v`. The
        // margin covers the rounding of three f32 distances (relative
        // 1e-5 each), so a skipped distance is one that would not have
        // lowered `v`: the sums, and the seeding, are those without it.
        let apart: Vec<f32> = centres[..c0].chunks_exact(dim).map(|o| d2(o, &c)).collect();
        nearest.par_iter_mut().zip(owner.par_iter_mut()).enumerate().for_each(|(i, (v, o))| {
            if skip && apart[*o as usize] >= SKIP_MARGIN * 4.0 * *v {
                return;
            }
            let d = d2(row(i), &c);
            if d < *v {
                (*v, *o) = (d, j);
            }
        });
    }
    centres
}

/// Above this many clusters, assignment queries a k-d tree of the centres.
const TREE_ABOVE: usize = 256;

/// The centres of one pass, to find a vector's nearest two: by a k-d tree
/// (`kiddo`) above [`TREE_ABOVE`] clusters of 16 or 32 dimensions, else by
/// scanning them all.
struct Nearest<'a> {
    centres: &'a [f32],
    dim: usize,
    tree: Tree,
}

enum Tree {
    None,
    D16(kiddo::ImmutableKdTree<f32, 16>),
    D32(kiddo::ImmutableKdTree<f32, 32>),
}

impl<'a> Nearest<'a> {
    fn new(centres: &'a [f32], dim: usize, k: usize) -> Self {
        let tree = match dim {
            16 if k > TREE_ABOVE => tree::<16>(centres).map_or(Tree::None, Tree::D16),
            32 if k > TREE_ABOVE => tree::<32>(centres).map_or(Tree::None, Tree::D32),
            _ => Tree::None,
        };
        Self { centres, dim, tree }
    }

    /// The nearest centre to `x` and the squared distances to it and to
    /// the second nearest (infinite with one centre).
    fn two(&self, x: &[f32]) -> (u32, f32, f32) {
        match &self.tree {
            Tree::D16(t) => tree_two(t, x),
            Tree::D32(t) => tree_two(t, x),
            Tree::None => {
                let (mut best, mut d_best, mut d_second) = (0u32, f32::INFINITY, f32::INFINITY);
                for (c, centre) in self.centres.chunks_exact(self.dim).enumerate() {
                    let d = d2(x, centre);
                    if d < d_best {
                        (best, d_best, d_second) = (c as u32, d, d_best);
                    } else if d < d_second {
                        d_second = d;
                    }
                }
                (best, d_best, d_second)
            }
        }
    }

    /// Per centre, half its distance to the nearest other: the second
    /// nearest to its own position (the nearest is itself, or another
    /// centre at the same place).
    fn half_gaps(&self) -> Vec<f32> {
        self.centres.par_chunks_exact(self.dim).map(|c| 0.5 * self.two(c).2.sqrt()).collect()
    }
}

/// A k-d tree of the `D`-long rows of `rows` (`None` where `kiddo`
/// cannot build one).
pub(crate) fn tree<const D: usize>(rows: &[f32]) -> Option<kiddo::ImmutableKdTree<f32, D>> {
    let pts: Vec<[f32; D]> = rows.chunks_exact(D).map(|c| std::array::from_fn(|j| c[j])).collect();
    kiddo::ImmutableKdTree::<f32, D>::new_from_slice(&pts).ok()
}

fn tree_two<const D: usize>(t: &kiddo::ImmutableKdTree<f32, D>, x: &[f32]) -> (u32, f32, f32) {
    let q: [f32; D] = std::array::from_fn(|j| x[j]);
    let two = NonZero::new(2).expect("2 is not 0");
    let found = t.query(&q).nearest_n::<kiddo::SquaredEuclidean<f32>>(two).execute();
    match found.as_slice() {
        [a, b, ..] => (a.item as u32, a.distance, b.distance),
        [a] => (a.item as u32, a.distance, f32::INFINITY),
        [] => (0, f32::INFINITY, f32::INFINITY),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn separates_obvious_clusters_and_repeats_exactly() {
        let mut data = Vec::new();
        for i in 0..60 {
            let c = (i % 3) as f32 * 10.0;
            data.extend_from_slice(&[c + (i as f32 * 0.01), c - (i as f32 * 0.02)]);
        }
        let a = kmeans(&data, 2, 3, 1);
        let b = kmeans(&data, 2, 3, 1);
        assert_eq!(a, b);
        for i in 0..60 {
            assert_eq!(a[i], a[i % 3], "vector {i}");
        }
        assert_ne!(a[0], a[1]);
        assert_ne!(a[1], a[2]);
    }

    #[test]
    fn the_seeding_s_skipped_distances_change_nothing() {
        use rand_distr::{Distribution, Normal};
        // 4,000 vectors in 40 clumps of 16 dimensions (where the skip
        // skips most distances), seeded into 200 centres.
        let mut rng = Pcg64::seed_from_u64(3);
        let noise = Normal::new(0.0f32, 0.05).unwrap();
        let hubs: Vec<f32> = (0..40 * 16).map(|_| rng.random_range(-1.0f32..1.0)).collect();
        let data: Vec<f32> = (0..4000)
            .flat_map(|i| {
                let h = (i % 40) * 16;
                (0..16).map(|j| hubs[h + j] + noise.sample(&mut rng)).collect::<Vec<_>>()
            })
            .collect();
        for seed in [1, 2] {
            let (with, without) = (seeds(&data, 16, 200, seed, true), seeds(&data, 16, 200, seed, false));
            assert_eq!(with.len(), 200 * 16);
            assert!(with.iter().zip(&without).all(|(a, b)| a.to_bits() == b.to_bits()), "seed {seed}");
        }
    }

    #[test]
    fn the_bounds_skipped_searches_change_nothing() {
        use rand_distr::{Distribution, Normal};
        // Clumps wide enough to overlap, so that vectors change clusters
        // over several passes; 16 and 32 dimensions, with clusters
        // found by scanning (40) and by the k-d tree (300).
        let mut rng = Pcg64::seed_from_u64(5);
        for (dim, k) in [(16usize, 40usize), (16, 300), (32, 300)] {
            let noise = Normal::new(0.0f32, 0.25).unwrap();
            let hubs: Vec<f32> = (0..60 * dim).map(|_| rng.random_range(-1.0f32..1.0)).collect();
            let data: Vec<f32> = (0..6000)
                .flat_map(|i| {
                    let h = (i % 60) * dim;
                    (0..dim).map(|j| hubs[h + j] + noise.sample(&mut rng)).collect::<Vec<_>>()
                })
                .collect();
            let (with, without) = (lloyd(&data, dim, k, 3, true), lloyd(&data, dim, k, 3, false));
            assert_eq!(with, without, "{dim} dimensions, {k} clusters");
        }
    }
}
