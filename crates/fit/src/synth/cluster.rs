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
    let n = if dim == 0 { 0 } else { data.len() / dim };
    if n == 0 {
        return Vec::new();
    }
    let k = k.clamp(1, n);
    let row = |i: usize| &data[i * dim..(i + 1) * dim];
    let mut centres = seeds(data, dim, k, seed, true);
    let mut assign = vec![u32::MAX; n];
    for _ in 0..MAX_ITERATIONS {
        let next = assign_all(data, dim, &centres, k);
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
        for c in 0..k {
            if counts[c] > 0 {
                for j in 0..dim {
                    centres[c * dim + j] = (sums[c * dim + j] / counts[c] as f64) as f32;
                }
            }
        }
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

fn assign_tree<const D: usize>(data: &[f32], centres: &[f32]) -> Vec<u32> {
    let pts: Vec<[f32; D]> = centres.chunks_exact(D).map(|c| std::array::from_fn(|j| c[j])).collect();
    let Ok(tree) = kiddo::ImmutableKdTree::<f32, D>::new_from_slice(&pts) else {
        return assign_scan(data, D, centres, pts.len());
    };
    data.par_chunks_exact(D)
        .map(|x| {
            let q: [f32; D] = std::array::from_fn(|j| x[j]);
            tree.query(&q).nearest_one::<kiddo::SquaredEuclidean<f32>>().execute().item as u32
        })
        .collect()
}

fn assign_all(data: &[f32], dim: usize, centres: &[f32], k: usize) -> Vec<u32> {
    match dim {
        16 if k > TREE_ABOVE => assign_tree::<16>(data, centres),
        32 if k > TREE_ABOVE => assign_tree::<32>(data, centres),
        _ => assign_scan(data, dim, centres, k),
    }
}

fn assign_scan(data: &[f32], dim: usize, centres: &[f32], k: usize) -> Vec<u32> {
    let n = data.len() / dim;
    (0..n)
        .into_par_iter()
        .map(|i| {
            let x = &data[i * dim..(i + 1) * dim];
            let mut best = (0u32, f32::INFINITY);
            for c in 0..k {
                let d = d2(x, &centres[c * dim..(c + 1) * dim]);
                if d < best.1 {
                    best = (c as u32, d);
                }
            }
            best.0
        })
        .collect()
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
}
