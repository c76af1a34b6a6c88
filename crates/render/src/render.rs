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

/// Render `material` (on `sample`) as seen in `scene`: each pixel's
/// radiance at its centre.
pub fn render(material: &dyn SvBrdf, sample: &SampleArea, scene: &Scene, seed: u64) -> Image {
    render_subpixels(material, sample, scene, seed, 1)
}

/// [`render`] with each pixel the mean of `n x n` rays through the centres
/// of an even grid of subpixels (a box filter over the pixel); `n = 1` is
/// the pixel's centre alone. A lobe narrower than what a pixel spans puts
/// its highlight on a few pixel centres or on none, so a one-ray render's
/// error depends on where the centres fall; more rays per pixel estimate
/// the pixel's mean radiance instead.
pub fn render_subpixels(material: &dyn SvBrdf, sample: &SampleArea, scene: &Scene, seed: u64, n: u32) -> Image {
    let cam = &scene.camera;
    let w = cam.width as usize;
    let n = n.max(1);
    let offsets: Vec<Vec2> =
        (0..n * n).map(|k| Vec2::new((k % n) as f32 + 0.5, (k / n) as f32 + 0.5) / n as f32).collect();
    let inv = 1.0 / offsets.len() as f32;
    let mut img = Image::new(cam.width, cam.height);
    img.pixels.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let mut rng = Pcg64::seed_from_u64(seed ^ (y as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        for (x, out) in row.iter_mut().enumerate() {
            let corner = Vec2::new(x as f32, y as f32);
            let mut sum = Vec3::ZERO;
            for &d in &offsets {
                let Some(q) = cam.pixel_to_plane(corner + d) else { continue };
                if !sample.contains(q) {
                    continue;
                }
                let p = q.extend(0.0);
                let o = cam.view_dir(p);
                if o.z <= 0.0 {
                    continue;
                }
                let b = material.at(q);
                sum += shade(&b, p, o, scene, &mut rng);
            }
            *out = sum * inv;
        }
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

#[cfg(test)]
mod tests {
    use material::PointMaterial;

    use super::*;
    use crate::scene::Light;

    /// Matte white left of `x = edge` (mm), black right of it.
    struct Edge {
        edge: f32,
    }

    impl SvBrdf for Edge {
        fn name(&self) -> &str {
            "edge"
        }
        fn at(&self, p: Vec2) -> PointMaterial {
            PointMaterial::Diffuse { kd: Vec3::splat(if p.x < self.edge { 1.0 } else { 0.0 }) }
        }
    }

    /// A pixel that an edge crosses is the white share of its footprint
    /// times the white's radiance (`1 / pi` under unit irradiance from
    /// overhead). With `n` even columns of rays, the share is counted in
    /// steps of `1 / n`, so each pixel is within `1 / n` of it; one ray (the
    /// pixel's centre) makes it all or nothing.
    #[test]
    fn rays_spread_over_a_pixel_give_the_share_of_an_edge_within_it() {
        let sample = SampleArea { width_mm: 60.0, height_mm: 60.0 };
        let camera = Scene::camera(0.0, 0.0, 300.0, 8.0, 24);
        let scene = Scene {
            camera,
            lights: vec![Light::Directional { direction: Vec3::Z, irradiance: Vec3::ONE }],
            env: None,
            env_samples: 0,
        };
        let white = std::f32::consts::FRAC_1_PI;
        for edge in [0.37f32, -2.9, 5.9] {
            let m = Edge { edge };
            let one = render(&m, &sample, &scene, 1);
            assert_eq!(one, render_subpixels(&m, &sample, &scene, 1, 1), "one ray is the pixel's centre");
            let mut crossed = 0;
            for n in [4u32, 8] {
                let img = render_subpixels(&m, &sample, &scene, 1, n);
                for y in 0..scene.camera.height {
                    for x in 0..scene.camera.width {
                        // The white share of the pixel's footprint, from its
                        // corners on the plane (the view is overhead, so the
                        // footprint is a square to within the perspective).
                        let corners: Vec<Vec2> = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
                            .iter()
                            .filter_map(|&(dx, dy)| {
                                scene.camera.pixel_to_plane(Vec2::new(x as f32 + dx, y as f32 + dy))
                            })
                            .collect();
                        assert_eq!(corners.len(), 4);
                        let lo = corners.iter().map(|c| c.x).fold(f32::INFINITY, f32::min);
                        let hi = corners.iter().map(|c| c.x).fold(f32::NEG_INFINITY, f32::max);
                        let share = ((edge - lo) / (hi - lo)).clamp(0.0, 1.0);
                        let got = img.pixels[(y * scene.camera.width + x) as usize].x / white;
                        assert!(
                            (got - share).abs() <= 1.0 / n as f32 + 1e-3,
                            "edge {edge}, n {n}, pixel ({x}, {y}): {got} against a share of {share}"
                        );
                        if n == 8 && share > 0.1 && share < 0.9 {
                            crossed += 1;
                            let centre = one.pixels[(y * scene.camera.width + x) as usize].x / white;
                            assert!(centre == 0.0 || (centre - 1.0).abs() < 1e-5, "one ray: {centre}");
                        }
                    }
                }
            }
            assert!(crossed > 0, "edge {edge} crosses no pixel away from its sides");
        }
    }
}
