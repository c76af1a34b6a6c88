//! The simulated rig's hidden physical truth: where its parts really are,
//! as opposed to what its rig file says.
//!
//! A real rig is built to a drawing within tolerances and its rig file is
//! the drawing. [`RigTruth::perturbed`] draws a rig that departs from its
//! file by errors of the size a lab bench has (the table of
//! [`Tolerances`], documented in RIGFILE.md); only the simulated camera
//! sees it. The host knows the rig file and whatever its calibrations
//! measured, so every error here reaches the fit unless a calibration
//! finds it. [`RigTruth::ideal`] is the rig exactly as filed (for tests
//! that isolate the method from the rig).
//!
//! What is modelled, in the sample frame of the rig file (`z = 0` the
//! nominal sample plane):
//! - the camera's pose, focal length, principal point and radial
//!   distortion (a [`CameraModel`] of its own);
//! - each LED's position on the bar, the bar's height, its tilt along its
//!   length (roll) and its skew to the travel (yaw);
//! - the gantry: an offset and a scale between commanded and physical
//!   position, and backlash (the carriage lags by half of it behind the
//!   direction of its last move);
//! - the sample's height above the nominal plane and its tilt;
//! - light in the room: an ambient irradiance on everything in view;
//! - the sensor's dark current (per pixel, with a few hot pixels);
//! - the LEDs' intensity drift as the bar warms ([`RigTruth::drift`]).
//!
//! The LEDs' axes are square to the bar, tilting with its roll
//! ([`RigTruth::led_axis`]).
//!
//! Not modelled: the bar cooling while its LEDs are off (a pause, or the
//! time between two runs of the simulator, which starts cold), and the
//! bar's shadow box tilting with it (the occluder moves with the bar's
//! height and the carriage's true position). The LEDs' spread and emission
//! profile are [`crate::camera::LedTruth`]'s.

use glam::{Mat3, Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use rand_pcg::Pcg64;
use setup::{CameraModel, RigGeometry};

/// Where the simulated operator lays the checkerboard for each view of the
/// geometric calibration: flat in the holder, then propped up about 20
/// degrees three ways (toward the camera, and toward either side), a
/// little off centre and turned, as hands would (rotation and origin in the
/// sample surface's frame).
pub fn target_placements() -> [Option<(Mat3, Vec3)>; 4] {
    [
        None,
        Some((Mat3::from_rotation_y(-0.35) * Mat3::from_rotation_z(0.1), Vec3::new(5.0, 3.0, 15.0))),
        Some((Mat3::from_rotation_x(0.35) * Mat3::from_rotation_z(-0.05), Vec3::new(-3.0, 2.0, 12.0))),
        Some((Mat3::from_rotation_x(-0.35), Vec3::new(2.0, -4.0, 12.0))),
    ]
}

/// Seconds of LED on-time (all LEDs together) over which the bar warms by
/// 63% of the way to its steady temperature. An assumed figure, not a
/// measured one: of the order of a small heat-sunk bar, and short enough
/// that a capture of a few thousand 20 ms shots drifts by much of its
/// range (what the drift correction must then undo).
pub const WARMUP_ON_S: f64 = 60.0;

/// The largest error of each kind a perturbed rig has. Each error is drawn
/// normal with a standard deviation of half its tolerance and clipped at
/// the tolerance, independently per component (per axis, per LED).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tolerances {
    pub camera_position_mm: f32,
    pub camera_rotation_deg: f32,
    /// Relative error of the focal length.
    pub focal: f32,
    /// Principal point offset per axis, as a fraction of the image width
    /// (the same physical offset at every resolution the camera is read
    /// at; 10 px on the default 256 px camera).
    pub principal_point: f32,
    /// First radial distortion coefficient (`k1`).
    pub radial_k1: f32,
    pub led_position_mm: f32,
    pub bar_height_mm: f32,
    pub bar_tilt_deg: f32,
    pub gantry_offset_mm: f32,
    /// Relative error of the gantry's scale.
    pub gantry_scale: f32,
    /// Backlash is drawn uniform in `[0, backlash_mm]`.
    pub backlash_mm: f32,
    pub sample_height_mm: f32,
    pub sample_tilt_deg: f32,
    /// Ambient irradiance, drawn uniform in `[0, ambient]`, as a fraction
    /// of the irradiance the nearest LED gives at the bar's nominal height.
    pub ambient: f32,
    /// Mean dark current, electrons per second (drawn uniform in
    /// `[0, dark_current_e_s]`); each pixel's rate is exponentially
    /// distributed about it.
    pub dark_current_e_s: f32,
    /// Fraction of pixels that are hot.
    pub hot_pixel_fraction: f32,
    /// A hot pixel's dark current, electrons per second.
    pub hot_pixel_e_s: f32,
    /// The largest loss of an LED's intensity once the bar is warm; each
    /// LED's loss is drawn uniform in `[led_drift / 2, led_drift]`.
    pub led_drift: f32,
}

impl Tolerances {
    /// These tolerances with every error of the parts not kept set to
    /// zero (the draw is otherwise the same: each error keeps its place in
    /// the seed's sequence).
    pub fn keeping(self, camera: bool, leds: bool, gantry: bool, sample: bool, sensor: bool, drift: bool) -> Self {
        let z = |keep: bool, v: f32| if keep { v } else { 0.0 };
        Self {
            camera_position_mm: z(camera, self.camera_position_mm),
            camera_rotation_deg: z(camera, self.camera_rotation_deg),
            focal: z(camera, self.focal),
            principal_point: z(camera, self.principal_point),
            radial_k1: z(camera, self.radial_k1),
            led_position_mm: z(leds, self.led_position_mm),
            bar_height_mm: z(leds, self.bar_height_mm),
            bar_tilt_deg: z(leds, self.bar_tilt_deg),
            gantry_offset_mm: z(gantry, self.gantry_offset_mm),
            gantry_scale: z(gantry, self.gantry_scale),
            backlash_mm: z(gantry, self.backlash_mm),
            sample_height_mm: z(sample, self.sample_height_mm),
            sample_tilt_deg: z(sample, self.sample_tilt_deg),
            ambient: z(sensor, self.ambient),
            dark_current_e_s: z(sensor, self.dark_current_e_s),
            hot_pixel_fraction: z(sensor, self.hot_pixel_fraction),
            hot_pixel_e_s: z(sensor, self.hot_pixel_e_s),
            led_drift: z(drift, self.led_drift),
        }
    }
}

impl Default for Tolerances {
    /// A rig assembled with care from machined parts and an off-the-shelf
    /// machine-vision camera and lens, aligned by eye and tape measure.
    fn default() -> Self {
        Self {
            camera_position_mm: 2.0,
            camera_rotation_deg: 1.0,
            focal: 0.02,
            principal_point: 10.0 / 256.0,
            radial_k1: 0.1,
            led_position_mm: 0.5,
            bar_height_mm: 1.0,
            bar_tilt_deg: 0.5,
            gantry_offset_mm: 1.0,
            gantry_scale: 0.005,
            backlash_mm: 0.1,
            sample_height_mm: 0.5,
            sample_tilt_deg: 0.5,
            ambient: 0.002,
            dark_current_e_s: 50.0,
            hot_pixel_fraction: 1e-4,
            hot_pixel_e_s: 20_000.0,
            // White LEDs lose of the order of 0.3% of their output per
            // kelvin of junction temperature; a warm bar is some kelvin
            // above a cold one.
            led_drift: 0.04,
        }
    }
}

/// The physical rig the simulated camera renders.
#[derive(Clone, Debug, PartialEq)]
pub struct RigTruth {
    /// The rig file's geometry with the true camera and bar height in place
    /// of the filed ones (the sample, the bar's size and the gantry's
    /// limits are as filed).
    pub geometry: RigGeometry,
    /// Each LED's displacement from its filed place on the bar, mm.
    pub led_offsets_mm: Vec<Vec3>,
    /// Roll of the bar about the travel axis: LED `k`'s height grows by
    /// `y_k * tan(roll)`.
    pub bar_roll_rad: f32,
    /// Yaw of the bar: LED `k` sits `y_k * tan(yaw)` ahead along `x`.
    pub bar_yaw_rad: f32,
    /// Physical carriage position = `offset + (1 + scale) * commanded`,
    /// less half the backlash in the direction of the last move.
    pub gantry_offset_mm: f32,
    pub gantry_scale: f32,
    pub backlash_mm: f32,
    /// The sample surface: its centre's height above `z = 0` and its tilt
    /// (rotation about `x`, then about `y`).
    pub sample_height_mm: f32,
    pub sample_tilt_rad: Vec2,
    /// Ambient irradiance on the sample (the units of LED irradiance).
    pub ambient_irradiance: f32,
    /// Dark current, electrons per second: the mean, and the hot pixels
    /// (pixel index, rate).
    pub dark_current_e_s: f32,
    pub hot_pixels: Vec<(u32, f32)>,
    /// Each LED's relative loss of intensity once the bar is warm (empty:
    /// no drift).
    pub led_drift: Vec<f32>,
    /// What lies in the sample holder is propped up off the sample's
    /// surface (a calibration target on a wedge): its frame's rotation and
    /// origin in the sample surface's frame.
    pub propped: Option<(Mat3, Vec3)>,
}

impl RigTruth {
    /// The rig exactly as its file says, with no ambient light and no dark
    /// current.
    pub fn ideal(geometry: &RigGeometry) -> Self {
        Self {
            geometry: geometry.clone(),
            led_offsets_mm: vec![Vec3::ZERO; geometry.bar.n_leds as usize],
            bar_roll_rad: 0.0,
            bar_yaw_rad: 0.0,
            gantry_offset_mm: 0.0,
            gantry_scale: 0.0,
            backlash_mm: 0.0,
            sample_height_mm: 0.0,
            sample_tilt_rad: Vec2::ZERO,
            ambient_irradiance: 0.0,
            dark_current_e_s: 0.0,
            hot_pixels: Vec::new(),
            led_drift: Vec::new(),
            propped: None,
        }
    }

    /// A rig built to `geometry` within the default tolerances, drawn from
    /// `seed`.
    pub fn perturbed(geometry: &RigGeometry, seed: u64) -> Self {
        Self::drawn(geometry, &Tolerances::default(), seed)
    }

    /// A rig built to `geometry` within `tol`, drawn from `seed`.
    pub fn drawn(geometry: &RigGeometry, tol: &Tolerances, seed: u64) -> Self {
        let mut rng = Pcg64::seed_from_u64(seed ^ 0x7a1e_5eed_0000_0017);
        let mut err = |t: f32| -> f32 {
            let n = Normal::new(0.0f32, 0.5 * t.abs()).map(|n| n.sample(&mut rng)).unwrap_or(0.0);
            n.clamp(-t.abs(), t.abs())
        };
        let vec = |e: &mut dyn FnMut(f32) -> f32, t: f32| Vec3::new(e(t), e(t), e(t));
        let mut g = geometry.clone();

        let cam = geometry.camera;
        let rot = vec(&mut err, tol.camera_rotation_deg.to_radians());
        let r = Mat3::from_rotation_z(rot.z) * Mat3::from_rotation_y(rot.y) * Mat3::from_rotation_x(rot.x);
        let position = cam.position_mm + vec(&mut err, tol.camera_position_mm);
        let focal = 1.0 + err(tol.focal);
        let half = (0.5 * cam.fov_y_deg.to_radians()).tan() / focal;
        g.camera = CameraModel {
            position_mm: position,
            look_at_mm: position + r * (cam.look_at_mm - cam.position_mm),
            up: r * cam.up,
            fov_y_deg: (2.0 * half.atan()).to_degrees(),
            principal_offset_px: cam.principal_offset_px
                + cam.width as f32 * Vec2::new(err(tol.principal_point), err(tol.principal_point)),
            radial_k: [cam.radial_k[0] + err(tol.radial_k1), cam.radial_k[1]],
            ..cam
        };

        g.bar.height_mm += err(tol.bar_height_mm);
        let led_offsets_mm = (0..geometry.bar.n_leds).map(|_| vec(&mut err, tol.led_position_mm)).collect();
        let bar_roll_rad = err(tol.bar_tilt_deg).to_radians();
        let bar_yaw_rad = err(tol.bar_tilt_deg).to_radians();
        let gantry_offset_mm = err(tol.gantry_offset_mm);
        let gantry_scale = err(tol.gantry_scale);
        let sample_height_mm = err(tol.sample_height_mm);
        let sample_tilt_rad = Vec2::new(err(tol.sample_tilt_deg).to_radians(), err(tol.sample_tilt_deg).to_radians());

        let backlash_mm = rng.random::<f32>() * tol.backlash_mm.max(0.0);
        let nearest = 1.0 / (geometry.bar.height_mm * geometry.bar.height_mm).max(1e-6);
        let ambient_irradiance = rng.random::<f32>() * tol.ambient.max(0.0) * nearest;
        let dark_current_e_s = rng.random::<f32>() * tol.dark_current_e_s.max(0.0);
        let n_pixels = cam.width * cam.height;
        let n_hot = (tol.hot_pixel_fraction.max(0.0) * n_pixels as f32).round() as u32;
        let hot_pixels = (0..n_hot)
            .map(|_| (rng.random_range(0..n_pixels.max(1)), tol.hot_pixel_e_s * (0.5 + rng.random::<f32>())))
            .collect();
        let led_drift =
            (0..geometry.bar.n_leds).map(|_| tol.led_drift.max(0.0) * (0.5 + 0.5 * rng.random::<f32>())).collect();

        Self {
            geometry: g,
            led_offsets_mm,
            bar_roll_rad,
            bar_yaw_rad,
            gantry_offset_mm,
            gantry_scale,
            backlash_mm,
            sample_height_mm,
            sample_tilt_rad,
            ambient_irradiance,
            dark_current_e_s,
            hot_pixels,
            led_drift,
            propped: None,
        }
    }

    /// LED `k`'s intensity relative to a cold bar after the LEDs have
    /// been lit for `on_s` seconds in all: the bar's temperature rises
    /// toward its steady state with a time constant of [`WARMUP_ON_S`]
    /// of on-time, and each LED loses its own fraction of output with it.
    pub fn drift(&self, k: u8, on_s: f64) -> f32 {
        let warm = 1.0 - (-on_s / WARMUP_ON_S).exp();
        1.0 - self.led_drift.get(k as usize).copied().unwrap_or(0.0) * warm as f32
    }

    /// The carriage's physical position (the bar's centre line, mm) when
    /// the controller has it at `commanded_mm`, its last move having been
    /// toward `+x` (`forward`) or `-x`.
    pub fn bar_x_mm(&self, commanded_mm: f32, forward: bool) -> f32 {
        let lag = if forward { -0.5 } else { 0.5 } * self.backlash_mm;
        self.gantry_offset_mm + (1.0 + self.gantry_scale) * commanded_mm + lag
    }

    /// Where LED `k` really is with the bar's centre line physically at
    /// `bar_x_mm`.
    pub fn led_position(&self, bar_x_mm: f32, k: u8) -> Vec3 {
        let nominal = self.geometry.bar.led_position(bar_x_mm, k);
        let y = nominal.y;
        nominal
            + Vec3::new(y * self.bar_yaw_rad.tan(), 0.0, y * self.bar_roll_rad.tan())
            + self.led_offsets_mm.get(k as usize).copied().unwrap_or(Vec3::ZERO)
    }

    /// The direction the LEDs shine (their axis, pointing down): square to
    /// the bar, which they are soldered to, so it tilts with the bar's
    /// roll (its yaw turns the bar about the vertical, which leaves the
    /// axis as it is).
    pub fn led_axis(&self) -> Vec3 {
        Vec3::new(0.0, self.bar_roll_rad.tan(), -1.0).normalize()
    }

    /// The frame of the surface the camera sees: the rotation from its own
    /// axes (in which the material is defined, `z` its normal) to the
    /// rig's, and its centre. The sample's surface, or what is propped on it.
    pub fn sample_frame(&self) -> (Mat3, Vec3) {
        let r = Mat3::from_rotation_y(self.sample_tilt_rad.y) * Mat3::from_rotation_x(self.sample_tilt_rad.x);
        let c = Vec3::new(0.0, 0.0, self.sample_height_mm);
        match self.propped {
            None => (r, c),
            Some((pr, pc)) => (r * pr, c + r * pc),
        }
    }

    /// Dark current of every pixel, electrons per second, from `seed`:
    /// exponentially distributed about the mean, the hot pixels at their
    /// rates.
    pub fn dark_current_map(&self, seed: u64) -> Vec<f32> {
        let cam = &self.geometry.camera;
        let n = (cam.width * cam.height) as usize;
        let mut rng = Pcg64::seed_from_u64(seed ^ 0xdc);
        let mut map: Vec<f32> = if self.dark_current_e_s > 0.0 {
            (0..n).map(|_| -self.dark_current_e_s * (1.0 - rng.random::<f32>()).ln()).collect()
        } else {
            vec![0.0; n]
        };
        for &(k, rate) in &self.hot_pixels {
            if let Some(m) = map.get_mut(k as usize) {
                *m = rate;
            }
        }
        map
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ideal_is_the_rig_file_and_perturbed_stays_within_tolerance() {
        let g = RigGeometry::default();
        let ideal = RigTruth::ideal(&g);
        assert_eq!(ideal.geometry, g);
        assert_eq!(ideal.led_position(12.5, 7), g.bar.led_position(12.5, 7));
        assert_eq!(ideal.bar_x_mm(-3.0, false), -3.0);
        let tol = Tolerances::default();
        for seed in 0..20 {
            let t = RigTruth::perturbed(&g, seed);
            let dp = t.geometry.camera.position_mm - g.camera.position_mm;
            assert!(dp.abs().max_element() <= tol.camera_position_mm + 1e-4, "{seed}: {dp}");
            let fwd = |c: &CameraModel| (c.look_at_mm - c.position_mm).normalize();
            let angle = fwd(&t.geometry.camera).dot(fwd(&g.camera)).min(1.0).acos().to_degrees();
            assert!(angle <= 3f32.sqrt() * tol.camera_rotation_deg + 1e-3, "{seed}: {angle} degrees");
            let pp = t.geometry.camera.principal_offset_px;
            assert!(pp.abs().max_element() <= tol.principal_point * 256.0 + 1e-3, "{seed}: {pp}");
            for k in 0..g.bar.n_leds {
                let d = t.led_position(0.0, k) - g.bar.led_position(0.0, k);
                // Own offset, plus the bar's height, roll and yaw at up to
                // 97.5 mm from the centre.
                let bound =
                    tol.led_position_mm + tol.bar_height_mm + 97.5 * tol.bar_tilt_deg.to_radians().tan() * 2f32.sqrt();
                assert!(d.length() <= bound * 1.01, "{seed}: LED {k} off by {d}");
            }
            let x = t.bar_x_mm(100.0, true);
            assert!((x - 100.0).abs() <= tol.gantry_offset_mm + 100.0 * tol.gantry_scale + tol.backlash_mm, "{x}");
            assert!(t.bar_x_mm(100.0, false) - x <= tol.backlash_mm + 1e-6, "backlash at most its tolerance");
            for k in 0..g.bar.n_leds {
                // Cold, no drift; warming, the LED dims monotonically to
                // between half its tolerance and all of it.
                assert_eq!(t.drift(k, 0.0), 1.0);
                assert!(t.drift(k, 30.0) > t.drift(k, 300.0), "{seed}: LED {k}");
                let loss = 1.0 - t.drift(k, 1e6);
                assert!((0.5 * tol.led_drift - 1e-6..=tol.led_drift + 1e-6).contains(&loss), "{seed}: LED {k} {loss}");
            }
        }
        assert_eq!(ideal.drift(3, 1e6), 1.0, "an ideal rig does not drift");
        // Different seeds give different rigs; the same seed the same.
        assert_ne!(RigTruth::perturbed(&g, 1), RigTruth::perturbed(&g, 2));
        assert_eq!(RigTruth::perturbed(&g, 3), RigTruth::perturbed(&g, 3));
    }

    #[test]
    fn a_tilted_sample_frame_is_a_rotation() {
        let t = RigTruth { sample_tilt_rad: Vec2::new(0.01, -0.007), ..RigTruth::ideal(&RigGeometry::default()) };
        let (r, c) = t.sample_frame();
        assert!((r.determinant() - 1.0).abs() < 1e-5);
        let n = r * Vec3::Z;
        assert!((n.z - (0.01f32.cos() * 0.007f32.cos())).abs() < 1e-5, "{n}");
        assert_eq!(c, Vec3::ZERO);
    }
}
