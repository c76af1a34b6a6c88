//! Range checks of everything a rig file and a calibration say, so that an
//! impossible rig (a NaN field of view, a gantry that cannot move, LEDs
//! that give no light) is refused before a capture starts, naming the field
//! and the range it must lie in.

use glam::Vec3;
use thiserror::Error;

use crate::calibration::Calibration;
use crate::geometry::RigGeometry;

/// A value outside the range the instrument can work with.
#[derive(Clone, Debug, PartialEq, Error)]
#[error("{field} = {value} is not usable: it must be {allowed}")]
pub struct Invalid {
    /// The field's path as written in the file (`geometry.bar.height_mm`).
    pub field: String,
    pub value: String,
    pub allowed: String,
}

impl Invalid {
    pub fn new(field: &str, value: impl std::fmt::Display, allowed: impl Into<String>) -> Self {
        Self { field: field.into(), value: value.to_string(), allowed: allowed.into() }
    }
}

/// `lo <= v <= hi` (false for NaN).
pub fn within(field: &str, v: f32, lo: f32, hi: f32) -> Result<(), Invalid> {
    if (lo..=hi).contains(&v) { Ok(()) } else { Err(Invalid::new(field, v, format!("between {lo} and {hi}"))) }
}

/// `lo < v <= hi` (false for NaN).
pub fn above(field: &str, v: f32, lo: f32, hi: f32) -> Result<(), Invalid> {
    if v > lo && v <= hi { Ok(()) } else { Err(Invalid::new(field, v, format!("above {lo} and at most {hi}"))) }
}

/// An integer in `lo..=hi`.
pub fn count(field: &str, v: u64, lo: u64, hi: u64) -> Result<(), Invalid> {
    if (lo..=hi).contains(&v) { Ok(()) } else { Err(Invalid::new(field, v, format!("between {lo} and {hi}"))) }
}

/// `got` items, one per `unit` of which there are `want`.
fn one_per(field: &str, got: usize, items: &str, unit: &str, want: usize) -> Result<(), Invalid> {
    if got == want {
        Ok(())
    } else {
        Err(Invalid::new(field, format!("{got} {items}"), format!("one per {unit} ({want})")))
    }
}

fn finite3(field: &str, v: Vec3, limit: f32) -> Result<(), Invalid> {
    if v.is_finite() && v.abs().max_element() <= limit {
        Ok(())
    } else {
        Err(Invalid::new(field, format!("{v}"), format!("finite, each coordinate within +-{limit}")))
    }
}

/// Largest distance (mm) anything of a bench-top rig is from the sample centre.
const REACH_MM: f32 = 10_000.0;

impl RigGeometry {
    /// Check every field against what a bench-top reflectometer can be.
    pub fn validate(&self) -> Result<(), Invalid> {
        let g = "geometry";
        let s = &self.sample;
        above(&format!("{g}.sample.width_mm"), s.width_mm, 0.0, 2000.0)?;
        above(&format!("{g}.sample.height_mm"), s.height_mm, 0.0, 2000.0)?;
        let b = &self.bar;
        count(&format!("{g}.bar.n_leds"), b.n_leds as u64, 1, 255)?;
        above(&format!("{g}.bar.pitch_mm"), b.pitch_mm, 0.0, 1000.0)?;
        within(&format!("{g}.bar.first_led_y_mm"), b.first_led_y_mm, -REACH_MM, REACH_MM)?;
        above(&format!("{g}.bar.height_mm"), b.height_mm, 0.0, 2000.0)?;
        within(&format!("{g}.bar.width_mm"), b.width_mm, 0.0, 1000.0)?;
        within(&format!("{g}.bar.thickness_mm"), b.thickness_mm, 0.0, 1000.0)?;
        let t = &self.gantry;
        within(&format!("{g}.gantry.travel_min_mm"), t.travel_min_mm, -REACH_MM, REACH_MM)?;
        within(&format!("{g}.gantry.travel_max_mm"), t.travel_max_mm, -REACH_MM, REACH_MM)?;
        if t.travel_max_mm <= t.travel_min_mm {
            return Err(Invalid::new(
                &format!("{g}.gantry.travel_max_mm"),
                t.travel_max_mm,
                format!("above travel_min_mm ({})", t.travel_min_mm),
            ));
        }
        above(&format!("{g}.gantry.speed_mm_s"), t.speed_mm_s, 0.0, 5000.0)?;
        above(&format!("{g}.gantry.accel_mm_s2"), t.accel_mm_s2, 0.0, 100_000.0)?;
        within(&format!("{g}.gantry.settle_ms"), t.settle_ms, 0.0, 60_000.0)?;
        above(&format!("{g}.gantry.homing_speed_mm_s"), t.homing_speed_mm_s, 0.0, 5000.0)?;
        within(&format!("{g}.emission.profile_exponent"), self.emission.profile_exponent, 0.0, 100.0)?;
        count(&format!("{g}.emission.current_ma"), self.emission.current_ma as u64, 1, 10_000)?;
        let c = &self.camera;
        finite3(&format!("{g}.camera.position_mm"), c.position_mm, REACH_MM)?;
        finite3(&format!("{g}.camera.look_at_mm"), c.look_at_mm, REACH_MM)?;
        finite3(&format!("{g}.camera.up"), c.up, 1e6)?;
        let forward = c.look_at_mm - c.position_mm;
        if forward.length() < 1.0 {
            return Err(Invalid::new(
                &format!("{g}.camera.look_at_mm"),
                format!("{}", c.look_at_mm),
                "at least 1 mm from position_mm",
            ));
        }
        if forward.normalize().cross(c.up).length() < 1e-3 {
            return Err(Invalid::new(
                &format!("{g}.camera.up"),
                format!("{}", c.up),
                "non-zero and not along the viewing direction",
            ));
        }
        above(&format!("{g}.camera.fov_y_deg"), c.fov_y_deg, 0.0, 170.0)?;
        count(&format!("{g}.camera.width"), c.width as u64, 8, 65_536)?;
        count(&format!("{g}.camera.height"), c.height as u64, 8, 65_536)?;
        let half = 0.5 * c.width.max(c.height) as f32;
        within(&format!("{g}.camera.principal_offset_px.x"), c.principal_offset_px.x, -half, half)?;
        within(&format!("{g}.camera.principal_offset_px.y"), c.principal_offset_px.y, -half, half)?;
        // Beyond these a lens folds its image over (the distortion's inverse
        // stops existing within the field of view of any rig camera).
        within(&format!("{g}.camera.radial_k[0]"), c.radial_k[0], -1.0, 1.0)?;
        within(&format!("{g}.camera.radial_k[1]"), c.radial_k[1], -1.0, 1.0)?;
        for (k, r) in self.references.iter().enumerate() {
            let f = format!("{g}.references[{k}]");
            within(&format!("{f}.centre_mm.x"), r.centre_mm.x, -REACH_MM, REACH_MM)?;
            within(&format!("{f}.centre_mm.y"), r.centre_mm.y, -REACH_MM, REACH_MM)?;
            above(&format!("{f}.size_mm.x"), r.size_mm.x, 0.0, 1000.0)?;
            above(&format!("{f}.size_mm.y"), r.size_mm.y, 0.0, 1000.0)?;
            // A patch on the sample would be fitted as the sample.
            let gap = (r.centre_mm.abs() - 0.5 * (r.size_mm + glam::Vec2::new(s.width_mm, s.height_mm))).max_element();
            if gap <= 0.0 {
                return Err(Invalid::new(
                    &format!("{f}.centre_mm"),
                    format!("{}", r.centre_mm),
                    "beside the sample, not on it (the patch and the sample area overlap)",
                ));
            }
        }
        Ok(())
    }
}

impl Calibration {
    /// Check that the calibration can turn pixel values into reflectance:
    /// finite, non-negative levels, every LED giving light, a positive
    /// flat field.
    pub fn validate(&self) -> Result<(), Invalid> {
        if let Some(c) = &self.camera {
            RigGeometry { camera: c.camera, ..RigGeometry::default() }.validate()?;
            within("camera.rms_px", c.rms_px, 0.0, 2.0)?;
        }
        if let Some(l) = &self.lights {
            one_per("lights.led_mm", l.led_mm.len(), "positions", "LED", self.led_scale.len())?;
            for (k, &p) in l.led_mm.iter().enumerate() {
                finite3(&format!("lights.led_mm[{k}]"), p, REACH_MM)?;
            }
            finite3("lights.travel_mm", l.travel_mm, 2.0)?;
            // A gantry whose true scale is 10% from its firmware's is
            // misconfigured, not out of calibration.
            within("lights.travel_mm length", l.travel_mm.length(), 0.9, 1.1)?;
            within("lights.rms_mm", l.rms_mm, 0.0, 5.0)?;
        }
        if let Some(d) = &self.drift_reference {
            if d.positions_mm.windows(2).any(|w| !(w[0] < w[1])) || d.positions_mm.iter().any(|x| !x.is_finite()) {
                return Err(Invalid::new("drift_reference.positions_mm", "", "finite and ascending"));
            }
            for (name, table) in [("reading", &d.reading), ("rel_var", &d.rel_var)] {
                let f = format!("drift_reference.{name}");
                one_per(&f, table.len(), "patches", "patch", d.patches.len())?;
                for (p, leds) in table.iter().enumerate() {
                    one_per(&format!("{f}[{p}]"), leds.len(), "LEDs", "LED", self.led_scale.len())?;
                    for (k, row) in leds.iter().enumerate() {
                        one_per(&format!("{f}[{p}][{k}]"), row.len(), "values", "position", d.positions_mm.len())?;
                        for (j, &v) in row.iter().enumerate() {
                            within(&format!("{f}[{p}][{k}][{j}]"), v, 0.0, f32::MAX)?;
                        }
                    }
                }
            }
        }
        for k in 0..3 {
            within("black_level", self.black_level[k], 0.0, 1e6)?;
            within("read_noise_dn", self.read_noise_dn[k], 0.0, 1e6)?;
        }
        if self.led_scale.is_empty() {
            return Err(Invalid::new("led_scale", "[]", "one intensity per LED"));
        }
        for (k, &v) in self.led_scale.iter().enumerate() {
            if !(v.is_finite() && v > 0.0) {
                return Err(Invalid::new(
                    &format!("led_scale[{k}]"),
                    v,
                    "finite and above 0 (an LED that gave no light in the white scan is broken or unplugged)",
                ));
            }
        }
        within("profile_exponent", self.profile_exponent, 0.0, 100.0)?;
        if let Some((k, &v)) = self.flat_field.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v > 0.0)) {
            return Err(Invalid::new(&format!("flat_field[{k}]"), v, "finite and above 0"));
        }
        above("reference_albedo", self.reference_albedo, 0.0, 1.0)?;
        within("residual_rms", self.residual_rms, 0.0, 1e6)?;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_rig_and_nominal_calibration_are_valid() {
        RigGeometry::default().validate().unwrap();
        Calibration::nominal(40, 1.0, 0.0).validate().unwrap();
    }

    #[test]
    fn impossible_values_name_their_field() {
        let cases: Vec<(&str, Box<dyn Fn(&mut RigGeometry)>)> = vec![
            ("geometry.camera.fov_y_deg", Box::new(|g| g.camera.fov_y_deg = f32::NAN)),
            ("geometry.bar.height_mm", Box::new(|g| g.bar.height_mm = -40.0)),
            ("geometry.sample.width_mm", Box::new(|g| g.sample.width_mm = -1.0)),
            ("geometry.gantry.speed_mm_s", Box::new(|g| g.gantry.speed_mm_s = 0.0)),
            ("geometry.gantry.travel_max_mm", Box::new(|g| g.gantry.travel_max_mm = g.gantry.travel_min_mm)),
            ("geometry.camera.up", Box::new(|g| g.camera.up = Vec3::ZERO)),
            ("geometry.camera.position_mm", Box::new(|g| g.camera.position_mm.x = f32::INFINITY)),
            ("geometry.bar.n_leds", Box::new(|g| g.bar.n_leds = 0)),
            ("geometry.references[1].size_mm.x", Box::new(|g| g.references[1].size_mm.x = f32::NAN)),
            ("geometry.references[0].centre_mm", Box::new(|g| g.references[0].centre_mm.x = -52.0)),
        ];
        for (field, spoil) in cases {
            let mut g = RigGeometry::default();
            spoil(&mut g);
            let e = g.validate().unwrap_err();
            assert_eq!(e.field, field, "{e}");
            assert!(e.to_string().contains("must be"), "{e}");
        }
    }

    #[test]
    fn a_calibration_without_light_is_refused() {
        let mut c = Calibration::nominal(40, 1.0, 0.0);
        c.led_scale = vec![0.0; 40];
        assert_eq!(c.validate().unwrap_err().field, "led_scale[0]");
        let mut c = Calibration::nominal(40, 1.0, 0.0);
        c.black_level[1] = f32::NAN;
        assert_eq!(c.validate().unwrap_err().field, "black_level");
        let mut c = Calibration::nominal(40, 1.0, 0.0);
        c.flat_field = vec![1.0, -0.5];
        assert_eq!(c.validate().unwrap_err().field, "flat_field[1]");
        // A drift reference of another rig's shape, or with an impossible
        // reading, is refused.
        let patch = crate::geometry::ReferencePatch { centre_mm: glam::Vec2::new(70.0, 0.0), size_mm: glam::Vec2::ONE };
        let good = crate::calibration::DriftReference {
            patches: vec![patch],
            positions_mm: vec![0.0, 1.0],
            reading: vec![vec![vec![1.0, 0.0]; 40]],
            rel_var: vec![vec![vec![1e-4, 0.0]; 40]],
        };
        let mut c = Calibration::nominal(40, 1.0, 0.0);
        c.drift_reference = Some(good.clone());
        c.validate().unwrap();
        c.drift_reference = Some(crate::calibration::DriftReference { positions_mm: vec![1.0, 0.0], ..good.clone() });
        assert_eq!(c.validate().unwrap_err().field, "drift_reference.positions_mm");
        c.drift_reference =
            Some(crate::calibration::DriftReference { reading: vec![vec![vec![1.0, 0.0]; 39]], ..good.clone() });
        assert_eq!(c.validate().unwrap_err().field, "drift_reference.reading[0]");
        let mut bad = good;
        bad.rel_var[0][3][1] = f32::NAN;
        c.drift_reference = Some(bad);
        assert_eq!(c.validate().unwrap_err().field, "drift_reference.rel_var[0][3][1]");
    }

    #[test]
    fn impossible_leds_are_refused() {
        let bar = crate::geometry::RigGeometry::default().bar;
        let good = crate::calibration::LightCalibration {
            id: "t".into(),
            led_mm: (0..40).map(|k| bar.led_position(0.0, k)).collect(),
            travel_mm: Vec3::X,
            measured: (10..30).collect(),
            highlights: 260,
            rms_mm: 0.01,
            max_mm: 0.02,
            scale_sd: 0.0015,
            white_scale: 1.0,
            white_placed: Vec::new(),
            backlash_mm: None,
        };
        let with = |l: crate::calibration::LightCalibration| Calibration {
            lights: Some(l),
            ..Calibration::nominal(40, 1.0, 0.0)
        };
        with(good.clone()).validate().unwrap();
        let short = crate::calibration::LightCalibration { led_mm: good.led_mm[..20].to_vec(), ..good.clone() };
        assert_eq!(with(short).validate().unwrap_err().field, "lights.led_mm");
        let mut nan = good.clone();
        nan.led_mm[7].y = f32::NAN;
        assert_eq!(with(nan).validate().unwrap_err().field, "lights.led_mm[7]");
        let long = crate::calibration::LightCalibration { travel_mm: 1.2 * Vec3::X, ..good };
        assert_eq!(with(long).validate().unwrap_err().field, "lights.travel_mm length");
    }
}
