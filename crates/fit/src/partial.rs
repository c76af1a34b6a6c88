//! From one point's samples to its partial microfacet NDF (the per-point
//! steps of Wang et al. 2008 and its talk, 1-7 below).
//!
//! 1. **Diffuse**: the robust lower mode of each channel ([`crate::diffuse`]).
//! 2. **Specular**: `r_q = rho_q - rho_d`; its colour is the ratio of the
//!    channels over the samples with significant specular; the scalar
//!    specular `s_q` is the luminance of `r_q`.
//! 3. **Splat** `D'_q = 4 s_q sigma(i_q) sigma(o) / F_rel(i_q . h_q)` at the
//!    half vector `h_q`. This is the talk's
//!    `D = 4 pi rho_s (i.n)(o.n) / (S(i) S(o))` with the projected-area form
//!    of `S` (`S / cos = 1 / sigma`) and `k_s` kept in `D'` (the talk's
//!    `k_s = 1/pi` start is the same thing, scaled). Each sample spreads
//!    over the cells around `h_q` with an angular Gaussian whose width is
//!    set by the local spacing of the capture's half vectors
//!    (`FitContext::half_vector_spacing`): near the normal the table's cells are far
//!    smaller than that spacing, and a splat into the four nearest cells
//!    would leave most of them empty; far from it, half vectors are denser
//!    and the kernel narrower. The kernel average lowers and widens a
//!    peaked lobe; one pass of twicing ([`SplatLayout::twice`]) splats the
//!    residuals at the samples and adds them back, cancelling the leading
//!    term of that bias (`FitSettings::bias_passes`).
//! 4. **Observed region**: cells with at least `observed_weight` of kernel
//!    weight (the region ends about one sample spacing beyond the outermost
//!    sample, see `FitSettings::observed_weight`), then a
//!    morphological closing (dilate, erode; 3x3, periodic in phi) that
//!    fills one-cell gaps without growing the boundary. Gaps inside are
//!    filled by push-pull ([`crate::pushpull`]); nothing is extrapolated
//!    beyond the sampling resolution.
//! 5. **Normalise and mask**: `k_s = integral D' cos`, `D = D' / k_s`,
//!    `sigma` from `D` by integration, and back to step 3 until `D` changes
//!    by less than the tolerance.
//! 6. **Fresnel**: most surfaces' NDFs are centrally symmetric,
//!    `D(hx, hy) = D(-hx, -hy)`, while the oblique camera sees the two cells
//!    of such a pair at different angles `theta_d` from `o`. So
//!    `D'(c) / D'(c') = F(o . h_c) / F(o . h_c')`, which determines `eta`
//!    with `D` unknown. `eta` minimises the weighted squared log-ratio error
//!    over every observed pair (golden-section search on `ln eta` in
//!    `[1.05, 30]`; 30 is a flat, metal-like `F`); then steps 3-5 run again
//!    with `F_rel(eta)`.
//!
//! Every output is finite: a point without usable specular data gets
//! `k_s = 0`, an empty table and a flag, never NaN.

use brdf::fresnel;
use brdf::ndf::{Coverage, MaskingOperator, MaskingTable, NdfGrid, NdfTable};
use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::diffuse::lower_mode;
use crate::pushpull::push_pull;
use crate::settings::FitSettings;
use crate::tol::MIN_FRESNEL_LOG;

/// Luminance weights (Rec. 709) that define the scalar specular.
pub const LUMA: [f32; 3] = [0.2126, 0.7152, 0.0722];

/// Point flags.
pub mod point_flag {
    /// No measurable specular reflection: diffuse only.
    pub const NO_SPECULAR: u32 = 0x01;
    /// Too few usable samples for a specular fit.
    pub const FEW_SAMPLES: u32 = 0x02;
    /// More than 5% of the point's lit samples were clipped in every exposure.
    pub const SATURATED: u32 = 0x04;
    /// The masking iteration hit its limit before converging.
    pub const NOT_CONVERGED: u32 = 0x08;
    /// Fresnel could not be fitted (too few symmetric pairs); default eta.
    pub const ETA_DEFAULT: u32 = 0x10;
    /// The observed region covers less than 2% of the hemisphere's cosine measure.
    pub const LOW_COVERAGE: u32 = 0x20;
    /// The point is not seen by the camera.
    pub const OUT_OF_VIEW: u32 = 0x40;
    /// The table was completed by synthesis.
    pub const SYNTHESIZED: u32 = 0x80;
    /// The table is its cluster's pooled estimate (`crate::pooled`).
    pub const POOLED: u32 = 0x100;

    pub const NAMES: &[(u32, &str)] = &[
        (NO_SPECULAR, "no_specular"),
        (FEW_SAMPLES, "few_samples"),
        (SATURATED, "saturated"),
        (NOT_CONVERGED, "not_converged"),
        (ETA_DEFAULT, "eta_default"),
        (LOW_COVERAGE, "low_coverage"),
        (OUT_OF_VIEW, "out_of_view"),
        (SYNTHESIZED, "synthesized"),
        (POOLED, "pooled"),
    ];
}

/// Index of refraction used when it cannot be fitted (typical dielectrics).
pub const DEFAULT_ETA: f32 = 1.5;
/// Range of the tables' fitted Fresnel index, and the lower bound of the
/// analytic lobes' (whose upper bound is a metal's reflectance,
/// [`brdf::params::MAX_ETA`]). Below: the lowest refractive indices of
/// common solids are about 1.3 (water ice 1.31, PTFE 1.35, magnesium
/// fluoride 1.38), and the relative Fresnel term `F(theta) / F(0)` grows
/// without bound as the index nears 1 (at 1.05, 1,700 times at grazing), so an index the rig's
/// angles cannot pin down must not drift there: brushed metal's tables sat
/// at the old bound of 1.05 (`refl inspect` of a fast capture before it
/// moved).
/// Above 30 the term is flat to within 1% at the rig's angles, as a
/// metal's nearly is: a table, whose amplitude is free, gains nothing
/// from a higher index.
pub const ETA_RANGE: (f32, f32) = (1.3, 30.0);

/// One usable sample of a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// Direction toward the light (local frame).
    pub i: Vec3,
    pub rho: [f32; 3],
    /// Variance of the sample's luminance reflectance.
    pub var: f32,
    /// Variance of each channel's reflectance (the diffuse estimate's).
    pub channel_var: [f32; 3],
    /// Angular width (radians) of its splatting kernel.
    pub kernel_rad: f32,
}

/// A point's samples and what is needed to interpret them.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointSamples {
    pub o: Vec3,
    pub samples: Vec<Sample>,
    /// Lit samples that were clipped in every exposure.
    pub saturated: usize,
    /// Lit samples in view (usable + saturated).
    pub lit: usize,
    pub in_view: bool,
}

/// The fit of one point.
#[derive(Clone, Debug, PartialEq)]
pub struct PointFit {
    pub kd: [f32; 3],
    /// Specular scale per channel: `k_s` times the specular colour.
    pub ks: [f32; 3],
    pub eta: f32,
    pub flags: u32,
    /// Normalised over the observed region (before synthesis).
    pub table: NdfTable,
    pub stats: PointStats,
}

#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PointStats {
    pub usable: u32,
    pub saturated: u32,
    pub significant: u32,
    pub iterations: u32,
    /// Standard deviation of the scalar specular noise (median over samples).
    pub noise: f32,
    /// Fraction of the hemisphere's cosine measure observed.
    pub coverage: f32,
}

/// Working buffers, reused across points by one thread.
#[derive(Debug, Default)]
pub struct Scratch {
    vals: Vec<f32>,
    vars: Vec<f32>,
    sort: Vec<f32>,
    spec: Vec<f32>,
    h: Vec<Vec3>,
    /// Kernel cells of every sample, concatenated; `offsets[k]..offsets[k+1]`.
    cells: Vec<(u32, f32)>,
    offsets: Vec<usize>,
    /// The last grid's cell centres and ring sines.
    kernel_grid: Option<KernelGrid>,
    /// Each sample's light direction located in the masking tables.
    mask_cells: Vec<brdf::ndf::MaskingCell>,
    sum_w: Vec<f32>,
    sum_wd: Vec<f32>,
    /// Fixed per point: covered cells, push-pull confidence, per-sample
    /// `sigma(i)` and Fresnel factor.
    covered: Vec<bool>,
    confidence: Vec<f32>,
    sigma_i: Vec<f32>,
    fresnel: Vec<f32>,
    /// Per sample: bilinear corners of its half vector and its NDF value
    /// in the current iteration.
    corners: Vec<[(u32, f32); 4]>,
    d: Vec<f32>,
}

/// Scalar specular sample counts as significant above this many standard
/// deviations: 3 sigma keeps pure-noise false positives at 0.13% per sample.
const SIGNIFICANT_SIGMA: f32 = 3.0;
/// Fewer significant samples than this and there is no specular to fit
/// (at least; see [`min_significant`]).
const MIN_SIGNIFICANT: usize = 5;
/// One-sided Gaussian tail beyond [`SIGNIFICANT_SIGMA`]: the chance that a
/// pure-noise sample counts as significant.
const SIGNIFICANT_TAIL: f64 = 1.35e-3;
/// The chance of a diffuse point getting a specular fit from noise alone:
/// one point in 10,000, a fraction of a point on the presets' grids.
const FALSE_SPECULAR: f64 = 1e-4;

/// Significant samples a point needs for a specular fit, out of `n`: at
/// least [`MIN_SIGNIFICANT`], and enough that a diffuse point reaches the
/// count by chance (a Poisson count of mean `n` times the tail) with
/// probability at most [`FALSE_SPECULAR`].
pub(crate) fn min_significant(n: usize) -> usize {
    let lambda = n as f64 * SIGNIFICANT_TAIL;
    // P(N >= m) = 1 - sum_{k < m} pmf(k), the pmf by its recurrence.
    let (mut pmf, mut below) = ((-lambda).exp(), 0.0f64);
    let mut m = 0usize;
    while 1.0 - below > FALSE_SPECULAR && m < n {
        below += pmf;
        m += 1;
        pmf *= lambda / m as f64;
    }
    m.max(MIN_SIGNIFICANT)
}
/// Fewer symmetric pairs than this and Fresnel is not fitted.
const MIN_PAIRS: usize = 6;
/// At most this many (strongest) pairs enter the Fresnel fit.
const MAX_PAIRS: usize = 128;

/// Luminance of a colour (the scalar specular's weights, [`LUMA`]).
pub(crate) fn lum(c: [f32; 3]) -> f32 {
    LUMA[0] * c[0] + LUMA[1] * c[1] + LUMA[2] * c[2]
}

fn finite_or(v: f32, d: f32) -> f32 {
    if v.is_finite() { v } else { d }
}

/// Entries of the Gaussian lookup table over `x = d^2 / (2 r^2)` in `[0, 3.125]`.
const GAUSS_LUT: usize = 1024;
const GAUSS_MAX_X: f32 = 3.125;

fn gauss_lut() -> &'static [f32; GAUSS_LUT + 1] {
    static LUT: std::sync::OnceLock<[f32; GAUSS_LUT + 1]> = std::sync::OnceLock::new();
    LUT.get_or_init(|| std::array::from_fn(|k| (-(k as f32) / GAUSS_LUT as f32 * GAUSS_MAX_X).exp()))
}

/// [`gauss_lut`] as `(value, step to the next value)` pairs, one load per
/// interpolation; the last entry's step is 0.
fn gauss_steps() -> &'static [(f32, f32); GAUSS_LUT + 1] {
    static STEPS: std::sync::OnceLock<[(f32, f32); GAUSS_LUT + 1]> = std::sync::OnceLock::new();
    STEPS.get_or_init(|| {
        let lut = gauss_lut();
        std::array::from_fn(|k| (lut[k], if k < GAUSS_LUT { lut[k + 1] - lut[k] } else { 0.0 }))
    })
}

/// What [`kernel`] reads of a table's geometry, computed once per
/// grid: each cell's centre direction and each ring's lower-edge sine.
#[derive(Debug)]
pub(crate) struct KernelGrid {
    pub(crate) grid: NdfGrid,
    centres: Vec<Vec3>,
    ring_sin: Vec<f32>,
}

impl KernelGrid {
    pub(crate) fn new(grid: NdfGrid) -> Self {
        let np = grid.n_phi as usize;
        let centres = (0..grid.len()).map(|c| grid.direction(c / np, c % np)).collect();
        let ring_sin =
            (0..grid.n_theta as usize).map(|t| grid.theta_edge(t).sin().max(crate::tol::MIN_RING_SIN)).collect();
        Self { grid, centres, ring_sin }
    }
}

/// A sample's kernel: pushed to `out`, the cells within 2.5 kernel widths
/// of `h` (beyond that the weight is below 0.044 and is dropped), with
/// Gaussian weights (from a 1,024-entry table, linearly interpolated:
/// relative error below 1e-6) `exp(-d^2 / (2 r^2))` of the chord distance
/// `d` to each cell centre.
/// The cells come ring by ring and, within a ring, sector by sector from
/// the first one in reach (the order the sums over them add in).
///
/// Returned: the four table cells around `h` and their bilinear weights
/// (the table's own interpolation, [`NdfGrid::bilinear`]), from the same
/// computation of `h`'s angles.
pub(crate) fn kernel(kg: &KernelGrid, h: Vec3, r: f32, out: &mut Vec<(u32, f32)>) -> [(u32, f32); 4] {
    kernel_at(kg, &KernelAt::new(h, r), out)
}

/// [`kernel`] of a sample whose half vector's angles are known.
pub(crate) fn kernel_at(kg: &KernelGrid, k: &KernelAt, out: &mut Vec<(u32, f32)>) -> [(u32, f32); 4] {
    kernel_cells(kg, k.h, k.theta, k.phi, k.r, out);
    let grid = kg.grid;
    grid.bilinear_at(k.theta, k.phi).weights(grid.n_phi as usize).map(|(c, w)| (c as u32, w))
}

/// A sample's half vector `h` with its polar angle and azimuth
/// (`brdf::frame::polar` and `phi` of it), and its kernel width `r`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct KernelAt {
    pub(crate) h: Vec3,
    pub(crate) theta: f32,
    pub(crate) phi: f32,
    pub(crate) r: f32,
}

impl KernelAt {
    pub(crate) fn new(h: Vec3, r: f32) -> Self {
        Self { h, theta: brdf::frame::polar(h), phi: brdf::frame::phi(h), r }
    }
}

/// [`kernel`]'s cells, with `h`'s polar angle and azimuth given.
fn kernel_cells(kg: &KernelGrid, h: Vec3, theta_h: f32, phi_h: f32, r: f32, out: &mut Vec<(u32, f32)>) {
    let grid = kg.grid;
    let (nt, np) = (grid.n_theta as usize, grid.n_phi as usize);
    let reach = 2.5 * r;
    let reach2 = reach * reach;
    let inv2r2 = 1.0 / (2.0 * r * r);
    let steps = gauss_steps();
    let scale = GAUSS_LUT as f32 / GAUSS_MAX_X;
    let x_max = GAUSS_LUT as f32 - 1e-3;
    let dphi = grid.dphi();
    let weight = |d2: f32| {
        let x = (d2 * inv2r2 * scale).min(x_max);
        let k = x as usize;
        let f = x - k as f32;
        let (v, step) = steps[k];
        v + step * f
    };
    let next = |p: usize| if p + 1 == np { 0 } else { p + 1 };
    let prev = |p: usize| if p == 0 { np - 1 } else { p - 1 };
    // The rings that meet `[theta_h - reach, theta_h + reach]` are
    // consecutive (the edges increase with `t`): start two rings before
    // the first one's estimate, test each ring exactly, stop past the last.
    let lo = theta_h - reach;
    let first = if lo > 0.0 { ((lo / std::f32::consts::FRAC_PI_2).sqrt() * nt as f32) as usize } else { 0 };
    for t in first.saturating_sub(2).min(nt)..nt {
        let (t0, t1) = (grid.theta_edge(t), grid.theta_edge(t + 1));
        if t0 > theta_h + reach {
            break;
        }
        if t1 < lo {
            continue;
        }
        let s = kg.ring_sin[t];
        let ring = &kg.centres[t * np..(t + 1) * np];
        let d2_at = |p: usize| (h - ring[p]).length_squared();
        if s > 2.0 * reach {
            // A centre of this ring within reach lies within `asin(reach /
            // s)` of `phi_h` in azimuth (the chord to a centre `a` away in
            // azimuth is at least `sin(theta) |sin(a)|`), inside the range
            // the scan below would visit; along the ring the chord grows
            // with `a`, by steps far above rounding here (`sin(theta_h) >
            // s / 2`, as the chord is at least `|sin(theta) -
            // sin(theta_h)|`). So the cells in reach are one arc around
            // the nearest centre, in the scan's order: find it and walk
            // out from it.
            let pc = brdf::ndf::wrap(brdf::frame::floor(phi_h / dphi) as i64, np);
            let (mut start, mut d2_start) = (pc, d2_at(pc));
            for p in [prev(pc), next(pc)] {
                let d2 = d2_at(p);
                if d2 < d2_start {
                    (start, d2_start) = (p, d2);
                }
            }
            if d2_start > reach2 {
                continue;
            }
            let mut left = start;
            for _ in 0..np / 2 {
                let p = prev(left);
                if d2_at(p) > reach2 {
                    break;
                }
                left = p;
            }
            // From the arc's first cell to `start`, then on while in reach.
            let mut p = left;
            while p != start {
                out.push(((t * np + p) as u32, weight(d2_at(p))));
                p = next(p);
            }
            out.push(((t * np + start) as u32, weight(d2_start)));
            for _ in 0..np / 2 {
                p = next(p);
                let d2 = d2_at(p);
                if d2 > reach2 {
                    break;
                }
                out.push(((t * np + p) as u32, weight(d2)));
            }
            continue;
        }
        // Near the pole (or a kernel as wide as the ring): every sector in
        // the azimuth the kernel can reach, in order from its first.
        let half = if s <= reach { std::f32::consts::PI } else { (reach / s).asin() * 1.3 };
        let (p_lo, p_hi) = if half >= std::f32::consts::PI {
            (0i64, np as i64 - 1)
        } else {
            let c = phi_h / dphi - 0.5;
            (brdf::frame::floor(c - half / dphi) as i64, brdf::frame::ceil(c + half / dphi) as i64)
        };
        let mut p = brdf::ndf::wrap(p_lo, np);
        for _ in p_lo..=p_hi {
            let d2 = d2_at(p);
            if d2 <= reach2 {
                out.push(((t * np + p) as u32, weight(d2)));
            }
            p = next(p);
        }
    }
}

/// The kernel layout of a splat, fixed while its values change: where each
/// sample's kernel lies, and the region's push-pull confidence and extent.
pub(crate) struct SplatLayout<'a> {
    pub(crate) grid: NdfGrid,
    pub(crate) kernels: Kernels<'a>,
    pub(crate) confidence: &'a [f32],
    pub(crate) covered: &'a [bool],
}

/// Each sample's bilinear corners and kernel cells.
pub(crate) enum Kernels<'a> {
    /// Computed once and kept (`cells[offsets[k]..offsets[k + 1]]`): a
    /// point's few hundred samples, read every iteration.
    Stored { cells: &'a [(u32, f32)], offsets: &'a [usize], corners: &'a [[(u32, f32); 4]] },
    /// Kept as `Stored` keeps them for the first `corners.len()` samples
    /// only, the rest computed again at every read from each sample's half
    /// vector and kernel width: a pool's millions of samples would hold
    /// gigabytes of cells.
    Computed {
        cells: &'a [(u32, f32)],
        offsets: &'a [usize],
        corners: &'a [[(u32, f32); 4]],
        kg: &'a KernelGrid,
        at: &'a [KernelAt],
    },
}

impl Kernels<'_> {
    /// Two per-cell sums over samples `0..n`, each sample adding to them
    /// through `add(k, scratch, sums)`. Many samples are summed in fixed
    /// chunks, in parallel, and the chunks' sums added in their order, so
    /// the result does not depend on the threads; a point's few hundred
    /// are one chunk.
    pub(crate) fn sums(
        &self,
        grid: NdfGrid,
        n: usize,
        add: impl Fn(usize, &mut Vec<(u32, f32)>, [&mut [f64]; 2]) + Sync,
    ) -> [Vec<f64>; 2] {
        let cells = grid.len();
        let chunk = n.div_ceil(SUM_CHUNKS).max(MIN_SUM_CHUNK);
        let run = |range: std::ops::Range<usize>| {
            let (mut a, mut b) = (vec![0.0f64; cells], vec![0.0f64; cells]);
            let mut scratch = Vec::new();
            for k in range {
                add(k, &mut scratch, [&mut a, &mut b]);
            }
            [a, b]
        };
        if n <= chunk {
            return run(0..n);
        }
        let parts: Vec<[Vec<f64>; 2]> =
            (0..n.div_ceil(chunk)).into_par_iter().map(|c| run(c * chunk..((c + 1) * chunk).min(n))).collect();
        let mut parts = parts.into_iter();
        let mut total = parts.next().unwrap_or_else(|| [vec![0.0; cells], vec![0.0; cells]]);
        for [a, b] in parts {
            total[0].iter_mut().zip(&a).for_each(|(t, v)| *t += v);
            total[1].iter_mut().zip(&b).for_each(|(t, v)| *t += v);
        }
        total
    }

    /// Sample `k`'s corners and kernel cells (`scratch` holds computed ones).
    pub(crate) fn get<'s>(&'s self, k: usize, scratch: &'s mut Vec<(u32, f32)>) -> ([(u32, f32); 4], &'s [(u32, f32)]) {
        match self {
            Kernels::Stored { cells, offsets, corners: c } => (c[k], &cells[offsets[k]..offsets[k + 1]]),
            Kernels::Computed { cells, offsets, corners: c, .. } if k < c.len() => {
                (c[k], &cells[offsets[k]..offsets[k + 1]])
            }
            Kernels::Computed { kg, at, .. } => {
                scratch.clear();
                (kernel_at(kg, &at[k], scratch), scratch.as_slice())
            }
        }
    }
}

impl SplatLayout<'_> {
    /// Tukey's twicing (Tukey 1977, *Exploratory Data Analysis*, ch. 16;
    /// for kernel smoothers Stuetzle and Mittal 1979), `passes` times:
    /// the table is read back at every sample's half vector, the residuals
    /// `d_k - table(h_k)` are splatted with the same kernels and weights and
    /// filled the same way, and the result is added to the table.
    ///
    /// Why: a kernel average of samples of a peaked `D` is `D` blurred by
    /// the kernel, lower at the peak and wider, by a bias of order
    /// `r^2 D'' / 2` for kernel width `r`; at the rig's spacing that bias is
    /// most of the per-point error on noiseless data (`refl bench budget`'s
    /// "method's own bias" row). One pass smooths with the kernel
    /// `2K - K*K`, whose second moment vanishes, so the leading bias term
    /// cancels while the region and its fill stay the same. The price is a
    /// larger variance (the residuals' noise is splatted again), which
    /// pooling's many samples per cell pay for.
    ///
    /// `d[k]` is sample `k`'s NDF value and `weight[k]` its weight (0 for a
    /// sample that is not used); without weights every sample weighs 1.
    pub(crate) fn twice(&self, values: &mut [f32], d: &[f32], weight: Option<&[f64]>, passes: u32) {
        let cells = self.grid.len();
        let mut corr = vec![0.0f32; cells];
        for _ in 0..passes {
            let values_now = &*values;
            let [sum_w, sum_wr] = self.kernels.sums(self.grid, d.len(), |k, scratch, [sum_w, sum_wr]| {
                let (dk, wk) = (d[k], weight.map_or(1.0, |w| w[k]));
                if !(wk > 0.0) || !dk.is_finite() {
                    return;
                }
                let (corners, cells) = self.kernels.get(k, scratch);
                let at: f32 = corners.iter().map(|&(c, w)| w * values_now[c as usize]).sum();
                let r = (dk - at) as f64;
                for &(c, w) in cells {
                    sum_w[c as usize] += w as f64 * wk;
                    sum_wr[c as usize] += w as f64 * wk * r;
                }
            });
            for c in 0..cells {
                corr[c] = if sum_w[c] > 0.0 { (sum_wr[c] / sum_w[c]) as f32 } else { 0.0 };
            }
            push_pull(self.grid.n_theta as usize, self.grid.n_phi as usize, &mut corr, self.confidence, self.covered);
            for (v, c) in values.iter_mut().zip(&corr) {
                if c.is_finite() {
                    *v += c;
                }
            }
        }
    }
}

/// Chunks of [`Kernels::sums`] over many samples, and the smallest chunk.
const SUM_CHUNKS: usize = 64;
const MIN_SUM_CHUNK: usize = 8192;

/// Morphological closing of the observed set (3x3 square, periodic in phi,
/// clamped in theta), as separable 3-tap passes.
pub(crate) fn close(grid: NdfGrid, observed: &[bool]) -> Vec<bool> {
    let (nt, np) = (grid.n_theta as usize, grid.n_phi as usize);
    let pass = |src: &[bool], dilate: bool, along_phi: bool| -> Vec<bool> {
        let mut out = vec![false; nt * np];
        for t in 0..nt {
            for p in 0..np {
                let (a, b) = if along_phi {
                    (src[t * np + (p + np - 1) % np], src[t * np + (p + 1) % np])
                } else {
                    (src[t.saturating_sub(1) * np + p], src[(t + 1).min(nt - 1) * np + p])
                };
                let c = src[t * np + p];
                out[t * np + p] = if dilate { a || b || c } else { a && b && c };
            }
        }
        out
    };
    let d = pass(&pass(observed, true, true), true, false);
    let mut c = pass(&pass(&d, false, true), false, false);
    // Closing never removes observed cells.
    for (o, c) in observed.iter().zip(c.iter_mut()) {
        *c |= *o;
    }
    c
}

pub(crate) struct Splatted {
    pub(crate) table: NdfTable,
    pub(crate) k_s: f32,
}

/// The parts of splatting that do not change between iterations: kernel
/// weight per cell, the observed region and its closing, and push-pull
/// confidences.
fn prepare(grid: NdfGrid, settings: &FitSettings, s: &mut Scratch) {
    let cells = grid.len();
    s.sum_w.clear();
    s.sum_w.resize(cells, 0.0);
    for &(c, w) in &s.cells {
        s.sum_w[c as usize] += w;
    }
    let observed: Vec<bool> = s.sum_w.iter().map(|&w| w >= settings.observed_weight).collect();
    s.covered = close(grid, &observed);
    s.confidence = s.sum_w.iter().map(|&w| (w / settings.observed_weight).min(1.0)).collect();
}

/// Steps 3-5 once: splat `D'` with the current per-sample `sigma(i)` and
/// Fresnel factors (in the scratch) and `sigma(o)`, fill, normalise.
fn splat_once(grid: NdfGrid, ps: &PointSamples, spec: &[f32], sigma_o: f32, passes: u32, s: &mut Scratch) -> Splatted {
    let cells = grid.len();
    s.sum_wd.clear();
    s.sum_wd.resize(cells, 0.0);
    s.d.clear();
    for k in 0..ps.samples.len() {
        let d = 4.0 * spec[k] * s.sigma_i[k] * sigma_o / s.fresnel[k];
        s.d.push(d);
        if !d.is_finite() {
            continue;
        }
        for &(c, w) in &s.cells[s.offsets[k]..s.offsets[k + 1]] {
            s.sum_wd[c as usize] += w * d;
        }
    }
    let mut values: Vec<f32> =
        s.sum_w.iter().zip(&s.sum_wd).map(|(&w, &wd)| if w > 0.0 { wd / w } else { 0.0 }).collect();
    push_pull(grid.n_theta as usize, grid.n_phi as usize, &mut values, &s.confidence, &s.covered);
    if passes > 0 {
        let layout = SplatLayout {
            grid,
            kernels: Kernels::Stored { cells: &s.cells, offsets: &s.offsets, corners: &s.corners },
            confidence: &s.confidence,
            covered: &s.covered,
        };
        layout.twice(&mut values, &s.d, None, passes);
    }
    let mut cov = Coverage::empty(cells);
    for (c, v) in values.iter_mut().enumerate() {
        if s.covered[c] {
            cov.set(c, true);
            *v = finite_or(*v, 0.0).max(0.0);
        } else {
            *v = 0.0;
        }
    }
    let mut table = NdfTable::from_values(grid, values, cov).unwrap_or_else(|_| NdfTable::zeros(grid));
    let k_s = table.normalize();
    Splatted { table, k_s }
}

/// Golden-section search of `eta` on centrally symmetric pairs; `None` when
/// there are too few pairs.
fn fit_eta(table: &NdfTable, k_s: f32, o: Vec3, observed: &[f32], settings: &FitSettings) -> Option<f32> {
    let grid = table.grid();
    let (nt, np) = (grid.n_theta as usize, grid.n_phi as usize);
    if np % 2 != 0 {
        return None;
    }
    let max = table.values().iter().copied().fold(0.0f32, f32::max);
    let mut pairs = Vec::new();
    for t in 1..nt {
        for p in 0..np / 2 {
            let (a, b) = (t * np + p, t * np + p + np / 2);
            if observed[a] < settings.observed_weight || observed[b] < settings.observed_weight {
                continue;
            }
            let (da, db) = (table.values()[a] * k_s, table.values()[b] * k_s);
            if da < 0.05 * max * k_s || db < 0.05 * max * k_s {
                continue;
            }
            let ca = o.dot(grid.direction(t, p)).clamp(0.0, 1.0);
            let cb = o.dot(grid.direction(t, p + np / 2)).clamp(0.0, 1.0);
            let w = (da * db).sqrt() * grid.cos_measure(t);
            pairs.push(((da / db).ln(), ca, cb, w));
        }
    }
    if pairs.len() < MIN_PAIRS {
        return None;
    }
    // The strongest pairs carry the information; 128 of them determine eta
    // to well below its noise, and bound the cost per point.
    if pairs.len() > MAX_PAIRS {
        pairs.sort_by(|a, b| b.3.total_cmp(&a.3));
        pairs.truncate(MAX_PAIRS);
    }
    let cost = |x: f32| -> f32 {
        let eta = x.exp();
        pairs
            .iter()
            .map(|&(r, ca, cb, w)| {
                let m = fresnel::dielectric(ca, eta).max(MIN_FRESNEL_LOG).ln()
                    - fresnel::dielectric(cb, eta).max(MIN_FRESNEL_LOG).ln();
                w * (r - m) * (r - m)
            })
            .sum()
    };
    // 25 golden-section steps shrink the bracket on ln(eta) by 0.618^25, to 2e-5.
    let x = crate::lsq::golden_section(cost, ETA_RANGE.0.ln(), ETA_RANGE.1.ln(), 25);
    let eta = x.exp();
    eta.is_finite().then_some(eta.clamp(ETA_RANGE.0, ETA_RANGE.1))
}

/// Fit one point from its samples.
pub fn fit_point(ps: &PointSamples, settings: &FitSettings, op: &MaskingOperator, s: &mut Scratch) -> PointFit {
    fit_point_with(ps, settings, op, s, None)
}

/// Refit one point whose NDF was completed by synthesis: the shadowing
/// term is recomputed from the completed NDF, the observed samples are
/// splatted again with it and Fresnel refitted, and the synthesized cells
/// are joined to the observed ones at the observed region's scale, so that
/// `k_s`, `S` and `eta` all belong to the completed NDF (the talk's last
/// step). Iterated until the table changes by less than the masking
/// tolerance.
pub fn refit_point(
    ps: &PointSamples,
    settings: &FitSettings,
    op: &MaskingOperator,
    s: &mut Scratch,
    completed: &NdfTable,
) -> PointFit {
    fit_point_with(ps, settings, op, s, Some(completed))
}

/// The observed table (normalised over its region, with scale `k_s`)
/// joined with `prior`'s cells outside that region, scaled so that the two
/// agree in mass over the observed region; `None` without overlap.
pub(crate) fn join(observed: &Splatted, prior: &NdfTable) -> Option<Splatted> {
    let grid = prior.grid();
    let np = grid.n_phi as usize;
    let cov = observed.table.coverage();
    let prior_mass: f32 =
        (0..grid.len()).filter(|&c| cov.get(c)).map(|c| prior.values()[c] * grid.cos_measure(c / np)).sum();
    if !(prior_mass > 0.0) {
        return None;
    }
    let a = observed.k_s / prior_mass;
    let mut table = NdfTable::zeros(grid);
    for c in 0..grid.len() {
        if cov.get(c) {
            table.values_mut()[c] = observed.k_s * observed.table.values()[c];
            table.coverage_mut().set(c, true);
        } else if prior.coverage().get(c) {
            table.values_mut()[c] = finite_or(a * prior.values()[c], 0.0).max(0.0);
            table.coverage_mut().set(c, true);
        }
    }
    let k_s = table.normalize();
    Some(Splatted { table, k_s })
}

fn fit_point_with(
    ps: &PointSamples,
    settings: &FitSettings,
    op: &MaskingOperator,
    s: &mut Scratch,
    prior: Option<&NdfTable>,
) -> PointFit {
    let grid = settings.grid;
    let mut flags = 0u32;
    let mut stats =
        PointStats { usable: ps.samples.len() as u32, saturated: ps.saturated as u32, ..PointStats::default() };
    if ps.lit > 0 && ps.saturated as f32 > 0.05 * ps.lit as f32 {
        flags |= point_flag::SATURATED;
    }
    let empty = |kd: [f32; 3], flags: u32, stats: PointStats| PointFit {
        kd,
        ks: [0.0; 3],
        eta: DEFAULT_ETA,
        flags: flags | point_flag::NO_SPECULAR,
        table: NdfTable::zeros(grid),
        stats,
    };
    if !ps.in_view {
        return empty([0.0; 3], flags | point_flag::OUT_OF_VIEW, stats);
    }
    // 1. Diffuse, per channel.
    let mut kd_rho = [0.0f32; 3];
    for (c, kd) in kd_rho.iter_mut().enumerate() {
        s.vars.clear();
        s.vars.extend(ps.samples.iter().map(|x| x.channel_var[c]));
        s.vals.clear();
        s.vals.extend(ps.samples.iter().map(|x| x.rho[c]));
        *kd = lower_mode(&s.vals, &s.vars, &mut s.sort).max(0.0);
    }
    let kd = kd_rho.map(|r| finite_or(r * std::f32::consts::PI, 0.0));
    if ps.samples.len() < settings.min_samples {
        return empty(kd, flags | point_flag::FEW_SAMPLES, stats);
    }
    // 2. Specular residual, colour and scalar.
    s.spec.clear();
    let (mut col, mut col_lum) = ([0.0f64; 3], 0.0f64);
    let mut significant = 0usize;
    let mut noises = Vec::with_capacity(ps.samples.len());
    for x in &ps.samples {
        let r = [x.rho[0] - kd_rho[0], x.rho[1] - kd_rho[1], x.rho[2] - kd_rho[2]];
        let sv = lum(r);
        let sd = x.var.max(0.0).sqrt();
        noises.push(sd);
        if sv > SIGNIFICANT_SIGMA * sd {
            significant += 1;
            for c in 0..3 {
                col[c] += r[c].max(0.0) as f64;
            }
            col_lum += sv as f64;
        }
        s.spec.push(sv);
    }
    stats.significant = significant as u32;
    noises.sort_by(|a, b| a.total_cmp(b));
    stats.noise = noises.get(noises.len() / 2).copied().unwrap_or(0.0);
    if significant < min_significant(ps.samples.len()) || col_lum <= 0.0 {
        return empty(kd, flags, stats);
    }
    let mut colour = [(col[0] / col_lum) as f32, (col[1] / col_lum) as f32, (col[2] / col_lum) as f32];
    let cl = lum(colour).max(crate::tol::MIN_LUMINANCE);
    colour.iter_mut().for_each(|c| *c = finite_or(*c / cl, 1.0).max(0.0));
    // Half vectors and kernel cells are fixed across iterations.
    s.h.clear();
    s.corners.clear();
    s.cells.clear();
    s.offsets.clear();
    s.offsets.push(0);
    let kg = match s.kernel_grid.take() {
        Some(kg) if kg.grid == grid => kg,
        _ => KernelGrid::new(grid),
    };
    for x in &ps.samples {
        let h = (x.i + ps.o).normalize_or(Vec3::Z);
        s.h.push(h);
        s.corners.push(kernel(&kg, h, x.kernel_rad.max(crate::tol::MIN_KERNEL_RAD), &mut s.cells));
        s.offsets.push(s.cells.len());
    }
    s.kernel_grid = Some(kg);
    // Where each light (and the view) falls in the masking tables, for
    // every masking step below.
    s.mask_cells.clear();
    s.mask_cells.extend(ps.samples.iter().map(|x| op.locate(x.i)));
    let o_cell = op.locate(ps.o);
    let spec = std::mem::take(&mut s.spec);
    prepare(grid, settings, s);
    // 3-5. Splat, normalise, mask, repeat (at most `iterations` masking steps).
    let iterate = |eta: Option<f32>,
                   start: Option<&MaskingTable>,
                   iterations: u32,
                   s: &mut Scratch,
                   stats: &mut PointStats|
     -> (Splatted, bool, Option<MaskingTable>) {
        let f0 = eta.map(fresnel::dielectric_f0).unwrap_or(1.0).max(crate::tol::MIN_DIVISOR);
        s.fresnel.clear();
        for (k, x) in ps.samples.iter().enumerate() {
            let f = match eta {
                Some(e) => (fresnel::dielectric(x.i.dot(s.h[k]), e) / f0).max(crate::tol::MIN_FRESNEL_RATIO),
                None => 1.0,
            };
            s.fresnel.push(f);
        }
        s.sigma_i.clear();
        let sigma_o = match start {
            Some(m) => {
                s.sigma_i.extend(s.mask_cells.iter().map(|c| m.projected_area_at(c)));
                m.projected_area_at(&o_cell)
            }
            None => {
                s.sigma_i.extend(ps.samples.iter().map(|x| x.i.z));
                ps.o.z
            }
        };
        let mut cur = splat_once(grid, ps, &spec, sigma_o, settings.bias_passes, s);
        let mut converged = false;
        let mut last = None;
        for _ in 0..iterations {
            stats.iterations += 1;
            if !(cur.k_s > 0.0) {
                break;
            }
            let m = op.projected_areas(&cur.table);
            s.sigma_i.clear();
            s.sigma_i.extend(s.mask_cells.iter().map(|c| m.projected_area_at(c)));
            let next = splat_once(grid, ps, &spec, m.projected_area_at(&o_cell), settings.bias_passes, s);
            let change = next.table.rel_l2(&cur.table, None).unwrap_or(0.0);
            cur = next;
            last = Some(m);
            if change < settings.masking_tolerance {
                converged = true;
                break;
            }
        }
        (cur, converged, last)
    };
    let (result, eta, converged) = match prior {
        None => {
            // A first estimate with F = 1 and one masking step is enough to fit eta.
            let iterations = if settings.fit_fresnel { 1 } else { settings.max_masking_iterations };
            let (first, converged, first_masking) = iterate(None, None, iterations, s, &mut stats);
            let eta = if settings.fit_fresnel && first.k_s > 0.0 {
                let observed = s.sum_w.clone();
                fit_eta(&first.table, first.k_s, ps.o, &observed, settings)
            } else {
                None
            };
            if eta.is_none() {
                flags |= point_flag::ETA_DEFAULT;
            }
            if settings.fit_fresnel && first.k_s > 0.0 {
                let (again, c, _) =
                    iterate(eta, first_masking.as_ref(), settings.max_masking_iterations, s, &mut stats);
                (again, eta.unwrap_or(DEFAULT_ETA), c)
            } else {
                (first, DEFAULT_ETA, converged)
            }
        }
        Some(prior) => {
            // Masking from the completed NDF, the observed samples splatted
            // with it, eta refitted on their symmetric pairs, then the join;
            // repeated while the joined table still changes.
            let mut full = prior.clone();
            let mut eta: Option<f32> = None;
            let mut converged = false;
            let mut out = None;
            for round in 0..settings.max_masking_iterations.max(1) {
                let m = op.projected_areas(&full);
                let (mut obs, _, _) = iterate(eta, Some(&m), 0, s, &mut stats);
                if round == 0 && settings.fit_fresnel && obs.k_s > 0.0 {
                    let observed = s.sum_w.clone();
                    eta = fit_eta(&obs.table, obs.k_s, ps.o, &observed, settings);
                    if eta.is_some() {
                        obs = iterate(eta, Some(&m), 0, s, &mut stats).0;
                    }
                }
                let Some(next) = join(&obs, prior) else {
                    out = Some(obs);
                    break;
                };
                let change = next.table.rel_l2(&full, None).unwrap_or(0.0);
                full = next.table.clone();
                out = Some(next);
                stats.iterations += 1;
                if change < settings.masking_tolerance {
                    converged = true;
                    break;
                }
            }
            if eta.is_none() {
                flags |= point_flag::ETA_DEFAULT;
            }
            let result = out.unwrap_or(Splatted { table: NdfTable::zeros(grid), k_s: 0.0 });
            (result, eta.unwrap_or(DEFAULT_ETA), converged)
        }
    };
    s.spec = spec;
    if !converged {
        flags |= point_flag::NOT_CONVERGED;
    }
    // The observed region (a refit's table also covers synthesized cells).
    let coverage_measure: f32 =
        (0..grid.len()).filter(|&c| s.covered[c]).map(|c| grid.cos_measure(c / grid.n_phi as usize)).sum::<f32>()
            / std::f32::consts::PI;
    stats.coverage = coverage_measure;
    if coverage_measure < 0.02 {
        flags |= point_flag::LOW_COVERAGE;
    }
    if !(result.k_s > 0.0) || !result.k_s.is_finite() {
        return empty(kd, flags, stats);
    }
    let ks = colour.map(|c| finite_or(c * result.k_s, 0.0));
    PointFit { kd, ks, eta: finite_or(eta, DEFAULT_ETA), flags, table: result.table, stats }
}

#[cfg(test)]
mod tests {
    use super::min_significant;

    #[test]
    fn the_specular_threshold_grows_with_the_chance_count() {
        // Few samples: the floor.
        assert_eq!(min_significant(24), 5);
        // The Poisson tail by direct sum at the threshold and one below.
        for n in [640usize, 2560, 10_240] {
            let lambda = n as f64 * 1.35e-3;
            let tail = |m: usize| {
                let mut pmf = (-lambda).exp();
                let mut below = 0.0;
                for k in 0..m {
                    below += pmf;
                    pmf *= lambda / (k + 1) as f64;
                }
                1.0 - below
            };
            let m = min_significant(n);
            assert!(tail(m) <= 1e-4 && tail(m - 1) > 1e-4, "{n}: {m}");
        }
    }
}

#[cfg(test)]
mod kernel_tests {
    use super::*;

    /// [`kernel`]'s cells as first written: every ring tested, the ring's
    /// sines from the library, one division per sector. The fast one must
    /// give its cells, order and weights bit for bit (the splat's sums add
    /// in that order).
    fn direct_scan(grid: NdfGrid, centres: &[Vec3], h: Vec3, r: f32, out: &mut Vec<(u32, f32)>) {
        let (nt, np) = (grid.n_theta as usize, grid.n_phi as usize);
        let reach = 2.5 * r;
        let theta_h = brdf::frame::sin2_theta(h).sqrt().atan2(h.z);
        let phi_h = brdf::frame::phi(h);
        let inv2r2 = 1.0 / (2.0 * r * r);
        let lut = gauss_lut();
        let scale = GAUSS_LUT as f32 / GAUSS_MAX_X;
        for t in 0..nt {
            let (t0, t1) = (grid.theta_edge(t), grid.theta_edge(t + 1));
            if t1 < theta_h - reach || t0 > theta_h + reach {
                continue;
            }
            let s = t0.sin().max(crate::tol::MIN_RING_SIN);
            let half = if s <= reach { std::f32::consts::PI } else { (reach / s).asin() * 1.3 };
            let (p_lo, p_hi) = if half >= std::f32::consts::PI {
                (0i64, np as i64 - 1)
            } else {
                let c = phi_h / grid.dphi() - 0.5;
                ((c - half / grid.dphi()).floor() as i64, (c + half / grid.dphi()).ceil() as i64)
            };
            for pp in p_lo..=p_hi {
                let p = pp.rem_euclid(np as i64) as usize;
                let c = t * np + p;
                let d2 = (h - centres[c]).length_squared();
                if d2 <= reach * reach {
                    let x = (d2 * inv2r2 * scale).min(GAUSS_LUT as f32 - 1e-3);
                    let k = x as usize;
                    let f = x - k as f32;
                    out.push((c as u32, lut[k] + (lut[k + 1] - lut[k]) * f));
                }
            }
        }
    }

    #[test]
    fn kernels_are_the_direct_scans_and_corners_the_tables_bit_for_bit() {
        let mut state = 12345u64;
        let mut rnd = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 40) as f32) / (1u64 << 24) as f32
        };
        for grid in [
            NdfGrid { n_theta: 16, n_phi: 48 },
            NdfGrid::DEFAULT,
            NdfGrid { n_theta: 64, n_phi: 192 },
            NdfGrid { n_theta: 8, n_phi: 4096 },
        ] {
            let kg = KernelGrid::new(grid);
            let centres: Vec<Vec3> =
                (0..grid.len()).map(|c| grid.direction(c / grid.n_phi as usize, c % grid.n_phi as usize)).collect();
            let (mut fast, mut direct) = (Vec::new(), Vec::new());
            let mut cells = 0;
            for k in 0..60_000 {
                // Half vectors over the hemisphere, the pole and the horizon
                // included, and kernels from a fraction of a cell to wide.
                let theta = match k % 10 {
                    0 => rnd() * 1e-3,
                    1 => std::f32::consts::FRAC_PI_2 - rnd() * 1e-3,
                    _ => rnd() * std::f32::consts::FRAC_PI_2,
                };
                let h = brdf::frame::spherical(theta, rnd() * std::f32::consts::TAU);
                let r = crate::tol::MIN_KERNEL_RAD.max(0.002 + 0.2 * rnd() * rnd());
                fast.clear();
                direct.clear();
                let corners = kernel(&kg, h, r, &mut fast);
                direct_scan(grid, &centres, h, r, &mut direct);
                let bits = |v: &[(u32, f32)]| v.iter().map(|&(c, w)| (c, w.to_bits())).collect::<Vec<_>>();
                assert_eq!(bits(&fast), bits(&direct), "h {h:?}, r {r}, grid {grid:?}");
                let table = grid.bilinear(h).weights(grid.n_phi as usize).map(|(c, w)| (c as u32, w));
                assert_eq!(bits(&corners), bits(&table), "corners of h {h:?}, grid {grid:?}");
                cells += fast.len();
            }
            // The kernels reached cells: the comparison compared something.
            assert!(cells > 60_000, "{cells} cells");
        }
    }

    #[test]
    fn kernels_kept_for_some_samples_read_and_sum_as_kernels_kept_for_all() {
        // A pool's store stops part-way (`Kernels::Computed` with a
        // prefix): every sample's kernel, and the sums over them, must be
        // the same bit for bit wherever the store stops.
        let grid = NdfGrid::DEFAULT;
        let kg = KernelGrid::new(grid);
        let mut state = 777u64;
        let mut rnd = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ((state >> 40) as f32) / (1u64 << 24) as f32
        };
        let at: Vec<KernelAt> = (0..20_000)
            .map(|_| {
                let h = brdf::frame::spherical(rnd() * 1.2, rnd() * std::f32::consts::TAU);
                KernelAt::new(h, 0.01 + 0.05 * rnd())
            })
            .collect();
        let (mut cells, mut offsets, mut corners) = (Vec::new(), vec![0], Vec::new());
        for k in &at {
            corners.push(kernel_at(&kg, k, &mut cells));
            offsets.push(cells.len());
        }
        let all = Kernels::Stored { cells: &cells, offsets: &offsets, corners: &corners };
        let bits = |v: &[(u32, f32)]| v.iter().map(|&(c, w)| (c, w.to_bits())).collect::<Vec<_>>();
        let values: Vec<f32> = (0..at.len()).map(|_| rnd()).collect();
        let sum = |kernels: &Kernels| {
            kernels.sums(grid, at.len(), |k, scratch, [a, b]| {
                for &(c, w) in kernels.get(k, scratch).1 {
                    a[c as usize] += w as f64;
                    b[c as usize] += (w * values[k]) as f64;
                }
            })
        };
        let whole = sum(&all);
        assert!(whole[0].iter().filter(|&&w| w > 0.0).count() > grid.len() / 2, "the samples reach the table");
        for kept in [0, 1, 8_191, 8_192, 12_345, at.len()] {
            let part = Kernels::Computed {
                cells: &cells[..offsets[kept]],
                offsets: &offsets[..=kept],
                corners: &corners[..kept],
                kg: &kg,
                at: &at,
            };
            let (mut s1, mut s2) = (Vec::new(), Vec::new());
            for k in 0..at.len() {
                let (c1, k1) = all.get(k, &mut s1);
                let (c2, k2) = part.get(k, &mut s2);
                assert_eq!((bits(&c1), bits(k1)), (bits(&c2), bits(k2)), "sample {k}, {kept} kept");
            }
            let partly = sum(&part);
            for (x, y) in whole.iter().flatten().zip(partly.iter().flatten()) {
                assert_eq!(x.to_bits(), y.to_bits(), "{kept} kept");
            }
        }
    }
}
