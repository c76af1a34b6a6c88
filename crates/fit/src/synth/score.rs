//! Scoring a candidate NDF against a query at every rotation at once.
//!
//! With the query `p` (values `Dp`, observed mask `Mp`) and a candidate `q`
//! rotated by `s` sectors (`Dq'(c) = Dq(c - s)` ring by ring), the match
//! is judged on the overlap of their observed regions, weighted by each
//! ring's cosine measure `w`:
//!
//! - `A(s) = sum w Mp Dp Mq' Dq'`, `B(s) = sum w Mp Dp^2 Mq'`,
//!   `C(s) = sum w Mp Mq' Dq'^2`: the normalised cross-correlation
//!   `rho = A / sqrt(B C)` is the cosine of the angle between the two NDFs
//!   on the overlap, and the **distance** is `sqrt(1 - rho^2)`: 0 for equal
//!   shapes at any scale (partial tables are normalised over different
//!   regions, so their scales legitimately differ), 1 for orthogonal ones.
//! - `N(s) = sum w Mp Mq'`: the **overlap**; a match needs at least
//!   `min_overlap` of the query's observed measure.
//! - `G(s) = sum w (1 - Mp) Mq'`: the **gain**, what the candidate would add
//!   where the query saw nothing; a match must add something.
//! - `A / C` is the least-squares scale that maps the candidate onto the
//!   query.
//!
//! Each is a circular cross-correlation along phi, ring by ring, summed over
//! rings: one product of half spectra per ring and one inverse real FFT per
//! quantity give all `n_phi` rotations, and zero-padding the summed spectrum
//! to `M` bins gives `M` rotation angles (trigonometric interpolation).

use std::sync::Arc;

use brdf::ndf::{NdfGrid, NdfTable};
use realfft::num_complex::Complex32;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};

use crate::tol::MIN_MISSING_MASS;

/// FFT plans for one grid and one number of rotation angles.
pub struct Plans {
    pub grid: NdfGrid,
    pub rotations: usize,
    nf: usize,
    mf: usize,
    r2c: Arc<dyn RealToComplex<f32>>,
    c2r: Arc<dyn ComplexToReal<f32>>,
}

impl std::fmt::Debug for Plans {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Plans").field("grid", &self.grid).field("rotations", &self.rotations).finish()
    }
}

impl Plans {
    /// `rotations` is at least `n_phi` (finer angles by zero-padding).
    pub fn new(grid: NdfGrid, rotations: usize) -> Self {
        let np = grid.n_phi as usize;
        let m = rotations.max(np);
        let mut planner = RealFftPlanner::<f32>::new();
        Self {
            grid,
            rotations: m,
            nf: np / 2 + 1,
            mf: m / 2 + 1,
            r2c: planner.plan_fft_forward(np),
            c2r: planner.plan_fft_inverse(m),
        }
    }

    fn spectra(&self, rows: &mut [f32], out: &mut [Complex32]) {
        let (nt, np, nf) = (self.grid.n_theta as usize, self.grid.n_phi as usize, self.nf);
        for t in 0..nt {
            let _ = self.r2c.process(&mut rows[t * np..(t + 1) * np], &mut out[t * nf..(t + 1) * nf]);
        }
    }
}

/// The query side: spectra of `w Mp Dp`, `w Mp Dp^2`, `w Mp`, `w (1 - Mp)`.
#[derive(Debug)]
pub struct QuerySpectra {
    s: [Vec<Complex32>; 4],
    /// `sum w Mp`: the query's observed measure.
    pub observed: f32,
    /// `sum w (1 - Mp)`: what it is missing.
    pub missing: f32,
}

/// The candidate side: spectra of `Mq Dq`, `Mq`, `Mq Dq^2`.
#[derive(Debug)]
pub struct CandidateSpectra {
    s: [Vec<Complex32>; 3],
}

fn mask_and_values(t: &NdfTable) -> (Vec<f32>, Vec<f32>) {
    let m: Vec<f32> = (0..t.grid().len()).map(|c| if t.coverage().get(c) { 1.0 } else { 0.0 }).collect();
    (m, t.values().to_vec())
}

impl QuerySpectra {
    pub fn new(plans: &Plans, t: &NdfTable) -> Self {
        let g = plans.grid;
        let (nt, np) = (g.n_theta as usize, g.n_phi as usize);
        let (m, d) = mask_and_values(t);
        let mut rows: [Vec<f32>; 4] = std::array::from_fn(|_| vec![0.0; nt * np]);
        let (mut observed, mut missing) = (0.0f32, 0.0f32);
        for tt in 0..nt {
            let w = g.cos_measure(tt);
            for p in 0..np {
                let c = tt * np + p;
                rows[0][c] = w * m[c] * d[c];
                rows[1][c] = w * m[c] * d[c] * d[c];
                rows[2][c] = w * m[c];
                rows[3][c] = w * (1.0 - m[c]);
                observed += w * m[c];
                missing += w * (1.0 - m[c]);
            }
        }
        let s = rows.map(|mut r| {
            let mut out = vec![Complex32::new(0.0, 0.0); nt * plans.nf];
            plans.spectra(&mut r, &mut out);
            out
        });
        Self { s, observed, missing }
    }
}

impl CandidateSpectra {
    pub fn new(plans: &Plans, t: &NdfTable) -> Self {
        let g = plans.grid;
        let (nt, np) = (g.n_theta as usize, g.n_phi as usize);
        let (m, d) = mask_and_values(t);
        let mut rows: [Vec<f32>; 3] = std::array::from_fn(|_| vec![0.0; nt * np]);
        for c in 0..nt * np {
            rows[0][c] = m[c] * d[c];
            rows[1][c] = m[c];
            rows[2][c] = m[c] * d[c] * d[c];
        }
        let s = rows.map(|mut r| {
            let mut out = vec![Complex32::new(0.0, 0.0); nt * plans.nf];
            plans.spectra(&mut r, &mut out);
            out
        });
        Self { s }
    }
}

/// The best rotation of one candidate for one query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Match {
    pub candidate: usize,
    /// Rotation in sectors (fractional when `rotations > n_phi`).
    pub shift: f32,
    pub distance: f32,
    /// Least-squares scale of the candidate onto the query.
    pub scale: f32,
    /// Fraction of the query's observed measure in the overlap.
    pub overlap: f32,
    /// Fraction of the query's missing measure the candidate covers.
    pub gain: f32,
}

/// Scratch buffers for [`best_rotation`].
#[derive(Debug, Default)]
pub struct ScoreScratch {
    acc: Vec<Vec<Complex32>>,
    out: Vec<Vec<f32>>,
    /// The inverse transform's own scratch (`process` would allocate it
    /// at every call).
    fft: Vec<Complex32>,
}

/// Score every rotation of candidate `c` against query `q`; return the
/// best admissible one (enough overlap, some gain), if any.
pub fn best_rotation(
    plans: &Plans,
    q: &QuerySpectra,
    c: &CandidateSpectra,
    index: usize,
    min_overlap: f32,
    scratch: &mut ScoreScratch,
) -> Option<Match> {
    let (nt, nf, mf, m) = (plans.grid.n_theta as usize, plans.nf, plans.mf, plans.rotations);
    if scratch.acc.len() != 5 || scratch.acc[0].len() != mf {
        scratch.acc = (0..5).map(|_| vec![Complex32::new(0.0, 0.0); mf]).collect();
        scratch.out = (0..5).map(|_| vec![0.0; m]).collect();
        scratch.fft = vec![Complex32::new(0.0, 0.0); plans.c2r.get_scratch_len()];
    }
    // (query spectrum, candidate spectrum) of A, B, C, N, G.
    let pairs = [(0, 0), (1, 1), (2, 2), (2, 1), (3, 1)];
    for (k, &(a, b)) in pairs.iter().enumerate() {
        let acc = &mut scratch.acc[k];
        acc.iter_mut().for_each(|v| *v = Complex32::new(0.0, 0.0));
        for t in 0..nt {
            let qa = &q.s[a][t * nf..(t + 1) * nf];
            let cb = &c.s[b][t * nf..(t + 1) * nf];
            for f in 0..nf {
                acc[f] += qa[f] * cb[f].conj();
            }
        }
        acc[0].im = 0.0;
        if m % 2 == 0 {
            acc[mf - 1].im = 0.0;
        }
        let _ = plans.c2r.process_with_scratch(acc, &mut scratch.out[k], &mut scratch.fft);
    }
    // The inverse FFT of n_phi bins zero-padded to m is scaled by 1/n_phi.
    let norm = 1.0 / plans.grid.n_phi as f32;
    let mut best: Option<Match> = None;
    for s in 0..m {
        let get = |k: usize| scratch.out[k][s] * norm;
        let (a, b, cc, n, g) = (get(0), get(1), get(2), get(3), get(4));
        if q.observed <= 0.0
            || n < min_overlap * q.observed
            || g <= 0.01 * q.missing.max(MIN_MISSING_MASS as f32)
            || b <= 0.0
            || cc <= 0.0
        {
            continue;
        }
        let rho2 = (a * a / (b * cc)).clamp(0.0, 1.0);
        let distance = (1.0 - rho2).sqrt();
        if best.is_none_or(|x| distance < x.distance) {
            best = Some(Match {
                candidate: index,
                shift: s as f32 * plans.grid.n_phi as f32 / m as f32,
                distance,
                scale: (a / cc).clamp(0.1, 10.0),
                overlap: n / q.observed,
                gain: g / q.missing.max(MIN_MISSING_MASS as f32),
            });
        }
    }
    best
}

/// A table as flat arrays for [`score_at`]: values and a 0/1 mask. A
/// candidate's ([`Flat::new`]) hold each ring twice over (`[ring |
/// ring]`), so that the ring turned by any whole number of sectors is one
/// contiguous slice of it; a query's ([`Flat::query`]) once.
#[derive(Clone, Debug, PartialEq)]
pub struct Flat {
    values: Vec<f32>,
    mask: Vec<f32>,
    n_phi: usize,
    /// Copies of each ring (2 for a candidate, 1 for a query).
    copies: usize,
    /// Per ring: the observed cells.
    ring_observed: Vec<f32>,
}

impl Flat {
    /// A candidate's.
    pub fn new(t: &NdfTable) -> Self {
        Self::build(t.grid(), t.values(), t.coverage().words(), 2)
    }

    /// Table `p` of `set` as a query.
    pub fn query(set: &brdf::ndf::TableSet, p: usize) -> Self {
        let mut values = vec![0.0f32; set.grid().len()];
        set.values_into(p, &mut values);
        Self::build(set.grid(), &values, set.coverage_words(p), 1)
    }

    fn build(g: NdfGrid, table: &[f32], words: &[u64], copies: usize) -> Self {
        let np = g.n_phi as usize;
        let (mut values, mut mask) = (Vec::with_capacity(copies * g.len()), Vec::with_capacity(copies * g.len()));
        let mut ring_observed = Vec::with_capacity(g.n_theta as usize);
        for (ring, row) in table.chunks_exact(np).enumerate() {
            let observed = |p: usize| brdf::ndf::bit(words, ring * np + p);
            let m: Vec<f32> = (0..np).map(|p| if observed(p) { 1.0 } else { 0.0 }).collect();
            ring_observed.push(m.iter().sum());
            for _ in 0..copies {
                values.extend_from_slice(row);
                mask.extend_from_slice(&m);
            }
        }
        Self { values, mask, n_phi: np, copies, ring_observed }
    }

    /// Ring `t` as stored (its first copy).
    fn ring(&self, t: usize) -> (&[f32], &[f32]) {
        let at = self.copies * t * self.n_phi;
        (&self.values[at..at + self.n_phi], &self.mask[at..at + self.n_phi])
    }

    /// Ring `t` turned by `s0` whole sectors (`s0 < n_phi`): sector `p` of
    /// the slices is the ring's sector `p - s0`. A candidate's only.
    fn turned(&self, t: usize, s0: usize) -> (&[f32], &[f32]) {
        assert_eq!(self.copies, 2, "a query's table is not turned");
        let at = 2 * t * self.n_phi + self.n_phi - s0;
        (&self.values[at..at + self.n_phi], &self.mask[at..at + self.n_phi])
    }
}

/// Lanes of [`score_at`]'s sums: each ring is summed in this many partial
/// sums, sector `p` into lane `p % LANES`. Written a whole set of lanes at
/// a time, with the blend fixed per call, they compile to vector
/// arithmetic (eight to a register where the processor has AVX); each
/// lane's sum is the same sequence of scalar operations it would be one
/// cell at a time.
const LANES: usize = 8;

/// One ring's operands of [`score_at`]'s sums: the query's values and
/// observed mask (`q`), the candidate turned by the whole sectors of the
/// shift (`a0`) and by one more (`a1`), and the blend `f` between them.
#[derive(Clone, Copy, Debug)]
struct Ring<'a> {
    q: (&'a [f32], &'a [f32]),
    a0: (&'a [f32], &'a [f32]),
    a1: (&'a [f32], &'a [f32]),
    f: f32,
}

/// One ring's sums over the overlap (see the module's notes): `A`, `B`,
/// `C`, `N` and `G` before the ring's weight. A blended cell counts as
/// observed only if both its sources were (`BLEND`; without it `f` is 0 and
/// `a1` is not read).
fn ring_sums<const BLEND: bool>(r: &Ring) -> [f32; 5] {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx") {
        // SAFETY: the processor has AVX, checked just above.
        return unsafe { ring_sums_avx::<BLEND>(r) };
    }
    ring_sums_lanes::<BLEND>(r)
}

/// [`ring_sums_lanes`] compiled for AVX: eight lanes to a register, and no
/// fused multiply-add, so the same sums to the last bit.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
fn ring_sums_avx<const BLEND: bool>(r: &Ring) -> [f32; 5] {
    ring_sums_lanes::<BLEND>(r)
}

#[inline(always)]
fn ring_sums_lanes<const BLEND: bool>(r: &Ring) -> [f32; 5] {
    let (Ring { q: (qv, qm), a0, a1, f }, n) = (*r, r.q.0.len());
    type V = [f32; LANES];
    #[inline(always)]
    fn at(x: &[f32], k: usize) -> V {
        x[k..k + LANES].try_into().expect("LANES values")
    }
    #[inline(always)]
    fn zip(a: V, b: V, op: impl Fn(f32, f32) -> f32) -> V {
        std::array::from_fn(|l| op(a[l], b[l]))
    }
    #[inline(always)]
    fn cell<const BLEND: bool>(acc: &mut [V; 5], (dp, mp): (V, V), (v0, m0): (V, V), (v1, m1): (V, V), f: f32) {
        let mq = if BLEND { zip(m0, m1, |a, b| a * b) } else { m0 };
        let dq = if BLEND { zip(v0, v1, |a, b| a * (1.0 - f) + b * f) } else { v0 };
        let m = zip(mp, mq, |a, b| a * b);
        let x = zip(m, dp, |a, b| a * b);
        acc[0] = zip(acc[0], zip(x, dq, |a, b| a * b), |a, b| a + b);
        acc[1] = zip(acc[1], zip(x, dp, |a, b| a * b), |a, b| a + b);
        acc[2] = zip(acc[2], zip(zip(m, dq, |a, b| a * b), dq, |a, b| a * b), |a, b| a + b);
        acc[3] = zip(acc[3], m, |a, b| a + b);
        acc[4] = zip(acc[4], zip(mp, mq, |a, b| (1.0 - a) * b), |a, b| a + b);
    }
    let mut acc = [[0.0f32; LANES]; 5];
    let whole = n - n % LANES;
    for k in (0..whole).step_by(LANES) {
        cell::<BLEND>(&mut acc, (at(qv, k), at(qm, k)), (at(a0.0, k), at(a0.1, k)), (at(a1.0, k), at(a1.1, k)), f);
    }
    // A ring not a multiple of LANES long: the rest one cell at a time,
    // into lane 0.
    for i in whole..n {
        let one = |x: &[f32]| std::array::from_fn(|l| if l == 0 { x[i] } else { 0.0 });
        let mut part = [[0.0f32; LANES]; 5];
        cell::<BLEND>(&mut part, (one(qv), one(qm)), (one(a0.0), one(a0.1)), (one(a1.0), one(a1.1)), f);
        for (a, p) in acc.iter_mut().zip(&part) {
            a[0] += p[0];
        }
    }
    acc.map(|lanes| lanes.iter().sum())
}

/// The same quantities at one given rotation, by direct summation over the
/// cells (for re-ranking a handful of candidates found by nearest
/// neighbours). A fractional shift blends the two neighbouring sectors; a
/// rotated cell counts as observed only if both sources were. A ring the
/// candidate did not observe adds nothing but the query's own measure, so
/// it is skipped.
/// `measures` holds the grid's [`NdfGrid::cos_measures`], one per ring.
pub fn score_at(
    measures: &[f32],
    query: &Flat,
    candidate: &Flat,
    shift: f32,
    index: usize,
    min_overlap: f32,
) -> Option<Match> {
    let np = query.n_phi;
    let (s0, f) = brdf::ndf::split_shift(shift, np);
    let s1 = if s0 + 1 == np { 0 } else { s0 + 1 };
    let (mut a, mut b, mut c, mut n, mut gain, mut observed, mut missing) = (0.0f64, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for (t, &w) in measures.iter().enumerate() {
        let w = w as f64;
        let ro = query.ring_observed[t];
        observed += w * ro as f64;
        missing += w * (np as f32 - ro) as f64;
        if candidate.ring_observed[t] == 0.0 {
            continue;
        }
        let r = Ring { q: query.ring(t), a0: candidate.turned(t, s0), a1: candidate.turned(t, s1), f };
        let [ra, rb, rc, rn, rg] = if f != 0.0 { ring_sums::<true>(&r) } else { ring_sums::<false>(&r) };
        a += w * ra as f64;
        b += w * rb as f64;
        c += w * rc as f64;
        n += w * rn as f64;
        gain += w * rg as f64;
    }
    if observed <= 0.0
        || n < min_overlap as f64 * observed
        || gain <= 0.01 * missing.max(MIN_MISSING_MASS)
        || b <= 0.0
        || c <= 0.0
    {
        return None;
    }
    let rho2 = (a * a / (b * c)).clamp(0.0, 1.0);
    Some(Match {
        candidate: index,
        shift,
        distance: (1.0 - rho2).sqrt() as f32,
        scale: (a / c).clamp(0.1, 10.0) as f32,
        overlap: (n / observed) as f32,
        gain: (gain / missing.max(MIN_MISSING_MASS)) as f32,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use brdf::ndf::{Beckmann, Coverage};

    fn partial(angle: f32, grid: NdfGrid) -> NdfTable {
        let mut t = NdfTable::from_ndf(grid, &Beckmann::new(0.1, 0.35, angle));
        let mut cov = Coverage::empty(grid.len());
        // Observed: a wedge of half the sectors, all rings up to 60 percent.
        for tt in 0..(grid.n_theta as usize * 6 / 10) {
            for p in 0..grid.n_phi as usize / 2 {
                cov.set(grid.index(tt, p), true);
            }
        }
        for c in 0..grid.len() {
            if !cov.get(c) {
                t.values_mut()[c] = 0.0;
            }
        }
        *t.coverage_mut() = cov;
        t
    }

    #[test]
    fn fft_scores_agree_with_direct_sums_and_find_the_true_rotation() {
        let grid = NdfGrid::new(16, 48).unwrap();
        let plans = Plans::new(grid, 48);
        let q = partial(0.0, grid);
        // The candidate's material is turned by -5 sectors; the camera saw
        // the same wedge of the hemisphere at both points.
        let c = partial(-5.0 * grid.dphi(), grid);
        let qs = QuerySpectra::new(&plans, &q);
        let cs = CandidateSpectra::new(&plans, &c);
        let best = best_rotation(&plans, &qs, &cs, 7, 0.3, &mut ScoreScratch::default()).unwrap();
        assert!((best.shift - 5.0).abs() < 1e-3, "{best:?}");
        assert!(best.distance < 1e-3, "{best:?}");
        let direct = score_at(&grid.cos_measures(), &Flat::new(&q), &Flat::new(&c), best.shift, 7, 0.3).unwrap();
        assert!((direct.distance - best.distance).abs() < 1e-3);
        assert!((direct.overlap - best.overlap).abs() < 1e-3 && (direct.gain - best.gain).abs() < 1e-3);
        assert!((direct.scale - best.scale).abs() < 1e-3 * direct.scale);
    }

    #[test]
    fn direct_sums_at_a_fractional_shift_are_those_of_the_turned_table() {
        let grid = NdfGrid::new(16, 48).unwrap();
        let q = partial(0.0, grid);
        let mut set = brdf::ndf::TableSet::new(grid, 2);
        set.set(1, &q);
        let c = partial(-5.0 * grid.dphi(), grid);
        // Across the ring's seam too: 47.5 sectors blends sectors 47 and 0
        // (a candidate whose observed wedge lies ten sectors back, so that
        // turned by about a whole ring it still adds to the query's).
        let seam = c.rotated(-10.0 * grid.dphi());
        for (c, shift) in [(&c, 5.25f32), (&c, 5.5), (&c, 3.0), (&seam, 44.5), (&seam, 47.5)] {
            let turned = score_at(
                &grid.cos_measures(),
                &Flat::new(&q),
                &Flat::new(&c.rotated(shift * grid.dphi())),
                0.0,
                3,
                0.3,
            );
            let direct = score_at(&grid.cos_measures(), &Flat::new(&q), &Flat::new(c), shift, 3, 0.3);
            let (Some(t), Some(d)) = (turned, direct) else {
                panic!("shift {shift}: {turned:?} against {direct:?}");
            };
            assert!((t.distance - d.distance).abs() < 1e-4, "shift {shift}: {t:?} against {d:?}");
            assert!((t.overlap - d.overlap).abs() < 1e-5 && (t.gain - d.gain).abs() < 1e-5, "shift {shift}");
            assert!((t.scale - d.scale).abs() < 1e-4 * d.scale, "shift {shift}");
            // The query read from a table set (half-precision values) scores
            // the same to the set's precision.
            let from_set = score_at(&grid.cos_measures(), &Flat::query(&set, 1), &Flat::new(c), shift, 3, 0.3).unwrap();
            assert!((from_set.distance - d.distance).abs() < 2e-3, "shift {shift}: {from_set:?}");
            assert_eq!((from_set.overlap, from_set.gain), (d.overlap, d.gain), "shift {shift}");
        }
    }

    /// The sums of the module's notes written one cell at a time, sector
    /// `p` into partial sum `p % LANES`, to hold [`ring_sums`] to.
    fn ring_sums_by_cell(r: &Ring, blend: bool) -> [f32; 5] {
        let Ring { q: (qv, qm), a0, a1, f } = *r;
        let mut acc = [[0.0f32; LANES]; 5];
        for i in 0..qv.len() {
            let l = if i < qv.len() - qv.len() % LANES { i % LANES } else { 0 };
            let mq = if blend { a0.1[i] * a1.1[i] } else { a0.1[i] };
            let dq = a0.0[i] * (1.0 - f) + a1.0[i] * f;
            let m = qm[i] * mq;
            let x = m * qv[i];
            acc[0][l] += x * dq;
            acc[1][l] += x * qv[i];
            acc[2][l] += m * dq * dq;
            acc[3][l] += m;
            acc[4][l] += (1.0 - qm[i]) * mq;
        }
        acc.map(|lanes| lanes.iter().sum())
    }

    #[test]
    fn ring_sums_are_the_cell_by_cell_sums_to_the_last_bit() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        // 96 sectors (the default grid's) and a ring with a remainder.
        for n in [96usize, 50] {
            for _ in 0..200 {
                let mut ring = |p: f64| -> (Vec<f32>, Vec<f32>) {
                    let m: Vec<f32> = (0..n).map(|_| if rng.random_bool(p) { 1.0 } else { 0.0 }).collect();
                    let v = m.iter().map(|&m| m * rng.random_range(0.0f32..40.0)).collect();
                    (v, m)
                };
                let (q, c0, c1) = (ring(0.6), ring(0.7), ring(0.7));
                let f = rng.random_range(0.0f32..1.0);
                let r = Ring { q: (&q.0, &q.1), a0: (&c0.0, &c0.1), a1: (&c1.0, &c1.1), f };
                let blended = ring_sums::<true>(&r);
                assert_eq!(blended.map(f32::to_bits), ring_sums_by_cell(&r, true).map(f32::to_bits));
                let r = Ring { f: 0.0, ..r };
                let whole = ring_sums::<false>(&r);
                assert_eq!(whole.map(f32::to_bits), ring_sums_by_cell(&r, false).map(f32::to_bits));
                // The portable lanes, as on a processor without AVX.
                let r = Ring { f, ..r };
                let portable = ring_sums_lanes::<true>(&r);
                assert_eq!(portable.map(f32::to_bits), blended.map(f32::to_bits));
            }
        }
    }
}
