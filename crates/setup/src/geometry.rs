//! Rig geometry in millimetres, in the sample frame: the sample plane is
//! `z = 0`, its centre the origin, `+x` the gantry's direction of travel,
//! `+z` up toward the light bar.

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use crate::camera::CameraModel;

/// The flat sample, centred at the origin.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SampleArea {
    pub width_mm: f32,
    pub height_mm: f32,
}

impl SampleArea {
    pub fn contains(&self, p: Vec2) -> bool {
        p.x.abs() <= 0.5 * self.width_mm && p.y.abs() <= 0.5 * self.height_mm
    }
}

/// A matte white patch fixed beside the sample, level with its surface and
/// in the camera's view, that every frame of a capture sees lit by the same
/// LED as the sample: what the LEDs' intensity drift during a capture is
/// measured from (`fit::drift`). Its albedo need not be known; it must not
/// change between the white scan and the capture.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ReferencePatch {
    /// Its centre in the sample plane, mm.
    pub centre_mm: Vec2,
    /// Its extent along `x` and `y`, mm.
    pub size_mm: Vec2,
}

impl ReferencePatch {
    /// Whether `p` (sample plane, mm) lies on the patch at least
    /// `margin_mm` inside its edges.
    pub fn contains(&self, p: Vec2, margin_mm: f32) -> bool {
        let d = (p - self.centre_mm).abs();
        d.x <= 0.5 * self.size_mm.x - margin_mm && d.y <= 0.5 * self.size_mm.y - margin_mm
    }
}

/// The bar of LEDs carried by the gantry, parallel to `y`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LedBar {
    pub n_leds: u8,
    pub pitch_mm: f32,
    /// `y` of LED 0.
    pub first_led_y_mm: f32,
    /// Height of the LEDs (the bar's underside) above the sample.
    pub height_mm: f32,
    /// Extent of the bar along `x` (it blocks the camera's view).
    pub width_mm: f32,
    pub thickness_mm: f32,
}

impl LedBar {
    /// Position of LED `k` with the bar's centre line at `bar_x_mm`.
    pub fn led_position(&self, bar_x_mm: f32, k: u8) -> Vec3 {
        Vec3::new(bar_x_mm, self.first_led_y_mm + k as f32 * self.pitch_mm, self.height_mm)
    }

    /// Does the bar, at `bar_x_mm`, block the straight path from `p` (on
    /// the sample) to `eye`? `margin_mm` grows the bar on every side (the
    /// fitter masks conservatively; the simulator renders with 0).
    pub fn occludes(&self, bar_x_mm: f32, p: Vec3, eye: Vec3, margin_mm: f32) -> bool {
        self.shadow_span(p, eye, margin_mm).is_some_and(|(lo, hi)| lo <= bar_x_mm && bar_x_mm <= hi)
    }

    /// The bar positions (its centre line's `x`, lowest and highest) at
    /// which it blocks the straight path from `p` to `eye`, or `None` where
    /// no position does. The path's stretch at the bar's `y` and height does
    /// not depend on where the bar is along `x`, so a renderer that looks
    /// from fixed points computes this once per point, not per frame.
    pub fn shadow_span(&self, p: Vec3, eye: Vec3, margin_mm: f32) -> Option<(f32, f32)> {
        let y0 = self.first_led_y_mm - 0.5 * self.pitch_mm - margin_mm;
        let y1 = self.first_led_y_mm + (self.n_leds as f32 - 0.5) * self.pitch_mm + margin_mm;
        let z0 = self.height_mm - margin_mm;
        let z1 = self.height_mm + self.thickness_mm + margin_mm;
        let d = eye - p;
        // Slab test along y and z: the part `t0..t1` of the segment
        // `p + t d`, `t` in 0..1, inside the bar's cross-section.
        let (mut t0, mut t1) = (0.0f32, 1.0f32);
        for (a, d, lo, hi) in [(p.y, d.y, y0, y1), (p.z, d.z, z0, z1)] {
            if d.abs() < 1e-12 {
                if a < lo || a > hi {
                    return None;
                }
            } else {
                let (ta, tb) = ((lo - a) / d, (hi - a) / d);
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
                if t0 > t1 {
                    return None;
                }
            }
        }
        // Along x that part spans `xa..xb`; the bar blocks it when its
        // width overlaps that span.
        let (xa, xb) = if d.x.abs() < 1e-12 { (p.x, p.x) } else { (p.x + d.x * t0, p.x + d.x * t1) };
        let half = 0.5 * self.width_mm + margin_mm;
        Some((xa.min(xb) - half, xa.max(xb) + half))
    }
}

/// Mechanical limits of the gantry (positions of the bar's centre line).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Gantry {
    pub travel_min_mm: f32,
    pub travel_max_mm: f32,
    pub speed_mm_s: f32,
    pub accel_mm_s2: f32,
    pub settle_ms: f32,
    pub homing_speed_mm_s: f32,
}

/// Seconds a move over `dist` takes at top speed `speed` and acceleration
/// `accel` (any one length unit): a trapezoidal profile, triangular when the
/// move is too short to reach full speed. The one motion model of the rig:
/// the gantry's plan time, the emulator's physics and the driver's
/// prediction of `MoveDone` all use it.
pub fn trapezoid_seconds(dist: f64, speed: f64, accel: f64) -> f64 {
    let d = dist.abs();
    let (v, a) = (speed.max(1e-9), accel.max(1e-9));
    if d >= v * v / a { d / v + v / a } else { 2.0 * (d / a).sqrt() }
}

impl Gantry {
    /// Seconds a move of `dist_mm` takes at this gantry's speed and
    /// acceleration, settling excluded.
    pub fn move_seconds(&self, dist_mm: f32) -> f64 {
        trapezoid_seconds(dist_mm as f64, self.speed_mm_s as f64, self.accel_mm_s2 as f64)
    }
}

/// LED emission: intensity falls off with the angle from the LED's axis
/// (straight down) as `cos^m`; real LEDs are near `m = 1` (Lambertian).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LedEmission {
    pub profile_exponent: f32,
    /// Current the plan drives the LEDs at.
    pub current_ma: u16,
}

impl LedEmission {
    /// Relative intensity toward a point at `cos_emit` from the LED axis.
    pub fn profile(&self, cos_emit: f32) -> f32 {
        cos_emit.max(0.0).powf(self.profile_exponent)
    }
}

/// Everything about the rig's shape.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RigGeometry {
    pub sample: SampleArea,
    pub bar: LedBar,
    pub gantry: Gantry,
    pub emission: LedEmission,
    pub camera: CameraModel,
    /// The white patches beside the sample that LED drift is measured from
    /// (none in a rig file that predates them: drift is then not corrected).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub references: Vec<ReferencePatch>,
}

impl Default for RigGeometry {
    /// The design's default rig: a 10 x 10 cm sample, 40 LEDs at 5 mm pitch
    /// 4 cm above it, travel -12..+12 cm, and a camera 45 degrees from the
    /// normal on the `-x` side, 45 cm away.
    fn default() -> Self {
        Self {
            sample: SampleArea { width_mm: 100.0, height_mm: 100.0 },
            bar: LedBar {
                n_leds: 40,
                pitch_mm: 5.0,
                first_led_y_mm: -97.5,
                height_mm: 40.0,
                width_mm: 10.0,
                thickness_mm: 12.0,
            },
            gantry: Gantry {
                travel_min_mm: -120.0,
                travel_max_mm: 120.0,
                speed_mm_s: 100.0,
                accel_mm_s2: 1000.0,
                settle_ms: 30.0,
                homing_speed_mm_s: 50.0,
            },
            emission: LedEmission { profile_exponent: 1.0, current_ma: 200 },
            camera: CameraModel::oblique(45.0, 450.0, 15.0, 256, 256),
            // One patch past each end of the sample along the travel, so
            // that every carriage position has one within about 75 mm
            // whose view the bar does not block (it hides the near one
            // with the carriage near -100 mm, the far one near +20 mm).
            // The camera sees the plane to about -74 and +96 mm on `y = 0`.
            references: vec![
                ReferencePatch { centre_mm: Vec2::new(-62.0, 0.0), size_mm: Vec2::new(10.0, 80.0) },
                ReferencePatch { centre_mm: Vec2::new(65.0, 0.0), size_mm: Vec2::new(14.0, 100.0) },
            ],
        }
    }
}

/// The rectified grid of sample points the fitter solves for and the
/// material maps are stored on. Row 0 is the far edge (`y = +h/2`), column 0
/// the `x = -w/2` edge, so a map viewed as an image is a top view with `x`
/// to the right and `y` up.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PointGrid {
    pub cols: u32,
    pub rows: u32,
}

impl PointGrid {
    pub fn len(&self) -> usize {
        (self.cols * self.rows) as usize
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Position (mm) of point `(col, row)` on a sample.
    pub fn position(&self, sample: &SampleArea, col: u32, row: u32) -> Vec2 {
        Vec2::new(
            -0.5 * sample.width_mm + (col as f32 + 0.5) * sample.width_mm / self.cols as f32,
            0.5 * sample.height_mm - (row as f32 + 0.5) * sample.height_mm / self.rows as f32,
        )
    }

    /// Position of point index `i` (row-major).
    pub fn position_of(&self, sample: &SampleArea, i: usize) -> Vec2 {
        self.position(sample, (i % self.cols as usize) as u32, (i / self.cols as usize) as u32)
    }

    /// For each point, the point that stands in for it: itself where
    /// `measured`, else the nearest measured point (Euclidean distance on
    /// the grid; of equals, the lowest index). Every point is its own
    /// stand-in when none is measured.
    pub fn stand_ins(&self, measured: &[bool]) -> Vec<u32> {
        let (cols, rows) = (self.cols as i64, self.rows as i64);
        let any = measured.iter().any(|&m| m);
        (0..self.len())
            .map(|i| {
                if !any || measured.get(i).copied().unwrap_or(false) {
                    return i as u32;
                }
                let (c0, r0) = (i as i64 % cols, i as i64 / cols);
                let mut best: Option<(i64, usize)> = None;
                // Ring by ring outward; a ring `r` holds no point nearer
                // than `r`, so once `r^2` exceeds the best distance the
                // search is over.
                for r in 1..cols.max(rows) {
                    if best.is_some_and(|(d, _)| r * r > d) {
                        break;
                    }
                    for dr in -r..=r {
                        for dc in -r..=r {
                            if dr.abs() != r && dc.abs() != r {
                                continue;
                            }
                            let (c, w) = (c0 + dc, r0 + dr);
                            if c < 0 || w < 0 || c >= cols || w >= rows {
                                continue;
                            }
                            let j = (w * cols + c) as usize;
                            let d = dc * dc + dr * dr;
                            if measured[j] && best.is_none_or(|(bd, bj)| d < bd || (d == bd && j < bj)) {
                                best = Some((d, j));
                            }
                        }
                    }
                }
                best.map_or(i as u32, |(_, j)| j as u32)
            })
            .collect()
    }

    /// Continuous grid coordinates `(col, row)` of a sample position
    /// (cell centres at integer + 0.5).
    pub fn coords(&self, sample: &SampleArea, p: Vec2) -> Vec2 {
        Vec2::new(
            (p.x + 0.5 * sample.width_mm) / sample.width_mm * self.cols as f32,
            (0.5 * sample.height_mm - p.y) / sample.height_mm * self.rows as f32,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bar_blocks_the_camera_where_it_should() {
        let g = RigGeometry::default();
        let eye = g.camera.position_mm;
        // The camera looks down at 45 degrees from -x: a ray from the
        // sample point x = 0 crosses z = 40 mm near x = -40 mm.
        let p = Vec3::ZERO;
        assert!(g.bar.occludes(-40.0, p, eye, 0.0));
        assert!(!g.bar.occludes(0.0, p, eye, 0.0));
        assert!(!g.bar.occludes(-80.0, p, eye, 0.0));
        // Off the end of the bar in y nothing is blocked.
        assert!(!g.bar.occludes(-40.0 + 0.0, Vec3::new(0.0, 150.0, 0.0), eye + Vec3::new(0.0, 150.0, 0.0), 0.0));
    }

    /// The span of blocking bar positions is the slab test of the whole
    /// box (x, y and z at once) at every bar position, away from the span's
    /// edges (where the two forms round differently).
    #[test]
    fn shadow_span_is_where_the_bar_box_meets_the_line_of_sight() {
        fn box_hit(a: Vec3, b: Vec3, lo: Vec3, hi: Vec3) -> bool {
            let d = b - a;
            let (mut t0, mut t1) = (0.0f32, 1.0f32);
            for k in 0..3 {
                if d[k] == 0.0 {
                    if a[k] < lo[k] || a[k] > hi[k] {
                        return false;
                    }
                    continue;
                }
                let (ta, tb) = ((lo[k] - a[k]) / d[k], (hi[k] - a[k]) / d[k]);
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
            t0 <= t1
        }
        let bar = RigGeometry::default().bar;
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = |lo: f32, hi: f32| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            lo + (hi - lo) * (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let (mut blocked, mut clear) = (0, 0);
        for _ in 0..200_000 {
            let p = Vec3::new(uniform(-60.0, 60.0), uniform(-60.0, 260.0), 0.0);
            let eye = Vec3::new(uniform(-300.0, 300.0), uniform(-100.0, 300.0), uniform(5.0, 400.0));
            let margin = if uniform(0.0, 1.0) < 0.5 { 0.0 } else { 2.0 };
            let x = uniform(-150.0, 150.0);
            let y0 = bar.first_led_y_mm - 0.5 * bar.pitch_mm - margin;
            let y1 = bar.first_led_y_mm + (bar.n_leds as f32 - 0.5) * bar.pitch_mm + margin;
            let hit = |x: f32| {
                let lo = Vec3::new(x - 0.5 * bar.width_mm - margin, y0, bar.height_mm - margin);
                let hi = Vec3::new(x + 0.5 * bar.width_mm + margin, y1, bar.height_mm + bar.thickness_mm + margin);
                box_hit(p, eye, lo, hi)
            };
            let want = hit(x);
            if hit(x - 1e-3) != want || hit(x + 1e-3) != want {
                continue;
            }
            assert_eq!(bar.occludes(x, p, eye, margin), want, "bar at {x}, p {p}, eye {eye}, margin {margin}");
            if want { blocked += 1 } else { clear += 1 }
        }
        assert!(blocked > 1000 && clear > 1000, "{blocked} blocked, {clear} clear");
    }

    #[test]
    fn unmeasured_points_borrow_their_nearest_measured_neighbour() {
        let g = PointGrid { cols: 5, rows: 4 };
        // Only the inner 3 x 2 block is measured.
        let measured: Vec<bool> =
            (0..g.len()).map(|i| (1..4).contains(&(i % 5)) && (1..3).contains(&(i / 5))).collect();
        let s = g.stand_ins(&measured);
        for i in 0..g.len() {
            let j = s[i] as usize;
            assert!(measured[j], "point {i} borrows unmeasured {j}");
            let d = |a: usize, b: usize| (a % 5).abs_diff(b % 5).pow(2) + (a / 5).abs_diff(b / 5).pow(2);
            let nearest = (0..g.len()).filter(|&k| measured[k]).map(|k| d(i, k)).min().unwrap();
            assert_eq!(d(i, j), nearest, "point {i} borrows {j}, not a nearest one");
        }
        assert_eq!(s[6], 6, "a measured point stands for itself");
        assert_eq!(s[0], 6, "a corner takes the diagonal neighbour");
        assert_eq!(g.stand_ins(&[false; 20]), (0..20).collect::<Vec<u32>>(), "nothing measured: nothing to borrow");
    }

    #[test]
    fn point_grid_round_trips() {
        let s = SampleArea { width_mm: 100.0, height_mm: 80.0 };
        let g = PointGrid { cols: 10, rows: 8 };
        let p = g.position(&s, 3, 5);
        let c = g.coords(&s, p);
        assert!((c - Vec2::new(3.5, 5.5)).length() < 1e-4);
        assert!(g.position(&s, 0, 0).y > 0.0);
    }
}
