//! Rendering a material on its flat sample.
//!
//! Each pixel's ray meets the sample plane at a point whose BRDF the
//! material gives. Point and directional lights are evaluated directly
//! (the sample is flat: nothing shadows it). An environment is integrated
//! by Monte Carlo with multiple importance sampling (balance heuristic,
//! Veach 1997) of the BRDF's own sampler and the environment's
//! luminance-proportional sampler; noise falls as `1/sqrt(env_samples)`.

use brdf::{Brdf, Rgb};
use glam::{Vec2, Vec3};
use material::SvBrdf;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use rayon::prelude::*;
use setup::SampleArea;

use crate::scene::{Light, Scene};

/// A linear HDR image (radiance per channel).
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<Rgb>,
}

impl Image {
    pub fn new(width: u32, height: u32) -> Self {
        Self { width, height, pixels: vec![Vec3::ZERO; (width * height) as usize] }
    }
}

/// Render `material` (on `sample`) as seen in `scene`.
pub fn render(material: &dyn SvBrdf, sample: &SampleArea, scene: &Scene, seed: u64) -> Image {
    let cam = &scene.camera;
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut img = Image::new(cam.width, cam.height);
    img.pixels.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let mut rng = Pcg64::seed_from_u64(seed ^ (y as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        for (x, out) in row.iter_mut().enumerate() {
            let px = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            let Some(q) = cam.pixel_to_plane(px) else { continue };
            if !sample.contains(q) {
                continue;
            }
            let p = q.extend(0.0);
            let o = cam.view_dir(p);
            if o.z <= 0.0 {
                continue;
            }
            let b = material.at(q);
            *out = shade(&b, p, o, scene, &mut rng);
        }
        let _ = h;
    });
    img
}

/// Radiance leaving `p` toward `o` under the scene's lights.
pub fn shade(b: &dyn Brdf, p: Vec3, o: Vec3, scene: &Scene, rng: &mut Pcg64) -> Rgb {
    let mut l = Vec3::ZERO;
    for light in &scene.lights {
        match *light {
            Light::Point { position_mm, intensity } => {
                let d = position_mm - p;
                let r2 = d.length_squared();
                if r2 <= 0.0 {
                    continue;
                }
                let i = d / r2.sqrt();
                if i.z > 0.0 {
                    l += b.eval(i, o) * intensity * (i.z / r2);
                }
            }
            Light::Directional { direction, irradiance } => {
                let i = direction.normalize_or(Vec3::Z);
                if i.z > 0.0 {
                    l += b.eval(i, o) * irradiance * i.z;
                }
            }
        }
    }
    if let Some(env) = &scene.env {
        let n = scene.env_samples.max(1);
        let mut acc = Vec3::ZERO;
        for _ in 0..n {
            // BRDF sample.
            let u = Vec2::new(rng.random(), rng.random());
            if let Some(s) = b.sample(o, u) {
                let pe = env.pdf(s.i);
                let w = s.pdf / (s.pdf + pe);
                acc += b.eval(s.i, o) * env.radiance(s.i) * (s.i.z * w / s.pdf);
            }
            // Environment sample.
            let u = Vec2::new(rng.random(), rng.random());
            if let Some((i, pe)) = env.sample(u) {
                if i.z > 0.0 {
                    let pb = b.pdf(o, i);
                    let w = pe / (pe + pb);
                    acc += b.eval(i, o) * env.radiance(i) * (i.z * w / pe);
                }
            }
        }
        l += acc / n as f32;
    }
    if l.is_finite() { l.max(Vec3::ZERO) } else { Vec3::ZERO }
}
