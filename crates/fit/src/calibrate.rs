//! Radiometric calibration from a white diffuse reference of known albedo
//! `a` (see `setup::calibration` for the model).
//!
//! With a nominal calibration (`S_q = 1`, `F = 1`, profile exponent `m0`),
//! each (point, light) sample of the white reference gives
//! `M = rho_nominal * pi / a = S_q F(x) cos_emit^(m - m0)`.
//! In logarithms, `ln M = ln S_q + ln F(x) + (m - m0) ln cos_emit`, which
//! alternating least squares solves exactly (each step is the closed-form
//! minimiser of one block with the others fixed), with `mean ln F = 0`
//! fixing the split between LEDs and flat field.

use frame::Frame;
use glam::Vec3;
use rayon::prelude::*;
use setup::{Calibration, PlannedShot};

use crate::context::FitContext;

/// Iterations of the alternating least squares (the residual stops
/// changing after about 10 on simulated and real-sized rigs); run twice,
/// the second time without outliers.
const ALS_ITERATIONS: usize = 25;

/// Samples whose log residual exceeds this many robust standard deviations
/// (1.4826 x the median absolute residual) after the first pass are
/// dropped: pixels at the edge of the bar's shadow or of a speck on the
/// reference, which a multiplicative model cannot explain.
const OUTLIER_SIGMAS: f64 = 4.0;

/// Samples with the camera's view this close to the bar's edge are not used
/// (the pixel footprint straddles the shadow).
const SHADOW_MARGIN_MM: f32 = 3.0;

/// Collects the signal of every usable white sample; [`WhiteAccumulator::solve`]
/// turns it into `ln M` and `ln cos_emit` with the rig's geometry.
#[derive(Debug)]
pub struct WhiteAccumulator<'a> {
    ctx: &'a FitContext,
    albedo: f32,
    /// `[light][point]`: `ln(signal pi / a)`, NaN where unusable.
    signal: Vec<f32>,
    black: [f32; 3],
    /// Dark frames taken with the scan, if any (else `black` is subtracted).
    dark: crate::ingest::DarkLevel,
    peak: Vec<f32>,
    /// The reference patches' readings (`crate::drift`).
    patches: crate::drift::DriftTrack,
}

/// The white scan's plan: every LED at 48 carriage positions over the
/// whole travel, at the rig's default exposure and gain.
pub fn white_plan(g: &setup::RigGeometry, exposure_us: u32, gain: f32) -> setup::CapturePlan {
    setup::CapturePlan {
        steps: 48,
        first_mm: g.gantry.travel_min_mm,
        last_mm: g.gantry.travel_max_mm,
        leds: (0..g.bar.n_leds).collect(),
        exposures_us: vec![exposure_us],
        gain,
        dark_frames: 0,
        bracket: setup::Bracket::Every,
    }
}

/// The points the white scan solves the flat field on.
pub const WHITE_GRID: setup::PointGrid = setup::PointGrid { cols: 24, rows: 24 };

/// Only samples lit at least this bright (relative to the point's brightest
/// light) are used: dimmer ones carry shot noise of several per cent and
/// add nothing the brighter ones do not measure better.
const MIN_RELATIVE_IRRADIANCE: f32 = 0.1;

/// The white scan searches the scale a mirror scan leaves open within this
/// many of its standard deviations (`setup::LightCalibration::scale_sd`).
pub const SCALE_SEARCH_SDS: f64 = 4.0;

impl<'a> WhiteAccumulator<'a> {
    /// `ctx` must be built with a nominal calibration (unit LED scale, no
    /// flat field) and the black level of a dark calibration.
    pub fn new(ctx: &'a FitContext, albedo: f32) -> Self {
        let n = ctx.n_points() * ctx.n_lights();
        let peak = (0..ctx.n_points())
            .into_par_iter()
            .map(|p| (0..ctx.n_lights()).filter_map(|q| ctx.sample(p, q)).map(|s| s.irradiance).fold(0.0f32, f32::max))
            .collect();
        Self {
            ctx,
            albedo,
            signal: vec![f32::NAN; n],
            black: ctx.inputs.calibration.black_level,
            dark: Default::default(),
            peak,
            patches: crate::drift::DriftTrack::new(ctx),
        }
    }

    /// Add a frame taken with every LED off, at the scan's exposure: the
    /// mean of these is subtracted pixel by pixel (dark current, hot
    /// pixels and the room's light, which a black level leaves in), from
    /// the shots pushed after them.
    pub fn push_dark(&mut self, f: &Frame) {
        self.dark.add(f);
    }

    pub fn push_shot(&mut self, shot: &PlannedShot, f: &Frame) {
        let ctx = self.ctx;
        let Some(q) = ctx.inputs.plan.light_index(shot.step, shot.led) else { return };
        let img = f.to_rgb();
        let (dark, black) = (&self.dark, self.black);
        self.patches.push(q, &img, |px| dark.at(px).unwrap_or(black), &f.meta);
        let scale = crate::ingest::per_second(&f.meta);
        let k = std::f32::consts::PI / self.albedo;
        let peak = &self.peak;
        let n = ctx.n_points();
        self.signal[q * n..(q + 1) * n].par_iter_mut().enumerate().for_each(|(p, slot)| {
            let (Some(px), Some(g)) = (ctx.pixels[p], ctx.sample(p, q)) else { return };
            let geo = &ctx.inputs.geometry;
            let light = &ctx.lights[q];
            if g.irradiance < MIN_RELATIVE_IRRADIANCE * peak[p]
                || geo.bar.occludes(light.bar_x_mm, ctx.positions[p], geo.camera.position_mm, SHADOW_MARGIN_MM)
            {
                return;
            }
            let Some((v, clipped)) = img.sample(px.x, px.y) else { return };
            if clipped {
                return;
            }
            let black = dark.at(px).unwrap_or(black);
            let lum = (0..3).map(|c| v[c] - black[c]).sum::<f32>() / 3.0;
            let m = lum * scale * k;
            if m > 0.0 && m.is_finite() {
                *slot = m.ln();
            }
        });
    }

    /// `(ln M, ln cos_emit)` of every sample (NaN `ln M` where unusable)
    /// with the LEDs scaled by `alpha` about `centre`, then each moved by
    /// its entry of `moved` (indexed by LED; none where it is short).
    fn log_data(&self, centre: Vec3, alpha: f32, moved: &[Vec3]) -> Vec<(f32, f32)> {
        let ctx = self.ctx;
        let np = ctx.n_points();
        let mut out = vec![(f32::NAN, 0.0f32); self.signal.len()];
        out.par_chunks_mut(np).enumerate().for_each(|(q, row)| {
            let pos = white_position(ctx.lights[q].pos, ctx.lights[q].led, centre, alpha, moved);
            for (p, slot) in row.iter_mut().enumerate() {
                let s = self.signal[q * np + p];
                if !s.is_finite() {
                    continue;
                }
                if let Some(g) = ctx.sample_from(p, q, pos) {
                    *slot = (s + g.to_rho.ln(), g.cos_emit.ln());
                }
            }
        });
        out
    }

    /// Solve for LED scales, flat field and profile exponent. With a
    /// mirror scan's LEDs in `base`, first the one scale the mirror could
    /// not see (`fit::mirror`): the LEDs scaled about the camera's mirror
    /// image to where the white's light falls as the model says (the
    /// smallest residual, by golden-section search within
    /// [`SCALE_SEARCH_SDS`] of the mirror's estimate; the light's fall-off
    /// across the sample changes with the LEDs' distance in a way no LED
    /// intensity, flat field or profile can take up), over the lights of
    /// the LEDs the mirror measured.
    pub fn solve(&self, base: &Calibration, id: String) -> Option<Calibration> {
        let (nq, np) = (self.ctx.n_lights(), self.ctx.n_points());
        let centre = crate::mirror::camera_image(self.ctx.inputs.geometry.camera.position_mm);
        let mut data = self.log_data(centre, 1.0, &[]);
        if data.iter().filter(|d| d.0.is_finite()).count() < (nq + np) * 2 {
            return None;
        }
        let mut ls = vec![0.0f64; nq];
        let mut lf = vec![0.0f64; np];
        let mut dm = 0.0f64;
        // First pass: the outliers, which every later solve leaves out.
        als(&data, nq, np, &mut ls, &mut lf, &mut dm);
        let mut abs: Vec<f64> = residuals(&data, nq, np, &ls, &lf, dm).map(|r| r.abs()).collect();
        let k = abs.len() / 2;
        let mad = *abs.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1;
        let limit = OUTLIER_SIGMAS * 1.4826 * mad.max(crate::tol::MIN_MAD);
        let mut kept = vec![true; nq * np];
        for q in 0..nq {
            for p in 0..np {
                let (lm, lc) = data[q * np + p];
                if lm.is_finite() && ((lm as f64 - ls[q] - lf[p] - dm * lc as f64).abs() > limit) {
                    kept[q * np + p] = false;
                    data[q * np + p].0 = f32::NAN;
                }
            }
        }
        let drop = |mut d: Vec<(f32, f32)>| {
            d.iter_mut().zip(&kept).filter(|(_, k)| !**k).for_each(|(v, _)| v.0 = f32::NAN);
            d
        };
        let mut alpha = 1.0f64;
        if let Some(lights) = base.lights.as_ref().filter(|l| l.scale_sd > 0.0) {
            let counted: Vec<bool> = self.ctx.lights.iter().map(|l| lights.measured.contains(&l.led)).collect();
            let (ls0, lf0, dm0) = (ls.clone(), lf.clone(), dm);
            let cost = |a: f64| {
                let d = drop(self.log_data(centre, a as f32, &[]));
                let (mut ls, mut lf, mut dm) = (ls0.clone(), lf0.clone(), dm0);
                als(&d, nq, np, &mut ls, &mut lf, &mut dm);
                (0..nq)
                    .filter(|&q| counted[q])
                    .flat_map(|q| (0..np).map(move |p| (q, p)))
                    .filter_map(|(q, p)| residual(d[q * np + p], dm, ls[q] + lf[p]))
                    .map(|r| r * r)
                    .sum::<f64>()
            };
            let reach = SCALE_SEARCH_SDS * lights.scale_sd as f64;
            // 25 steps shrink the bracket to 1e-5 of itself, well under 0.001%.
            alpha = crate::lsq::golden_section(cost, 1.0 - reach, 1.0 + reach, 25);
            data = drop(self.log_data(centre, alpha as f32, &[]));
        }
        als(&data, nq, np, &mut ls, &mut lf, &mut dm);
        // The LEDs the mirror did not see, each where its own light's
        // fall-off says with the flat field and profile held; then the flat
        // field and profile again with those LEDs in their places.
        let mut moved = vec![Vec3::ZERO; base.led_scale.len()];
        let mut placed = Vec::new();
        if let Some(lights) = base.lights.as_ref().filter(|l| !l.measured.is_empty()) {
            let unmeasured: Vec<u8> = (0..moved.len() as u8).filter(|k| !lights.measured.contains(k)).collect();
            for _ in 0..PLACEMENT_ROUNDS {
                let found: Vec<(u8, Option<Vec3>)> = unmeasured
                    .par_iter()
                    .map(|&k| (k, self.place_led(k, centre, alpha as f32, &kept, &lf, dm, limit / OUTLIER_SIGMAS)))
                    .collect();
                placed.clear();
                for (k, d) in found {
                    moved[k as usize] = d.unwrap_or(Vec3::ZERO);
                    placed.extend(d.map(|_| k));
                }
                data = drop(self.log_data(centre, alpha as f32, &moved));
                als(&data, nq, np, &mut ls, &mut lf, &mut dm);
            }
        }
        let (mut ss, mut n) = (0.0f64, 0usize);
        for r in residuals(&data, nq, np, &ls, &lf, dm) {
            ss += r * r;
            n += 1;
        }
        // A point without data (its pixels see past the sample's edge)
        // takes the flat field of its nearest measured neighbour: the
        // flat field is smooth, and a later grid's point between the two
        // interpolates between them.
        let measured: Vec<bool> = (0..np).map(|p| (0..nq).any(|q| data[q * np + p].0.is_finite())).collect();
        let stand_in = self.ctx.inputs.grid.stand_ins(&measured);
        let lf: Vec<f64> = stand_in.iter().map(|&j| lf[j as usize]).collect();
        // Every step gives an estimate of the same LED: average them.
        let mut led_scale = base.led_scale.clone();
        let n_leds = led_scale.len();
        let mut acc = vec![(0.0f64, 0usize); n_leds];
        for (q, l) in self.ctx.lights.iter().enumerate() {
            if (l.led as usize) < n_leds && ls[q] != 0.0 {
                acc[l.led as usize].0 += ls[q];
                acc[l.led as usize].1 += 1;
            }
        }
        for (k, (s, c)) in acc.into_iter().enumerate() {
            if c > 0 {
                led_scale[k] = (s / c as f64).exp() as f32 * base.led_scale[k];
            }
        }
        let a = alpha as f32;
        let profile_exponent = base.profile_exponent + dm as f32;
        // The patches' readings under each LED at each position, for the
        // captures' drift (`crate::drift`).
        let drift_reference = (!self.patches.is_empty()).then(|| {
            let (reading, rel_var) = self.patches.reference(
                self.ctx,
                n_leds,
                |q| white_position(self.ctx.lights[q].pos, self.ctx.lights[q].led, centre, a, &moved),
                profile_exponent,
            );
            let plan = &self.ctx.inputs.plan;
            setup::calibration::DriftReference {
                patches: self.ctx.inputs.geometry.references.clone(),
                positions_mm: (0..plan.steps).map(|s| plan.step_um(s) as f32 / 1000.0).collect(),
                reading,
                rel_var,
            }
        });
        let lights = base.lights.clone().map(|l| setup::calibration::LightCalibration {
            led_mm: l.led_mm.iter().zip(0u8..).map(|(&p, k)| white_position(p, k, centre, a, &moved)).collect(),
            white_placed: placed,
            travel_mm: a * l.travel_mm,
            white_scale: l.white_scale * a,
            ..l
        });
        Some(Calibration {
            id,
            led_scale,
            profile_exponent,
            flat_field: lf.iter().map(|v| v.exp() as f32).collect(),
            flat_field_grid: Some(self.ctx.inputs.grid),
            reference_albedo: self.albedo,
            residual_rms: ((ss / n.max(1) as f64).sqrt()) as f32,
            lights,
            drift_reference,
            ..base.clone()
        })
    }

    /// Where LED `k` lies, as a displacement from its place with the LEDs
    /// scaled by `alpha` about `centre`: the one that best explains how its
    /// light falls off across the white at every carriage position, with
    /// the flat field `lf` and profile term `dm` of the whole scan held and
    /// each light's own level free (Levenberg-Marquardt on the kept
    /// samples' log residuals, each light's mean taken out). `None` where
    /// the LED has too few samples, or the fit does not lower their
    /// residual or lands beyond [`PLACEMENT_REACH_MM`].
    #[allow(clippy::too_many_arguments)]
    fn place_led(
        &self,
        k: u8,
        centre: Vec3,
        alpha: f32,
        kept: &[bool],
        lf: &[f64],
        dm: f64,
        sigma: f64,
    ) -> Option<Vec3> {
        use levenberg_marquardt::LevenbergMarquardt;
        use nalgebra::DVector;
        let ctx = self.ctx;
        let np = ctx.n_points();
        // The LED's (light, points) with a usable sample where it is now.
        let rows: Vec<(usize, Vec<usize>)> = (0..ctx.n_lights())
            .filter(|&q| ctx.lights[q].led == k)
            .map(|q| {
                let pos = white_position(ctx.lights[q].pos, k, centre, alpha, &[]);
                let ps = (0..np)
                    .filter(|&p| {
                        kept[q * np + p] && self.signal[q * np + p].is_finite() && ctx.sample_from(p, q, pos).is_some()
                    })
                    .collect::<Vec<_>>();
                (q, ps)
            })
            .filter(|(_, ps)| ps.len() >= MIN_PLACEMENT_POINTS)
            .collect();
        let n: usize = rows.iter().map(|(_, ps)| ps.len()).sum();
        if rows.len() < 2 || n < 4 * MIN_PLACEMENT_POINTS {
            return None;
        }
        let residuals = |u: &DVector<f64>| {
            let d = Vec3::new(u[0] as f32, u[1] as f32, u[2] as f32);
            let mut out = Vec::with_capacity(n);
            for (q, ps) in &rows {
                let pos = white_position(ctx.lights[*q].pos, k, centre, alpha, &[]) + d;
                let first = out.len();
                for &p in ps {
                    let x = ctx.sample_from(p, *q, pos).map_or(f64::NAN, |g| {
                        self.signal[*q * np + p] as f64 + (g.to_rho as f64).ln() - lf[p] - dm * (g.cos_emit as f64).ln()
                    });
                    out.push(x);
                }
                let row = &mut out[first..];
                let mean = finite_mean(row.iter().copied().filter(|x| x.is_finite())).unwrap_or(0.0);
                row.iter_mut().for_each(|x| *x = if x.is_finite() { *x - mean } else { 0.0 });
            }
            // The bar's build: each LED within its placement tolerance of
            // its place (half of it one standard deviation, as the mirror
            // scan takes it), in units of one sample's noise.
            out.extend((0..3).map(|i| sigma * u[i] / (0.5 * crate::mirror::LED_PLACEMENT_MM)));
            DVector::from_vec(out)
        };
        let start = residuals(&DVector::zeros(3)).norm_squared();
        let problem = crate::lsq::Numeric::new(residuals, DVector::zeros(3), crate::lsq::Step::Central(0.01));
        let (solved, _) = LevenbergMarquardt::new().with_patience(50).minimize(problem);
        let u = &solved.u;
        let d = Vec3::new(u[0] as f32, u[1] as f32, u[2] as f32);
        let end = solved.residuals_at(u).norm_squared();
        (d.is_finite() && d.length() <= PLACEMENT_REACH_MM && end < start).then_some(d)
    }
}

/// Where the white scan puts a light or LED at `pos` (as its context or
/// the mirror has it): scaled by `alpha` about `centre` (the scale the
/// mirror left open), then moved by its LED's entry of `moved` (the
/// placement of an LED the mirror did not see; none where it is short).
fn white_position(pos: Vec3, led: u8, centre: Vec3, alpha: f32, moved: &[Vec3]) -> Vec3 {
    centre + alpha * (pos - centre) + moved.get(led as usize).copied().unwrap_or(Vec3::ZERO)
}

/// Rounds of placing the LEDs the mirror did not measure and solving the
/// flat field again with them in place (the second round's places move by
/// hundredths of a millimetre on the simulated rigs).
const PLACEMENT_ROUNDS: usize = 2;

/// A light of an unmeasured LED counts toward its placement with at least
/// this many usable points of the white.
const MIN_PLACEMENT_POINTS: usize = 8;

/// The farthest the white scan moves an LED from its place on the line
/// through the measured ones: several times an LED's placement tolerance
/// on a bar (a fit that goes farther has found something else).
pub const PLACEMENT_REACH_MM: f32 = 3.0;

/// What a stack of dark frames says about the sensor, per Bayer colour
/// (mono sensors fill all three slots with the one value).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DarkStatistics {
    /// Mean dark level, DN.
    pub black_level: [f32; 3],
    /// Temporal noise, DN: from differences of consecutive frames (each
    /// difference has twice a frame's variance), so that a fixed pattern
    /// does not count as noise. With a single frame, the spatial spread.
    pub read_noise: [f32; 3],
    /// Spread across pixels of the per-pixel mean, DN. Far above the read
    /// noise, it means the frames are not dark: light reaches the sensor
    /// (no lens cap, a room light) or the camera sends a picture.
    pub spatial_sd: [f32; 3],
}

impl DarkStatistics {
    /// Why these frames should not be trusted as dark frames, if so: a
    /// per-pixel mean that varies by more than 5 read-noise sigmas (and
    /// more than 2 DN, for noiseless test sensors).
    pub fn light_leak(&self) -> Option<String> {
        let c = 1;
        let (spread, noise) = (self.spatial_sd[c], self.read_noise[c]);
        (spread > 5.0 * noise && spread > 2.0).then(|| {
            format!(
                "the dark frames are not uniform (pixels differ by {spread:.1} DN, read noise {noise:.1} DN): \
                 light reaches the sensor; put the lens cap on and switch off the room light"
            )
        })
    }
}

/// Black level, temporal read noise and fixed-pattern spread per Bayer
/// colour from dark frames of one size (`None` without pixels).
pub fn dark_statistics(frames: &[Frame]) -> Option<DarkStatistics> {
    let first = frames.first()?;
    let (w, h) = (first.width, first.height);
    let frames: Vec<&Frame> = frames.iter().filter(|f| f.width == w && f.height == h).collect();
    let channel = |x: u32, y: u32| match first.layout {
        frame::Layout::Bayer { pattern } => pattern.channel(x, y),
        _ => 1,
    };
    let nf = frames.len() as f64;
    let mut sum = [0.0f64; 3];
    let mut sum2 = [0.0f64; 3];
    let mut n = [0u64; 3];
    let mut diff2 = [0.0f64; 3];
    let mut nd = [0u64; 3];
    for y in 0..h {
        for x in 0..w {
            let i = (y * w + x) as usize;
            let c = channel(x, y);
            let pixel_mean = frames.iter().map(|f| f.data[i] as f64).sum::<f64>() / nf;
            sum[c] += pixel_mean;
            sum2[c] += pixel_mean * pixel_mean;
            n[c] += 1;
            for pair in frames.windows(2) {
                let d = pair[1].data[i] as f64 - pair[0].data[i] as f64;
                diff2[c] += d * d;
                nd[c] += 1;
            }
        }
    }
    if n.iter().sum::<u64>() == 0 {
        return None;
    }
    let mut out = DarkStatistics { black_level: [0.0; 3], read_noise: [0.0; 3], spatial_sd: [0.0; 3] };
    for c in 0..3 {
        if n[c] == 0 {
            continue;
        }
        let m = sum[c] / n[c] as f64;
        out.black_level[c] = m as f32;
        out.spatial_sd[c] = (sum2[c] / n[c] as f64 - m * m).max(0.0).sqrt() as f32;
        out.read_noise[c] = if nd[c] > 0 { (diff2[c] / nd[c] as f64 / 2.0).sqrt() as f32 } else { out.spatial_sd[c] };
    }
    // Mono sensors fill only the green slot; copy it.
    if n[0] == 0 && n[2] == 0 {
        out.black_level = [out.black_level[1]; 3];
        out.read_noise = [out.read_noise[1]; 3];
        out.spatial_sd = [out.spatial_sd[1]; 3];
    }
    Some(out)
}

fn residuals<'a>(
    data: &'a [(f32, f32)],
    nq: usize,
    np: usize,
    ls: &'a [f64],
    lf: &'a [f64],
    dm: f64,
) -> impl Iterator<Item = f64> + 'a {
    (0..nq * np).filter_map(move |k| {
        let (q, p) = (k / np, k % np);
        residual(data[k], dm, ls[q] + lf[p])
    })
}

/// `ln M - other - dm ln cos_emit` for a measured `(ln M, ln cos_emit)`;
/// `None` where nothing was measured.
fn residual((lm, lc): (f32, f32), dm: f64, other: f64) -> Option<f64> {
    lm.is_finite().then(|| lm as f64 - other - dm * lc as f64)
}

/// Mean of the values; `None` for none.
fn finite_mean(values: impl Iterator<Item = f64>) -> Option<f64> {
    let (s, n) = values.fold((0.0, 0usize), |(s, n), v| (s + v, n + 1));
    (n > 0).then(|| s / n as f64)
}

/// Alternating least squares for `ln M = ls[q] + lf[p] + dm ln cos_emit`
/// with `mean lf = 0`.
fn als(data: &[(f32, f32)], nq: usize, np: usize, ls: &mut [f64], lf: &mut [f64], dm: &mut f64) {
    for _ in 0..ALS_ITERATIONS {
        let d = *dm;
        for p in 0..np {
            let r = |q: usize| residual(data[q * np + p], d, ls[q]);
            lf[p] = finite_mean((0..nq).filter_map(r)).unwrap_or(lf[p]);
        }
        let mean_f = lf.iter().sum::<f64>() / np as f64;
        lf.iter_mut().for_each(|v| *v -= mean_f);
        for q in 0..nq {
            let r = |p: usize| residual(data[q * np + p], d, lf[p]);
            ls[q] = finite_mean((0..np).filter_map(r)).unwrap_or(ls[q]);
        }
        let (mut num, mut den) = (0.0, 0.0);
        for q in 0..nq {
            for p in 0..np {
                let (lm, lc) = data[q * np + p];
                if lm.is_finite() {
                    num += (lm as f64 - ls[q] - lf[p]) * lc as f64;
                    den += (lc as f64) * (lc as f64);
                }
            }
        }
        if den > 0.0 {
            *dm = num / den;
        }
    }
}

#[cfg(test)]
mod tests {
    use frame::{FrameFlags, FrameMeta, Layout, MonoNs};
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    use super::*;

    fn mono(data: Vec<u16>, w: u32) -> Frame {
        let h = data.len() as u32 / w;
        let meta = FrameMeta {
            sequence: 0,
            exposure_start: MonoNs(0),
            exposure_end: MonoNs(0),
            exposure_us: 1000,
            gain: 1.0,
            flags: FrameFlags::default(),
        };
        Frame { width: w, height: h, layout: Layout::Mono, bit_depth: 12, data, meta }
    }

    /// Dark frames: `pattern` fixed per pixel plus temporal noise of 3 DN.
    fn stack(pattern: impl Fn(usize) -> f64) -> Vec<Frame> {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(7);
        let noise = Normal::new(0.0, 3.0).unwrap();
        (0..8)
            .map(|_| {
                mono((0..64 * 64).map(|i| (100.0 + pattern(i) + noise.sample(&mut rng)).round() as u16).collect(), 64)
            })
            .collect()
    }

    #[test]
    fn read_noise_is_temporal_and_a_picture_is_a_light_leak() {
        let flat = dark_statistics(&stack(|_| 0.0)).unwrap();
        assert!((flat.black_level[1] - 100.0).abs() < 0.1, "{flat:?}");
        assert!((flat.read_noise[1] - 3.0).abs() < 0.15, "{flat:?}");
        assert_eq!(flat.read_noise[0], flat.read_noise[1], "mono fills every slot");
        assert!(flat.light_leak().is_none(), "{flat:?}");
        // A fixed pattern (hot columns, or a picture) is not read noise...
        let bars = dark_statistics(&stack(|i| if (i % 64) < 32 { 0.0 } else { 400.0 })).unwrap();
        assert!((bars.read_noise[1] - 3.0).abs() < 0.15, "{bars:?}");
        assert!(bars.spatial_sd[1] > 150.0, "{bars:?}");
        // ...but it does say the frames are not dark.
        assert!(bars.light_leak().unwrap().contains("lens cap"));
    }

    #[test]
    fn one_frame_falls_back_to_the_spatial_spread() {
        let one = dark_statistics(&stack(|_| 0.0)[..1]).unwrap();
        assert!((one.read_noise[1] - 3.0).abs() < 0.3, "{one:?}");
        assert!(dark_statistics(&[]).is_none());
    }
}
