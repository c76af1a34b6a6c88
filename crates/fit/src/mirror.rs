//! Where the LEDs are: the second half of the geometric calibration, from
//! a flat front-surface mirror laid in the sample holder.
//!
//! With the camera calibrated in the sample's frame ([`crate::geometric`]),
//! the highlight of LED `k` at carriage position `c` in the mirror (the
//! plane `z = 0`) is a pixel whose ray meets the mirror at `m`; the law of
//! reflection sends the ray on in the direction `d` (the view direction
//! mirrored in the normal), and the LED lies on the line `m + t d`. The
//! LED moves with the carriage, `L_k(c) = p_k + c v` (`p_k` its position
//! with the carriage commanded to 0, `v` the carriage's displacement per
//! commanded millimetre), so every highlight gives two linear equations in
//! `p_k` and `v`, and the scan's highlights are one linear least-squares
//! problem.
//!
//! **What a flat mirror cannot measure.** Every reflected ray passes
//! through the camera's mirror image `C'`, so the LEDs scaled about `C'`
//! (and the travel with them) reflect into the very same pixels: the
//! highlights fix everything but that one scale. Two facts of the build
//! fix it: the bar's LEDs are soldered at their pitch (each within
//! [`LED_PLACEMENT_MM`]), and the gantry's scale is within
//! [`GANTRY_SCALE_TOLERANCE`] of its firmware's; both enter as priors.
//! What the remaining uncertainty (about 0.15%, [`LightSolution::scale_sd`])
//! moves is an LED along the line from `C'`, the direction in which the
//! camera sees it mirrored: the half vector of a point seen at its
//! specular peak does not change, but the LED's distance from every point
//! does. The white scan then measures the scale from how its light falls
//! off ([`crate::calibrate::WhiteAccumulator::solve`]).
//!
//! A mirror the sample's size shows the LEDs over its middle (on the
//! default rig 20 of 40); the others are placed on the straight line
//! fitted through the measured ones, at their places along the bar.

use glam::{Vec2, Vec3};
use nalgebra::{DMatrix, DVector, Vector3};
use setup::{CameraModel, RigGeometry};
use thiserror::Error;

use crate::geometric::Luma;

/// The mirror scan's exposure, as a fraction of the rig's default: the
/// image of an LED in a mirror is some thousand times brighter than a
/// white diffuse surface under it.
pub const EXPOSURE_DIVISOR: u32 = 1024;

/// Dark frames averaged and subtracted from every frame of the scan.
pub const DARK_FRAMES: u32 = 8;

/// Spacing of the scan's carriage positions, mm.
pub const STEP_MM: f32 = 8.0;

/// How far from the mirror's edge a highlight must lie to be used, mm (a
/// spot cut by the edge has its centre moved).
pub const EDGE_MM: f32 = 5.0;

/// The assumed build: each LED within this distance of its place on the
/// bar, mm (the standard deviation of the pitch prior is half of it).
pub const LED_PLACEMENT_MM: f64 = 0.5;

/// The assumed build: the gantry's true scale within this fraction of its
/// firmware's (belt stretch, pulley tolerance).
pub const GANTRY_SCALE_TOLERANCE: f64 = 0.005;

/// How well a highlight places its LED's ray, mm: a spot's centre to some
/// hundredths of a pixel (0.5-0.7 mm on the default rig), and the small
/// shift the light's fall-off across the spot gives its peak.
const RAY_NOISE_MM: f64 = 0.05;

#[derive(Debug, Error, PartialEq)]
pub enum MirrorError {
    #[error(
        "the mirror showed {leds} LEDs at three or more carriage positions ({highlights} highlights in all); at least 3 are needed: is the mirror in the holder, face up, and clean?"
    )]
    TooFew { leds: usize, highlights: usize },
    #[error("the mirror's highlights do not determine the LEDs (a singular system)")]
    Singular,
}

/// One highlight: LED `led` with the carriage commanded to `commanded_mm`
/// seen at `pixel`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Highlight {
    pub led: u8,
    pub commanded_mm: f32,
    pub pixel: Vec2,
}

/// Carriage positions (of [`scan_positions`]) the mirror scan visits a
/// second time, approached from above: the first, the middle and the last,
/// visited downward.
pub fn return_positions(positions: &[f32]) -> Vec<f32> {
    let mut out: Vec<f32> = match positions {
        [] => Vec::new(),
        [a] => vec![*a],
        _ => vec![positions[0], positions[positions.len() / 2], positions[positions.len() - 1]],
    };
    out.dedup();
    out.reverse();
    out
}

/// The gantry's backlash as the mirror saw it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Backlash {
    /// How much farther along `+x` the carriage stands at a position
    /// approached from above than at the same position approached from
    /// below, commanded millimetres.
    pub mm: f32,
    /// Its standard error (from the spread of the pairs).
    pub sd_mm: f32,
    /// Highlights seen from both directions.
    pub pairs: usize,
}

/// The backlash from highlights of the same LED at the same commanded
/// position approached from below (`up`, the scan's own) and from above
/// (`down`): each pair's shift of the spot, projected on how the spot moves
/// per commanded millimetre (that LED's spots at the neighbouring positions
/// of `up`), is the carriage's shift; the median of them. `None` without
/// pairs.
pub fn backlash(up: &[Highlight], down: &[Highlight]) -> Option<Backlash> {
    let mut shifts: Vec<f32> = down
        .iter()
        .filter_map(|d| {
            let same = |h: &&Highlight| h.led == d.led;
            let at = up.iter().filter(same).find(|h| h.commanded_mm == d.commanded_mm)?;
            let below = up.iter().filter(same).filter(|h| h.commanded_mm < d.commanded_mm);
            let above = up.iter().filter(same).filter(|h| h.commanded_mm > d.commanded_mm);
            let lo = below.max_by(|a, b| a.commanded_mm.total_cmp(&b.commanded_mm)).unwrap_or(at);
            let hi = above.min_by(|a, b| a.commanded_mm.total_cmp(&b.commanded_mm)).unwrap_or(at);
            let run = hi.commanded_mm - lo.commanded_mm;
            if run <= 0.0 {
                return None;
            }
            let per_mm = (hi.pixel - lo.pixel) / run;
            let moved = d.pixel - at.pixel;
            (per_mm.length_squared() > 0.0).then(|| moved.dot(per_mm) / per_mm.length_squared())
        })
        .collect();
    let n = shifts.len();
    if n == 0 {
        return None;
    }
    let (mm, mad) = median_and_mad(&mut shifts);
    // The median's standard error: 1.25 times the mean's for normal spread.
    Some(Backlash { mm, sd_mm: 1.25 * 1.4826 * mad / (n as f32).sqrt(), pairs: n })
}

/// The camera at `camera_mm` mirrored in the plane `z = 0`: every ray a
/// flat mirror there reflects into the camera passes through it.
pub fn camera_image(camera_mm: Vec3) -> Vec3 {
    Vec3::new(camera_mm.x, camera_mm.y, -camera_mm.z)
}

/// Where a camera at `camera_mm` sees a point `led` (above `z = 0`) in a
/// flat mirror at `z = 0`: on the line from the camera's mirror image to it.
pub fn mirror_point(camera_mm: Vec3, led: Vec3) -> Vec3 {
    let image = camera_image(camera_mm);
    image + (camera_mm.z / (camera_mm.z + led.z)) * (led - image)
}

/// The carriage positions of the mirror scan, in increasing order: where
/// the highlight of an LED over the middle of the sample lands on the
/// mirror at least [`EDGE_MM`] from its edge, seen past the bar, every
/// [`STEP_MM`], by the rig file's geometry.
pub fn scan_positions(g: &RigGeometry) -> Vec<f32> {
    let c = g.camera.position_mm;
    let half = 0.5 * g.sample.width_mm - EDGE_MM;
    let steps = ((g.gantry.travel_max_mm - g.gantry.travel_min_mm) / STEP_MM).floor().max(0.0) as u32;
    (0..=steps)
        .map(|k| g.gantry.travel_min_mm + k as f32 * STEP_MM)
        .filter(|&x| {
            let m = mirror_point(c, Vec3::new(x, 0.0, g.bar.height_mm));
            m.x.abs() <= half && !g.bar.occludes(x, m, c, 2.0)
        })
        .collect()
}

/// The highlight's centre in `img` (a frame less its dark frames), if it
/// has one: the peak of a quadratic fitted to the logarithm of the
/// brightest spot (a Gaussian's log is quadratic), over the pixels above a
/// tenth of its peak and below `ceiling` (saturated pixels carry no
/// shape). None when the brightest spot is not well above the noise, or not
/// a peak.
pub fn find_highlight(img: &Luma, ceiling: f32) -> Option<Vec2> {
    let (w, h) = (img.width as i64, img.height as i64);
    let at = |x: i64, y: i64| img.data[(y.clamp(0, h - 1) * w + x.clamp(0, w - 1)) as usize];
    // The brightest 3 x 3 block, so that one hot pixel is not a highlight.
    let mut best = (f32::MIN, 0i64, 0i64);
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let v = at(x, y);
            if v <= best.0 / 9.0 {
                continue;
            }
            let s: f32 =
                (-1..=1).flat_map(|dy| (-1..=1).map(move |dx| (dx, dy))).map(|(dx, dy)| at(x + dx, y + dy)).sum();
            if s > best.0 {
                best = (s, x, y);
            }
        }
    }
    let (sum, cx, cy) = best;
    let noise = noise_sd(img);
    if !(sum / 9.0 > 50.0 * noise) {
        return None;
    }
    let peak = (-1..=1)
        .flat_map(|dy| (-1..=1).map(move |dx| (dx, dy)))
        .map(|(dx, dy)| at(cx + dx, cy + dy))
        .fold(0.0f32, f32::max);
    const R: i64 = 6;
    let mut a = DMatrix::<f64>::zeros(6, 6);
    let mut b = DVector::<f64>::zeros(6);
    let mut n = 0;
    for dy in -R..=R {
        for dx in -R..=R {
            let (x, y) = (cx + dx, cy + dy);
            if x < 0 || y < 0 || x >= w || y >= h {
                continue;
            }
            let v = at(x, y);
            if v < 0.1 * peak || v >= ceiling {
                continue;
            }
            let (u, t) = (dx as f64, dy as f64);
            let row = [1.0, u, t, u * u, u * t, t * t];
            // The log's variance is about 1/v for shot noise: weight v.
            let wgt = v as f64;
            let lv = (v as f64).ln();
            for i in 0..6 {
                b[i] += wgt * row[i] * lv;
                for j in 0..6 {
                    a[(i, j)] += wgt * row[i] * row[j];
                }
            }
            n += 1;
        }
    }
    if n < 8 {
        return None;
    }
    let q = a.cholesky()?.solve(&b);
    // Gradient zero: [2 q3, q4; q4, 2 q5] (u, t) = -(q1, q2).
    let (hxx, hxy, hyy) = (2.0 * q[3], q[4], 2.0 * q[5]);
    let det = hxx * hyy - hxy * hxy;
    if !(hxx < 0.0 && det > 0.0) {
        return None;
    }
    let u = (-q[1] * hyy + q[2] * hxy) / det;
    let t = (-q[2] * hxx + q[1] * hxy) / det;
    if !(u.abs() <= 2.0 && t.abs() <= 2.0) {
        return None;
    }
    // Pixel (x, y) covers [x, x + 1): its centre is x + 0.5.
    Some(Vec2::new((cx as f64 + u + 0.5) as f32, (cy as f64 + t + 0.5) as f32))
}

/// The image's noise, from the median absolute deviation of a sample of
/// its pixels (a highlight covers a few dozen of tens of thousands).
fn noise_sd(img: &Luma) -> f32 {
    let mut v: Vec<f32> = img.data.iter().step_by(7).copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f32::INFINITY;
    }
    (1.4826 * median_and_mad(&mut v).1).max(1e-3)
}

/// The median of `v` (not empty; reordered) and the median absolute
/// deviation from it.
fn median_and_mad(v: &mut [f32]) -> (f32, f32) {
    let mid = v.len() / 2;
    let median = *v.select_nth_unstable_by(mid, f32::total_cmp).1;
    let mut dev: Vec<f32> = v.iter().map(|x| (x - median).abs()).collect();
    (median, *dev.select_nth_unstable_by(mid, f32::total_cmp).1)
}

/// The LEDs as the mirror scan measured them.
#[derive(Clone, Debug, PartialEq)]
pub struct LightSolution {
    /// Each LED's position with the carriage commanded to 0 (sample frame, mm).
    pub led_mm: Vec<Vec3>,
    /// The carriage's displacement per commanded millimetre.
    pub travel_mm: Vec3,
    /// LEDs measured (the others placed on the line through them).
    pub measured: Vec<u8>,
    /// Highlights used, and their LEDs' distances from their rays (mm).
    pub used: usize,
    pub rms_mm: f32,
    pub max_mm: f32,
    /// Relative standard deviation of the scale the highlights leave open
    /// (from the two priors alone): an LED `r` mm from the camera's mirror
    /// image is known to about `r` times this along the line from it.
    pub scale_sd: f32,
}

/// A highlight's ray: where it meets the mirror and where it goes.
fn ray(camera: &CameraModel, pixel: Vec2) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let m = camera.pixel_to(pixel, Vec3::ZERO, Vec3::Z)?;
    let v = camera.view_dir(m);
    let d = Vec3::new(-v.x, -v.y, v.z);
    let f = |p: Vec3| Vector3::new(p.x as f64, p.y as f64, p.z as f64);
    Some((f(m), f(d).normalize()))
}

/// Solve the LEDs' positions and the carriage's travel from the scan's
/// highlights, seen by `camera` (the calibrated one, in the sample frame);
/// `filed` gives the bar's pitch and how many LEDs it has. Highlights
/// whose rays miss the mirror by less than [`EDGE_MM`] are left out, and
/// those far off the solution (a reflection of something else, a spot cut
/// by the bar) are dropped and the rest solved again.
pub fn solve_lights(
    highlights: &[Highlight],
    camera: &CameraModel,
    filed: &RigGeometry,
) -> Result<LightSolution, MirrorError> {
    let s = filed.sample;
    let inner = setup::SampleArea { width_mm: s.width_mm - 2.0 * EDGE_MM, height_mm: s.height_mm - 2.0 * EDGE_MM };
    let mut obs: Vec<(u8, f64, Vector3<f64>, Vector3<f64>)> = highlights
        .iter()
        .filter_map(|h| {
            let (m, d) = ray(camera, h.pixel)?;
            inner.contains(Vec2::new(m.x as f32, m.y as f32)).then_some((h.led, h.commanded_mm as f64, m, d))
        })
        .collect();
    let mut last = None;
    for _ in 0..4 {
        let (leds, p, v, res) = solve_once(&obs, filed)?;
        // LEDs left with too few highlights have no solution (infinite
        // residual): their highlights go.
        let fin: Vec<f64> = res.iter().copied().filter(|r| r.is_finite()).collect();
        let rms = (fin.iter().map(|r| r * r).sum::<f64>() / fin.len().max(1) as f64).sqrt();
        let cut = (4.0 * rms).max(2.0 * RAY_NOISE_MM);
        let kept: Vec<_> = obs.iter().zip(&res).filter(|(_, r)| **r <= cut).map(|(o, _)| *o).collect();
        let max = fin.iter().copied().fold(0.0, f64::max);
        last = Some((leds, p, v, fin.len(), rms, max));
        if kept.len() == obs.len() {
            break;
        }
        obs = kept;
    }
    let Some((leds, p, v, used, rms, max)) = last else { return Err(MirrorError::Singular) };
    // The line through the measured LEDs: position = a + b k.
    let ks: Vec<f64> = leds.iter().map(|&k| k as f64).collect();
    let kbar = ks.iter().sum::<f64>() / ks.len() as f64;
    let skk: f64 = ks.iter().map(|k| (k - kbar).powi(2)).sum();
    let pbar = p.iter().fold(Vector3::zeros(), |a, q| a + q) / p.len() as f64;
    let slope = ks.iter().zip(&p).fold(Vector3::zeros(), |a, (k, q)| a + (k - kbar) * (q - pbar)) / skk.max(1e-12);
    let g = |q: Vector3<f64>| Vec3::new(q.x as f32, q.y as f32, q.z as f32);
    let led_mm = (0..filed.bar.n_leds)
        .map(|k| match leds.iter().position(|&l| l == k) {
            Some(j) => g(p[j]),
            None => g(pbar + (k as f64 - kbar) * slope),
        })
        .collect();
    let (sg, sp) = (0.5 * GANTRY_SCALE_TOLERANCE, 0.5 * LED_PLACEMENT_MM / skk.sqrt() / filed.bar.pitch_mm as f64);
    let scale_sd = (1.0 / (1.0 / (sg * sg) + 1.0 / (sp * sp))).sqrt() as f32;
    Ok(LightSolution {
        led_mm,
        travel_mm: g(v),
        measured: leds,
        used,
        rms_mm: rms as f32,
        max_mm: max as f32,
        scale_sd,
    })
}

/// One linear solve: the LEDs with at least three highlights, their
/// positions, the travel, and each highlight's distance from its ray.
#[allow(clippy::type_complexity)]
fn solve_once(
    obs: &[(u8, f64, Vector3<f64>, Vector3<f64>)],
    filed: &RigGeometry,
) -> Result<(Vec<u8>, Vec<Vector3<f64>>, Vector3<f64>, Vec<f64>), MirrorError> {
    let mut counts = vec![0usize; filed.bar.n_leds as usize];
    for o in obs {
        if let Some(c) = counts.get_mut(o.0 as usize) {
            *c += 1;
        }
    }
    let leds: Vec<u8> = (0..filed.bar.n_leds).filter(|&k| counts[k as usize] >= 3).collect();
    if leds.len() < 3 {
        return Err(MirrorError::TooFew { leds: leds.len(), highlights: obs.len() });
    }
    let index = |k: u8| leds.iter().position(|&l| l == k);
    let n = 3 * leds.len() + 3;
    let tv = 3 * leds.len();
    let mut a = DMatrix::<f64>::zeros(n, n);
    let mut b = DVector::<f64>::zeros(n);
    // Accumulate one weighted row `coef . u = rhs` into the normal equations.
    let mut add = |coef: &[(usize, f64)], rhs: f64, sd: f64| {
        let w = 1.0 / (sd * sd);
        for &(i, ci) in coef {
            b[i] += w * ci * rhs;
            for &(j, cj) in coef {
                a[(i, j)] += w * ci * cj;
            }
        }
    };
    for &(k, c, m, d) in obs {
        let Some(j) = index(k) else { continue };
        let proj = across(d);
        for r in 0..3 {
            let mut coef = Vec::with_capacity(6);
            for col in 0..3 {
                coef.push((3 * j + col, proj[(r, col)]));
                coef.push((tv + col, c * proj[(r, col)]));
            }
            add(&coef, (proj.row(r) * m)[0], RAY_NOISE_MM);
        }
    }
    // The scale the highlights leave open: the gantry's, and the bar's pitch
    // (the slope of the LEDs' y over their numbers).
    add(&[(tv, 1.0)], 1.0, 0.5 * GANTRY_SCALE_TOLERANCE);
    let ks: Vec<f64> = leds.iter().map(|&k| k as f64).collect();
    let kbar = ks.iter().sum::<f64>() / ks.len() as f64;
    let skk: f64 = ks.iter().map(|k| (k - kbar).powi(2)).sum();
    let coef: Vec<(usize, f64)> = ks.iter().enumerate().map(|(j, k)| (3 * j + 1, (k - kbar) / skk)).collect();
    add(&coef, filed.bar.pitch_mm as f64, 0.5 * LED_PLACEMENT_MM / skk.sqrt());
    let u = a.cholesky().ok_or(MirrorError::Singular)?.solve(&b);
    let p: Vec<Vector3<f64>> = (0..leds.len()).map(|j| Vector3::new(u[3 * j], u[3 * j + 1], u[3 * j + 2])).collect();
    let v = Vector3::new(u[tv], u[tv + 1], u[tv + 2]);
    let res = obs
        .iter()
        .map(|&(k, c, m, d)| match index(k) {
            Some(j) => {
                let e = p[j] + c * v - m;
                (e - d * d.dot(&e)).norm()
            }
            None => f64::INFINITY,
        })
        .collect();
    Ok((leds, p, v, res))
}

/// `I - d d^T`: what is left of a vector once its component along the
/// unit vector `d` is removed.
fn across(d: Vector3<f64>) -> nalgebra::Matrix3<f64> {
    nalgebra::Matrix3::identity() - d * d.transpose()
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::*;

    #[test]
    fn the_backlash_is_the_shift_between_the_two_approaches() {
        // Spots moving 1.9 px per commanded mm along a slant; the carriage
        // 0.06 mm farther along when approached from above; a spot the
        // return pass did not find is no pair.
        let per_mm = Vec2::new(1.9, 0.4);
        let spot = |led: u8, x: f32, shift: f32| Highlight {
            led,
            commanded_mm: x,
            pixel: Vec2::new(20.0 * led as f32, 100.0) + (x + shift) * per_mm,
        };
        let positions = [-16.0, -8.0, 0.0, 8.0, 16.0];
        let up: Vec<Highlight> = (0..4).flat_map(|led| positions.map(|x| spot(led, x, 0.0))).collect();
        let back = return_positions(&positions);
        assert_eq!(back, vec![16.0, 0.0, -16.0]);
        let down: Vec<Highlight> =
            (0..3).flat_map(|led| back.iter().map(move |&x| spot(led, x, 0.06))).chain([spot(9, 0.0, 0.06)]).collect();
        let b = backlash(&up, &down).unwrap();
        assert_eq!(b.pairs, 9);
        assert!((b.mm - 0.06).abs() < 1e-4, "{b:?}");
        assert!(backlash(&up, &[]).is_none());
    }

    #[test]
    fn exact_highlights_give_the_leds_and_travel_back() {
        let g = RigGeometry::default();
        // A bar 1 mm high, yawed and offset, on a gantry whose travel is
        // skewed and tilted: the pitch and the scale are as the priors
        // say (which is all a mirror cannot see), everything else not.
        let travel = Vec3::new(1.0, 0.003, -0.001);
        let led = |k: u8| g.bar.led_position(0.0, k) + Vec3::new(0.8 + 0.004 * k as f32, 0.0, 1.0);
        let mut hl = Vec::new();
        for x in scan_positions(&g) {
            for k in 0..g.bar.n_leds {
                let m = mirror_point(g.camera.position_mm, led(k) + x * travel);
                if m.x.abs() < 45.0 && m.y.abs() < 45.0 {
                    hl.push(Highlight { led: k, commanded_mm: x, pixel: g.camera.project(m).unwrap() });
                }
            }
        }
        let sol = solve_lights(&hl, &g.camera, &g).unwrap();
        assert!(sol.measured.len() >= 18, "{:?}", sol.measured);
        assert!(sol.rms_mm < 1e-3, "{}", sol.rms_mm);
        for k in 0..g.bar.n_leds {
            // The unmeasured ones are on the line through the measured,
            // which here is exact.
            let e = (sol.led_mm[k as usize] - led(k)).length();
            assert!(e < 0.01, "LED {k}: {e} mm");
        }
        assert!((sol.travel_mm - travel).length() < 1e-4, "{}", sol.travel_mm);
    }

    #[test]
    fn too_few_highlights_are_refused() {
        let g = RigGeometry::default();
        let hl = [Highlight { led: 20, commanded_mm: 40.0, pixel: Vec2::new(128.0, 128.0) }];
        assert!(matches!(solve_lights(&hl, &g.camera, &g), Err(MirrorError::TooFew { .. })));
    }

    /// A Gaussian spot of `peak` DN centred at `centre` (pixel
    /// coordinates, pixel `(x, y)` covering `[x, x + 1)`), with read noise.
    fn spot(centre: Vec2, sigma: f32, peak: f32, noise: f32, seed: u64) -> Luma {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
        let mut img = Luma::new(64, 48);
        for y in 0..48 {
            for x in 0..64 {
                let d = Vec2::new(x as f32 + 0.5, y as f32 + 0.5) - centre;
                let n: f32 = (0..12).map(|_| rng.random::<f32>()).sum::<f32>() - 6.0;
                img.data[y * 64 + x] = peak * (-d.length_squared() / (2.0 * sigma * sigma)).exp() + noise * n;
            }
        }
        img
    }

    #[test]
    fn a_highlight_is_found_to_hundredths_of_a_pixel() {
        for (k, c) in [Vec2::new(30.3, 20.7), Vec2::new(12.52, 33.01), Vec2::new(50.9, 9.45)].into_iter().enumerate() {
            // 3000 DN over 3 DN of noise: the simulated mirror scan's level.
            let found = find_highlight(&spot(c, 2.0, 3000.0, 3.0, k as u64), 4000.0).unwrap();
            assert!((found - c).length() < 0.02, "{c} found at {found}");
            // Saturated at two thirds of its peak: the flat top is left
            // out and the flanks still place it.
            let found = find_highlight(&spot(c, 2.0, 3000.0, 3.0, k as u64), 2000.0).unwrap();
            assert!((found - c).length() < 0.05, "saturated {c} found at {found}");
        }
        // Nothing but noise, or one hot pixel: no highlight.
        assert_eq!(find_highlight(&spot(Vec2::ZERO, 2.0, 0.0, 3.0, 9), 4000.0), None);
        let mut hot = spot(Vec2::ZERO, 2.0, 0.0, 3.0, 9);
        hot.data[20 * 64 + 20] = 3000.0;
        assert_eq!(find_highlight(&hot, 4000.0), None);
    }
}
