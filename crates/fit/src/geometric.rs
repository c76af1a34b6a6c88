//! The geometric calibration of the camera: its intrinsics (focal length,
//! principal point, radial distortion) and its pose in the sample's frame,
//! from images of the printed checkerboard ([`setup::CheckerTarget`]).
//!
//! The operator shows the camera the target twice: flat in the sample
//! holder (which defines the sample frame: centred, rows along the travel)
//! and propped up on anything at 10-30 degrees (which separates the focal
//! length and principal point from the pose, as in Zhang, "A flexible new
//! technique for camera calibration", PAMI 2000: one view of a plane leaves
//! a one-parameter family of cameras). Each view is the sum of frames lit
//! by LEDs at both ends of the travel.
//!
//! 1. [`detect_corners`]: saddle points of the smoothed image (where the
//!    Hessian's determinant is most negative), refined to a fraction of a
//!    pixel by the gradient-orthogonality condition (each gradient near an
//!    X-corner is perpendicular to its offset from the corner).
//! 2. [`grid_corners`]: the corners grown into the board's lattice from the
//!    one nearest the middle, step by step along the local lattice
//!    vectors; the board's size fixes the indices, and the rough camera
//!    pose of the rig file fixes which way round the board lies.
//! 3. [`solve_camera`]: Levenberg-Marquardt over the camera and the propped
//!    target's pose, from the rig file's camera, minimising the
//!    reprojection error of every corner.

use glam::{Vec2, Vec3};
use levenberg_marquardt::LevenbergMarquardt;
use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, Vector2, Vector3};
use serde::{Deserialize, Serialize};
use setup::{CameraModel, CheckerTarget};
use thiserror::Error;

use crate::lsq::{Numeric, Step};

#[derive(Debug, Error, PartialEq)]
pub enum GeometryError {
    #[error(
        "view {view}: found {found} of the target's corners in a {cols} x {rows} grid, not {want} x {want} (at least three quarters of them); is all of the target in view and lit?"
    )]
    Incomplete { view: usize, found: usize, cols: u32, rows: u32, want: u32 },
    #[error("view {view}: no checkerboard corner was found; is the target in place and lit?")]
    NoCorners { view: usize },
    #[error("the camera solve did not converge (reprojection error {rms_px:.2} px RMS)")]
    Diverged { rms_px: f32 },
}

/// A luminance image (row-major, `width x height`).
#[derive(Clone, Debug, PartialEq)]
pub struct Luma {
    pub width: u32,
    pub height: u32,
    pub data: Vec<f32>,
}

impl Luma {
    pub fn new(width: u32, height: u32) -> Luma {
        Luma { width, height, data: vec![0.0; (width * height) as usize] }
    }

    /// Add `weight` times a frame. A colour mosaic is taken raw, each
    /// pixel as it was measured: the target is grey, and demosaicing would
    /// interpolate red and blue from samples two pixels apart, moving every
    /// edge by up to a pixel with where it falls between them. The channels'
    /// slightly different gains leave a pattern of a two-pixel period,
    /// which the detector's smoothing removes. A frame of another size is
    /// refused.
    pub fn add(&mut self, f: &frame::Frame, weight: f32) -> bool {
        if f.width != self.width || f.height != self.height {
            return false;
        }
        match f.layout {
            frame::Layout::Bayer { .. } | frame::Layout::Mono => {
                for (d, &v) in self.data.iter_mut().zip(&f.data) {
                    *d += weight * v as f32;
                }
            }
            frame::Layout::Rgb => {
                let rgb = f.to_rgb();
                for (k, d) in self.data.iter_mut().enumerate() {
                    *d += weight * (0.25 * rgb.r[k] + 0.5 * rgb.g[k] + 0.25 * rgb.b[k]);
                }
            }
        }
        true
    }

    fn at(&self, x: i64, y: i64) -> f32 {
        let x = x.clamp(0, self.width as i64 - 1) as usize;
        let y = y.clamp(0, self.height as i64 - 1) as usize;
        self.data[y * self.width as usize + x]
    }

    /// Separable Gaussian blur.
    fn blurred(&self, sigma: f32) -> Luma {
        let r = (3.0 * sigma).ceil() as i64;
        let k: Vec<f32> = (-r..=r).map(|d| (-(d * d) as f32 / (2.0 * sigma * sigma)).exp()).collect();
        let norm: f32 = k.iter().sum();
        let (w, h) = (self.width as i64, self.height as i64);
        let mut tmp = vec![0.0f32; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                tmp[(y * w + x) as usize] =
                    (-r..=r).map(|d| k[(d + r) as usize] * self.at(x + d, y)).sum::<f32>() / norm;
            }
        }
        let t = Luma { width: self.width, height: self.height, data: tmp };
        let mut out = vec![0.0f32; (w * h) as usize];
        for y in 0..h {
            for x in 0..w {
                out[(y * w + x) as usize] = (-r..=r).map(|d| k[(d + r) as usize] * t.at(x, y + d)).sum::<f32>() / norm;
            }
        }
        Luma { width: self.width, height: self.height, data: out }
    }
}

/// Dark frames taken per view and subtracted (scaled to the lit frames'
/// count): they remove the black level, the ambient light and hot pixels,
/// whose bright specks are strong blobs in the corner detector.
pub const DARK_FRAMES_PER_VIEW: u32 = 8;

/// Exposure of the target's frames, in multiples of the rig's default:
/// the LEDs that light it are far (see [`lighting_positions`]).
pub const EXPOSURE_FACTOR: u32 = 8;

/// Carriage positions (mm) that light a view of the target: the nearest
/// ones, up to three on each side, from which the bar hides no part of the
/// sample holder from the camera, even over a target propped 30 mm up, and
/// that are at least the bar's height beyond the sample's edge (a propped
/// target would come so near the LEDs above it that it saturated there
/// while its far side stayed dark).
pub fn lighting_positions(g: &setup::RigGeometry) -> Vec<f32> {
    let s = g.sample;
    let probes: Vec<Vec3> = (0..=4)
        .flat_map(|a| (0..=4).map(move |b| (a, b)))
        .flat_map(|(a, b)| {
            let p = Vec2::new(s.width_mm * (a as f32 / 4.0 - 0.5), s.height_mm * (b as f32 / 4.0 - 0.5));
            [p.extend(0.0), p.extend(30.0)]
        })
        .collect();
    let t = g.gantry;
    let mut ok: Vec<f32> = (0..)
        .map(|k| t.travel_min_mm + 10.0 * k as f32)
        .take_while(|&x| x <= t.travel_max_mm)
        .filter(|&x| x.abs() >= 0.5 * s.width_mm + g.bar.height_mm)
        .filter(|&x| !probes.iter().any(|&p| g.bar.occludes(x, p, g.camera.position_mm, 2.0)))
        .collect();
    ok.sort_by(|a, b| a.abs().total_cmp(&b.abs()));
    // Light from both sides: a target tilted toward one end of the travel
    // is dark from the other.
    let mut near: Vec<f32> = ok.iter().copied().filter(|&x| x < 0.0).take(3).collect();
    near.extend(ok.iter().copied().filter(|&x| x >= 0.0).take(3));
    near
}

/// Smoothing before corner detection, pixels.
const BLUR_SIGMA: f32 = 1.2;
/// The typical error of a corner's position, pixels (what the priors of
/// the camera solve are weighed against).
const CORNER_NOISE_PX: f64 = 0.1;

/// Corners nearer each other than this (pixels) are one corner: the
/// refinement's window needs squares of at least twice its radius.
const MIN_SPACING: f32 = 3.0;
/// Half-size of the window of the sub-pixel refinement, pixels.
const REFINE_RADIUS: i64 = 5;

/// An X-corner found in an image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Corner {
    /// Continuous pixel coordinates (pixel centres at integer + 0.5).
    pub pixel: Vec2,
    /// The second angular harmonic of the image around the corner (a
    /// complex number): neighbours along a row or column of the board have
    /// opposite phases (their dark squares lie the other way round),
    /// diagonal neighbours the same.
    pub harmonic: Vec2,
}

impl Corner {
    fn opposite(&self, other: &Corner) -> bool {
        self.harmonic.dot(other.harmonic) < 0.0
    }
}

/// X-corners of a checkerboard image.
pub fn detect_corners(img: &Luma) -> Vec<Corner> {
    // The light falls off across a view (many times over, from the LEDs'
    // distances) and from one square to the next (about 10%); squares of
    // unequal brightness pull a blurred corner off its lines' crossing.
    // The image is divided by its local mean first (a blur over about two
    // squares: its ripple from the squares vanishes, with its slope, at
    // every corner). Where nothing is lit the noise is not magnified.
    let local = img.blurred(3.0 * REFINE_RADIUS as f32);
    let floor = 0.05 * local.data.iter().copied().fold(0.0f32, f32::max);
    let flat = Luma {
        width: img.width,
        height: img.height,
        data: img.data.iter().zip(&local.data).map(|(v, m)| v / m.max(floor).max(f32::MIN_POSITIVE)).collect(),
    };
    let s = flat.blurred(BLUR_SIGMA);
    let (w, h) = (img.width as i64, img.height as i64);
    let mut saddle = vec![0.0f32; (w * h) as usize];
    for y in 1..h - 1 {
        for x in 1..w - 1 {
            let c = s.at(x, y);
            let ixx = s.at(x + 1, y) - 2.0 * c + s.at(x - 1, y);
            let iyy = s.at(x, y + 1) - 2.0 * c + s.at(x, y - 1);
            let ixy = 0.25 * (s.at(x + 1, y + 1) - s.at(x + 1, y - 1) - s.at(x - 1, y + 1) + s.at(x - 1, y - 1));
            saddle[(y * w + x) as usize] = (ixy * ixy - ixx * iyy).max(0.0);
        }
    }
    let max = saddle.iter().copied().fold(0.0f32, f32::max);
    if max <= 0.0 {
        return Vec::new();
    }
    let r = 3;
    let mut found: Vec<(f32, Corner)> = Vec::new();
    for y in r..h - r {
        for x in r..w - r {
            let v = saddle[(y * w + x) as usize];
            // Weak saddles are kept (squares vary in contrast); what is
            // not an X-corner fails `x_corner`.
            if v < 0.01 * max {
                continue;
            }
            let is_max = (-r..=r).all(|dy| {
                (-r..=r).all(|dx| {
                    let u = saddle[((y + dy) * w + x + dx) as usize];
                    u < v || (u == v && (dy, dx) <= (0, 0))
                })
            });
            if is_max {
                let q = refine(&s, Vec2::new(x as f32 + 0.5, y as f32 + 0.5));
                if let Some(harmonic) = x_corner(&s, q) {
                    found.push((v, Corner { pixel: q, harmonic }));
                }
            }
        }
    }
    // Noise can split one saddle into maxima a pixel or two apart: the
    // strongest is kept (corners nearer than `MIN_SPACING` are not
    // resolved anyway).
    found.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut out: Vec<Corner> = Vec::new();
    for (_, c) in found {
        if out.iter().all(|o| (o.pixel - c.pixel).length() > MIN_SPACING) {
            out.push(c);
        }
    }
    out
}

/// Whether the image around `q` is an X-corner (four squares, opposite
/// ones alike) rather than the corner of one square against the margin
/// (an L- or T-junction, which also looks like a saddle) or an edge: on a
/// circle about `q`, the image crosses its mean four times and its second
/// angular harmonic outweighs its first (an L-corner's quarter-turn dip
/// has the first harmonic 1.4 times the second; an X-corner none, but for
/// the slope of the light across it). Returns the second harmonic.
fn x_corner(s: &Luma, q: Vec2) -> Option<Vec2> {
    const N: usize = 24;
    let r = REFINE_RADIUS as f32;
    let ring: Vec<f32> = (0..N)
        .map(|k| {
            let a = k as f32 * std::f32::consts::TAU / N as f32;
            bilinear(s, q + r * Vec2::new(a.cos(), a.sin()))
        })
        .collect();
    let mean = ring.iter().sum::<f32>() / N as f32;
    let harmonic = |n: f32| -> Vec2 {
        (0..N)
            .map(|k| {
                let a = n * k as f32 * std::f32::consts::TAU / N as f32;
                (ring[k] - mean) * Vec2::new(a.cos(), a.sin())
            })
            .sum()
    };
    let (first, second) = (harmonic(1.0), harmonic(2.0));
    let crossings = (0..N).filter(|&k| (ring[k] > mean) != (ring[(k + 1) % N] > mean)).count();
    (crossings == 4 && first.length() < 0.5 * second.length()).then_some(second)
}

/// The image at continuous pixel coordinates (centres at integer + 0.5).
fn bilinear(s: &Luma, p: Vec2) -> f32 {
    let (x, y) = (p.x - 0.5, p.y - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (fx, fy) = (x - x0, y - y0);
    let (x0, y0) = (x0 as i64, y0 as i64);
    (1.0 - fy) * ((1.0 - fx) * s.at(x0, y0) + fx * s.at(x0 + 1, y0))
        + fy * ((1.0 - fx) * s.at(x0, y0 + 1) + fx * s.at(x0 + 1, y0 + 1))
}

/// Sub-pixel position of the X-corner near `start`: the point `q` that
/// minimises `sum w (g . (p - q))^2` over the window's gradients `g` at
/// pixel centres `p`.
fn refine(s: &Luma, start: Vec2) -> Vec2 {
    let mut q = start;
    for _ in 0..10 {
        let (cx, cy) = ((q.x - 0.5).round() as i64, (q.y - 0.5).round() as i64);
        let (mut a, mut b, mut c, mut bx, mut by) = (0.0f64, 0.0f64, 0.0f64, 0.0f64, 0.0f64);
        for y in cy - REFINE_RADIUS..=cy + REFINE_RADIUS {
            for x in cx - REFINE_RADIUS..=cx + REFINE_RADIUS {
                let gx = 0.5 * (s.at(x + 1, y) - s.at(x - 1, y)) as f64;
                let gy = 0.5 * (s.at(x, y + 1) - s.at(x, y - 1)) as f64;
                let p = (x as f64 + 0.5, y as f64 + 0.5);
                let d = ((p.0 - q.x as f64).powi(2) + (p.1 - q.y as f64).powi(2)).sqrt();
                // Only the edges' straight runs: nearer the corner than
                // twice the blur the two edges' gradients mix, and squares
                // of unequal brightness pull the crossing off; beyond the
                // radius, other corners.
                let inner = 2.0 * BLUR_SIGMA as f64;
                let wgt = ((d - inner).min(REFINE_RADIUS as f64 - d) + 0.5).clamp(0.0, 1.0);
                a += wgt * gx * gx;
                b += wgt * gx * gy;
                c += wgt * gy * gy;
                bx += wgt * (gx * gx * p.0 + gx * gy * p.1);
                by += wgt * (gx * gy * p.0 + gy * gy * p.1);
            }
        }
        let det = a * c - b * b;
        if det.abs() < 1e-12 {
            break;
        }
        let next = Vec2::new(((c * bx - b * by) / det) as f32, ((a * by - b * bx) / det) as f32);
        if (next - start).length() > REFINE_RADIUS as f32 {
            break;
        }
        let done = (next - q).length() < 1e-3;
        q = next;
        if done {
            break;
        }
    }
    q
}

/// One corner of one view: its index on the board and where it was seen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Seen {
    pub i: u32,
    pub j: u32,
    pub pixel: Vec2,
}

/// Arrange detected corners into the board's lattice. `prior` (the rig
/// file's camera) says which image directions the target's `+x` and `+y`
/// roughly take; the lattice is grown from the detection nearest the
/// middle of all detections.
pub fn grid_corners(
    view: usize,
    detected: &[Corner],
    target: &CheckerTarget,
    prior: &CameraModel,
) -> Result<Vec<Seen>, GeometryError> {
    let want = target.corners_per_side();
    if detected.is_empty() {
        return Err(GeometryError::NoCorners { view });
    }
    let mean = detected.iter().map(|c| c.pixel).sum::<Vec2>() / detected.len() as f32;
    // The detection nearest `p` among those of the opposite polarity to
    // `of` (any, without `of`).
    let nearest = |p: Vec2, of: Option<usize>| -> Option<(usize, f32)> {
        detected
            .iter()
            .enumerate()
            .filter(|(_, c)| of.is_none_or(|o| detected[o].opposite(c)))
            .map(|(k, c)| (k, (c.pixel - p).length()))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    };
    let Some((start, _)) = nearest(mean, None) else { return Err(GeometryError::NoCorners { view }) };
    // The target's axes in the image, from the rig file's camera.
    let axis = |d: Vec3| -> Vec2 {
        let (a, b) = (prior.project(Vec3::ZERO), prior.project(d));
        match (a, b) {
            (Some(a), Some(b)) => (b - a).normalize_or_zero(),
            _ => Vec2::ZERO,
        }
    };
    let (ax, ay) = (axis(Vec3::X), axis(Vec3::Y));
    // The four nearest detections of the opposite polarity are the
    // start's neighbours along the board's rows and columns (a diagonal
    // neighbour, which foreshortening can bring nearer, has the same).
    let at0 = detected[start].pixel;
    let mut near: Vec<(usize, f32)> = detected
        .iter()
        .enumerate()
        .filter(|(_, c)| detected[start].opposite(c))
        .map(|(k, c)| (k, (c.pixel - at0).length()))
        .collect();
    near.sort_by(|a, b| a.1.total_cmp(&b.1));
    let steps: Vec<Vec2> = near.iter().take(4).map(|(k, _)| detected[*k].pixel - at0).collect();
    let best =
        |dir: Vec2| steps.iter().copied().max_by(|a, b| a.normalize().dot(dir).total_cmp(&b.normalize().dot(dir)));
    let (Some(u), Some(v)) = (best(ax), best(ay)) else {
        return Err(GeometryError::Incomplete { view, found: 1, cols: 1, rows: 1, want });
    };
    // Grow: each placed corner predicts its four neighbours from the local
    // lattice step (measured where a neighbour is placed, else the start's).
    let mut at: std::collections::BTreeMap<(i64, i64), usize> = std::collections::BTreeMap::new();
    let mut used = vec![false; detected.len()];
    at.insert((0, 0), start);
    used[start] = true;
    let mut queue = std::collections::VecDeque::from([(0i64, 0i64)]);
    while let Some((i, j)) = queue.pop_front() {
        let here = at[&(i, j)];
        let p = detected[here].pixel;
        for (di, dj) in [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)] {
            let key = (i + di, j + dj);
            if at.contains_key(&key) {
                continue;
            }
            let back = at.get(&(i - di, j - dj)).map(|&k| p - detected[k].pixel);
            let step = back.unwrap_or(if di != 0 { u * di as f32 } else { v * dj as f32 });
            let guess = p + step;
            let tol = 0.2 * step.length();
            if let Some((k, d)) = nearest(guess, Some(here))
                && d <= tol
                && !used[k]
            {
                used[k] = true;
                at.insert(key, k);
                queue.push_back(key);
            }
        }
    }
    // Something beside the board taken for a corner (a speck in line with
    // a row) adds a row or column with a corner or two: while the lattice
    // is wider than the board, the sparser of its outermost lines goes.
    let extent = |at: &std::collections::BTreeMap<(i64, i64), usize>, axis: usize| {
        at.keys()
            .map(|k| if axis == 0 { k.0 } else { k.1 })
            .fold((i64::MAX, i64::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)))
    };
    for axis in 0..2 {
        loop {
            let (lo, hi) = extent(&at, axis);
            if at.is_empty() || hi - lo < want as i64 {
                break;
            }
            let on = |line: i64| at.keys().filter(|k| if axis == 0 { k.0 == line } else { k.1 == line }).count();
            let drop = if on(lo) <= on(hi) { lo } else { hi };
            at.retain(|k, _| if axis == 0 { k.0 != drop } else { k.1 != drop });
        }
    }
    let ((imin, imax), (jmin, jmax)) = (extent(&at, 0), extent(&at, 1));
    let (cols, rows) = ((imax - imin + 1).max(0) as u32, (jmax - jmin + 1).max(0) as u32);
    // The board's full extent fixes the indices; a few corners inside it
    // may be missing (too dim, or a speck of dust), not a quarter.
    if cols != want || rows != want || 4 * at.len() < 3 * (want * want) as usize {
        return Err(GeometryError::Incomplete { view, found: at.len(), cols, rows, want });
    }
    // In board order, rows first (the solve's sums follow this order).
    let mut seen: Vec<Seen> = at
        .iter()
        .map(|(&(i, j), &k)| Seen { i: (i - imin) as u32, j: (j - jmin) as u32, pixel: detected[k].pixel })
        .collect();
    seen.sort_by_key(|s| (s.j, s.i));
    Ok(seen)
}

/// The geometric calibration's result.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraSolution {
    /// The camera in the sample's frame.
    pub camera: CameraModel,
    /// Reprojection error over every corner of every view, pixels.
    pub rms_px: f32,
    pub max_px: f32,
    pub corners: usize,
}

/// Camera parameters as the solver moves them: `CameraModel`'s projection
/// again, in `f64`, because the solve's central differences (step 1e-6)
/// need more than `f32`'s seven digits.
#[derive(Clone, Copy, Debug)]
struct Cam {
    f: f64,
    c: Vector2<f64>,
    k1: f64,
    /// World (sample frame) to camera: rows right, down, forward.
    r: Matrix3<f64>,
    centre: Vector3<f64>,
}

impl Cam {
    fn from_model(m: &CameraModel) -> Self {
        let b = m.basis();
        let row = |v: Vec3| Vector3::new(v.x as f64, v.y as f64, v.z as f64);
        let r = Matrix3::from_rows(&[row(b.right).transpose(), row(b.down).transpose(), row(b.forward).transpose()]);
        let pp = m.principal_px();
        Cam {
            f: b.focal_px as f64,
            c: Vector2::new(pp.x as f64, pp.y as f64),
            k1: m.radial_k[0] as f64,
            r,
            centre: row(m.position_mm),
        }
    }

    fn project(&self, x: &Vector3<f64>) -> Vector2<f64> {
        let p = self.r * (x - self.centre);
        let n = Vector2::new(p.x / p.z, p.y / p.z);
        let d = n * (1.0 + self.k1 * n.norm_squared());
        self.c + self.f * d
    }

    fn to_model(self, like: &CameraModel) -> CameraModel {
        let v = |a: Vector3<f64>| Vec3::new(a.x as f32, a.y as f32, a.z as f32);
        // `CameraModel` rebuilds `right` as `forward x up`, with `up = -down`.
        let (down, forward) = (self.r.row(1).transpose(), self.r.row(2).transpose());
        let position = v(self.centre);
        let dist = (like.look_at_mm - like.position_mm).length().max(1.0);
        let half_px = 0.5 * like.height as f64;
        CameraModel {
            position_mm: position,
            look_at_mm: position + dist * v(forward),
            up: -v(down),
            fov_y_deg: (2.0 * (half_px / self.f).atan()).to_degrees() as f32,
            principal_offset_px: Vec2::new(
                (self.c.x - 0.5 * like.width as f64) as f32,
                (self.c.y - 0.5 * like.height as f64) as f32,
            ),
            radial_k: [self.k1 as f32, 0.0],
            ..*like
        }
    }
}

/// A plane's rotation and origin in the sample frame.
type Pose = (Matrix3<f64>, Vector3<f64>);

/// The least-squares problem: parameters `[f, cx, cy, k1, w_cam(3), c(3)]`
/// then `[w(3), t(3)]` per propped view (its rotation vector and origin in
/// the sample frame, relative to its initial pose).
struct Problem<'a> {
    start: Cam,
    propped0: Vec<Pose>,
    views: &'a [Vec<(Vec2, Vec2)>],
}

impl Problem<'_> {
    fn unpack(&self, u: &DVector<f64>) -> (Cam, Vec<Pose>) {
        let rot = |k: usize| *Rotation3::new(Vector3::new(u[k], u[k + 1], u[k + 2])).matrix();
        let cam = Cam {
            f: self.start.f * (1.0 + u[0]),
            c: self.start.c + Vector2::new(u[1], u[2]),
            k1: u[3],
            r: self.start.r * rot(4),
            centre: self.start.centre + Vector3::new(u[7], u[8], u[9]),
        };
        let poses = self
            .propped0
            .iter()
            .enumerate()
            .map(|(k, (r0, t0))| (rot(10 + 6 * k) * r0, t0 + Vector3::new(u[13 + 6 * k], u[14 + 6 * k], u[15 + 6 * k])))
            .collect();
        (cam, poses)
    }

    /// Corner residuals, then the priors: the rig file's focal length,
    /// centred principal point and no distortion, each to within the
    /// tolerance of a bench rig (2%, 10 px, `k1` 0.1), weighed as if a
    /// corner's error were `CORNER_NOISE_PX`. Where the views determine a
    /// parameter the prior does not bind; where they cannot (distortion
    /// over a narrow field, which moves the sample's image by a fifth of a
    /// pixel at most) it keeps the solution from wandering along the
    /// family of cameras that fit equally well.
    fn residuals_at(&self, u: &DVector<f64>) -> DVector<f64> {
        let mut r = self.corner_residuals(u);
        let n = r.len();
        r = r.resize_vertically(n + 4, 0.0);
        let w = CORNER_NOISE_PX;
        r[n] = w * u[0] / 0.02;
        r[n + 1] = w * u[1] / 10.0;
        r[n + 2] = w * u[2] / 10.0;
        r[n + 3] = w * u[3] / 0.1;
        r
    }

    fn corner_residuals(&self, u: &DVector<f64>) -> DVector<f64> {
        let (cam, poses) = self.unpack(u);
        let mut r = Vec::new();
        for (v, seen) in self.views.iter().enumerate() {
            let (rot, t) = if v == 0 { (Matrix3::identity(), Vector3::zeros()) } else { poses[v - 1] };
            for (xy, px) in seen {
                let x = rot * Vector3::new(xy.x as f64, xy.y as f64, 0.0) + t;
                let p = cam.project(&x);
                r.push(p.x - px.x as f64);
                r.push(p.y - px.y as f64);
            }
        }
        crate::lsq::finite_or(DVector::from_vec(r), 1e6)
    }
}

/// Homography from plane points to pixels (direct linear transform on
/// normalised coordinates; `h33 = 1` is not assumed).
fn homography(pairs: &[(Vec2, Vec2)]) -> Option<Matrix3<f64>> {
    let norm = |pts: Vec<Vector2<f64>>| {
        let n = pts.len() as f64;
        let c = pts.iter().sum::<Vector2<f64>>() / n;
        let s = (pts.iter().map(|p| (p - c).norm()).sum::<f64>() / n).max(1e-12) / 2f64.sqrt();
        Matrix3::new(1.0 / s, 0.0, -c.x / s, 0.0, 1.0 / s, -c.y / s, 0.0, 0.0, 1.0)
    };
    let v2 = |p: Vec2| Vector2::new(p.x as f64, p.y as f64);
    let ta = norm(pairs.iter().map(|p| v2(p.0)).collect());
    let tb = norm(pairs.iter().map(|p| v2(p.1)).collect());
    let mut a = DMatrix::zeros(2 * pairs.len(), 9);
    for (k, (x, u)) in pairs.iter().enumerate() {
        let x = ta * Vector3::new(x.x as f64, x.y as f64, 1.0);
        let u = tb * Vector3::new(u.x as f64, u.y as f64, 1.0);
        let (x, y, ux, uy) = (x.x, x.y, u.x, u.y);
        let r0 = [-x, -y, -1.0, 0.0, 0.0, 0.0, ux * x, ux * y, ux];
        let r1 = [0.0, 0.0, 0.0, -x, -y, -1.0, uy * x, uy * y, uy];
        for c in 0..9 {
            a[(2 * k, c)] = r0[c];
            a[(2 * k + 1, c)] = r1[c];
        }
    }
    let svd = a.svd(false, true);
    let vt = svd.v_t?;
    let (kmin, _) = svd.singular_values.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1))?;
    let h = vt.row(kmin);
    let hn = Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], h[8]);
    Some(tb.try_inverse()? * hn * ta)
}

/// The pose (rotation, origin) in the sample frame of a plane seen through
/// homography `h` by camera `cam` (distortion neglected: a starting point).
fn plane_pose(cam: &Cam, h: &Matrix3<f64>) -> Option<Pose> {
    let k = Matrix3::new(cam.f, 0.0, cam.c.x, 0.0, cam.f, cam.c.y, 0.0, 0.0, 1.0);
    let m = k.try_inverse()? * h;
    let (h1, h2, h3) = (m.column(0).into_owned(), m.column(1).into_owned(), m.column(2).into_owned());
    let mut s = 2.0 / (h1.norm() + h2.norm());
    if h3.z * s < 0.0 {
        s = -s; // the plane is in front of the camera
    }
    let r1 = h1 * s;
    let r2 = h2 * s;
    let r3 = r1.cross(&r2);
    let approx = Matrix3::from_columns(&[r1, r2, r3]);
    // Nearest rotation.
    let svd = approx.svd(true, true);
    let rc = svd.u? * svd.v_t?;
    let tc = h3 * s;
    // Camera frame to sample frame.
    let rt = cam.r.transpose();
    Some((rt * rc, rt * tc + cam.centre))
}

/// Per-corner reprojection distances from stacked `(dx, dy)` residuals.
fn distances(r: &DVector<f64>) -> Vec<f64> {
    (0..r.len() / 2).map(|k| (r[2 * k].powi(2) + r[2 * k + 1].powi(2)).sqrt()).collect()
}

fn rms(d: &[f64]) -> f64 {
    (d.iter().map(|x| x * x).sum::<f64>() / d.len().max(1) as f64).sqrt()
}

/// Solve the camera from views of the target: view 0 flat in the sample
/// holder (its frame is the sample's), the others anywhere. `prior` is the
/// rig file's camera, the starting point.
pub fn solve_camera(
    target: &CheckerTarget,
    views: &[Vec<Seen>],
    prior: &CameraModel,
) -> Result<CameraSolution, GeometryError> {
    let pairs: Vec<Vec<(Vec2, Vec2)>> =
        views.iter().map(|v| v.iter().map(|s| (target.corner(s.i, s.j), s.pixel)).collect()).collect();
    let start = Cam::from_model(prior);
    let mut propped0 = Vec::new();
    for v in pairs.iter().skip(1) {
        let pose =
            homography(v).and_then(|h| plane_pose(&start, &h)).unwrap_or((Matrix3::identity(), Vector3::zeros()));
        propped0.push(pose);
    }
    let n = 10 + 6 * propped0.len();
    // Central differences: every parameter is a small correction, of order
    // 1e-3 (relative focal length, radians) to 10 (pixels, millimetres).
    let solve = |views: &[Vec<(Vec2, Vec2)>], u0: DVector<f64>| {
        let problem = Problem { start, propped0: propped0.clone(), views };
        let numeric = Numeric::new(|u: &DVector<f64>| problem.residuals_at(u), u0, Step::Central(1e-6));
        let (solved, _report) = LevenbergMarquardt::new().with_patience(200).minimize(numeric);
        let d = distances(&problem.corner_residuals(&solved.u));
        (solved.u, d)
    };
    let (u, d) = solve(&pairs, DVector::zeros(n));
    // A corner far off the solution (a speck taken for a corner, a corner
    // shifted by clipping) is dropped, once, and the camera solved again
    // from the solution so far.
    let first = rms(&d);
    let mut k = 0;
    let kept: Vec<Vec<(Vec2, Vec2)>> = pairs
        .iter()
        .map(|v| {
            v.iter()
                .copied()
                .filter(|_| {
                    k += 1;
                    d[k - 1] <= (3.0 * first).max(0.5)
                })
                .collect()
        })
        .collect();
    let (u, d) = solve(&kept, u);
    let corners = d.len();
    let rms_px = rms(&d) as f32;
    let max_px = d.iter().copied().fold(0.0, f64::max) as f32;
    if !rms_px.is_finite() || rms_px > 2.0 {
        return Err(GeometryError::Diverged { rms_px });
    }
    let (cam, _) = Problem { start, propped0, views: &kept }.unpack(&u);
    Ok(CameraSolution { camera: cam.to_model(prior), rms_px, max_px, corners })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic image of the target seen by `cam` (anti-aliased by
    /// supersampling), lit evenly.
    fn render(cam: &CameraModel, target: &CheckerTarget, pose: (glam::Mat3, Vec3)) -> Luma {
        let (w, h) = (cam.width, cam.height);
        let normal = pose.0 * Vec3::Z;
        let mut data = vec![0.0f32; (w * h) as usize];
        for v in 0..h {
            for u in 0..w {
                let mut acc = 0.0;
                for s in 0..8 {
                    for t in 0..8 {
                        let px = Vec2::new(u as f32 + (s as f32 + 0.5) / 8.0, v as f32 + (t as f32 + 0.5) / 8.0);
                        let q =
                            cam.pixel_to(px, pose.1, normal).map(|p| (pose.0.transpose() * (p - pose.1)).truncate());
                        acc += match q {
                            Some(q) if target.is_dark(q) => 0.05,
                            Some(_) => 0.8,
                            None => 0.0,
                        };
                    }
                }
                data[(v * w + u) as usize] = 1000.0 * acc / 64.0;
            }
        }
        Luma { width: w, height: h, data }
    }

    #[test]
    fn a_camera_off_its_rig_file_is_recovered_from_two_views() {
        let target = CheckerTarget::default();
        let prior = CameraModel::oblique(45.0, 450.0, 15.0, 256, 256);
        // The true camera: moved 2 mm, turned about 1 degree, focal 2%
        // longer, principal point 8 px off, barrel distortion.
        let mut truth = prior;
        truth.position_mm += Vec3::new(1.5, -2.0, 1.0);
        truth.look_at_mm += Vec3::new(4.0, 6.0, -3.0);
        truth.fov_y_deg = 2.0 * ((0.5 * prior.fov_y_deg.to_radians()).tan() / 1.02).atan().to_degrees();
        truth.principal_offset_px = Vec2::new(-8.0, 5.0);
        truth.radial_k = [-0.08, 0.0];
        let flat = (glam::Mat3::IDENTITY, Vec3::ZERO);
        let poses = [
            flat,
            (glam::Mat3::from_rotation_y(-0.35) * glam::Mat3::from_rotation_z(0.1), Vec3::new(5.0, 3.0, 15.0)),
            (glam::Mat3::from_rotation_x(0.35) * glam::Mat3::from_rotation_z(-0.05), Vec3::new(-3.0, 2.0, 12.0)),
            (glam::Mat3::from_rotation_x(-0.35), Vec3::new(2.0, -4.0, 12.0)),
        ];
        let mut views = Vec::new();
        for (k, pose) in poses.into_iter().enumerate() {
            let img = render(&truth, &target, pose);
            let corners = detect_corners(&img);
            let seen = grid_corners(k, &corners, &target, &prior).unwrap();
            views.push(seen);
        }
        let sol = solve_camera(&target, &views, &prior).unwrap();
        assert!(sol.rms_px < 0.1, "reprojection {} px", sol.rms_px);
        let c = sol.camera;
        assert!((c.position_mm - truth.position_mm).length() < 1.0, "{} vs {}", c.position_mm, truth.position_mm);
        assert!((c.principal_offset_px - truth.principal_offset_px).length() < 2.0, "{}", c.principal_offset_px);
        assert!((c.fov_y_deg / truth.fov_y_deg - 1.0).abs() < 0.005, "{} vs {}", c.fov_y_deg, truth.fov_y_deg);
        // What the fitter uses: where a sample point is seen.
        for p in [Vec3::ZERO, Vec3::new(45.0, -45.0, 0.0), Vec3::new(-45.0, 40.0, 0.0)] {
            let e = (c.project(p).unwrap() - truth.project(p).unwrap()).length();
            assert!(e < 0.15, "{p} projects {e} px off");
        }
    }

    #[test]
    fn a_target_partly_out_of_view_is_refused() {
        let target = CheckerTarget::default();
        let prior = CameraModel::oblique(45.0, 450.0, 15.0, 256, 256);
        let mut cam = prior;
        cam.look_at_mm = Vec3::new(0.0, 40.0, 0.0);
        let img = render(&cam, &target, (glam::Mat3::IDENTITY, Vec3::ZERO));
        let e = grid_corners(0, &detect_corners(&img), &target, &prior).unwrap_err();
        assert!(matches!(e, GeometryError::Incomplete { .. }), "{e}");
        assert!(e.to_string().contains("in view"));
    }
}
