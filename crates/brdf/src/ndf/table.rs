//! The hemisphere table that holds tabulated NDFs.
//!
//! Cells are rings of constant polar angle split into `n_phi` equal azimuth
//! sectors, so a rotation about the normal by a multiple of `2 pi / n_phi` is
//! a cyclic shift of every ring (synthesis relies on this). Ring edges are
//! warped, `theta_k = (k / n_theta)^2 * pi / 2`, like the RGL tables
//! (Dupuy and Jakob 2018): rings are narrow near the normal, where sharp lobes
//! live, and wide near the horizon, where microfacet normals are rare.
//! The default 32 x 96 = 3,072 cells is the talk's table size.
//!
//! Cell values are cosine-weighted cell averages of `D`, so
//! `sum(D_c * cos_measure_c) = integral of D cos dw` exactly for a table made
//! from an analytic NDF, and the normalisation `integral D cos dw = 1` is a
//! finite sum. Between cell centres the table interpolates bilinearly in
//! `(sqrt(2 theta / pi), phi)`.

use std::f32::consts::{FRAC_PI_2, TAU};

use glam::Vec3;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::frame;

/// `i` modulo `n` in `0..n`; the division only for an `i` outside
/// `0..n` (this sits in the masking term's, the tables' and the kernels' inner
/// loops).
#[inline]
pub fn wrap(i: i64, n: usize) -> usize {
    if (0..n as i64).contains(&i) { i as usize } else { i.rem_euclid(n as i64) as usize }
}

/// A rotation by `shift` sectors as the whole sectors it turns by, in
/// `0..n_phi`, and the fraction toward the next (what
/// [`rotation_sources`] and the blend of its two sources take).
pub fn split_shift(shift: f32, n_phi: usize) -> (usize, f32) {
    let s0 = frame::floor(shift);
    (wrap(s0 as i64, n_phi), shift - s0)
}

/// The source sectors of each destination sector `p` in `0..n_phi` of a
/// ring turned by `s0` whole sectors (`s0 < n_phi`) and a fraction toward
/// the next: `(p - s0, p - s0 - 1)` modulo `n_phi`, in order of `p`. They
/// step around the ring, with no division per sector (the rotations of
/// synthesis' search and scoring run over every cell of many tables).
pub fn rotation_sources(n_phi: usize, s0: usize) -> impl Iterator<Item = (usize, usize)> {
    let step = move |i: usize| if i + 1 == n_phi { 0 } else { i + 1 };
    let (mut a, mut b) = ((n_phi - s0) % n_phi, (2 * n_phi - s0 - 1) % n_phi);
    (0..n_phi).map(move |_| {
        let out = (a, b);
        (a, b) = (step(a), step(b));
        out
    })
}

/// Errors from building or reading a table.
#[derive(Debug, Error, PartialEq)]
pub enum TableError {
    #[error("table grid {n_theta} x {n_phi} is not usable: need 2..=512 rings and 4..=4096 sectors")]
    BadGrid { n_theta: u32, n_phi: u32 },
    #[error("table holds {got} values but its {n_theta} x {n_phi} grid needs {want}")]
    WrongLength { n_theta: u32, n_phi: u32, got: usize, want: usize },
    #[error("table value at cell {index} is {value}, but NDF values must be finite and non-negative")]
    BadValue { index: usize, value: f32 },
}

/// Where a direction falls between four cell centres (see
/// [`NdfGrid::bilinear`]): rings `t`, sectors `p`, and the fractions toward
/// the second of each.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bilinear {
    pub t: [usize; 2],
    pub ft: f32,
    pub p: [usize; 2],
    pub fp: f32,
}

impl Bilinear {
    /// The four cells (ring-major indices on an `n_phi`-sector grid) and
    /// their weights, which sum to 1.
    pub fn weights(&self, n_phi: usize) -> [(usize, f32); 4] {
        let (ft, fp) = (self.ft, self.fp);
        [
            (self.t[0] * n_phi + self.p[0], (1.0 - ft) * (1.0 - fp)),
            (self.t[0] * n_phi + self.p[1], (1.0 - ft) * fp),
            (self.t[1] * n_phi + self.p[0], ft * (1.0 - fp)),
            (self.t[1] * n_phi + self.p[1], ft * fp),
        ]
    }
}

/// Geometry of a hemisphere table: `n_theta` warped rings by `n_phi` sectors.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct NdfGrid {
    pub n_theta: u32,
    pub n_phi: u32,
}

impl Default for NdfGrid {
    fn default() -> Self {
        Self::DEFAULT
    }
}

impl NdfGrid {
    /// The talk's 3,072-cell table.
    pub const DEFAULT: NdfGrid = NdfGrid { n_theta: 32, n_phi: 96 };

    pub fn new(n_theta: u32, n_phi: u32) -> Result<Self, TableError> {
        if !(2..=512).contains(&n_theta) || !(4..=4096).contains(&n_phi) {
            return Err(TableError::BadGrid { n_theta, n_phi });
        }
        Ok(Self { n_theta, n_phi })
    }

    /// Number of cells.
    pub fn len(&self) -> usize {
        (self.n_theta * self.n_phi) as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    #[inline]
    pub fn index(&self, t: usize, p: usize) -> usize {
        t * self.n_phi as usize + p
    }

    /// Azimuth width of a sector.
    #[inline]
    pub fn dphi(&self) -> f32 {
        TAU / self.n_phi as f32
    }

    /// Polar angle of ring edge `k` in `0..=n_theta`.
    #[inline]
    pub fn theta_edge(&self, k: usize) -> f32 {
        let u = k as f32 / self.n_theta as f32;
        u * u * FRAC_PI_2
    }

    /// Polar angle of the centre of ring `t` (centre in the warped coordinate).
    #[inline]
    pub fn theta_center(&self, t: usize) -> f32 {
        let u = (t as f32 + 0.5) / self.n_theta as f32;
        u * u * FRAC_PI_2
    }

    /// Azimuth of the centre of sector `p`.
    #[inline]
    pub fn phi_center(&self, p: usize) -> f32 {
        (p as f32 + 0.5) * self.dphi()
    }

    /// Unit direction through the centre of cell `(t, p)`.
    pub fn direction(&self, t: usize, p: usize) -> Vec3 {
        frame::spherical(self.theta_center(t), self.phi_center(p))
    }

    /// `integral of cos(theta) dw` over one cell of ring `t`.
    pub fn cos_measure(&self, t: usize) -> f32 {
        let (s0, s1) = (self.theta_edge(t).sin(), self.theta_edge(t + 1).sin());
        0.5 * self.dphi() * (s1 * s1 - s0 * s0)
    }

    /// [`NdfGrid::cos_measure`] of every ring, for loops that would
    /// otherwise find it (two sines) once per cell or per call.
    pub fn cos_measures(&self) -> Vec<f32> {
        (0..self.n_theta as usize).map(|t| self.cos_measure(t)).collect()
    }

    /// Solid angle of one cell of ring `t`.
    pub fn solid_angle(&self, t: usize) -> f32 {
        self.dphi() * (self.theta_edge(t).cos() - self.theta_edge(t + 1).cos())
    }

    /// Continuous table coordinates of a direction: `(ring, sector)` measured
    /// in cells, so cell `(t, p)` spans `[t, t+1) x [p, p+1)`.
    pub fn coords(&self, h: Vec3) -> (f32, f32) {
        self.coords_at(frame::polar(h), frame::phi(h))
    }

    /// [`NdfGrid::coords`] of the direction at polar angle `theta` and
    /// azimuth `phi` (`frame::polar` and `frame::phi` of it), for a caller
    /// that has them already.
    pub fn coords_at(&self, theta: f32, phi: f32) -> (f32, f32) {
        let theta = theta.clamp(0.0, FRAC_PI_2);
        let u = (theta / FRAC_PI_2).sqrt() * self.n_theta as f32;
        let p = phi / self.dphi();
        (u, p)
    }

    /// The four cell centres around a direction and its fractions between
    /// them: [`NdfTable::eval`]'s interpolation, bilinear in
    /// `(sqrt(2 theta / pi), phi)`, periodic in phi and clamped in theta.
    pub fn bilinear(&self, h: Vec3) -> Bilinear {
        self.bilinear_at(frame::polar(h), frame::phi(h))
    }

    /// [`NdfGrid::bilinear`] from the direction's polar angle and azimuth.
    pub fn bilinear_at(&self, theta: f32, phi: f32) -> Bilinear {
        let (t, ft) = self.rings_at(theta);
        let (p, fp) = self.sectors_at(phi);
        Bilinear { t, ft, p, fp }
    }

    /// The polar half of [`NdfGrid::bilinear_at`]: the two rings whose
    /// centres bracket `theta` and the fraction toward the second (for a
    /// caller that reads one direction at many azimuths).
    #[inline]
    pub fn rings_at(&self, theta: f32) -> ([usize; 2], f32) {
        let (u, _) = self.coords_at(theta, 0.0);
        let nt = self.n_theta as usize;
        let tu = (u - 0.5).clamp(0.0, (nt - 1) as f32);
        let t0 = (tu as usize).min(nt - 1);
        ([t0, (t0 + 1).min(nt - 1)], tu - t0 as f32)
    }

    /// The azimuthal half of [`NdfGrid::bilinear_at`]: the two sectors
    /// whose centres bracket `phi` and the fraction toward the second.
    #[inline]
    pub fn sectors_at(&self, phi: f32) -> ([usize; 2], f32) {
        let np = self.n_phi as usize;
        let pp = phi / self.dphi() - 0.5;
        let pf = frame::floor(pp);
        let p0 = wrap(pf as i64, np);
        let p1 = if p0 + 1 == np { 0 } else { p0 + 1 };
        ([p0, p1], pp - pf)
    }

    /// The cell holding a direction at or above the horizon.
    pub fn cell(&self, h: Vec3) -> Option<(usize, usize)> {
        if h.z < 0.0 {
            return None;
        }
        Some(self.cell_at(frame::polar(h), frame::phi(h)))
    }

    /// [`NdfGrid::cell`] of a direction at or above the horizon, from its
    /// polar angle and azimuth.
    pub fn cell_at(&self, theta: f32, phi: f32) -> (usize, usize) {
        let (u, p) = self.coords_at(theta, phi);
        let t = (u as usize).min(self.n_theta as usize - 1);
        let p = (p as usize) % self.n_phi as usize;
        (t, p)
    }
}

/// Bit `i` of a coverage bitmap stored as words ([`Coverage::words`],
/// [`super::TableSet::coverage_words`]): whether cell `i` is observed.
#[inline]
pub fn bit(words: &[u64], i: usize) -> bool {
    (words[i / 64] >> (i % 64)) & 1 == 1
}

/// One bit per cell: which cells of a table were observed.
#[derive(Clone, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Coverage {
    len: usize,
    bits: Vec<u64>,
}

impl Coverage {
    pub fn empty(len: usize) -> Self {
        Self { len, bits: vec![0; len.div_ceil(64)] }
    }

    /// The coverage of `len` cells whose bits are `words` (cell `i` is bit
    /// `i % 64` of word `i / 64`; bits past `len` are ignored). `words`
    /// must hold at least `len` bits.
    pub fn from_words(len: usize, words: &[u64]) -> Self {
        let mut bits = words[..len.div_ceil(64)].to_vec();
        if len % 64 != 0
            && let Some(last) = bits.last_mut()
        {
            *last &= (1u64 << (len % 64)) - 1;
        }
        Self { len, bits }
    }

    pub fn full(len: usize) -> Self {
        let mut c = Self::empty(len);
        for i in 0..len {
            c.set(i, true);
        }
        c
    }

    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    #[inline]
    pub fn get(&self, i: usize) -> bool {
        bit(&self.bits, i)
    }

    #[inline]
    pub fn set(&mut self, i: usize, on: bool) {
        let (w, b) = (i / 64, i % 64);
        if on {
            self.bits[w] |= 1 << b;
        } else {
            self.bits[w] &= !(1 << b);
        }
    }

    /// Number of covered cells.
    pub fn count(&self) -> usize {
        self.bits.iter().map(|w| w.count_ones() as usize).sum()
    }

    /// Number of cells covered in both.
    pub fn and_count(&self, other: &Coverage) -> usize {
        self.bits.iter().zip(&other.bits).map(|(a, b)| (a & b).count_ones() as usize).sum()
    }

    /// Number of cells covered in `other` but not in `self`.
    pub fn gain_count(&self, other: &Coverage) -> usize {
        self.bits.iter().zip(&other.bits).map(|(a, b)| (!a & b).count_ones() as usize).sum()
    }

    pub fn union_with(&mut self, other: &Coverage) {
        for (a, b) in self.bits.iter_mut().zip(&other.bits) {
            *a |= b;
        }
    }

    pub fn intersect_with(&mut self, other: &Coverage) {
        for (a, b) in self.bits.iter_mut().zip(&other.bits) {
            *a &= b;
        }
    }

    /// Iterator over the indices of covered cells.
    pub fn iter_set(&self) -> impl Iterator<Item = usize> + '_ {
        (0..self.len).filter(move |&i| self.get(i))
    }

    /// Raw words (for serialisation).
    pub fn words(&self) -> &[u64] {
        &self.bits
    }
}

/// A tabulated NDF: one value per cell plus the cells that were observed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct NdfTable {
    grid: NdfGrid,
    values: Vec<f32>,
    coverage: Coverage,
}

impl NdfTable {
    /// An all-zero table with nothing observed.
    pub fn zeros(grid: NdfGrid) -> Self {
        Self { grid, values: vec![0.0; grid.len()], coverage: Coverage::empty(grid.len()) }
    }

    /// A table from values, checking length and that every value is finite
    /// and non-negative.
    pub fn from_values(grid: NdfGrid, values: Vec<f32>, coverage: Coverage) -> Result<Self, TableError> {
        if values.len() != grid.len() || coverage.len() != grid.len() {
            return Err(TableError::WrongLength {
                n_theta: grid.n_theta,
                n_phi: grid.n_phi,
                got: values.len().min(coverage.len()),
                want: grid.len(),
            });
        }
        if let Some((index, &value)) = values.iter().enumerate().find(|(_, v)| !v.is_finite() || **v < 0.0) {
            return Err(TableError::BadValue { index, value });
        }
        Ok(Self { grid, values, coverage })
    }

    /// Cosine-weighted cell averages of `f`, with `sub x sub` stratified
    /// samples per cell placed uniformly in `(sin^2 theta, phi)` (uniform in
    /// the cosine measure), and every cell marked observed.
    pub fn from_fn(grid: NdfGrid, sub: usize, f: impl Fn(Vec3) -> f32) -> Self {
        let sub = sub.max(1);
        let mut values = vec![0.0; grid.len()];
        for t in 0..grid.n_theta as usize {
            let (s0, s1) = (grid.theta_edge(t).sin().powi(2), grid.theta_edge(t + 1).sin().powi(2));
            for p in 0..grid.n_phi as usize {
                let mut acc = 0.0f64;
                for a in 0..sub {
                    let s2 = s0 + (s1 - s0) * (a as f32 + 0.5) / sub as f32;
                    let (st, ct) = (s2.sqrt(), (1.0 - s2).max(0.0).sqrt());
                    for b in 0..sub {
                        let ph = (p as f32 + (b as f32 + 0.5) / sub as f32) * grid.dphi();
                        let h = Vec3::new(st * ph.cos(), st * ph.sin(), ct);
                        let v = f(h);
                        if v.is_finite() && v > 0.0 {
                            acc += v as f64;
                        }
                    }
                }
                values[grid.index(t, p)] = (acc / (sub * sub) as f64) as f32;
            }
        }
        Self { grid, values, coverage: Coverage::full(grid.len()) }
    }

    /// Resample any NDF into a table (cell averages, fully observed).
    pub fn from_ndf(grid: NdfGrid, ndf: &impl super::Ndf) -> Self {
        Self::from_fn(grid, 6, |h| ndf.d(h))
    }

    pub fn grid(&self) -> NdfGrid {
        self.grid
    }

    pub fn values(&self) -> &[f32] {
        &self.values
    }

    pub fn values_mut(&mut self) -> &mut [f32] {
        &mut self.values
    }

    pub fn coverage(&self) -> &Coverage {
        &self.coverage
    }

    pub fn coverage_mut(&mut self) -> &mut Coverage {
        &mut self.coverage
    }

    pub fn into_parts(self) -> (NdfGrid, Vec<f32>, Coverage) {
        (self.grid, self.values, self.coverage)
    }

    #[inline]
    pub fn at(&self, t: usize, p: usize) -> f32 {
        self.values[self.grid.index(t, p)]
    }

    /// `integral of D cos dw` by the table's own quadrature.
    pub fn integral_cos(&self) -> f32 {
        let n_phi = self.grid.n_phi as usize;
        let mut acc = 0.0f64;
        for t in 0..self.grid.n_theta as usize {
            let ring: f64 = self.values[t * n_phi..(t + 1) * n_phi].iter().map(|&v| v as f64).sum();
            acc += ring * self.grid.cos_measure(t) as f64;
        }
        acc as f32
    }

    /// How concentrated the table's mass is: the half-angle (radians) of
    /// the cone whose solid angle equals that of the smallest set of cells
    /// holding half of `integral D cos dw` (the densest cells first), and
    /// the densest cell's direction. The width does not assume the lobe's
    /// shape, centre or symmetry; it is no finer than the cells the mass
    /// sits in. `None` for a table without mass.
    pub fn half_mass_cone(&self) -> Option<(f32, Vec3)> {
        let g = self.grid;
        let np = g.n_phi as usize;
        let mass: Vec<f64> =
            self.values.iter().enumerate().map(|(k, &v)| v.max(0.0) as f64 * g.cos_measure(k / np) as f64).collect();
        let total: f64 = mass.iter().sum();
        if !(total > 0.0) || !total.is_finite() {
            return None;
        }
        let mut order: Vec<usize> = (0..self.values.len()).collect();
        order.sort_by(|&a, &b| self.values[b].total_cmp(&self.values[a]));
        let (mut held, mut omega) = (0.0f64, 0.0f64);
        for &k in &order {
            if held >= 0.5 * total {
                break;
            }
            held += mass[k];
            omega += g.solid_angle(k / np) as f64;
        }
        let angle = (1.0 - omega / std::f64::consts::TAU).clamp(-1.0, 1.0).acos() as f32;
        Some((angle, g.direction(order[0] / np, order[0] % np)))
    }

    /// Scale so that `integral D cos dw = 1`; returns the integral before
    /// scaling (the fitter's `k_s`). A table whose integral is below
    /// [`MIN_NORMALISABLE`] is left unchanged and 0 is returned.
    pub fn normalize(&mut self) -> f32 {
        let k = self.integral_cos();
        if !(k > MIN_NORMALISABLE) || !k.is_finite() {
            return 0.0;
        }
        let inv = 1.0 / k;
        self.values.iter_mut().for_each(|v| *v *= inv);
        k
    }

    /// Bilinear interpolation in `(sqrt(2 theta / pi), phi)` between cell
    /// centres, periodic in phi and clamped in theta. 0 below the horizon.
    pub fn eval(&self, h: Vec3) -> f32 {
        if h.z < 0.0 {
            return 0.0;
        }
        self.eval_at(self.grid.bilinear(h))
    }

    /// [`NdfTable::eval`] of a direction at or above the horizon whose
    /// interpolation (`NdfGrid::bilinear`) the caller has.
    pub fn eval_at(&self, b: Bilinear) -> f32 {
        let Bilinear { t, ft, p, fp } = b;
        let np = self.grid.n_phi as usize;
        let v = |t: usize, p: usize| self.values[t * np + p];
        let a = v(t[0], p[0]) * (1.0 - fp) + v(t[0], p[1]) * fp;
        let b = v(t[1], p[0]) * (1.0 - fp) + v(t[1], p[1]) * fp;
        a * (1.0 - ft) + b * ft
    }

    /// The table rotated about the normal by `angle_rad`:
    /// `rotated(h) = self(R(-angle) h)`. A multiple of the sector width is an
    /// exact cyclic shift; otherwise the two neighbouring shifts are blended
    /// linearly and a cell counts as observed only if both sources were.
    pub fn rotated(&self, angle_rad: f32) -> NdfTable {
        let np = self.grid.n_phi as usize;
        let shift = angle_rad / self.grid.dphi();
        let (s0, f) = split_shift(shift, np);
        let mut out = NdfTable::zeros(self.grid);
        for t in 0..self.grid.n_theta as usize {
            for (p, (a, b)) in rotation_sources(np, s0).enumerate() {
                let (a, b) = (self.grid.index(t, a), self.grid.index(t, b));
                let dst = self.grid.index(t, p);
                out.values[dst] = self.values[a] * (1.0 - f) + self.values[b] * f;
                let covered =
                    if f == 0.0 { self.coverage.get(a) } else { self.coverage.get(a) && self.coverage.get(b) };
                out.coverage.set(dst, covered);
            }
        }
        out
    }

    /// Relative L2 distance `sqrt(sum w (a - b)^2 / sum w b^2)` to a reference
    /// table on the same grid, weighted by each cell's cosine measure, over
    /// the cells in `mask` (all cells when `None`). `None` if the reference
    /// has no energy there or the grids differ.
    pub fn rel_l2(&self, reference: &NdfTable, mask: Option<&Coverage>) -> Option<f32> {
        let (num, den) = self.l2_sums(reference, |i| mask.is_none_or(|m| m.get(i)))?;
        (den > 0.0).then(|| (num / den).sqrt() as f32)
    }

    /// The two sums behind [`NdfTable::rel_l2`] over the cells `include`
    /// accepts, `(sum w (self - ref)^2, sum w ref^2)` in the cosine measure,
    /// for pooling the error of many tables; `None` if the grids differ.
    pub fn l2_sums(&self, reference: &NdfTable, include: impl Fn(usize) -> bool) -> Option<(f64, f64)> {
        if self.grid != reference.grid {
            return None;
        }
        let np = self.grid.n_phi as usize;
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for t in 0..self.grid.n_theta as usize {
            let w = self.grid.cos_measure(t) as f64;
            for p in 0..np {
                let i = t * np + p;
                if !include(i) {
                    continue;
                }
                let (a, b) = (self.values[i] as f64, reference.values[i] as f64);
                num += w * (a - b) * (a - b);
                den += w * b * b;
            }
        }
        Some((num, den))
    }
}

/// A table whose cosine integral is below this has no measurable specular
/// energy: `1e-12` is six orders of magnitude below the smallest `k_s` the
/// fitter reports (1e-6), so normalising it would only amplify noise.
pub const MIN_NORMALISABLE: f32 = 1e-12;

#[cfg(test)]
mod tests {
    use super::*;

    /// A caller that has a direction's angles reads the same cell and the
    /// same value, to the bit, as one that has only the direction.
    #[test]
    fn reading_from_known_angles_is_reading_from_the_direction() {
        let g = NdfGrid::new(16, 48).unwrap();
        let values = (0..g.len()).map(|c| ((c * 7919) % 101) as f32 / 17.0).collect();
        let t = NdfTable::from_values(g, values, Coverage::full(g.len())).unwrap();
        for k in 0..2000 {
            let (theta, phi) = (k as f32 * 0.000_785 % FRAC_PI_2, k as f32 * 0.0377);
            let h = frame::spherical(theta, phi);
            let (th, ph) = (frame::polar(h), frame::phi(h));
            assert_eq!(Some(g.cell_at(th, ph)), g.cell(h), "{h}");
            assert_eq!(t.eval_at(g.bilinear_at(th, ph)).to_bits(), t.eval(h).to_bits(), "{h}");
        }
    }

    #[test]
    fn a_shift_splits_into_whole_sectors_around_the_ring_and_a_fraction() {
        assert_eq!(split_shift(2.25, 96), (2, 0.25));
        assert_eq!(split_shift(-0.25, 96), (95, 0.75));
        assert_eq!(split_shift(96.5, 96), (0, 0.5));
        assert_eq!(split_shift(-192.0, 96), (0, 0.0));
    }

    #[test]
    fn wrap_is_the_euclidean_remainder() {
        for n in [1usize, 4, 7, 96, 4096] {
            for i in -3 * n as i64 - 2..3 * n as i64 + 2 {
                assert_eq!(wrap(i, n), i.rem_euclid(n as i64) as usize, "wrap({i}, {n})");
            }
        }
        assert_eq!(wrap(i64::MIN, 96), i64::MIN.rem_euclid(96) as usize);
        assert_eq!(wrap(i64::MAX, 96), i64::MAX.rem_euclid(96) as usize);
    }

    #[test]
    fn rotation_sources_are_the_sectors_behind_by_the_shift() {
        for np in [1usize, 4, 5, 96, 97] {
            for s0 in 0..np {
                let got: Vec<(usize, usize)> = rotation_sources(np, s0).collect();
                let want: Vec<(usize, usize)> =
                    (0..np).map(|p| ((p + np - s0) % np, (p + 2 * np - s0 - 1) % np)).collect();
                assert_eq!(got, want, "n_phi {np}, shift {s0}");
            }
        }
    }

    #[test]
    fn cos_measure_sums_to_pi() {
        let g = NdfGrid::DEFAULT;
        let s: f32 = (0..g.n_theta as usize).map(|t| g.cos_measure(t) * g.n_phi as f32).sum();
        assert!((s - std::f32::consts::PI).abs() < 1e-5, "{s}");
        let w: f32 = (0..g.n_theta as usize).map(|t| g.solid_angle(t) * g.n_phi as f32).sum();
        assert!((w - TAU).abs() < 1e-4, "{w}");
    }

    #[test]
    fn cell_lookup_inverts_cell_centres() {
        let g = NdfGrid::new(16, 48).unwrap();
        for t in 0..16 {
            for p in 0..48 {
                assert_eq!(g.cell(g.direction(t, p)), Some((t, p)));
            }
        }
    }

    #[test]
    fn eval_at_centre_returns_the_cell_value() {
        let g = NdfGrid::new(8, 16).unwrap();
        let mut t = NdfTable::zeros(g);
        for (i, v) in t.values_mut().iter_mut().enumerate() {
            *v = i as f32;
        }
        for tt in 0..8 {
            for p in 0..16 {
                let e = t.eval(g.direction(tt, p));
                assert!((e - t.at(tt, p)).abs() < 1e-3, "{tt} {p} {e}");
            }
        }
    }

    #[test]
    fn rotation_by_whole_sectors_is_a_cyclic_shift_and_invertible() {
        let g = NdfGrid::new(4, 12).unwrap();
        let mut t = NdfTable::zeros(g);
        for (i, v) in t.values_mut().iter_mut().enumerate() {
            *v = i as f32;
        }
        t.coverage_mut().set(5, true);
        let r = t.rotated(3.0 * g.dphi());
        assert_eq!(r.at(0, 3), t.at(0, 0));
        assert!(r.coverage().get(8));
        let back = r.rotated(-3.0 * g.dphi());
        assert_eq!(back, t);
    }

    #[test]
    fn from_values_rejects_bad_input() {
        let g = NdfGrid::new(2, 4).unwrap();
        assert!(matches!(
            NdfTable::from_values(g, vec![0.0; 7], Coverage::empty(8)),
            Err(TableError::WrongLength { .. })
        ));
        let mut v = vec![0.0; 8];
        v[3] = f32::NAN;
        assert!(matches!(NdfTable::from_values(g, v, Coverage::empty(8)), Err(TableError::BadValue { index: 3, .. })));
        assert!(NdfGrid::new(1, 4).is_err());
    }
}
