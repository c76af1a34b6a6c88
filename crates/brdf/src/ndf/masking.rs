//! Smith masking of a tabulated NDF by integration.
//!
//! `sigma(k) = integral of max(0, h . k) D(h) dw` (Ashikhmin, Premoze and
//! Shirley 2000; Dupuy et al. 2015) and `S(k) = cos(theta_k) / sigma(k)`.
//!
//! For `k` at polar angle `theta_j` and azimuth `phi_q`, the kernel
//! `max(0, h . k)` integrated over a table cell depends only on the cell's
//! ring and its azimuth offset from `phi_q`. So `sigma` at every `phi_q` of
//! ring `j` is a sum over NDF rings of circular cross-correlations along phi,
//! which one FFT per ring evaluates for all azimuths at once:
//! `O(n_theta_k * n_theta * n_phi)` per table instead of the
//! `O(n_theta_k * n_phi * n_theta * n_phi)` of direct quadrature.
//! The kernel's spectra depend only on the grid, so a [`MaskingOperator`] is
//! built once and shared.
//!
//! `sigma` is tabulated at `n_theta_k` polar angles spaced uniformly from 0 to
//! `pi / 2` (masking changes fastest near the horizon, where the NDF grid's
//! warped rings are widest) and at the NDF grid's sector centres.

use std::f32::consts::FRAC_PI_2;
use std::sync::Arc;

use glam::Vec3;
use realfft::num_complex::Complex32;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};

use super::{NdfGrid, NdfTable, wrap};
use crate::frame;

/// Sub-samples per cell edge used to integrate the kernel over a cell: 8 in
/// theta by 4 in phi keeps the quadrature error of `sigma` below 1e-3 for the
/// default grid (checked against Smith's closed forms in the tests).
const KERNEL_SUB_THETA: usize = 8;
const KERNEL_SUB_PHI: usize = 4;

/// Precomputed kernel spectra for one grid.
///
/// The kernel of a ring is real and even in the azimuth offset, so its
/// spectrum is real: the products are real-by-complex, over the half
/// spectrum of real FFTs (about 6x fewer operations than complex FFTs with
/// complex products).
pub struct MaskingOperator {
    grid: NdfGrid,
    n_theta_k: usize,
    /// Number of half-spectrum bins, `n_phi / 2 + 1`.
    n_freq: usize,
    /// `[j][t][f]`: real spectrum of the cell-integrated kernel of ring `t`
    /// as seen from direction ring `j`.
    kernel: Vec<f32>,
    r2c: Arc<dyn RealToComplex<f32>>,
    c2r: Arc<dyn ComplexToReal<f32>>,
}

impl std::fmt::Debug for MaskingOperator {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MaskingOperator").field("grid", &self.grid).field("n_theta_k", &self.n_theta_k).finish()
    }
}

impl MaskingOperator {
    /// Build the operator for a grid, with `2 * n_theta + 1` direction rings.
    pub fn new(grid: NdfGrid) -> Self {
        Self::with_direction_rings(grid, 2 * grid.n_theta as usize + 1)
    }

    /// Build the operator for a grid, with `n_theta_k` direction rings (at
    /// least 2). Panics past 65,535 rings or sectors, which
    /// [`MaskingCell`]'s 16-bit indices cannot hold (a table that size
    /// would take 16 GiB).
    pub fn with_direction_rings(grid: NdfGrid, n_theta_k: usize) -> Self {
        let n_theta_k = n_theta_k.max(2);
        assert!(
            n_theta_k <= u16::MAX as usize && grid.n_phi <= u16::MAX as u32,
            "masking tables of {n_theta_k} rings by {} sectors are past 16-bit indices",
            grid.n_phi
        );
        let (nt, np) = (grid.n_theta as usize, grid.n_phi as usize);
        let n_freq = np / 2 + 1;
        let mut planner = RealFftPlanner::<f32>::new();
        let r2c = planner.plan_fft_forward(np);
        let c2r = planner.plan_fft_inverse(np);
        let mut kernel = vec![0.0f32; n_theta_k * nt * n_freq];
        let dphi = grid.dphi();
        let mut row = vec![0.0f32; np];
        let mut spec = vec![Complex32::new(0.0, 0.0); n_freq];
        for j in 0..n_theta_k {
            let theta_k = j as f32 / (n_theta_k - 1) as f32 * FRAC_PI_2;
            let (sk, ck) = theta_k.sin_cos();
            for t in 0..nt {
                let (th0, th1) = (grid.theta_edge(t), grid.theta_edge(t + 1));
                for (delta, slot) in row.iter_mut().enumerate() {
                    // Offsets are symmetric: sector `delta` and `np - delta`
                    // see the same kernel; use the signed offset.
                    let off = if delta <= np / 2 { delta as f32 } else { delta as f32 - np as f32 };
                    let mut acc = 0.0f64;
                    for a in 0..KERNEL_SUB_THETA {
                        let th = th0 + (th1 - th0) * (a as f32 + 0.5) / KERNEL_SUB_THETA as f32;
                        let (sh, ch) = th.sin_cos();
                        let w_theta = sh * (th1 - th0) / KERNEL_SUB_THETA as f32;
                        for b in 0..KERNEL_SUB_PHI {
                            let ph = (off - 0.5 + (b as f32 + 0.5) / KERNEL_SUB_PHI as f32) * dphi;
                            let dot = sh * sk * ph.cos() + ch * ck;
                            if dot > 0.0 {
                                acc += (dot * w_theta * dphi / KERNEL_SUB_PHI as f32) as f64;
                            }
                        }
                    }
                    *slot = acc as f32;
                }
                // A planned FFT of the right length cannot fail.
                let _ = r2c.process(&mut row, &mut spec);
                let dst = &mut kernel[(j * nt + t) * n_freq..(j * nt + t + 1) * n_freq];
                for (d, c) in dst.iter_mut().zip(&spec) {
                    *d = c.re;
                }
            }
        }
        Self { grid, n_theta_k, n_freq, kernel, r2c, c2r }
    }

    pub fn grid(&self) -> NdfGrid {
        self.grid
    }

    /// Projected areas `sigma(k)` of a table (which should be normalised) at
    /// every direction of the masking grid.
    pub fn projected_areas(&self, table: &NdfTable) -> MaskingTable {
        assert_eq!(table.grid(), self.grid, "masking operator built for another grid");
        let (nt, np, nf) = (self.grid.n_theta as usize, self.grid.n_phi as usize, self.n_freq);
        let mut spectra = vec![Complex32::new(0.0, 0.0); nt * nf];
        let mut row = vec![0.0f32; np];
        let mut active = vec![false; nt];
        // One scratch buffer for every transform of the call (`process`
        // would allocate one per transform; the results are the same).
        let mut scratch = vec![Complex32::new(0.0, 0.0); self.r2c.get_scratch_len().max(self.c2r.get_scratch_len())];
        for t in 0..nt {
            row.copy_from_slice(&table.values()[t * np..(t + 1) * np]);
            active[t] = row.iter().any(|&v| v != 0.0);
            if active[t] {
                let _ = self.r2c.process_with_scratch(&mut row, &mut spectra[t * nf..(t + 1) * nf], &mut scratch);
            }
        }
        let mut sigma = vec![0.0f32; self.n_theta_k * np];
        let mut acc = vec![Complex32::new(0.0, 0.0); nf];
        let mut out = vec![0.0f32; np];
        for j in 0..self.n_theta_k {
            acc.iter_mut().for_each(|c| *c = Complex32::new(0.0, 0.0));
            for t in (0..nt).filter(|&t| active[t]) {
                let k = &self.kernel[(j * nt + t) * nf..(j * nt + t + 1) * nf];
                let d = &spectra[t * nf..(t + 1) * nf];
                // Cross-correlation with an even real kernel: a product
                // with the (real) kernel spectrum.
                for f in 0..nf {
                    acc[f] += d[f] * k[f];
                }
            }
            // The DC (and, for even n, Nyquist) bins of a real signal's
            // spectrum are real; keep rounding from making them otherwise.
            acc[0].im = 0.0;
            if np % 2 == 0 {
                acc[nf - 1].im = 0.0;
            }
            let _ = self.c2r.process_with_scratch(&mut acc, &mut out, &mut scratch);
            let scale = 1.0 / np as f32;
            for q in 0..np {
                sigma[j * np + q] = (out[q] * scale).max(0.0);
            }
        }
        MaskingTable { n_theta_k: self.n_theta_k, n_phi: np, sigma }
    }
}

/// Where a direction falls among the directions of a masking table: the
/// two rings and sectors around it, the fractions toward the second, and
/// its `z`. It depends on the operator's grid only, so a direction read
/// under many tables of one operator (a sample's `sigma(i)` at every
/// masking iteration) is located once. 16 bytes: pooling keeps one for
/// each of up to some 38 million samples; the second sector is the one
/// after the first, modulo the table's sectors, and the operator's rings
/// and sectors fit in 16 bits ([`MaskingOperator::with_direction_rings`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MaskingCell {
    j0: u16,
    q0: u16,
    fj: f32,
    fq: f32,
    z: f32,
}

const _: () = assert!(std::mem::size_of::<MaskingCell>() == 16);

impl MaskingOperator {
    /// Where `v` falls in this operator's tables ([`MaskingTable::projected_area_at`]).
    pub fn locate(&self, v: Vec3) -> MaskingCell {
        locate(self.n_theta_k, self.grid.n_phi as usize, v)
    }
}

/// [`MaskingOperator::locate`] on a grid of `n_theta_k` rings of `n_phi`
/// sectors.
fn locate(n_theta_k: usize, n_phi: usize, v: Vec3) -> MaskingCell {
    if v.z <= 0.0 {
        return MaskingCell { z: v.z, ..MaskingCell::default() };
    }
    let theta = frame::sin2_theta(v).sqrt().atan2(v.z);
    let x = theta / FRAC_PI_2 * (n_theta_k - 1) as f32;
    let j0 = (x as usize).min(n_theta_k - 2);
    let fj = (x - j0 as f32).clamp(0.0, 1.0);
    let y = frame::phi(v) / std::f32::consts::TAU * n_phi as f32 - 0.5;
    let yf = frame::floor(y);
    let fq = y - yf;
    let q0 = wrap(yf as i64, n_phi);
    MaskingCell { j0: j0 as u16, q0: q0 as u16, fj, fq, z: v.z }
}

/// `sigma(k)` tabulated over directions, with interpolation.
#[derive(Clone, Debug, PartialEq)]
pub struct MaskingTable {
    n_theta_k: usize,
    n_phi: usize,
    sigma: Vec<f32>,
}

impl MaskingTable {
    /// Projected area toward `v`, bilinear in `(theta, phi)` and never below
    /// `v.z` (see [`super::Ndf::projected_area`]). 1 for `v.z <= 0`.
    pub fn projected_area(&self, v: Vec3) -> f32 {
        self.projected_area_at(&locate(self.n_theta_k, self.n_phi, v))
    }

    /// [`MaskingTable::projected_area`] toward a direction located once
    /// ([`MaskingOperator::locate`], by this table's operator): the same
    /// value, bit for bit.
    pub fn projected_area_at(&self, c: &MaskingCell) -> f32 {
        if c.z <= 0.0 {
            return 1.0;
        }
        let (j0, q0, fj, fq) = (c.j0 as usize, c.q0 as usize, c.fj, c.fq);
        let q1 = if q0 + 1 == self.n_phi { 0 } else { q0 + 1 };
        let s = |j: usize, q: usize| self.sigma[j * self.n_phi + q];
        let a = s(j0, q0) * (1.0 - fq) + s(j0, q1) * fq;
        let b = s(j0 + 1, q0) * (1.0 - fq) + s(j0 + 1, q1) * fq;
        let sigma = a * (1.0 - fj) + b * fj;
        if sigma.is_finite() { sigma.max(c.z) } else { c.z.max(MIN_SIGMA) }
    }

    /// Smith masking `S(v) = cos(theta_v) / sigma(v)`.
    pub fn g1(&self, v: Vec3) -> f32 {
        if v.z <= 0.0 { 0.0 } else { (v.z / self.projected_area(v)).clamp(0.0, 1.0) }
    }

    /// Raw `sigma` values, `[j][q]`.
    pub fn values(&self) -> &[f32] {
        &self.sigma
    }
}

/// Floor for a projected area that is not finite (cannot happen for finite
/// tables; kept so no NaN can escape).
const MIN_SIGMA: f32 = 1e-6;
