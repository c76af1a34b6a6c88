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
