//! Streaming ingest: frames in any order become reflectance samples.
//!
//! - **Dark frames** (per exposure) are averaged into a per-pixel dark level;
//!   without them the calibration's black level is used.
//! - **Shots**: the frame is demosaiced once, each point's pixel is sampled
//!   bilinearly, the dark level and exposure are divided out, and the
//!   calibrated geometry turns the signal into reflectance.
//! - **HDR**: when a light has several exposures, the sample keeps the
//!   longest exposure that did not clip at that point. Its weight in a
//!   minimum-variance merge would be 8x that of the next bracket (brackets
//!   are 8x apart), so dropping the shorter ones costs at most 1/9 of the
//!   SNR while needing no per-sample accumulator. A sample clipped in every
//!   exposure is flagged saturated.
//! - **Drift**: each frame's reference patches are read as it arrives, and
//!   at the end every light's samples are divided by its LED's drift since
//!   the white scan ([`crate::drift`]).
//! - **Masks**: occluded by the bar, outside the camera's view, light at
//!   grazing incidence, or irradiance below [`DIM_FRACTION`] of the point's
//!   brightest light.
//!
//! The order of frames does not matter (a resumed capture replays stored
//! frames, then streams new ones), except that a dark frame must arrive
//! before the shots of its exposure for them to use it.

use frame::{Frame, RgbImage};
use half::f16;
use rayon::prelude::*;
use setup::PlannedShot;

use crate::context::FitContext;
use crate::samples::{SampleStore, flag};

/// A sample whose irradiance is below 2% of the point's brightest light is
/// flagged dim: at 2% of the peak the shot-noise SNR of a mid-grey diffuse
/// surface is about 7x worse than at the peak, and such samples add noise,
/// not information, to the diffuse and NDF estimates.
pub const DIM_FRACTION: f32 = 0.02;

/// Largest storable reflectance (f16's largest finite value is 65,504).
/// Reflectances of real surfaces stay below about 1e4 even for mirror-like
/// lobes seen by a camera pixel.
pub const MAX_RHO: f32 = 6.0e4;

/// The factor from a frame's DN to signal: per second of exposure at unit
/// gain.
pub fn per_second(meta: &frame::FrameMeta) -> f32 {
    1.0 / (meta.exposure_us.max(1) as f32 * 1e-6 * meta.gain.max(crate::tol::MIN_DIVISOR))
}

/// The mean of a set of dark frames (LEDs off) per pixel, demosaiced: the
/// sensor's black level and dark current and the room's light, pixel by
/// pixel.
#[derive(Clone, Debug, Default)]
pub struct DarkLevel {
    /// Sum and count of the frames.
    sum: Option<(RgbImage, u32)>,
}

impl DarkLevel {
    pub fn add(&mut self, frame: &Frame) {
        let img = frame.to_rgb();
        match &mut self.sum {
            None => self.sum = Some((img, 1)),
            Some((sum, n)) if sum.width == img.width && sum.height == img.height => {
                for (a, b) in sum.r.iter_mut().zip(&img.r) {
                    *a += b;
                }
                for (a, b) in sum.g.iter_mut().zip(&img.g) {
                    *a += b;
                }
                for (a, b) in sum.b.iter_mut().zip(&img.b) {
                    *a += b;
                }
                *n += 1;
            }
            // A frame of another size is not a dark frame of this camera.
            Some(_) => {}
        }
    }

    /// The mean dark level (DN) at a pixel; `None` without frames.
    pub fn at(&self, px: glam::Vec2) -> Option<[f32; 3]> {
        let (sum, n) = self.sum.as_ref()?;
        let (v, _) = sum.sample(px.x, px.y)?;
        let k = 1.0 / *n as f32;
        Some([v[0] * k, v[1] * k, v[2] * k])
    }
}

/// The dark level (DN) at a pixel for exposure `exposure`: the mean of its
/// dark frames, else `black` (the calibration's black level).
fn dark_level(dark: &[DarkLevel], exposure: u8, px: glam::Vec2, black: [f32; 3]) -> [f32; 3] {
    dark.get(exposure as usize).and_then(|d| d.at(px)).unwrap_or(black)
}

/// Where a capture's frames go: the ingest itself, or a pipeline that
/// times it (`crate::Pipeline`). Replaying a stored capture feeds either.
pub trait FrameSink {
    /// A dark frame of exposure index `exposure`.
    fn push_dark(&mut self, exposure: u8, frame: &Frame);
    /// A planned shot's frame.
    fn push_shot(&mut self, shot: &PlannedShot, frame: &Frame);
}

impl FrameSink for Ingest<'_> {
    fn push_dark(&mut self, exposure: u8, frame: &Frame) {
        Ingest::push_dark(self, exposure, frame);
    }
    fn push_shot(&mut self, shot: &PlannedShot, frame: &Frame) {
        Ingest::push_shot(self, shot, frame);
    }
}

#[derive(Debug)]
pub struct Ingest<'a> {
    ctx: &'a FitContext,
    store: SampleStore,
    /// Dark frames per exposure.
    dark: Vec<DarkLevel>,
    /// Brightest irradiance over all lights, per point.
    peak_irradiance: Vec<f32>,
    drift: crate::drift::DriftTrack,
    pub frames: u64,
}

impl<'a> Ingest<'a> {
    pub fn new(ctx: &'a FitContext) -> Self {
        Self::for_points(ctx, 0..ctx.n_points())
    }

    /// An ingest that keeps the samples of the grid's points `points` only
    /// (one tile of a fit spread over machines, [`crate::TilePipeline`]). Each
    /// point's samples are those the whole grid's ingest makes.
    pub fn for_points(ctx: &'a FitContext, points: std::ops::Range<usize>) -> Self {
        let peak_irradiance = points
            .clone()
            .into_par_iter()
            .map(|p| (0..ctx.n_lights()).filter_map(|q| ctx.sample(p, q)).map(|s| s.irradiance).fold(0.0f32, f32::max))
            .collect();
        Self {
            ctx,
            store: SampleStore::for_points(points, ctx.n_lights()),
            dark: vec![DarkLevel::default(); ctx.inputs.plan.exposures_us.len()],
            peak_irradiance,
            drift: crate::drift::DriftTrack::new(ctx),
            frames: 0,
        }
    }

    /// Add a dark frame taken at exposure index `exposure`.
    pub fn push_dark(&mut self, exposure: u8, frame: &Frame) {
        if let Some(d) = self.dark.get_mut(exposure as usize) {
            d.add(frame);
            self.frames += 1;
        }
    }

    /// Dark level (DN) at a pixel for an exposure.
    fn dark_at(&self, exposure: u8, px: glam::Vec2) -> [f32; 3] {
        dark_level(&self.dark, exposure, px, self.ctx.inputs.calibration.black_level)
    }

    /// Add the frame of a planned shot.
    pub fn push_shot(&mut self, shot: &PlannedShot, frame: &Frame) {
        let ctx = self.ctx;
        let Some(q) = ctx.inputs.plan.light_index(shot.step, shot.led) else { return };
        let exposures = &ctx.inputs.plan.exposures_us;
        let e = shot.exposure as usize;
        if e >= exposures.len() {
            return;
        }
        let img = frame.to_rgb();
        let (dark, black) = (&self.dark, ctx.inputs.calibration.black_level);
        self.drift.push(q, &img, |px| dark_level(dark, shot.exposure, px, black), &frame.meta);
        let scale = per_second(&frame.meta);
        let first = self.store.points().start;
        let darks: Vec<[f32; 3]> = ctx.pixels[self.store.points()]
            .iter()
            .map(|px| px.map_or([0.0; 3], |px| self.dark_at(shot.exposure, px)))
            .collect();
        let peak = &self.peak_irradiance;
        self.store.edit_row(q, |rho_row, flag_row| {
            rho_row.par_iter_mut().zip(flag_row.par_iter_mut()).enumerate().for_each(|(i, (rho, fl))| {
                let p = first + i;
                let Some(px) = ctx.pixels[p] else {
                    *fl = flag::OUT_OF_VIEW;
                    return;
                };
                let Some(g) = ctx.sample(p, q) else {
                    *fl = flag::DIM;
                    return;
                };
                if g.occluded {
                    *fl = flag::OCCLUDED;
                    return;
                }
                if g.irradiance < DIM_FRACTION * peak[i] {
                    *fl = flag::DIM;
                    return;
                }
                let Some((v, clipped)) = img.sample(px.x, px.y) else {
                    *fl = flag::OUT_OF_VIEW;
                    return;
                };
                // Keep the longest unclipped exposure (module docs).
                let prev_missing = *fl & flag::MISSING != 0;
                let prev_sat = *fl & flag::SATURATED != 0;
                let prev_e = SampleStore::exposure_of(*fl) as usize;
                let longer = exposures[e] > exposures[prev_e.min(exposures.len() - 1)];
                let take = prev_missing
                    || (prev_sat && !clipped)
                    || (!prev_sat && !clipped && longer)
                    || (prev_sat && clipped && !longer);
                if !take {
                    return;
                }
                let d = darks[i];
                let k = scale * g.to_rho;
                let r = [(v[0] - d[0]) * k, (v[1] - d[1]) * k, (v[2] - d[2]) * k];
                // A reflectance beyond f16's range means the calibration does
                // not describe this rig; such a sample is unusable, not infinite.
                let out_of_range = r.iter().any(|x| !(x.abs() < MAX_RHO));
                *rho = r.map(|x| f16::from_f32(x.clamp(-MAX_RHO, MAX_RHO)));
                *fl = ((e as u8) << flag::EXPOSURE_SHIFT) | if clipped || out_of_range { flag::SATURATED } else { 0 };
            });
        });
        self.frames += 1;
    }

    /// The samples, each light's divided by its LED's drift, and what the
    /// drift correction did (`None` on a rig without reference patches).
    pub fn finish(self) -> (SampleStore, Option<crate::drift::DriftSummary>) {
        let mut store = self.store;
        if self.drift.is_empty() {
            return (store, None);
        }
        let summary = self.drift.apply(self.ctx, &mut store);
        (store, Some(summary))
    }

    pub fn store(&self) -> &SampleStore {
        &self.store
    }
}
