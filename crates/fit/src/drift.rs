//! LED intensity drift during a capture, measured from the rig's white
//! reference patches (`setup::ReferencePatch`) in the frames themselves.
//!
//! An LED's output falls as the bar warms (a few per cent on a real bar),
//! so a capture taken on a cold bar after a white scan on a warm one, or
//! one that warms as it goes, reads every reflectance high or low by that
//! much, differently for each LED and over time. Every frame of a capture
//! also shows the patches beside the sample, lit by the same LED, so:
//!
//! - a patch's **reading** in a frame is its signal summed over the pixels
//!   that see only it, over the irradiance the calibrated geometry gives
//!   those points (profile, incidence, distance; the LED's intensity left
//!   out): the patch's albedo times the LED's intensity at that moment;
//! - the white scan keeps each patch's reading of each LED at each of its
//!   carriage positions ([`DriftTrack::reference`]);
//! - in a capture, a reading over the white scan's at the same carriage
//!   position (interpolated between its steps) is the LED's intensity now
//!   relative to then: the drift. The patch's albedo cancels, and so does
//!   any error of the calibrated geometry, which is the same at the same
//!   position. Each light's samples are divided by it
//!   ([`DriftTrack::apply`]).
//!
//! A light's estimate combines the patches by their shot and read noise.
//! One frame's is noisy where the patches are far from the bar (dimly lit),
//! so the estimates are not used one by one: the LEDs share one bar, whose
//! temperature sets how far each has drifted, so the model is
//! `ln drift = a_k t_s`, one warmth `t_s` per gantry step shared by all
//! LEDs (0 at the white scan's) and a sensitivity per LED ([`shared_drift`],
//! fitted to every reading at once by weighted alternating least squares;
//! with no drift to see, its estimate is a product of two noises). A patch
//! hidden from the camera by the bar, clipped in every exposure, lit from
//! below [`crate::context::MIN_COS_I`] or noisier than [`MAX_READING_SD`]
//! gives no reading for that light.
//!
//! What it assumes: the patches' albedo does not change between the white
//! scan and the capture (keep them clean); the LEDs' colour does not drift
//! (one factor for all three channels); and the white scan's LEDs held
//! their intensity through the scan, so that each position's reading
//! stands for the LED's calibrated intensity (which is their mean). A white
//! scan on a warm bar (after the geometric scan, as `capture --calibrate
//! all` runs them) does; one started on a cold bar drifts by a fraction of
//! the bar's range over its minute, and that fraction, position by
//! position, is what the correction then gets wrong.

use frame::RgbImage;
use glam::{Vec2, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use setup::RigGeometry;

use crate::context::{FitContext, OCCLUSION_MARGIN_MM, light_at};
use crate::samples::SampleStore;

/// A patch's reading noisier than this (relative standard deviation from
/// shot and read noise) is left out: such a patch is far from the bar, at
/// a few electrons per pixel, where a tenth of a DN of error in the dark
/// level biases the reading by more than its noise.
pub const MAX_READING_SD: f64 = 0.03;

/// The bar's warmth at a step is a straight line through its estimates
/// at the steps this far on either side (a step takes a second or two, the
/// bar warms over minutes).
const WARMTH_STEPS: usize = 3;

/// The white scan's readings of a patch are smoothed along the travel over
/// this many of its positions on either side (5 mm apart on the default
/// rig: the irradiance a misplaced LED gives a patch changes over tens of
/// millimetres).
const REFERENCE_STEPS: usize = 2;

/// Rounds of the alternating least squares of [`shared_drift`] (each
/// lowers its weighted residual; 20 leave it changing by under 1e-6 of
/// itself on simulated captures).
const DRIFT_ITERATIONS: usize = 20;

/// A patch of which fewer pixels see only it is not read (a patch at the
/// edge of the view, or one the camera hardly resolves).
pub const MIN_PIXELS: usize = 16;

/// The pixels that see only one patch: each pixel's centre and the point
/// of the sample plane it sees.
pub type PatchPixels = Vec<(Vec2, Vec3)>;

/// How far, in pixels, a patch pixel's value reaches: it is read at its
/// centre (no interpolation), its demosaiced value takes each colour from
/// the pixels within one pixel, and each of those integrates half a pixel
/// beyond its centre.
pub const PATCH_REACH: f32 = 1.5;

/// For each of the geometry's reference patches, the pixels whose reach
/// ([`PATCH_REACH`]) lies on it; a patch with fewer than [`MIN_PIXELS`] has
/// none.
pub fn patch_pixels(g: &RigGeometry) -> Vec<PatchPixels> {
    let cam = &g.camera;
    g.references
        .iter()
        .map(|r| {
            let h = 0.5 * r.size_mm;
            let corners = [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
                .map(|(sx, sy)| cam.project((r.centre_mm + Vec2::new(sx * h.x, sy * h.y)).extend(0.0)));
            let Some(c) = corners.into_iter().collect::<Option<Vec<Vec2>>>() else { return Vec::new() };
            let lo = c.iter().fold(Vec2::splat(f32::MAX), |a, &b| a.min(b)).max(Vec2::ZERO);
            let hi = c
                .iter()
                .fold(Vec2::splat(f32::MIN), |a, &b| a.max(b))
                .min(Vec2::new(cam.width as f32, cam.height as f32));
            let mut out = Vec::new();
            for v in lo.y as u32..hi.y.ceil().max(0.0) as u32 {
                for u in lo.x as u32..hi.x.ceil().max(0.0) as u32 {
                    let px = Vec2::new(u as f32 + 0.5, v as f32 + 0.5);
                    let inside = |d: Vec2| cam.pixel_to_plane(px + d).is_some_and(|q| r.contains(q, 0.0));
                    let within_frame = px.cmpge(Vec2::splat(PATCH_REACH)).all()
                        && px.cmple(Vec2::new(cam.width as f32, cam.height as f32) - PATCH_REACH).all();
                    if within_frame
                        && [(-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0), (1.0, 1.0)]
                            .into_iter()
                            .all(|(sx, sy)| inside(PATCH_REACH * Vec2::new(sx, sy)))
                        && let Some(q) = cam.pixel_to_plane(px)
                    {
                        out.push((px, q.extend(0.0)));
                    }
                }
            }
            if out.len() < MIN_PIXELS { Vec::new() } else { out }
        })
        .collect()
}

/// One patch in one frame: its signal summed over its pixels (DN per
/// second at unit gain, the mean of the three channels, dark level
/// subtracted) and that sum's variance from shot and read noise.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Reading {
    pub signal: f32,
    pub var: f32,
}

/// The sensor's noise, for weighing readings: electrons per DN at unit
/// gain and read noise in DN.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Noise {
    pub e_per_dn: f32,
    pub read_dn: f32,
}

/// Read a patch off a frame (`scale` = 1 / (exposure_s x gain), `dark` the
/// dark level at a pixel); `None` if any of its pixels clipped or it has
/// none.
pub fn read(
    pixels: &[(Vec2, Vec3)],
    img: &RgbImage,
    dark: impl Fn(Vec2) -> [f32; 3],
    scale: f32,
    gain: f32,
    noise: Noise,
) -> Option<Reading> {
    if pixels.is_empty() {
        return None;
    }
    let (mut sum, mut var) = (0.0f64, 0.0f64);
    for &(px, _) in pixels {
        let (v, clipped) = img.sample(px.x, px.y)?;
        if clipped {
            return None;
        }
        let d = dark(px);
        let lum = ((v[0] - d[0]) + (v[1] - d[1]) + (v[2] - d[2])) / 3.0;
        sum += lum as f64;
        // DN = electrons x gain / e_per_dn: a count of `lum` DN has
        // variance `lum x gain / e_per_dn` from shot noise.
        let dn_per_e = gain as f64 / noise.e_per_dn.max(crate::tol::MIN_DIVISOR) as f64;
        var += lum.max(0.0) as f64 * dn_per_e + (noise.read_dn as f64).powi(2);
    }
    let s = scale as f64;
    Some(Reading { signal: (sum * s) as f32, var: (var * s * s) as f32 })
}

/// The irradiance a patch's points get from an LED at `pos` shining along
/// `axis` (profile exponent `profile`, unit intensity), summed over its
/// pixels; `None` if the bar at `bar_x_mm` hides any of them from the
/// camera or the light grazes the patch.
pub fn irradiance(
    pixels: &[(Vec2, Vec3)],
    g: &RigGeometry,
    bar_x_mm: f32,
    pos: Vec3,
    axis: Vec3,
    profile: f32,
) -> Option<f32> {
    let mut sum = 0.0f32;
    for &(_, x) in pixels {
        let (i, r2, cos_emit) = light_at(x, pos, axis)?;
        if g.bar.occludes(bar_x_mm, x, g.camera.position_mm, OCCLUSION_MARGIN_MM) {
            return None;
        }
        sum += cos_emit.powf(profile) * i.z / r2;
    }
    (sum > 0.0 && sum.is_finite()).then_some(sum)
}

/// Each patch's best reading of each light of a plan: the longest exposure
/// that did not clip (the most light, as for the samples).
#[derive(Clone, Debug)]
pub struct DriftTrack {
    pixels: Vec<PatchPixels>,
    noise: Noise,
    n_lights: usize,
    /// `[patch][light]`: the reading and its exposure, µs.
    readings: Vec<Option<(Reading, u32)>>,
}

impl DriftTrack {
    /// For the plan, geometry and sensor of `ctx`.
    pub fn new(ctx: &FitContext) -> Self {
        let pixels = patch_pixels(&ctx.inputs.geometry);
        let noise = Noise {
            e_per_dn: ctx.inputs.e_per_dn,
            read_dn: ctx.inputs.calibration.read_noise_dn.iter().sum::<f32>() / 3.0,
        };
        let n_lights = ctx.n_lights();
        Self { readings: vec![None; pixels.len() * n_lights], pixels, noise, n_lights }
    }

    /// Whether the rig has no reference patches at all.
    pub fn is_empty(&self) -> bool {
        self.pixels.is_empty()
    }

    /// Read every patch off the frame of light `q`.
    pub fn push(&mut self, q: usize, img: &RgbImage, dark: impl Fn(Vec2) -> [f32; 3], meta: &frame::FrameMeta) {
        if q >= self.n_lights {
            return;
        }
        let (scale, gain) = (crate::ingest::per_second(meta), meta.gain.max(crate::tol::MIN_DIVISOR));
        for (p, px) in self.pixels.iter().enumerate() {
            let Some(r) = read(px, img, &dark, scale, gain, self.noise) else { continue };
            let slot = &mut self.readings[p * self.n_lights + q];
            if slot.is_none_or(|(_, e)| meta.exposure_us > e) {
                *slot = Some((r, meta.exposure_us));
            }
        }
    }

    /// Patch `p`'s reading of light `q` over its irradiance with the LED at
    /// `pos` (unit intensity, profile exponent `profile`), and that ratio's
    /// relative variance.
    fn ratio(&self, ctx: &FitContext, p: usize, q: usize, pos: Vec3, profile: f32) -> Option<(f64, f64)> {
        let (r, _) = self.readings[p * self.n_lights + q]?;
        let l = &ctx.lights[q];
        let e = irradiance(&self.pixels[p], &ctx.inputs.geometry, l.bar_x_mm, pos, ctx.led_axis, profile)?;
        let m = r.signal as f64 / e as f64;
        let rv = r.var as f64 / (r.signal as f64).powi(2);
        (m > 0.0 && m.is_finite() && rv <= MAX_READING_SD * MAX_READING_SD).then_some((m, rv))
    }

    /// The white scan's part: each patch's reading of each light (LED
    /// positions `pos(q)` and the profile exponent as the scan solved
    /// them), as `[patch][led][step]` readings and their relative
    /// variances, 0 where unread.
    pub fn reference(
        &self,
        ctx: &FitContext,
        n_leds: usize,
        pos: impl Fn(usize) -> Vec3 + Sync,
        profile: f32,
    ) -> (Vec<Vec<Vec<f32>>>, Vec<Vec<Vec<f32>>>) {
        let steps = ctx.inputs.plan.steps as usize;
        let mut reading = vec![vec![vec![0.0f32; steps]; n_leds]; self.pixels.len()];
        let mut rel_var = reading.clone();
        for p in 0..self.pixels.len() {
            let read: Vec<Option<(f64, f64)>> =
                (0..self.n_lights).into_par_iter().map(|q| self.ratio(ctx, p, q, pos(q), profile)).collect();
            let mut by_led = vec![vec![None; steps]; n_leds];
            for (q, r) in read.into_iter().enumerate() {
                let l = &ctx.lights[q];
                if let (Some((m, rv)), true) = (r, (l.led as usize) < n_leds && (l.step as usize) < steps) {
                    by_led[l.led as usize][l.step as usize] = Some((m.ln(), 1.0 / rv.max(1e-12)));
                }
            }
            // Smoothed along the travel: the calibrated geometry's errors
            // change the reading smoothly with the position (and must be
            // kept: they cancel against the capture's), the noise does not.
            for (k, row) in by_led.iter().enumerate() {
                for (j, v) in smooth_weighted(row, REFERENCE_STEPS).into_iter().enumerate() {
                    if let Some((y, w)) = v {
                        reading[p][k][j] = y.exp() as f32;
                        rel_var[p][k][j] = (1.0 / w) as f32;
                    }
                }
            }
        }
        (reading, rel_var)
    }

    /// The capture's part: each light's LED intensity relative to the
    /// calibration's, from the model of [`shared_drift`], or `None` where
    /// the calibration has no usable reference or the LED was never read.
    pub fn factors(&self, ctx: &FitContext) -> Vec<Option<f32>> {
        let n = self.n_lights;
        let reference = ctx
            .inputs
            .calibration
            .drift_reference
            .as_ref()
            .filter(|d| d.patches == ctx.inputs.geometry.references && d.reading.len() == self.pixels.len());
        let Some(reference) = reference else { return vec![None; n] };
        let profile = ctx.inputs.calibration.profile_exponent;
        // ln(drift) and its weight per light, the patches combined.
        let est: Vec<(f64, f64)> = ctx
            .lights
            .par_iter()
            .enumerate()
            .map(|(q, l)| {
                let mut e = (0.0f64, 0.0f64);
                for p in 0..self.pixels.len() {
                    let Some((white, white_rv)) = reference.at(p, l.led, l.bar_x_mm) else { continue };
                    let Some((m, rv)) = self.ratio(ctx, p, q, l.pos, profile) else { continue };
                    let w = 1.0 / (rv + white_rv).max(1e-12);
                    e.0 += w * (m.ln() - white);
                    e.1 += w;
                }
                e
            })
            .collect();
        let plan = &ctx.inputs.plan;
        let obs: Vec<Option<(f64, f64)>> =
            est.into_iter().map(|(s, w)| (w > 0.0 && s.is_finite()).then(|| (s / w, w))).collect();
        shared_drift(&obs, plan.steps as usize, plan.leds.len())
            .into_iter()
            .map(|v| v.map(|v| v.exp() as f32).filter(|f| f.is_finite() && *f > 0.0))
            .collect()
    }

    /// Divide each light's samples by its drift; what was done, for the
    /// report.
    pub fn apply(&self, ctx: &FitContext, store: &mut SampleStore) -> DriftSummary {
        let factors = self.factors(ctx);
        let known: Vec<f32> = factors.iter().flatten().copied().collect();
        for (q, f) in factors.iter().enumerate() {
            let Some(f) = f else { continue };
            let k = 1.0 / f;
            for r in store.held_rho_mut(q) {
                *r = r.map(|x| {
                    half::f16::from_f32((x.to_f32() * k).clamp(-crate::ingest::MAX_RHO, crate::ingest::MAX_RHO))
                });
            }
        }
        let (lowest, highest, mean) = if known.is_empty() {
            (1.0, 1.0, 1.0)
        } else {
            let (lo, hi) = known.iter().fold((f32::MAX, f32::MIN), |(a, b), &f| (a.min(f), b.max(f)));
            (lo, hi, known.iter().sum::<f32>() / known.len() as f32)
        };
        DriftSummary {
            patches: self.pixels.len(),
            patches_read: self.pixels.iter().filter(|p| !p.is_empty()).count(),
            lights_corrected: known.len(),
            lights: factors.len(),
            lowest,
            highest,
            mean,
        }
    }
}

/// What the drift correction did to a capture: the LEDs' intensity relative
/// to the white scan's, over the lights it corrected.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DriftSummary {
    /// The rig file's reference patches, and those of them with enough
    /// pixels in view to be read ([`MIN_PIXELS`]).
    pub patches: usize,
    pub patches_read: usize,
    pub lights_corrected: usize,
    pub lights: usize,
    pub lowest: f32,
    pub highest: f32,
    pub mean: f32,
}

/// The model of the module docs, `ln drift = a_k t_s`, fitted to
/// `obs[step * n_leds + led]` (`ln drift` and its weight; `None` where
/// unread): the model's value for every light, `None` for an LED never
/// read. A step no LED was read at takes the warmth of the nearest step
/// read (the bar warms slowly).
pub fn shared_drift(obs: &[Option<(f64, f64)>], steps: usize, n_leds: usize) -> Vec<Option<f64>> {
    let at = |s: usize, k: usize| obs.get(s * n_leds + k).copied().flatten();
    let read_led: Vec<bool> = (0..n_leds).map(|k| (0..steps).any(|s| at(s, k).is_some())).collect();
    let mut slope = vec![1.0f64; n_leds];
    let mut warmth = vec![None::<f64>; steps];
    for _ in 0..DRIFT_ITERATIONS {
        // Each step's warmth from every LED read there.
        for (s, t) in warmth.iter_mut().enumerate() {
            let (mut num, mut den) = (0.0, 0.0);
            for (k, a) in slope.iter().enumerate() {
                if let Some((y, w)) = at(s, k) {
                    num += w * a * y;
                    den += w * a * a;
                }
            }
            *t = (den > 0.0).then(|| num / den);
        }
        // The bar warms over minutes, a step takes a second or two: the
        // warmth is smooth over neighbouring steps.
        warmth = smooth(&warmth, WARMTH_STEPS);
        let read: Vec<f64> = warmth.iter().flatten().copied().collect();
        if read.is_empty() {
            return vec![None; obs.len()];
        }
        // The model is the same for any scale of the warmth: unit spread.
        let rms = (read.iter().map(|t| t * t).sum::<f64>() / read.len() as f64).sqrt();
        let rms = if rms > 1e-12 { rms } else { 1.0 };
        warmth.iter_mut().flatten().for_each(|t| *t /= rms);
        // Each LED's sensitivity: weighted least squares through 0.
        for (k, a) in slope.iter_mut().enumerate() {
            let (mut sxx, mut sxy) = (0.0, 0.0);
            for (s, t) in warmth.iter().enumerate() {
                if let (Some((y, w)), Some(x)) = (at(s, k), *t) {
                    sxx += w * x * x;
                    sxy += w * x * y;
                }
            }
            *a = if sxx > 0.0 { sxy / sxx } else { 0.0 };
        }
    }
    // Steps never read: the nearest read step's warmth.
    let read: Vec<usize> = (0..steps).filter(|&s| warmth[s].is_some()).collect();
    let filled: Vec<f64> = (0..steps)
        .map(|s| {
            let near = read.iter().min_by_key(|&&r| r.abs_diff(s)).copied().unwrap_or(s);
            warmth.get(near).copied().flatten().unwrap_or(0.0)
        })
        .collect();
    (0..steps * n_leds)
        .map(|q| {
            let k = q % n_leds;
            read_led[k].then(|| slope[k] * filled[q / n_leds])
        })
        .collect()
}

/// Each read value replaced by the straight line through the read values
/// within `half` places on either side (unweighted), read at its place.
fn smooth(v: &[Option<f64>], half: usize) -> Vec<Option<f64>> {
    let weighted: Vec<Option<(f64, f64)>> = v.iter().map(|y| y.map(|y| (y, 1.0))).collect();
    smooth_weighted(&weighted, half).into_iter().map(|e| e.map(|(y, _)| y)).collect()
}

/// Each read value replaced by the weighted straight line through the read
/// values within `half` places on either side, read at its place, with the
/// weight of their sum (their noise averaged, not the line's own).
fn smooth_weighted(v: &[Option<(f64, f64)>], half: usize) -> Vec<Option<(f64, f64)>> {
    (0..v.len())
        .map(|i| {
            v[i]?;
            let (lo, hi) = (i.saturating_sub(half), (i + half).min(v.len() - 1));
            let (mut sw, mut sx, mut sy, mut sxx, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for (j, e) in v.iter().enumerate().take(hi + 1).skip(lo) {
                if let Some((y, w)) = e {
                    let x = j as f64 - i as f64;
                    sw += w;
                    sx += w * x;
                    sy += w * y;
                    sxx += w * x * x;
                    sxy += w * x * y;
                }
            }
            let det = sw * sxx - sx * sx;
            let y = if det > 1e-9 * sw * sw { (sy * sxx - sx * sxy) / det } else { sy / sw };
            Some((y, sw))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Readings made exactly from the model, with holes (steps where the
    /// bar hid every patch, an LED never read), give the model back.
    #[test]
    fn the_shared_warmth_model_is_recovered_from_incomplete_readings() {
        let (steps, leds) = (30usize, 6usize);
        let warmth = |s: usize| 1.0 - (-(s as f64) / 12.0).exp();
        let sens = |k: usize| -0.02 - 0.004 * k as f64;
        // Against a white scan at warmth 0.6.
        let truth = |s: usize, k: usize| sens(k) * (warmth(s) - 0.6);
        // A straight line through `WARMTH_STEPS` steps on either side is off
        // an exponential by at most its curvature (largest at step 0,
        // 1/144) times half the window's square; each LED sees that times
        // its sensitivity.
        let bend = |k: usize| sens(k).abs() * (1.0 / 144.0) * (WARMTH_STEPS * WARMTH_STEPS) as f64 / 2.0 + 1e-9;
        let obs: Vec<Option<(f64, f64)>> = (0..steps * leds)
            .map(|q| {
                let (s, k) = (q / leds, q % leds);
                let hidden = (10..13).contains(&s) || k == 5 || (s + k) % 7 == 0;
                (!hidden).then(|| (truth(s, k), 1.0 + (q % 3) as f64))
            })
            .collect();
        let fitted = shared_drift(&obs, steps, leds);
        for (q, f) in fitted.iter().enumerate() {
            let (s, k) = (q / leds, q % leds);
            // Hidden steps take the nearest step's warmth.
            let near = match s {
                10 | 11 => 9,
                12 => 13,
                _ => s,
            };
            match f {
                None => assert_eq!(k, 5, "only the LED never read has no estimate"),
                Some(v) => assert!((v - truth(near, k)).abs() < bend(k), "{s} {k}: {v}"),
            }
        }
    }
}
