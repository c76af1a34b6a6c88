//! The simulated camera: renders the frame the real camera would take, from
//! a material, the rig geometry and the physical timeline.
//!
//! For every pixel the ray from the camera meets the sample plane at a
//! point (precomputed once, with its BRDF, view direction, vignetting and
//! Bayer colour). For each exposure, the LEDs lit during it are read from
//! the [`World`] with the carriage position, and each pixel integrates the
//! light of every LED interval that overlaps the exposure: an LED switched
//! mid-exposure gives a mixed frame, as on a real sensor. Pixels whose view
//! of the sample is blocked by the light bar see its black underside.
//!
//! The rig it renders is the hidden [`RigTruth`] (the rig file's geometry,
//! perturbed or not), never the host's idea of it: pixels are traced
//! through the true lens onto the true (possibly tilted) sample surface and
//! lit by the LEDs where they truly are.
//!
//! Sensor model: electrons = sensitivity x radiance x exposure x vignetting
//! x (1 + pixel response non-uniformity) + dark current x exposure; shot
//! noise (Poisson, as a Gaussian of variance equal to the mean above 30
//! electrons) and read noise; saturation at the full well; DN = electrons x
//! gain / (electrons per DN) plus the black level, rounded and clipped to
//! the bit depth. A pixel integrates its footprint: a diffuse texture is
//! averaged over it. Noise is seeded by the physical shot (position, LED,
//! exposure) and drawn per pixel from counter-based streams (`noise`), so a
//! resumed capture sees exactly the frames an uninterrupted one would.
//!
//! Pixels are rendered eight at a time where their surface allows
//! (`batch`: nothing, diffuse, or one or two lobes, each Beckmann or a
//! pile distribution: every built-in sample) and one at a time elsewhere
//! (`Lit::radiance`, also the reference the batch is tested against).
//!
//! Timing: in real time the camera free-runs at its frame rate and a
//! request waits for the first frame exposed after the LED came on; in fast
//! mode every duration is multiplied by `time_scale` (frames still carry
//! consistent timestamps, and signal levels use the nominal exposure).

use std::sync::Arc;
use std::time::Duration;

use brdf::Brdf;
use frame::{BayerPattern, Frame, FrameFlags, FrameMeta, Layout, MonoNs};
use glam::{Vec2, Vec3};
use material::{PointMaterial, SvBrdf};
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use rig::camera::{AppliedSettings, Camera, CameraError, CameraSettings, FrameFilter, Verdict};
use rig::clock;
use tokio::time::Instant;

use crate::batch::{self, LANES, PixelColumns, PixelIn};
use crate::faults::FaultSpec;
use crate::reflect::Reflectance;
use crate::truth::RigTruth;
use crate::world::World;

/// The simulated sensor.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorModel {
    pub bit_depth: u8,
    pub black_level_dn: f32,
    pub full_well_e: f32,
    pub read_noise_e: f32,
    /// Electrons per second per unit radiance (irradiance from an LED of
    /// unit intensity at 1 mm is 1).
    pub sensitivity: f32,
    /// Standard deviation of pixel response non-uniformity.
    pub prnu: f32,
    pub pattern: BayerPattern,
}

impl Default for SensorModel {
    /// A 12-bit machine-vision sensor: a white reference under the nearest
    /// LED at 20 ms fills about 40% of the well.
    fn default() -> Self {
        Self {
            bit_depth: 12,
            black_level_dn: 64.0,
            full_well_e: 12_000.0,
            read_noise_e: 6.0,
            sensitivity: 1.2e9,
            prnu: 0.005,
            pattern: BayerPattern::Rggb,
        }
    }
}

impl SensorModel {
    /// Electrons per DN at unit gain (the full well maps onto the code range).
    pub fn e_per_dn(&self) -> f32 {
        self.full_well_e / (((1u32 << self.bit_depth) - 1) as f32 - self.black_level_dn)
    }
}

/// The true, unknown-to-the-host LED properties: intensities differ by a few
/// per cent and the profile is not quite Lambertian. Calibration measures them.
#[derive(Clone, Debug, PartialEq)]
pub struct LedTruth {
    pub scale: Vec<f32>,
    pub profile_exponent: f32,
    /// Current at which `scale` holds (intensity is proportional to current).
    pub nominal_current_ma: u16,
}

impl LedTruth {
    pub fn realistic(n_leds: u8, seed: u64) -> Self {
        let mut rng = Pcg64::seed_from_u64(seed ^ 0x1ed5);
        let n = Normal::new(1.0f32, 0.04).ok();
        Self {
            scale: (0..n_leds).map(|_| n.map_or(1.0, |n| n.sample(&mut rng)).clamp(0.85, 1.15)).collect(),
            profile_exponent: 1.25,
            nominal_current_ma: 200,
        }
    }
}

/// How the camera keeps time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CameraTiming {
    /// Every duration (exposure, readout) times `time_scale`; frames are
    /// produced on request.
    Fast { time_scale: f32 },
    /// Free-running at `fps`, frames available `readout_ms` after exposure ends.
    RealTime { fps: f32, readout_ms: f32 },
}

#[derive(Clone, Debug)]
pub struct SimCameraConfig {
    /// The rig as it physically is (its camera, LEDs, gantry and sample).
    pub truth: RigTruth,
    pub sensor: SensorModel,
    pub leds: LedTruth,
    pub timing: CameraTiming,
    pub seed: u64,
    pub faults: FaultSpec,
    /// Physical rest position of the carriage before the first move (for
    /// reading positions off the world timeline), micrometres.
    pub rest_um: f64,
}

struct Pixel {
    /// Where the pixel's ray meets the sample surface (rig frame).
    p: Vec3,
    /// Toward the camera, in the sample surface's own frame.
    o: Vec3,
    /// The bar positions at which the bar hides `p` from the camera
    /// ([`setup::LedBar::shadow_span`]; empty where none does).
    shadow: (f32, f32),
    gain: f32,
    /// Radiance from the room's ambient light.
    ambient: f32,
    /// Dark current, electrons per second.
    dark_e_s: f32,
    /// What the surface reflects toward this pixel, in its channel.
    reflect: Reflectance,
}

/// An empty span of bar positions: the bar never hides the pixel.
const NO_SHADOW: (f32, f32) = (f32::INFINITY, f32::NEG_INFINITY);

/// Albedo of what surrounds the sample in view (a matte black mount).
const SURROUND_ALBEDO: f32 = 0.03;

/// Albedo of the rig's white reference patches beside the sample
/// (`setup::ReferencePatch`): a matte white such as sintered PTFE. The
/// host does not know it (it measures the patches against the white scan).
pub const REFERENCE_ALBEDO: f32 = 0.8;

pub struct SimCamera {
    cfg: SimCameraConfig,
    world: World,
    pixels: Arc<Vec<Pixel>>,
    /// The same pixels' constants as columns, for the batched path.
    columns: Arc<PixelColumns>,
    exposure_us: u32,
    gain: f32,
    settings: Option<CameraSettings>,
    filter: FrameFilter,
    sequence: u64,
    requests: u64,
    started: Instant,
    dark_counter: u64,
    /// Seconds the LEDs have been lit in all (the bar's warmth:
    /// [`RigTruth::drift`]): since this camera was made, on top of what
    /// [`SimCamera::set_on_time_s`] started it from.
    on_s: f64,
    unplugged_until: Option<Instant>,
    fault_rng: Pcg64,
    pub frames_rendered: u64,
}

impl std::fmt::Debug for SimCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimCamera").field("frames_rendered", &self.frames_rendered).finish_non_exhaustive()
    }
}

impl SimCamera {
    /// Prepare the per-pixel geometry and BRDFs for `material`.
    pub fn new(cfg: SimCameraConfig, material: Arc<dyn SvBrdf>, world: World) -> Self {
        let pixels = Self::trace(&cfg, material);
        let columns = Arc::new(Self::columns(&pixels));
        let fault_rng = Pcg64::seed_from_u64(cfg.faults.seed ^ 0xca3e);
        Self {
            exposure_us: 20_000,
            gain: 1.0,
            settings: None,
            filter: FrameFilter::new(2),
            sequence: 0,
            requests: 0,
            started: Instant::now(),
            dark_counter: 0,
            on_s: 0.0,
            unplugged_until: None,
            fault_rng,
            frames_rendered: 0,
            pixels: Arc::new(pixels),
            columns,
            world,
            cfg,
        }
    }

    /// Put something else in the sample holder (the operator's hands): a
    /// new material, propped up off the sample's surface or not.
    pub fn restage(&mut self, material: Arc<dyn SvBrdf>, propped: Option<(glam::Mat3, Vec3)>) {
        self.cfg.truth.propped = propped;
        let pixels = Self::trace(&self.cfg, material);
        self.columns = Arc::new(Self::columns(&pixels));
        self.pixels = Arc::new(pixels);
    }

    fn columns(pixels: &[Pixel]) -> PixelColumns {
        PixelColumns::new(pixels.iter().map(|px| PixelIn {
            p: px.p,
            o: px.o,
            shadow: px.shadow,
            ambient: px.ambient,
            gain: px.gain,
            dark_e_s: px.dark_e_s,
            reflect: &px.reflect,
        }))
    }

    /// Each pixel's ray traced onto the surface in the holder.
    fn trace(cfg: &SimCameraConfig, material: Arc<dyn SvBrdf>) -> Vec<Pixel> {
        let truth = &cfg.truth;
        let cam = truth.geometry.camera;
        let sample = truth.geometry.sample;
        let (to_rig, centre) = truth.sample_frame();
        let to_sample = to_rig.transpose();
        let normal = to_rig * Vec3::Z;
        let dark = truth.dark_current_map(cfg.seed);
        // Ambient light as a uniform sky: the radiance of a surface under
        // it is `pi f(n, o) E` for a diffuse one; the BRDF at normal
        // incidence stands in for its hemispherical mean.
        let ambient_e = truth.ambient_irradiance * std::f32::consts::PI;
        let surround = PointMaterial::Diffuse { kd: Vec3::splat(SURROUND_ALBEDO) };
        let white = PointMaterial::Diffuse { kd: Vec3::splat(REFERENCE_ALBEDO) };
        // The reference patches are level with the sample's surface, on
        // the holder; something propped up in it hides them from this
        // model (the calibration target's views, which do not use them).
        let patches: &[setup::ReferencePatch] = if truth.propped.is_none() { &truth.geometry.references } else { &[] };
        let mut resp_rng = Pcg64::seed_from_u64(cfg.seed ^ 0x9e1);
        // A non-finite spread (a broken sensor model) reads as none.
        let prnu = Normal::new(1.0f32, cfg.sensor.prnu.max(0.0)).ok();
        let responses: Vec<f32> =
            (0..cam.width * cam.height).map(|_| prnu.map_or(1.0, |d| d.sample(&mut resp_rng))).collect();
        (0..cam.width * cam.height)
            .into_par_iter()
            .map(|k| {
                let (u, v) = (k % cam.width, k / cam.width);
                let px = Vec2::new(u as f32 + 0.5, v as f32 + 0.5);
                let channel = cfg.sensor.pattern.channel(u, v) as u8;
                let gain = cam.vignetting(px) * responses[k as usize];
                let dark_e_s = dark[k as usize];
                match cam.pixel_to(px, centre, normal) {
                    Some(p) => {
                        let q = (to_sample * (p - centre)).truncate();
                        let at = |q: Vec2| {
                            if sample.contains(q) {
                                material.at(q)
                            } else if patches.iter().any(|r| r.contains(q, 0.0)) {
                                white.clone()
                            } else {
                                surround.clone()
                            }
                        };
                        let brdf = Arc::new(match at(q) {
                            // A pixel integrates its whole footprint: a
                            // diffuse texture (a print, an edge) is averaged
                            // over it. Glossy materials keep the centre's
                            // BRDF (their lobes are not linear in anything
                            // an average could keep).
                            PointMaterial::Diffuse { kd } => {
                                Self::footprint_kd(&cam, px, centre, normal, to_sample, &at)
                                    .map_or(PointMaterial::Diffuse { kd }, |kd| PointMaterial::Diffuse { kd })
                            }
                            m => m,
                        });
                        let o = to_sample * cam.view_dir(p);
                        let ambient = ambient_e * brdf.eval(Vec3::Z, o)[channel as usize];
                        let reflect = Reflectance::new(brdf, o, channel as usize);
                        let shadow = truth.geometry.bar.shadow_span(p, cam.position_mm, 0.0).unwrap_or(NO_SHADOW);
                        Pixel { p, o, shadow, gain, ambient, dark_e_s, reflect }
                    }
                    None => Pixel {
                        p: Vec3::ZERO,
                        o: Vec3::Z,
                        shadow: NO_SHADOW,
                        gain,
                        ambient: 0.0,
                        dark_e_s,
                        reflect: Reflectance::Black,
                    },
                }
            })
            .collect()
    }

    /// Mean albedo over the pixel at `px` (8 x 8 sub-pixel samples), if
    /// every sample is diffuse.
    fn footprint_kd(
        cam: &setup::CameraModel,
        px: Vec2,
        centre: Vec3,
        normal: Vec3,
        to_sample: glam::Mat3,
        at: &dyn Fn(Vec2) -> PointMaterial,
    ) -> Option<Vec3> {
        const N: u32 = 8;
        let mut sum = Vec3::ZERO;
        for s in 0..N {
            for t in 0..N {
                let d = Vec2::new((s as f32 + 0.5) / N as f32 - 0.5, (t as f32 + 0.5) / N as f32 - 0.5);
                let p = cam.pixel_to(px + d, centre, normal)?;
                match at((to_sample * (p - centre)).truncate()) {
                    PointMaterial::Diffuse { kd } => sum += kd,
                    _ => return None,
                }
            }
        }
        Some(sum / (N * N) as f32)
    }

    fn scale(&self) -> f32 {
        match self.cfg.timing {
            CameraTiming::Fast { time_scale } => time_scale,
            CameraTiming::RealTime { .. } => 1.0,
        }
    }

    /// Render the frame exposed over `[t0, t1)` (real time), with signal
    /// computed for the nominal exposure, from the LEDs the world says were
    /// lit then.
    fn render(&mut self, t0: Instant, t1: Instant, sequence: u64) -> Frame {
        let truth = &self.cfg.truth;
        let span = (t1 - t0).as_secs_f64();
        let mut lights = Vec::new();
        let intervals = if span > 0.0 {
            self.world.led_intervals(t0, t1)
        } else {
            // An instantaneous exposure (fast mode): the LED lit at t0.
            self.world.led_at(t0).map(|(l, c)| (l, c, t0, t0)).into_iter().collect()
        };
        let mut on_s = 0.0;
        for (led, current, s, e) in intervals {
            let frac = if span > 0.0 { ((e - s).as_secs_f64() / span) as f32 } else { 1.0 };
            let mid = s + (e - s) / 2;
            let commanded_mm = (self.world.position_at(mid, self.cfg.rest_um) / 1000.0) as f32;
            let bar_x_mm = truth.bar_x_mm(commanded_mm, self.world.forward_at(mid));
            lights.push((truth.led_position(bar_x_mm, led), bar_x_mm, self.led_intensity(led, current) * frac));
            on_s += frac as f64 * self.exposure_us as f64 * 1e-6;
        }
        self.on_s += on_s;
        let bar_um = self.world.position_at(t0, self.cfg.rest_um).round() as i64;
        let key = self.noise_key(bar_um, self.world.led_at(t0).map(|l| l.0));
        self.render_lights(&lights, key, t0, t1, sequence)
    }

    /// Render the frame for the carriage at `position_um` with LED `led`
    /// (or none: a dark frame) lit at its nominal current, without a world
    /// timeline or an MCU. The noise is the same as the full path gives for
    /// the same shot, so direct and rig-driven captures agree.
    /// The carriage is taken to have arrived moving toward `+x`.
    pub fn render_direct(&mut self, position_um: i32, led: Option<u8>) -> Frame {
        self.render_direct_approached(position_um, led, true)
    }

    /// [`Self::render_direct`] with the carriage's last move toward `+x`
    /// (`forward`) or `-x`, which its backlash follows.
    pub fn render_direct_approached(&mut self, position_um: i32, led: Option<u8>, forward: bool) -> Frame {
        let truth = &self.cfg.truth;
        let bar_x_mm = truth.bar_x_mm(position_um as f32 / 1000.0, forward);
        let lights: Vec<_> = led
            .map(|l| {
                (truth.led_position(bar_x_mm, l), bar_x_mm, self.led_intensity(l, self.cfg.leds.nominal_current_ma))
            })
            .into_iter()
            .collect();
        if led.is_some() {
            self.on_s += self.exposure_us as f64 * 1e-6;
        }
        let key = self.noise_key(position_um as i64, led);
        let now = Instant::now();
        self.sequence += 1;
        let seq = self.sequence;
        self.render_lights(&lights, key, now, now, seq)
    }

    /// LED `led`'s intensity at `current_ma`, as warm as the bar now is.
    fn led_intensity(&self, led: u8, current_ma: u16) -> f32 {
        self.cfg.leds.scale.get(led as usize).copied().unwrap_or(0.0) * current_ma as f32
            / self.cfg.leds.nominal_current_ma.max(1) as f32
            * self.cfg.truth.drift(led, self.on_s)
    }

    /// Seconds the LEDs have been lit in all: the bar's warmth.
    pub fn on_time_s(&self) -> f64 {
        self.on_s
    }

    /// Start from a bar that has had `on_s` seconds of LED light (another
    /// session's, a moment ago on the same bench).
    pub fn set_on_time_s(&mut self, on_s: f64) {
        self.on_s = on_s.max(0.0);
    }

    /// LED `led`'s intensity now relative to a cold bar (the drift a
    /// frame rendered now carries; tests compare the fitter's estimate with
    /// it).
    pub fn drift_now(&self, led: u8) -> f32 {
        self.cfg.truth.drift(led, self.on_s)
    }

    /// Noise stream of a shot: its physical identity, not the order of requests.
    fn noise_key(&mut self, bar_um: i64, led: Option<u8>) -> u64 {
        match led {
            Some(led) => (bar_um as u64) ^ ((led as u64) << 40),
            None => {
                self.dark_counter += 1;
                0xda4c_0000_0000_0000 ^ self.dark_counter
            }
        }
    }

    /// Set exposure and gain for [`SimCamera::render_direct`].
    pub fn set_exposure_direct(&mut self, exposure_us: u32, gain: f32) {
        self.exposure_us = exposure_us;
        self.gain = gain;
    }

    fn render_lights(
        &mut self,
        lights: &[(Vec3, f32, f32)],
        key: u64,
        t0: Instant,
        t1: Instant,
        sequence: u64,
    ) -> Frame {
        let lit = Lit::new(&self.cfg, lights);
        let (pixels, columns) = (&*self.pixels, &*self.columns);
        let data = self.expose(key, |first, out| lit.radiance_run(first, pixels, columns, out));
        self.frame(data, t0, t1, sequence)
    }

    /// The sensor's reading of every pixel given its radiance (`radiance`
    /// fills a run of pixels from the first index it is given): signal,
    /// dark current, shot noise (Poisson, as a Gaussian above
    /// `noise::POISSON_MAX_MEAN` electrons), the full well, read noise and
    /// quantisation. Rows in parallel; every pixel's noise comes from a
    /// counter-based stream (`noise::word`) keyed by the shot (`key`), the
    /// exposure, the gain, its row and its column.
    fn expose(&self, key: u64, radiance: impl Fn(usize, &mut [f32]) + Sync) -> Vec<u16> {
        let seed = self.cfg.seed
            ^ key.wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ ((self.exposure_us as u64) << 20)
            ^ self.gain.to_bits() as u64;
        let sensor = &self.cfg.sensor;
        let exposure_s = self.exposure_us as f32 * 1e-6;
        let x = batch::Exposure {
            e_per_radiance: sensor.sensitivity * exposure_s,
            exposure_s,
            full_well_e: sensor.full_well_e,
            // A non-finite read noise (a broken sensor model) reads as none.
            read_sd_e: if sensor.read_noise_e.is_finite() { sensor.read_noise_e.max(0.0) } else { 0.0 },
            dn_per_e: self.gain / sensor.e_per_dn(),
            black_level_dn: sensor.black_level_dn,
            max_dn: ((1u32 << sensor.bit_depth) - 1) as f32,
        };
        let cam = &self.cfg.truth.geometry.camera;
        let (w, h) = (cam.width as usize, cam.height as usize);
        let columns = &*self.columns;
        let mut data = vec![0u16; w * h];
        // Each thread's working row of radiance.
        data.par_chunks_mut(w).enumerate().for_each_init(
            || vec![0.0f32; w],
            |signal, (row, out)| {
                let row_seed = seed ^ (row as u64).wrapping_mul(0xA24B_AED4_963E_E407);
                let px = row * w..(row + 1) * w;
                radiance(row * w, signal);
                batch::expose_row(&x, row_seed, signal, &columns.gain[px.clone()], &columns.dark_e_s[px], out);
            },
        );
        data
    }

    /// A frame of `data` exposed over `t0..t1` with the camera's settings now.
    fn frame(&mut self, data: Vec<u16>, t0: Instant, t1: Instant, sequence: u64) -> Frame {
        let cam = &self.cfg.truth.geometry.camera;
        self.frames_rendered += 1;
        Frame {
            width: cam.width,
            height: cam.height,
            layout: Layout::Bayer { pattern: self.cfg.sensor.pattern },
            bit_depth: self.cfg.sensor.bit_depth,
            data,
            meta: FrameMeta {
                sequence,
                exposure_start: clock::to_mono(t0),
                exposure_end: clock::to_mono(t1),
                exposure_us: self.exposure_us,
                gain: self.gain,
                flags: FrameFlags::default(),
            },
        }
    }

    /// The sensor's noise parameters as the capture records them.
    pub fn sensor(&self) -> &SensorModel {
        &self.cfg.sensor
    }
}

/// A frame's lights, as every pixel sees them: each LED's true position,
/// the bar position it was lit at and its intensity (times the share of
/// the exposure it was lit for).
struct Lit<'a> {
    lights: &'a [(Vec3, f32, f32)],
    /// The rig frame into the sample surface's own.
    to_sample: glam::Mat3,
    /// The LEDs' optical axis (the bar's, as it truly sits).
    axis: Vec3,
    /// The LEDs' emission profile, `cos^profile` about `axis`.
    profile: f32,
}

impl<'a> Lit<'a> {
    fn new(cfg: &SimCameraConfig, lights: &'a [(Vec3, f32, f32)]) -> Self {
        let (to_rig, _) = cfg.truth.sample_frame();
        Self { lights, to_sample: to_rig.transpose(), axis: cfg.truth.led_axis(), profile: cfg.leds.profile_exponent }
    }

    /// The radiance of the pixels from `first` on into `out`: eight at a
    /// time where [`PixelColumns`] can batch them, one at a time elsewhere.
    fn radiance_run(&self, first: usize, pixels: &[Pixel], columns: &PixelColumns, out: &mut [f32]) {
        let mut j = 0;
        while j < out.len() {
            let k = first + j;
            if j + LANES <= out.len() && columns.batched_from(k) {
                let r = columns.radiance(k, self.lights, self.to_sample, self.axis, self.profile);
                out[j..j + LANES].copy_from_slice(&r);
                j += LANES;
            } else {
                out[j] = self.radiance(&pixels[k]);
                j += 1;
            }
        }
    }

    /// The radiance toward the camera at `px`: ambient light plus each
    /// LED's light that is not hidden by the bar, from above the surface.
    #[inline]
    fn radiance(&self, px: &Pixel) -> f32 {
        let mut radiance = px.ambient;
        if px.reflect.is_black() {
            return radiance;
        }
        for &(led_pos, bar_x, intensity) in self.lights {
            if intensity <= 0.0 || (px.shadow.0 <= bar_x && bar_x <= px.shadow.1) {
                continue;
            }
            let d = led_pos - px.p;
            let r2 = d.length_squared();
            let i = d / r2.sqrt();
            let i_local = self.to_sample * i;
            let cos_emit = -i.dot(self.axis);
            // Behind the LED (a bar rolled past the horizon) nothing is lit.
            if i.z <= 0.0 || i_local.z <= 0.0 || cos_emit <= 0.0 {
                continue;
            }
            let irradiance = intensity * cos_emit.powf(self.profile) * i_local.z / r2;
            radiance += px.reflect.eval(i_local, px.o) * irradiance;
        }
        radiance
    }
}

impl Camera for SimCamera {
    fn describe(&self) -> String {
        "simulated camera".into()
    }

    async fn configure(&mut self, s: &CameraSettings) -> Result<AppliedSettings, CameraError> {
        let cam = &self.cfg.truth.geometry.camera;
        if s.width != cam.width || s.height != cam.height {
            return Err(CameraError::Unsupported(format!(
                "the simulated sensor is {}x{}, not {}x{}",
                cam.width, cam.height, s.width, s.height
            )));
        }
        self.exposure_us = s.exposure_us;
        self.gain = s.gain;
        self.filter = FrameFilter::new(s.settle_frames);
        self.filter.control_changed(Some(self.sequence));
        self.settings = Some(s.clone());
        let mut controls = std::collections::BTreeMap::new();
        controls.insert("exposure_auto".into(), 1);
        controls.insert("exposure_absolute".into(), (s.exposure_us / 100) as i64);
        controls.insert("gain".into(), (s.gain * 100.0) as i64);
        controls.insert("white_balance_automatic".into(), 0);
        controls.insert("gain_automatic".into(), 0);
        Ok(AppliedSettings {
            device: "sim".into(),
            driver: "reflectometer-sim".into(),
            format: format!("RG{}", self.cfg.sensor.bit_depth),
            width: cam.width,
            height: cam.height,
            bit_depth: self.cfg.sensor.bit_depth,
            layout: Some(Layout::Bayer { pattern: self.cfg.sensor.pattern }),
            exposure_us: s.exposure_us,
            gain: s.gain,
            controls,
            warnings: Vec::new(),
        })
    }

    async fn set_exposure(&mut self, exposure_us: u32, gain: f32) -> Result<(), CameraError> {
        if exposure_us != self.exposure_us || gain != self.gain {
            self.exposure_us = exposure_us;
            self.gain = gain;
            self.filter.control_changed(Some(self.sequence));
        }
        Ok(())
    }

    async fn frame_after(&mut self, after: MonoNs, timeout: Duration) -> Result<Frame, CameraError> {
        self.requests += 1;
        let faults = self.cfg.faults.clone();
        let give_up = Instant::now() + timeout;
        if let Some(until) = self.unplugged_until {
            if Instant::now() < until {
                return Err(CameraError::Gone("simulated unplug".into()));
            }
            self.unplugged_until = None;
        }
        if faults.camera_unplug_at.contains(&self.requests) {
            self.unplugged_until = Some(Instant::now() + Duration::from_millis(faults.reconnect_ms));
            return Err(CameraError::Gone("simulated unplug".into()));
        }
        if faults.frame_timeout_at.contains(&self.requests) {
            tokio::time::sleep_until(give_up).await;
            return Err(CameraError::Timeout { waited_ms: timeout.as_millis() as u64 });
        }
        let after_i = clock::to_instant(after);
        let scale = self.scale();
        let exposure = Duration::from_secs_f64(self.exposure_us as f64 * 1e-6 * scale as f64);
        loop {
            if Instant::now() >= give_up {
                return Err(CameraError::Timeout { waited_ms: timeout.as_millis() as u64 });
            }
            let (t0, deliver) = match self.cfg.timing {
                CameraTiming::Fast { .. } => {
                    let t0 = Instant::now().max(after_i);
                    (t0, t0 + exposure)
                }
                CameraTiming::RealTime { fps, readout_ms } => {
                    let period = 1.0 / fps.max(0.1) as f64;
                    let since = (after_i.max(Instant::now() - exposure) - self.started).as_secs_f64();
                    let k = (since / period).ceil().max(0.0);
                    let t0 = self.started + Duration::from_secs_f64(k * period);
                    (t0, t0 + exposure + Duration::from_secs_f64(readout_ms as f64 * 1e-3))
                }
            };
            tokio::time::sleep_until(deliver).await;
            self.sequence += 1;
            let seq = self.sequence;
            let mut f = self.render(t0, t0 + exposure, seq);
            if self.fault_rng.random::<f64>() < faults.error_frame {
                f.meta.flags.error = true;
            }
            if self.fault_rng.random::<f64>() < faults.stale_frame {
                // A late buffer from before the LED came on.
                f.meta.exposure_start = MonoNs(after.0.saturating_sub(5_000_000));
            }
            match self.filter.judge(&f.meta, after) {
                Verdict::Accept => return Ok(f),
                v => tracing::debug!(?v, seq, "simulated frame discarded"),
            }
        }
    }

    async fn discards(&mut self) -> rig::camera::Discards {
        rig::camera::Discards {
            error_flagged: self.filter.dropped_error,
            stale: self.filter.dropped_early,
            settling: self.filter.dropped_settling,
            short: 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(material: &str, px: u32, seed: u64) -> SimCamera {
        let mut g = setup::RigGeometry::default();
        g.camera.width = px;
        g.camera.height = px;
        let cfg = SimCameraConfig {
            truth: RigTruth::perturbed(&g, seed),
            sensor: SensorModel::default(),
            leds: LedTruth::realistic(g.bar.n_leds, seed),
            timing: CameraTiming::Fast { time_scale: 0.0 },
            seed,
            faults: FaultSpec::default(),
            rest_um: 0.0,
        };
        let material = crate::materials::builtin(material).expect("a built-in sample");
        SimCamera::new(cfg, material, World::new())
    }

    /// The batched radiance is the one-pixel-at-a-time radiance (the
    /// renderer's reference path) for every built-in sample, on a perturbed
    /// rig (tilted sample, rolled bar), lit by LEDs from one end of the bar
    /// to the other, with the carriage on either side and above the view.
    /// Within 2e-5 of the reference: that is 0.24 electrons at the full
    /// well (0.08 DN), far below the shot noise at any signal, so the frames
    /// are the same images but for the noise's own draws. The mismatches
    /// come from the batch's polynomial `exp`, `ln` and `erf` (each within a
    /// few parts in 1e7) and, deep in a lobe's tail, `exp` of a large
    /// argument (an ulp of the argument is a relative error of the value).
    #[test]
    fn batched_radiance_is_the_reference_radiance() {
        for (name, _) in crate::materials::BUILTIN {
            let cam = camera(name, 96, 3);
            let truth = &cam.cfg.truth;
            let n = cam.pixels.len();
            let (mut batched, mut worst) = (0, 0.0f64);
            for (position_mm, led) in [(-90.0, 0u8), (-40.0, 7), (0.0, 19), (25.0, 33), (70.0, 39)] {
                let bar_x = truth.bar_x_mm(position_mm, true);
                let lights = [(truth.led_position(bar_x, led), bar_x, 1.0)];
                let lit = Lit::new(&cam.cfg, &lights);
                let mut got = vec![0.0; n];
                lit.radiance_run(0, &cam.pixels, &cam.columns, &mut got);
                let scale = (0..n).map(|k| lit.radiance(&cam.pixels[k])).fold(0.0f32, f32::max) as f64;
                assert!(scale > 0.0, "{name}: a dark frame");
                for k in 0..n {
                    let want = lit.radiance(&cam.pixels[k]) as f64;
                    let err = (got[k] as f64 - want).abs() / want.abs().max(1e-3 * scale);
                    assert!(
                        err <= 2e-5,
                        "{name}, bar at {position_mm} mm, LED {led}, pixel {k}: {} against {want}",
                        got[k]
                    );
                    worst = worst.max(err);
                }
                batched += (0..n).filter(|&k| cam.columns.batched_from(k)).count();
            }
            eprintln!("{name}: {batched} batch starts over 5 frames, worst relative difference {worst:.2e}");
            assert!(batched > n, "{name}: the batch was not used");
        }
    }

    /// The sensor's reading of a uniform signal over many pixels has the
    /// mean and variance of the sensor model: `black + g mu` and
    /// `g^2 (mu + read^2) + 1/12` DN (`g` DN per electron; the last term is
    /// rounding, Sheppard's correction, as every level's noise exceeds a
    /// DN), at levels in the Poisson regime, on either side of its edge and
    /// well into the Gaussian one. The bounds are 5 standard errors of the
    /// estimates over 262,144 pixels.
    #[test]
    fn a_uniform_signal_reads_with_the_sensors_mean_and_variance() {
        let sensor = SensorModel::default();
        let (w, rows) = (1024usize, 256usize);
        let x = batch::Exposure {
            e_per_radiance: 1.0,
            exposure_s: 1.0,
            full_well_e: sensor.full_well_e,
            read_sd_e: sensor.read_noise_e,
            dn_per_e: 1.0 / sensor.e_per_dn(),
            black_level_dn: sensor.black_level_dn,
            max_dn: ((1u32 << sensor.bit_depth) - 1) as f32,
        };
        let g = x.dn_per_e as f64;
        for mu in [0.4f32, 3.0, 12.5, 29.9, 30.1, 200.0, 4000.0] {
            let signal = vec![mu; w];
            let (gain, dark) = (vec![1.0; w], vec![0.0; w]);
            let mut out = vec![0u16; w];
            let (mut sum, mut sum2) = (0.0f64, 0.0f64);
            for row in 0..rows {
                batch::expose_row(
                    &x,
                    77 ^ (row as u64).wrapping_mul(0xA24B_AED4_963E_E407),
                    &signal,
                    &gain,
                    &dark,
                    &mut out,
                );
                for &v in &out {
                    sum += v as f64;
                    sum2 += (v as f64).powi(2);
                }
            }
            let n = (w * rows) as f64;
            let mean = sum / n;
            let var = sum2 / n - mean * mean;
            let want_mean = x.black_level_dn as f64 + g * mu as f64;
            let want_var = g * g * (mu as f64 + (x.read_sd_e as f64).powi(2)) + 1.0 / 12.0;
            let mean_bound = 5.0 * (want_var / n).sqrt();
            let var_bound = 5.0 * want_var * (2.0 / n).sqrt();
            eprintln!("{mu} e: mean {mean:.4} DN (model {want_mean:.4}), variance {var:.4} (model {want_var:.4})");
            assert!((mean - want_mean).abs() <= mean_bound, "{mu} e: mean {mean} DN, the model {want_mean}");
            assert!((var - want_var).abs() <= var_bound, "{mu} e: variance {var} DN^2, the model {want_var}");
        }
    }
}
