//! Fitting every point, in parallel, into compact per-point maps.

use brdf::ndf::{MaskingOperator, TableSet, TableSlot};
use rayon::prelude::*;

use crate::context::FitContext;
use crate::partial::{PointFit, PointSamples, PointStats, Sample, Scratch, fit_point, point_flag, refit_point};
use crate::samples::{SampleStore, flag};
use crate::settings::FitSettings;

/// Per-point results over the whole grid.
#[derive(Clone, Debug, PartialEq)]
pub struct PointMaps {
    pub kd: Vec<[f32; 3]>,
    pub ks: Vec<[f32; 3]>,
    pub eta: Vec<f32>,
    pub flags: Vec<u32>,
    pub tables: TableSet,
    pub stats: Vec<PointStats>,
}

impl PointMaps {
    pub fn len(&self) -> usize {
        self.kd.len()
    }

    /// `n` like points (kd 0.2, ks 0.1, index 1.5, empty tables on the
    /// default grid), for unit tests.
    #[cfg(test)]
    pub(crate) fn alike(n: usize) -> Self {
        PointMaps {
            kd: vec![[0.2; 3]; n],
            ks: vec![[0.1; 3]; n],
            eta: vec![1.5; n],
            flags: vec![0; n],
            tables: TableSet::new(brdf::ndf::NdfGrid::DEFAULT, n),
            stats: vec![Default::default(); n],
        }
    }

    pub fn is_empty(&self) -> bool {
        self.kd.is_empty()
    }

    /// The maps of consecutive tiles, in order, as one; `None` when their
    /// table grids differ.
    pub fn concat(parts: Vec<PointMaps>) -> Option<PointMaps> {
        let grid = parts.first()?.tables.grid();
        if parts.iter().any(|m| m.tables.grid() != grid) {
            return None;
        }
        let n = parts.iter().map(PointMaps::len).sum();
        let (mut values, mut coverage) = (Vec::new(), Vec::new());
        let mut all = PointMaps {
            kd: Vec::with_capacity(n),
            ks: Vec::with_capacity(n),
            eta: Vec::with_capacity(n),
            flags: Vec::with_capacity(n),
            tables: TableSet::new(grid, 0),
            stats: Vec::with_capacity(n),
        };
        for m in parts {
            let (v, c) = m.tables.raw();
            values.extend_from_slice(v);
            coverage.extend_from_slice(c);
            all.kd.extend(m.kd);
            all.ks.extend(m.ks);
            all.eta.extend(m.eta);
            all.flags.extend(m.flags);
            all.stats.extend(m.stats);
        }
        all.tables = TableSet::from_raw(grid, n, values, coverage)?;
        Some(all)
    }
}

/// Collect one point's usable samples with their noise variance (the
/// lights the settings do not hold out).
pub fn gather(ctx: &FitContext, store: &SampleStore, p: usize, settings: &FitSettings) -> PointSamples {
    gather_where(ctx, store, p, settings, |q| !settings.holds_out(&ctx.inputs.plan, q))
}

/// The samples of the model choice's held-out lights at point `p`
/// ([`FitSettings::choice_holds_out`]).
pub fn gather_choice_held_out(ctx: &FitContext, store: &SampleStore, p: usize, settings: &FitSettings) -> PointSamples {
    gather_where(ctx, store, p, settings, |q| settings.choice_holds_out(&ctx.inputs.plan, q))
}

/// How many lights ahead [`gather_where`] asks for a point's flags and
/// their places ([`SampleStore::prefetch`]); it asks for the reflectances
/// half as far ahead, where those places have arrived.
const PREFETCH_LIGHTS: usize = 8;

fn gather_where(
    ctx: &FitContext,
    store: &SampleStore,
    p: usize,
    settings: &FitSettings,
    keep: impl Fn(usize) -> bool,
) -> PointSamples {
    let inputs = &ctx.inputs;
    let noise = SampleNoise::new(ctx);
    let footprint = noise.footprint(ctx, p);
    let in_view = ctx.pixels[p].is_some() && settings.fits_point(&inputs.grid, p);
    let mut ps = PointSamples { o: ctx.view[p], in_view, ..PointSamples::default() };
    if !in_view {
        return ps;
    }
    ps.samples.reserve(ctx.n_lights());
    for q in 0..ctx.n_lights() {
        store.prefetch(q + PREFETCH_LIGHTS, p);
        store.prefetch_sample(q + PREFETCH_LIGHTS / 2, p);
        if !keep(q) {
            continue;
        }
        let (rho, fl) = store.get(q, p);
        if fl & (flag::OCCLUDED | flag::OUT_OF_VIEW | flag::DIM | flag::MISSING) == 0 {
            ps.lit += 1;
            if fl & flag::SATURATED != 0 {
                ps.saturated += 1;
            }
        }
        let Some((g, var)) = noise.usable(ctx, p, q, rho, fl, &footprint) else { continue };
        let kernel_rad = settings.kernel_scale * ctx.half_vector_spacing(p, q);
        ps.samples.push(Sample { i: g.i, rho, var: var.lum, channel_var: var.channel, kernel_rad });
    }
    ps
}

/// How a point's luminance and each of its channels take up each colour's
/// pixel noise ([`frame::Layout::sample_footprint`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Footprint {
    pub lum: [f32; 3],
    pub channel: [[f32; 3]; 3],
}

/// The variance of one sample's luminance and of each channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleVariance {
    pub lum: f32,
    pub channel: [f32; 3],
}

/// The noise of a capture's samples: shot and read noise of the sensor's
/// pixels carried through the demosaic, the bilinear sample, the
/// luminance weights, the exposure, gain and calibration into the
/// luminance reflectance.
#[derive(Clone, Debug)]
pub struct SampleNoise {
    exposures_us: Vec<u32>,
    gain: f32,
    read_dn: [f32; 3],
    e_per_dn: f32,
    layout: Option<frame::Layout>,
    size: (u32, u32),
    /// Read-noise variance of the dark level relative to one frame's: the
    /// mean of the plan's dark frames, or nothing where the calibration's
    /// black level stands in for them.
    dark_share: f32,
}

impl SampleNoise {
    pub fn new(ctx: &FitContext) -> Self {
        let inputs = &ctx.inputs;
        let camera = &inputs.geometry.camera;
        Self {
            exposures_us: inputs.plan.exposures_us.clone(),
            gain: inputs.plan.gain.max(crate::tol::MIN_DIVISOR),
            read_dn: inputs.calibration.read_noise_dn,
            e_per_dn: inputs.e_per_dn.max(crate::tol::MIN_DIVISOR),
            layout: inputs.sensor_layout,
            size: (camera.width, camera.height),
            dark_share: if inputs.plan.dark_frames > 0 { 1.0 / inputs.plan.dark_frames as f32 } else { 0.0 },
        }
    }

    /// How point `p`'s luminance and channels take up each colour's pixel
    /// noise ([`frame::Layout::sample_footprint`] at its pixel). A capture
    /// that does not record its sensor's layout gets the weights
    /// themselves: each value as noisy as one pixel, which for a Bayer
    /// sensor overstates the luminance's variance about fourfold
    /// (`tests/noise_model.rs`).
    pub fn footprint(&self, ctx: &FitContext, p: usize) -> Footprint {
        let at = |weights: [f32; 3]| {
            match (self.layout, ctx.pixels.get(p).copied().flatten()) {
                (Some(layout), Some(px)) => layout.sample_footprint(self.size.0, self.size.1, px.x, px.y, weights),
                _ => None,
            }
            .unwrap_or(weights)
        };
        Footprint {
            lum: at(crate::partial::LUMA),
            channel: [at([1.0, 0.0, 0.0]), at([0.0, 1.0, 0.0]), at([0.0, 0.0, 1.0])],
        }
    }

    /// Whether the sample of light `q` at point `p` (reflectance `rho`,
    /// flag byte `fl`) is one the fitter uses, and if so its geometry and
    /// the variances of its luminance and channel reflectances, for the
    /// point's noise `footprint` ([`SampleNoise::footprint`]).
    pub fn usable(
        &self,
        ctx: &FitContext,
        p: usize,
        q: usize,
        rho: [f32; 3],
        fl: u8,
        footprint: &Footprint,
    ) -> Option<(crate::context::SampleGeometry, SampleVariance)> {
        if fl & flag::UNUSABLE != 0 || rho.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let g = ctx.sample(p, q)?;
        let e = SampleStore::exposure_of(fl) as usize;
        let t = self.exposures_us.get(e).or(self.exposures_us.first()).copied().unwrap_or(1) as f32 * 1e-6;
        // rho = (DN - dark) k; a pixel of colour c has Var(DN) = read_c^2
        // + (DN - dark) gain / e_per_dn, with DN - dark about rho_c / k,
        // and the dark level, a mean of dark frames, read_c^2 / frames.
        let k = g.to_rho / (t * self.gain);
        let var = |f: &[f32; 3]| {
            let (mut read, mut shot) = (0.0f32, 0.0f32);
            for c in 0..3 {
                read += f[c] * self.read_dn[c] * self.read_dn[c];
                shot += f[c] * rho[c].max(0.0);
            }
            let v = k * k * read * (1.0 + self.dark_share) + k * shot * self.gain / self.e_per_dn;
            v.max(crate::tol::MIN_VARIANCE)
        };
        Some((g, SampleVariance { lum: var(&footprint.lum), channel: footprint.channel.each_ref().map(var) }))
    }
}

/// What [`fit_points`] and [`refit_completed`] keep of a point's fit once
/// its table is in its place in the maps' set. Each table goes there as
/// soon as its point is fitted: held until every point had been fitted,
/// the `f32` tables took 12 KB a point (7.9 GB at 800 x 800).
struct Placed {
    kd: [f32; 3],
    ks: [f32; 3],
    eta: f32,
    flags: u32,
    stats: PointStats,
}

impl Placed {
    fn place(f: PointFit, slot: &mut TableSlot) -> Self {
        slot.set(&f.table);
        Self::without_table(f)
    }

    fn without_table(f: PointFit) -> Self {
        Placed { kd: f.kd, ks: f.ks, eta: f.eta, flags: f.flags, stats: f.stats }
    }
}

/// Whether `t` is a table as [`TableSet::new`] makes it.
fn is_blank(t: &brdf::ndf::NdfTable) -> bool {
    t.values().iter().all(|v| v.to_bits() == 0) && t.coverage().count() == 0
}

/// Fit every point the store holds (parallel over points): the whole grid,
/// or one tile of it (the maps' entry `i` is then the tile's `i`-th point).
pub fn fit_points(ctx: &FitContext, store: &SampleStore, settings: &FitSettings, op: &MaskingOperator) -> PointMaps {
    let n = store.points().len();
    ctx.progress.begin(crate::FitStage::Points, n as u64);
    let mut tables = TableSet::new(settings.grid, n);
    let slots: Vec<TableSlot> = tables.slots().collect();
    let fits: Vec<Placed> = store
        .points()
        .into_par_iter()
        .zip(slots)
        .map_init(Scratch::default, |scratch, (p, mut slot)| {
            let ps = gather(ctx, store, p, settings);
            let f = fit_point(&ps, settings, op, scratch);
            ctx.progress.advance(1);
            // A blank table (a point without a fit) is left unwritten, as
            // the new set holds it, taking no memory.
            if is_blank(&f.table) { Placed::without_table(f) } else { Placed::place(f, &mut slot) }
        })
        .collect();
    let mut maps = PointMaps {
        kd: Vec::with_capacity(n),
        ks: Vec::with_capacity(n),
        eta: Vec::with_capacity(n),
        flags: Vec::with_capacity(n),
        tables,
        stats: Vec::with_capacity(n),
    };
    for f in fits {
        maps.kd.push(f.kd);
        maps.ks.push(f.ks);
        maps.eta.push(f.eta);
        maps.flags.push(f.flags);
        maps.stats.push(f.stats);
    }
    maps
}

/// After synthesis: refit the points whose NDF was completed (`added[p]`)
/// from their samples and completed table (which `maps.tables` holds for
/// them; [`refit_point`]), replacing their maps' entries; the others keep
/// their partial fit. Returns the number of points refitted.
pub fn refit_completed(
    ctx: &FitContext,
    store: &SampleStore,
    maps: &mut PointMaps,
    added: &[bool],
    settings: &FitSettings,
    op: &MaskingOperator,
) -> usize {
    let todo: Vec<(usize, TableSlot)> =
        maps.tables.slots().enumerate().filter(|&(p, _)| added.get(p).copied().unwrap_or(false)).collect();
    ctx.progress.begin(crate::FitStage::Refit, todo.len() as u64);
    let fits: Vec<(usize, Placed)> = todo
        .into_par_iter()
        .map_init(Scratch::default, |scratch, (p, mut slot)| {
            let ps = gather(ctx, store, p, settings);
            let f = refit_point(&ps, settings, op, scratch, &slot.get());
            ctx.progress.advance(1);
            (p, Placed::place(f, &mut slot))
        })
        .collect();
    for &(p, ref f) in &fits {
        maps.kd[p] = f.kd;
        maps.ks[p] = f.ks;
        maps.eta[p] = f.eta;
        maps.flags[p] = f.flags | point_flag::SYNTHESIZED;
        maps.stats[p] = f.stats;
    }
    fits.len()
}
