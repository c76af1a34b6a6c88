//! Everything the fitter precomputes from the rig: for each sample point
//! its position, camera pixel, view direction and flat field; for each
//! light (gantry step x LED) its position and calibrated intensity; and,
//! per (point, light), the sample geometry of the radiometric equation
//!
//! `rho = signal r^2 / (S_q F(x) P(cos_emit) cos_i)`  (see `setup::calibration`).

use glam::{Vec2, Vec3};
use setup::{Calibration, CapturePlan, PointGrid, RigGeometry};

/// The capture-side facts the fitter needs (all recorded in `capture.json`).
#[derive(Clone, Debug, PartialEq)]
pub struct FitInputs {
    pub geometry: RigGeometry,
    pub plan: CapturePlan,
    pub calibration: Calibration,
    pub grid: PointGrid,
    /// Sensor electrons per DN at unit gain (shot-noise model).
    pub e_per_dn: f32,
    pub bit_depth: u8,
    /// The sensor's sample layout, for the noise model
    /// ([`crate::points::SampleNoise`]); `None` models each sample's noise
    /// as one pixel's (an overstatement for a Bayer sensor).
    pub sensor_layout: Option<frame::Layout>,
}

/// One light: a (step, LED) pair.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Light {
    pub step: u32,
    pub led: u8,
    pub bar_x_mm: f32,
    pub pos: Vec3,
    /// Calibrated intensity `S_q`.
    pub scale: f32,
}

/// Geometry of one (point, light) sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleGeometry {
    /// Unit direction toward the light.
    pub i: Vec3,
    /// Cosine of the angle from the LED's axis toward the point.
    pub cos_emit: f32,
    /// Factor from signal to reflectance: `r^2 / (S_q F P cos_i)`.
    pub to_rho: f32,
    /// Relative irradiance `S_q F P cos_i / r^2` (for the dim-light mask).
    pub irradiance: f32,
    pub occluded: bool,
}

/// A light below this elevation above the point's horizon (cos 0.035, two
/// degrees) is dropped: the reflectance estimate divides by `cos_i`, which
/// there amplifies noise and any error in the sample's height by 30x.
pub const MIN_COS_I: f32 = 0.035;

/// How far, in pixels, a point's value reaches in the frame: the bilinear
/// sample reads the pixels whose centres are within one pixel of it, the
/// bilinear demosaicing of a Bayer frame takes each of those from its
/// neighbours one pixel further, and a pixel integrates over half a pixel
/// beyond its centre. A point whose reach leaves the sample (or the frame)
/// mixes in whatever lies beyond the edge and is not measured; the
/// material shows it with its nearest measured neighbour
/// (`material::MaterialView`).
pub const PIXEL_REACH: f32 = 2.5;

/// Safety margin around the light bar when masking occluded samples: one
/// millimetre covers the bar's edges blurring over a pixel and small
/// errors of the camera pose.
pub const OCCLUSION_MARGIN_MM: f32 = 1.0;

/// An LED at `pos` shining along `axis`, seen from the point `x` of the
/// sample plane: the unit direction toward it, the squared distance and the
/// cosine from its axis (floored at [`MIN_COS_I`]); `None` at or below the
/// point's horizon (beyond [`MIN_COS_I`]). The radiometric equation's
/// geometry, for samples and for the reference patches (`crate::drift`).
pub fn light_at(x: Vec3, pos: Vec3, axis: Vec3) -> Option<(Vec3, f32, f32)> {
    let d = pos - x;
    let r2 = d.length_squared();
    let i = d / r2.sqrt();
    if i.z < MIN_COS_I {
        return None;
    }
    Some((i, r2, (-i.dot(axis)).max(MIN_COS_I)))
}

#[derive(Debug)]
pub struct FitContext {
    pub inputs: FitInputs,
    pub positions: Vec<Vec3>,
    /// Continuous pixel coordinates of each point (None if out of view, or
    /// so near the sample's edge that its pixels see beyond it).
    pub pixels: Vec<Option<Vec2>>,
    pub view: Vec<Vec3>,
    pub flat: Vec<f32>,
    pub lights: Vec<Light>,
    /// Spacing of neighbouring lights along the gantry and along the bar (mm).
    pub step_spacing_mm: f32,
    /// The direction the LEDs shine (`setup::Calibration::led_axis`).
    pub led_axis: Vec3,
    pub led_spacing_mm: f32,
    /// Where the fit on this context is (watched from other threads).
    pub progress: std::sync::Arc<crate::FitProgress>,
}

impl FitContext {
    pub fn new(inputs: FitInputs) -> Self {
        let g = &inputs.geometry;
        let n = inputs.grid.len();
        let mut positions = Vec::with_capacity(n);
        let mut pixels = Vec::with_capacity(n);
        let mut view = Vec::with_capacity(n);
        let mut flat = Vec::with_capacity(n);
        for i in 0..n {
            let p = inputs.grid.position_of(&g.sample, i).extend(0.0);
            positions.push(p);
            let px = g.camera.project(p).filter(|px| {
                let (w, h) = (g.camera.width as f32, g.camera.height as f32);
                px.x >= PIXEL_REACH
                    && px.y >= PIXEL_REACH
                    && px.x <= w - PIXEL_REACH
                    && px.y <= h - PIXEL_REACH
                    && g.camera.sees_only(&g.sample, *px, PIXEL_REACH)
            });
            pixels.push(px);
            view.push(g.camera.view_dir(p));
            flat.push(inputs.calibration.flat_at(&g.sample, p.truncate()).max(crate::tol::MIN_FLAT));
        }
        let mut lights = Vec::with_capacity(inputs.plan.n_lights());
        for s in 0..inputs.plan.steps {
            let bar_x_mm = inputs.plan.step_um(s) as f32 / 1000.0;
            for &led in &inputs.plan.leds {
                let scale = inputs
                    .calibration
                    .led_scale
                    .get(led as usize)
                    .copied()
                    .unwrap_or(1.0)
                    .max(crate::tol::MIN_LED_SCALE);
                let pos = inputs.calibration.light_position(&g.bar, bar_x_mm, led);
                lights.push(Light { step: s, led, bar_x_mm, pos, scale });
            }
        }
        let plan = &inputs.plan;
        let step_spacing_mm =
            if plan.steps > 1 { (plan.last_mm - plan.first_mm).abs() / (plan.steps - 1) as f32 } else { 1.0 };
        let led_spacing_mm = if plan.leds.len() > 1 {
            let span =
                (*plan.leds.iter().max().unwrap_or(&0) as f32 - *plan.leds.iter().min().unwrap_or(&0) as f32).abs();
            span * g.bar.pitch_mm / (plan.leds.len() - 1) as f32
        } else {
            g.bar.pitch_mm
        };
        let led_axis = inputs.calibration.led_axis();
        Self {
            inputs,
            positions,
            pixels,
            view,
            flat,
            lights,
            step_spacing_mm,
            led_spacing_mm,
            led_axis,
            progress: Default::default(),
        }
    }

    /// Report the fit's progress into `progress` (which a watcher holds).
    pub fn with_progress(mut self, progress: std::sync::Arc<crate::FitProgress>) -> Self {
        self.progress = progress;
        self
    }

    /// Angular spacing (radians) between the half vector of light `q` at
    /// point `p` and those of its neighbouring lights: the larger of the
    /// steps along the gantry and along the bar, seen from the point
    /// (`|displacement perpendicular to i| / r`), halved-and-more by the
    /// half vector (`dh = di / |i + o|`).
    pub fn half_vector_spacing(&self, p: usize, q: usize) -> f32 {
        let d = self.lights[q].pos - self.positions[p];
        let r = d.length().max(crate::tol::MIN_DISTANCE_MM);
        let i = d / r;
        let dx = self.step_spacing_mm * (1.0 - i.x * i.x).max(0.0).sqrt();
        let dy = self.led_spacing_mm * (1.0 - i.y * i.y).max(0.0).sqrt();
        dx.max(dy) / r / (i + self.view[p]).length().max(crate::tol::MIN_HALF_SUM)
    }

    pub fn n_points(&self) -> usize {
        self.positions.len()
    }

    pub fn n_lights(&self) -> usize {
        self.lights.len()
    }

    /// The geometry of point `p` lit by light `q`; `None` if the light is
    /// at or below the point's horizon (beyond [`MIN_COS_I`]).
    pub fn sample(&self, p: usize, q: usize) -> Option<SampleGeometry> {
        self.sample_from(p, q, self.lights[q].pos)
    }

    /// [`FitContext::sample`] with light `q`'s LED at `pos` instead of
    /// where the calibration puts it (the white scan trying the scale a
    /// mirror cannot see, `calibrate`).
    pub fn sample_from(&self, p: usize, q: usize, pos: Vec3) -> Option<SampleGeometry> {
        let x = self.positions[p];
        let l = &self.lights[q];
        let (i, r2, cos_emit) = light_at(x, pos, self.led_axis)?;
        let profile = cos_emit.powf(self.inputs.calibration.profile_exponent);
        let irradiance = l.scale * self.flat[p] * profile * i.z / r2;
        let g = &self.inputs.geometry;
        let occluded = g.bar.occludes(l.bar_x_mm, x, g.camera.position_mm, OCCLUSION_MARGIN_MM);
        Some(SampleGeometry { i, cos_emit, to_rho: 1.0 / irradiance, irradiance, occluded })
    }
}
