//! Short descriptions of NDFs for clustering and nearest-neighbour search,
//! and coarse coverage masks for pruning.
//!
//! **Core region.** Every point's camera saw the cone around the normal up
//! to some angle; the core is the largest cone that (almost) every point saw
//! completely, so it is observed at every rotation of every candidate. The
//! descriptor samples an NDF there: `rings x sectors` band averages
//! (cosine-weighted), normalised to unit length so that it describes shape,
//! not scale (partial tables are normalised over different regions). It is
//! the talk's "NDFs subsampled to 32 values". A rotation of a candidate by
//! `s` sectors is computed on the core cells only.
//!
//! **Coarse masks.** Coverage reduced to 8 rings x 16 sectors (a cell is set
//! when at least half of its fine cells are), one `u16` per ring: the
//! overlap and the gain of a rotated candidate are estimated with a few
//! rotations and popcounts, to prune candidates before exact scoring (the
//! talk's "intersection approximation").

use brdf::ndf::{NdfGrid, NdfTable, TableSet};
use rayon::prelude::*;

/// Rings of the coarse mask.
pub const COARSE_RINGS: usize = 8;
/// Sectors of the coarse mask (one `u16` per ring).
pub const COARSE_SECTORS: usize = 16;

/// The core cone and the descriptor layout.
#[derive(Clone, Debug, PartialEq)]
pub struct Core {
    pub grid: NdfGrid,
    /// Rings of the table inside the core.
    pub rings: usize,
    pub bands: usize,
    pub sectors: usize,
    /// Cosine measure of each core ring.
    measures: Vec<f32>,
    /// Each descriptor entry's summed cosine measure (the same for every
    /// table and rotation).
    weights: Vec<f32>,
}

impl Core {
    pub fn len(&self) -> usize {
        self.bands * self.sectors
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Find the core: the largest number of innermost rings that all
    /// sectors of which are observed at 95% of the points given.
    pub fn find(tables: &TableSet, points: &[usize], length: usize) -> Self {
        let g = tables.grid();
        let (nt, np) = (g.n_theta as usize, g.n_phi as usize);
        let mut full_rings: Vec<usize> = points
            .iter()
            .map(|&k| {
                let w = tables.coverage_words(k);
                (0..nt).take_while(|&t| (0..np).all(|p| brdf::ndf::bit(w, t * np + p))).count()
            })
            .collect();
        full_rings.sort_unstable();
        let rings = full_rings.get(full_rings.len() / 20).copied().unwrap_or(0).max(2).min(nt);
        let bands = if length >= 32 { 2 } else { 1 }.min(rings);
        let sectors = (length / bands).clamp(4, np);
        let measures: Vec<f32> = (0..rings).map(|t| g.cos_measure(t)).collect();
        let mut weights = vec![0.0f32; bands * sectors];
        for (t, &w) in measures.iter().enumerate() {
            let band = t * bands / rings;
            for p in 0..np {
                weights[band * sectors + p * sectors / np] += w;
            }
        }
        Self { grid: g, rings, bands, sectors, measures, weights }
    }

    /// The unrotated descriptors of `points`' tables, row-major.
    pub fn describe_all(&self, tables: &TableSet, points: &[usize]) -> Vec<f32> {
        let dlen = self.len();
        let mut out = vec![0.0f32; points.len() * dlen];
        out.par_chunks_mut(dlen.max(1)).zip(points.par_iter()).for_each(|(d, &p)| {
            if let Some(value) = tables.cells(p) {
                self.describe_with(value, 0.0, d);
            }
        });
        out
    }

    /// Descriptor of `t` rotated by `shift` sectors (fractional shifts
    /// interpolate linearly), unit length (zero if the core is empty).
    pub fn describe(&self, t: &NdfTable, shift: f32, out: &mut [f32]) {
        let values = t.values();
        self.describe_with(|c| values[c], shift, out);
    }

    /// [`Core::describe`] of the table whose value at cell `c` is `value(c)`.
    fn describe_with(&self, value: impl Fn(usize) -> f32, shift: f32, out: &mut [f32]) {
        let np = self.grid.n_phi as usize;
        out.iter_mut().for_each(|v| *v = 0.0);
        let (s0, f) = brdf::ndf::split_shift(shift, np);
        for (t_, &w) in self.measures.iter().enumerate() {
            let band = t_ * self.bands / self.rings;
            for (p, (a, b)) in brdf::ndf::rotation_sources(np, s0).enumerate() {
                // Rotated value at p: source sectors p - s0 and p - s0 - 1.
                let (a, b) = (value(t_ * np + a), value(t_ * np + b));
                let v = a * (1.0 - f) + b * f;
                out[band * self.sectors + p * self.sectors / np] += w * v;
            }
        }
        let mut norm = 0.0f32;
        for (o, w) in out.iter_mut().zip(&self.weights) {
            if *w > 0.0 {
                *o /= w;
            }
            norm += *o * *o;
        }
        let norm = norm.sqrt();
        if norm > 0.0 {
            out.iter_mut().for_each(|v| *v /= norm);
        }
    }
}

/// Coverage at 8 x 16 resolution, one `u16` per ring.
pub type CoarseMask = [u16; COARSE_RINGS];

pub fn coarse_mask(grid: NdfGrid, words: &[u64]) -> CoarseMask {
    let (nt, np) = (grid.n_theta as usize, grid.n_phi as usize);
    let mut m = [0u16; COARSE_RINGS];
    for (a, ring) in m.iter_mut().enumerate() {
        let (t0, t1) = (a * nt / COARSE_RINGS, ((a + 1) * nt / COARSE_RINGS).max(a * nt / COARSE_RINGS + 1));
        for b in 0..COARSE_SECTORS {
            let (p0, p1) = (b * np / COARSE_SECTORS, ((b + 1) * np / COARSE_SECTORS).max(b * np / COARSE_SECTORS + 1));
            let (mut on, mut all) = (0, 0);
            for t in t0..t1.min(nt) {
                for p in p0..p1.min(np) {
                    let c = t * np + p;
                    all += 1;
                    on += brdf::ndf::bit(words, c) as usize;
                }
            }
            if all > 0 && 2 * on >= all {
                *ring |= 1 << b;
            }
        }
    }
    m
}

/// Rotate a coarse mask by `shift` fine sectors (rounded to coarse ones).
pub fn rotate_mask(m: &CoarseMask, shift: f32, n_phi: u32) -> CoarseMask {
    let k = ((shift * COARSE_SECTORS as f32 / n_phi as f32).round() as i64).rem_euclid(COARSE_SECTORS as i64) as u32;
    m.map(|r| r.rotate_left(k))
}

/// Estimated (overlap, gain) in coarse cells of a rotated candidate mask.
pub fn coarse_overlap_gain(query: &CoarseMask, rotated: &CoarseMask) -> (u32, u32) {
    let mut o = 0;
    let mut g = 0;
    for (q, c) in query.iter().zip(rotated) {
        o += (q & c).count_ones();
        g += (!q & c).count_ones();
    }
    (o, g)
}

#[cfg(test)]
mod tests {
    use super::*;
    use brdf::ndf::Beckmann;

    #[test]
    fn a_rotated_descriptor_equals_the_descriptor_of_the_rotated_ndf() {
        let grid = NdfGrid::new(16, 48).unwrap();
        let mut set = TableSet::new(grid, 2);
        let a = NdfTable::from_ndf(grid, &Beckmann::new(0.1, 0.4, 0.0));
        let b = NdfTable::from_ndf(grid, &Beckmann::new(0.1, 0.4, 6.0 * grid.dphi()));
        set.set(0, &a);
        set.set(1, &b);
        let core = Core::find(&set, &[0, 1], 32);
        let (mut da, mut db) = (vec![0.0; core.len()], vec![0.0; core.len()]);
        core.describe(&a, 6.0, &mut da);
        core.describe(&b, 0.0, &mut db);
        let diff: f32 = da.iter().zip(&db).map(|(x, y)| (x - y).abs()).sum();
        assert!(diff < 1e-4, "{diff}");
        let m = coarse_mask(grid, set.coverage_words(0));
        assert_eq!(m, [u16::MAX; COARSE_RINGS]);
        assert_eq!(coarse_overlap_gain(&m, &rotate_mask(&m, 7.0, 48)), (128, 0));
    }
}
