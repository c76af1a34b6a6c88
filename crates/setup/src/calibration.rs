//! Radiometric calibration: what turns a pixel value into reflectance.
//!
//! For a point `x` lit by LED `q` at `P_q`, the design's radiometry is
//! `rho = I_q(x) / ((n . i_q) L_q |P_q - x|^2)` (Wang et al. 2008, the
//! acquisition section of its talk).
//! A real rig needs three more factors, all measured from a white diffuse
//! reference scan of known albedo:
//!
//! `signal = (DN - black) / (exposure_s * gain)`
//! `rho = signal * r^2 / (S_q * F(x) * P(cos_emit) * cos_i)`
//!
//! - `S_q`: each LED's intensity (LEDs differ by several per cent),
//! - `P`: the LEDs' angular emission profile, `cos^m` of the angle from the
//!   LED axis,
//! - `F(x)`: the flat field of each sample point (lens vignetting and
//!   pixel response),
//!
//! and a dark scan gives the black level. Taking logarithms,
//! `log M = log S_q + log F(x) + m log cos_emit` is linear in the unknowns;
//! [`crate::calibration`] consumers solve it by alternating least squares
//! (see the `fit` crate's `calibrate` module).

use serde::{Deserialize, Serialize};

/// A radiometric calibration of one rig.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// Identifier (creation time, UTC, `YYYYMMDDTHHMMSSZ`), recorded in every
    /// capture that uses it.
    pub id: String,
    /// Black level in DN per colour channel (from the dark scan).
    pub black_level: [f32; 3],
    /// Read noise in DN per channel (standard deviation of the dark scan).
    pub read_noise_dn: [f32; 3],
    /// Per-LED intensity `S_q` (signal units at unit reflectance, unit
    /// profile and unit distance, in mm^2), indexed by LED number.
    pub led_scale: Vec<f32>,
    /// Emission profile exponent `m`.
    pub profile_exponent: f32,
    /// Flat field per point of the grid it was measured on (mean 1), row-major;
    /// empty means uniform.
    pub flat_field: Vec<f32>,
    pub flat_field_grid: Option<crate::geometry::PointGrid>,
    /// Albedo of the white reference used.
    pub reference_albedo: f32,
    /// RMS relative residual of the white fit (how well the model explains it).
    pub residual_rms: f32,
    /// The camera as the geometric calibration measured it; without one
    /// the rig file's camera is trusted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraCalibration>,
    /// Where the LEDs are, as the geometric calibration's mirror scan
    /// measured them; without it the rig file's bar is trusted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lights: Option<LightCalibration>,
    /// How bright the rig's reference patches were during the white scan,
    /// under each LED at each carriage position: what a capture's own
    /// readings of them are compared with to correct LED drift
    /// (`fit::drift`). Absent from a calibration of a rig without patches
    /// or made before they existed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drift_reference: Option<DriftReference>,
}

/// The reference patches as the white scan saw them, under each LED at each
/// of its carriage positions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DriftReference {
    /// The patches it was measured on (the rig file's when the white scan
    /// ran; a capture whose rig file names others cannot use it).
    pub patches: Vec<crate::geometry::ReferencePatch>,
    /// The white scan's commanded carriage positions, mm, ascending.
    pub positions_mm: Vec<f32>,
    /// `[patch][led][position]`: the patch's signal over the irradiance the
    /// calibrated geometry gives it at unit LED intensity (`fit::drift`); 0
    /// where it was not read (hidden by the bar, or too dimly lit).
    pub reading: Vec<Vec<Vec<f32>>>,
    /// The same shape: each reading's relative variance from shot and read
    /// noise.
    pub rel_var: Vec<Vec<Vec<f32>>>,
}

impl DriftReference {
    /// Patch `p`'s reading of LED `led` with the carriage commanded to
    /// `x_mm`, in logarithms, and its relative variance: interpolated
    /// between the two positions around it when both were read, else the
    /// nearer one's if it is within a quarter of their spacing; `None`
    /// outside the positions or where unread.
    pub fn at(&self, p: usize, led: u8, x_mm: f32) -> Option<(f64, f64)> {
        let (r, v) = (self.reading.get(p)?.get(led as usize)?, self.rel_var.get(p)?.get(led as usize)?);
        let x = &self.positions_mm;
        let i = x.windows(2).position(|w| w[0] <= x_mm && x_mm <= w[1])?;
        let t = ((x_mm - x[i]) / (x[i + 1] - x[i]).max(f32::MIN_POSITIVE)) as f64;
        let read = |j: usize| {
            let (m, rv) = (*r.get(j)?, *v.get(j)?);
            (m > 0.0).then(|| ((m as f64).ln(), rv as f64))
        };
        match (read(i), read(i + 1)) {
            (Some((a, va)), Some((b, vb))) => Some(((1.0 - t) * a + t * b, (1.0 - t).powi(2) * va + t * t * vb)),
            (Some(a), None) if t <= 0.25 => Some(a),
            (None, Some(b)) if t >= 0.75 => Some(b),
            _ => None,
        }
    }
}

/// The LEDs' positions in the sample frame of the camera calibration, from
/// the highlights of a flat mirror in the sample holder
/// (`capture --calibrate geometry`). LED `k` with the carriage commanded to
/// `c` mm is at `led_mm[k] + c * travel_mm`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct LightCalibration {
    /// When it was measured (`YYYYMMDDTHHMMSSZ`).
    pub id: String,
    /// Each LED's position with the carriage commanded to 0, mm, indexed by
    /// LED number.
    pub led_mm: Vec<glam::Vec3>,
    /// The carriage's displacement per commanded millimetre (its length is
    /// the gantry's true scale).
    pub travel_mm: glam::Vec3,
    /// LEDs whose highlights were measured; the others lie on the straight
    /// line fitted through them, at their places along the bar.
    pub measured: Vec<u8>,
    pub highlights: u32,
    /// Distance of the LEDs from the rays their highlights reflect, RMS and
    /// largest, mm.
    pub rms_mm: f32,
    pub max_mm: f32,
    /// What the mirror cannot see: the relative scale of the LEDs' distances
    /// from the camera's mirror image, known from the bar's pitch and the
    /// gantry's build tolerance to this standard deviation.
    pub scale_sd: f32,
    /// The factor by which the white scan, from how its light falls off
    /// across the sample, scaled the mirror's LEDs and travel about the
    /// camera's mirror image (1 before a white scan).
    #[serde(default = "one")]
    pub white_scale: f32,
    /// LEDs the mirror did not measure that the white scan placed, from how
    /// each one's light falls off across the white (the others of those
    /// stay on the line through the measured ones).
    #[serde(default)]
    pub white_placed: Vec<u8>,
    /// The gantry's backlash, mm: how much farther along its travel the
    /// carriage stands at a position approached from above than from
    /// below (the mirror scan revisits three positions from above). Every
    /// scan and capture approaches from below, so it does not enter a fit;
    /// it is kept to watch the lead screw. `None` before it was measured.
    #[serde(default)]
    pub backlash_mm: Option<f32>,
}

fn one() -> f32 {
    1.0
}

impl LightCalibration {
    /// The direction the LEDs shine (pointing down): square to the bar they
    /// are soldered to, whose plane holds the line of the measured LEDs and
    /// the carriage's travel. `None` if those are not measured.
    pub fn led_axis(&self) -> Option<glam::Vec3> {
        let first = self.led_mm.get(*self.measured.first()? as usize)?;
        let last = self.led_mm.get(*self.measured.last()? as usize)?;
        let n = self.travel_mm.cross(*last - *first).try_normalize()?;
        Some(if n.z > 0.0 { -n } else { n })
    }
}

/// The camera's intrinsics and pose in the sample frame, from views of the
/// checkerboard target (`capture --calibrate geometry`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraCalibration {
    /// When it was measured (`YYYYMMDDTHHMMSSZ`).
    pub id: String,
    pub camera: crate::camera::CameraModel,
    /// Reprojection error of the target's corners, RMS and largest, pixels.
    pub rms_px: f32,
    pub max_px: f32,
    pub corners: u32,
    pub views: u32,
}

impl Calibration {
    /// A calibration that trusts the nominal rig: equal LEDs of unit
    /// intensity, nominal profile, no flat-field correction.
    pub fn nominal(n_leds: u8, profile_exponent: f32, black_level: f32) -> Self {
        Self {
            id: "nominal".into(),
            black_level: [black_level; 3],
            read_noise_dn: [0.0; 3],
            led_scale: vec![1.0; n_leds as usize],
            profile_exponent,
            flat_field: Vec::new(),
            flat_field_grid: None,
            reference_albedo: 1.0,
            residual_rms: 0.0,
            camera: None,
            lights: None,
            drift_reference: None,
        }
    }

    /// The direction the LEDs shine: as the mirror scan measured the bar,
    /// else straight down.
    pub fn led_axis(&self) -> glam::Vec3 {
        self.lights.as_ref().and_then(LightCalibration::led_axis).unwrap_or(glam::Vec3::NEG_Z)
    }

    /// Where LED `k` of `bar` is with the carriage commanded to
    /// `commanded_mm`: as the mirror scan measured it, else as the rig file
    /// says.
    pub fn light_position(&self, bar: &crate::geometry::LedBar, commanded_mm: f32, k: u8) -> glam::Vec3 {
        match self.lights.as_ref().and_then(|l| l.led_mm.get(k as usize).map(|p| (p, l.travel_mm))) {
            Some((&p, travel)) => p + commanded_mm * travel,
            None => bar.led_position(commanded_mm, k),
        }
    }

    /// The rig as this calibration knows it: `filed` (the rig file's
    /// geometry) with the measured camera in place of the filed one. A
    /// camera read at another resolution of the same shape (the simulated
    /// rig's presets, a binned mode) has the same lens and pose: its
    /// principal point scales with the width. Of another shape it is not
    /// the measured camera, and the filed one stays.
    pub fn geometry_of(&self, filed: &crate::geometry::RigGeometry) -> crate::geometry::RigGeometry {
        let mut g = filed.clone();
        if let Some(c) = &self.camera {
            let (w, h) = (g.camera.width, g.camera.height);
            let m = c.camera;
            if m.width as u64 * h as u64 == m.height as u64 * w as u64 {
                let scale = w as f32 / m.width.max(1) as f32;
                g.camera = crate::camera::CameraModel {
                    width: w,
                    height: h,
                    principal_offset_px: m.principal_offset_px * scale,
                    ..m
                };
            }
        }
        g
    }

    /// Flat-field factor at a sample position (bilinear over the grid it
    /// was measured on, clamped at the edges); 1 if none was measured.
    pub fn flat_at(&self, sample: &crate::geometry::SampleArea, p_mm: glam::Vec2) -> f32 {
        let Some(g) = self.flat_field_grid else { return 1.0 };
        if self.flat_field.len() != g.len() || g.is_empty() {
            return 1.0;
        }
        let c = g.coords(sample, p_mm) - glam::Vec2::splat(0.5);
        let x = c.x.clamp(0.0, (g.cols - 1) as f32);
        let y = c.y.clamp(0.0, (g.rows - 1) as f32);
        let (x0, y0) = (x as usize, y as usize);
        let (x1, y1) = ((x0 + 1).min(g.cols as usize - 1), (y0 + 1).min(g.rows as usize - 1));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let at = |xx: usize, yy: usize| self.flat_field[yy * g.cols as usize + xx];
        let v =
            (at(x0, y0) * (1.0 - fx) + at(x1, y0) * fx) * (1.0 - fy) + (at(x0, y1) * (1.0 - fx) + at(x1, y1) * fx) * fy;
        if v.is_finite() && v > 0.0 { v } else { 1.0 }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_white_scans_patch_reading_is_interpolated_between_its_positions() {
        let d = DriftReference {
            patches: Vec::new(),
            positions_mm: vec![0.0, 10.0, 20.0, 30.0],
            reading: vec![vec![vec![1.0, 4.0, 0.0, 2.0]]],
            rel_var: vec![vec![vec![1e-4, 4e-4, 0.0, 1e-4]]],
        };
        // Between two readings: their logarithms, linearly.
        let (ln, var) = d.at(0, 0, 5.0).unwrap();
        assert!((ln - 0.5 * 4f64.ln()).abs() < 1e-9, "{ln}");
        assert!((var - 0.25 * (1e-4 + 4e-4)).abs() < 1e-9, "{var}");
        // Beside an unread position: the read one only when near it.
        assert!((d.at(0, 0, 12.0).unwrap().0 - 4f64.ln()).abs() < 1e-9);
        assert!(d.at(0, 0, 15.0).is_none());
        assert!((d.at(0, 0, 28.0).unwrap().0 - 2f64.ln()).abs() < 1e-9);
        // Outside the travel, another LED or patch: nothing.
        assert!(d.at(0, 0, -1.0).is_none() && d.at(0, 0, 31.0).is_none());
        assert!(d.at(0, 1, 5.0).is_none() && d.at(1, 0, 5.0).is_none());
    }
}
