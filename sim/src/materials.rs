//! Built-in materials with known ground truth everywhere. Each is written
//! in the talk's microfacet form with Ward's elliptical-Gaussian
//! (anisotropic Beckmann) lobes, mixed where a point has several, so the
//! true NDF of every point is known exactly and the whole hemisphere can be
//! scored, not only the part the camera saw.
//!
//! | name | what it is |
//! |---|---|
//! | `satin` | golden 5-harness satin: warp floats (4 of 5 cells) and weft (1 of 5), each point a mix of both thread lobes, the weave drifting by about 8 degrees across the sample |
//! | `red-satin` | the same weave in red, finer lobes, turned 30 degrees |
//! | `wallpaper` | printed diffuse damask pattern, glossy isotropic embossing in a diamond pattern, matte elsewhere |
//! | `velvet` | inverted-Gaussian pile distribution: bright grazing rim and grazing retro-reflection, crushed-pile variation of colour |
//! | `brushed-metal` | one narrow anisotropic lobe, conductor Fresnel, brushing direction turning by about 110 degrees across the sample (spun around a centre below the sample) |
//! | `ward` | one anisotropic Ward lobe (0.1 x 0.3 at 30 degrees), the same everywhere |
//! | `white` | Lambertian reference of albedo 0.95 (the calibration target) |

use std::f32::consts::{FRAC_PI_2, PI, TAU};
use std::sync::{Arc, OnceLock};

use brdf::fresnel::Fresnel;
use brdf::ndf::{Beckmann, Mixture, Ndf, Sheen};
use glam::{Vec2, Vec3};
use material::{PointMaterial, SvBrdf};

/// Names and one-line descriptions of the built-in materials.
pub const BUILTIN: &[(&str, &str)] = &[
    ("satin", "golden satin weave, two anisotropic thread lobes per point, orientation drifting"),
    ("red-satin", "red satin weave, finer lobes, turned 30 degrees"),
    ("wallpaper", "printed diffuse pattern with glossy embossing"),
    ("velvet", "pile with grazing sheen and retro-reflection"),
    ("brushed-metal", "one narrow anisotropic lobe whose direction turns across the sample"),
    ("ward", "a single anisotropic Ward lobe, homogeneous"),
    ("white", "Lambertian white reference (albedo 0.95)"),
];

/// The built-in material called `name`.
pub fn builtin(name: &str) -> Option<Arc<dyn SvBrdf>> {
    let m: Arc<dyn SvBrdf> = match name {
        "satin" => Arc::new(Satin::golden()),
        "red-satin" => Arc::new(Satin::red()),
        "wallpaper" => Arc::new(Wallpaper),
        "velvet" => Arc::new(Velvet::new()),
        "brushed-metal" => Arc::new(BrushedMetal),
        "ward" => Arc::new(WardSurface),
        "white" => Arc::new(White),
        _ => return None,
    };
    Some(m)
}

/// A list of the built-in names for error messages.
pub fn builtin_names() -> String {
    BUILTIN.iter().map(|(n, _)| *n).collect::<Vec<_>>().join(", ")
}

fn dielectric() -> Fresnel {
    Fresnel::Dielectric { eta: 1.5 }
}

/// Satin: a 5-harness weave. In weave coordinates (rotated by `angle`),
/// cell `(i, j)` shows weft where `(i - 2 j) mod 5 == 0` and a warp float
/// elsewhere. A thread is a cylinder, so its normals spread across it: the
/// lobe is narrow along the thread (`along`) and wide across it (`across`).
#[derive(Clone, Debug)]
pub struct Satin {
    name: &'static str,
    kd: Vec3,
    ks: f32,
    angle: f32,
    pitch_mm: f32,
    along: f32,
    across: f32,
    drift_rad: f32,
    own_weight: f32,
}

impl Satin {
    pub fn golden() -> Self {
        Self {
            name: "satin",
            kd: Vec3::new(0.30, 0.22, 0.04),
            ks: 1.0,
            angle: 0.0,
            pitch_mm: 2.5,
            along: 0.10,
            across: 0.35,
            drift_rad: 0.14,
            own_weight: 0.85,
        }
    }

    pub fn red() -> Self {
        Self {
            name: "red-satin",
            kd: Vec3::new(0.42, 0.03, 0.05),
            ks: 1.0,
            angle: 30f32.to_radians(),
            pitch_mm: 2.0,
            along: 0.07,
            across: 0.28,
            drift_rad: 0.10,
            own_weight: 0.85,
        }
    }

    /// Weave direction at `p` (radians from the sample's x axis).
    pub fn warp_angle(&self, p: Vec2) -> f32 {
        self.angle + self.drift_rad * (TAU * p.x / 80.0).sin() * (TAU * p.y / 110.0).cos()
    }

    /// True where the weft shows.
    pub fn is_weft(&self, p: Vec2) -> bool {
        let (s, c) = self.angle.sin_cos();
        let u = c * p.x + s * p.y;
        let v = -s * p.x + c * p.y;
        let i = (u / self.pitch_mm).floor() as i64;
        let j = (v / self.pitch_mm).floor() as i64;
        (i - 2 * j).rem_euclid(5) == 0
    }
}

impl SvBrdf for Satin {
    fn name(&self) -> &str {
        self.name
    }

    fn at(&self, p: Vec2) -> PointMaterial {
        let warp = self.warp_angle(p);
        let weft = warp + FRAC_PI_2;
        let (own, other) = if self.is_weft(p) { (weft, warp) } else { (warp, weft) };
        let ndf = Mixture::new(vec![
            (self.own_weight, Arc::new(Beckmann::new(self.along, self.across, own)) as Arc<dyn Ndf>),
            (1.0 - self.own_weight, Arc::new(Beckmann::new(self.along, self.across, other))),
        ])
        .map(|m| Arc::new(m) as Arc<dyn Ndf>)
        .unwrap_or_else(|| Arc::new(Beckmann::isotropic(0.3)));
        PointMaterial::microfacet(self.kd, Vec3::splat(self.ks), ndf, dielectric())
    }
}

/// Wallpaper: a printed two-colour damask motif, glossy where embossed.
#[derive(Clone, Copy, Debug)]
pub struct Wallpaper;

impl Wallpaper {
    fn motif(p: Vec2) -> f32 {
        // Smooth repeating motif in [0, 1].
        let a = (TAU * p.x / 25.0).sin() * (TAU * p.y / 25.0).sin();
        let r = ((p.x.rem_euclid(25.0) - 12.5).powi(2) + (p.y.rem_euclid(25.0) - 12.5).powi(2)).sqrt();
        let ring = (-(r - 7.0).powi(2) / 4.0).exp();
        (0.5 + 0.5 * a).max(ring).clamp(0.0, 1.0)
    }

    fn embossed(p: Vec2) -> bool {
        // Diamond lattice of raised lines, 1.5 mm wide, 12 mm apart.
        let d1 = (p.x + p.y).rem_euclid(12.0);
        let d2 = (p.x - p.y).rem_euclid(12.0);
        d1 < 1.5 || d2 < 1.5
    }
}

impl SvBrdf for Wallpaper {
    fn name(&self) -> &str {
        "wallpaper"
    }

    fn at(&self, p: Vec2) -> PointMaterial {
        let m = Self::motif(p);
        let cream = Vec3::new(0.72, 0.66, 0.52);
        let green = Vec3::new(0.12, 0.28, 0.18);
        let kd = cream.lerp(green, m);
        if Self::embossed(p) {
            PointMaterial::microfacet(kd, Vec3::ONE, Arc::new(Beckmann::isotropic(0.12)), dielectric())
        } else {
            PointMaterial::microfacet(kd, Vec3::splat(0.5), Arc::new(Beckmann::isotropic(0.45)), dielectric())
        }
    }
}

/// Velvet: pile distribution with a broad base lobe.
#[derive(Clone)]
pub struct Velvet {
    ndf: Arc<dyn Ndf>,
}

impl std::fmt::Debug for Velvet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Velvet")
    }
}

impl Velvet {
    pub fn new() -> Self {
        static NDF: OnceLock<Arc<dyn Ndf>> = OnceLock::new();
        let ndf = NDF
            .get_or_init(|| {
                let m = Mixture::new(vec![
                    (0.8, Arc::new(Sheen::new(0.35, 6.0)) as Arc<dyn Ndf>),
                    (0.2, Arc::new(Beckmann::isotropic(0.5))),
                ]);
                match m {
                    Some(m) => Arc::new(m) as Arc<dyn Ndf>,
                    None => Arc::new(Beckmann::isotropic(0.5)),
                }
            })
            .clone();
        Self { ndf }
    }
}

impl Default for Velvet {
    fn default() -> Self {
        Self::new()
    }
}

impl SvBrdf for Velvet {
    fn name(&self) -> &str {
        "velvet"
    }

    fn at(&self, p: Vec2) -> PointMaterial {
        // Crushed pile: patches where the colour is lighter.
        let crush = 0.5 + 0.5 * ((p.x / 13.0).sin() * (p.y / 17.0 + 0.5 * (p.x / 29.0).cos()).sin());
        let kd = Vec3::new(0.22, 0.015, 0.035) * (0.75 + 0.5 * crush);
        PointMaterial::microfacet(kd, Vec3::splat(1.5), self.ndf.clone(), dielectric())
    }
}

/// Brushed aluminium, spun around a centre below the sample.
#[derive(Clone, Copy, Debug)]
pub struct BrushedMetal;

impl BrushedMetal {
    const CENTRE: Vec2 = Vec2::new(-20.0, -80.0);

    /// Brushing direction at `p`: tangent to the circle around the centre.
    pub fn direction(p: Vec2) -> f32 {
        let d = p - Self::CENTRE;
        d.y.atan2(d.x) + FRAC_PI_2
    }
}

impl SvBrdf for BrushedMetal {
    fn name(&self) -> &str {
        "brushed-metal"
    }

    fn at(&self, p: Vec2) -> PointMaterial {
        let angle = Self::direction(p).rem_euclid(PI);
        let ndf = Arc::new(Beckmann::new(0.05, 0.25, angle));
        // Aluminium at roughly R, G, B wavelengths.
        let fresnel = Fresnel::Conductor { eta: Vec3::new(1.66, 0.88, 0.52), k: Vec3::new(9.2, 6.3, 4.8) };
        PointMaterial::microfacet(Vec3::splat(0.01), Vec3::ONE, ndf, fresnel)
    }
}

/// One anisotropic Ward lobe everywhere.
#[derive(Clone, Copy, Debug)]
pub struct WardSurface;

impl SvBrdf for WardSurface {
    fn name(&self) -> &str {
        "ward"
    }

    fn at(&self, _p: Vec2) -> PointMaterial {
        let ndf = Arc::new(Beckmann::new(0.1, 0.3, 30f32.to_radians()));
        PointMaterial::microfacet(Vec3::splat(0.2), Vec3::ONE, ndf, dielectric())
    }
}

/// The white calibration reference.
#[derive(Clone, Copy, Debug)]
pub struct White;

/// Albedo of the simulated white reference.
pub const WHITE_ALBEDO: f32 = 0.95;

/// The printed checkerboard of the geometric calibration (matte paper and
/// toner), laid on the sample holder. Not a sample: not in [`BUILTIN`].
#[derive(Clone, Copy, Debug)]
pub struct Target(pub setup::CheckerTarget);

impl SvBrdf for Target {
    fn name(&self) -> &str {
        "checkerboard target"
    }

    fn at(&self, p: Vec2) -> PointMaterial {
        let albedo = if self.0.is_dark(p) { 0.04 } else { 0.8 };
        PointMaterial::Diffuse { kd: Vec3::splat(albedo) }
    }
}

/// A front-surface (aluminised) mirror laid in the sample holder for the
/// geometric calibration's mirror scan. A point LED seen in a perfect
/// mirror is a point; a real LED's die and the mirror's slight roughness
/// make a spot of a few pixels, modelled here as a very narrow isotropic
/// lobe (`alpha` 0.01, the spot's half-vector spread about 0.4 degrees).
/// Not a sample: not in [`BUILTIN`].
#[derive(Clone, Copy, Debug)]
pub struct Mirror;

/// Roughness of the simulated mirror's lobe.
pub const MIRROR_ALPHA: f32 = 0.01;

impl SvBrdf for Mirror {
    fn name(&self) -> &str {
        "front-surface mirror"
    }

    fn at(&self, _p: Vec2) -> PointMaterial {
        let ndf = Arc::new(Beckmann::new(MIRROR_ALPHA, MIRROR_ALPHA, 0.0));
        PointMaterial::microfacet(Vec3::ZERO, Vec3::splat(0.9), ndf, Fresnel::One)
    }
}

impl SvBrdf for White {
    fn name(&self) -> &str {
        "white"
    }

    fn at(&self, _p: Vec2) -> PointMaterial {
        PointMaterial::Diffuse { kd: Vec3::splat(WHITE_ALBEDO) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use brdf::Brdf;

    #[test]
    fn every_builtin_is_finite_and_satin_has_both_thread_directions() {
        for (name, _) in BUILTIN {
            let m = builtin(name).unwrap();
            for p in [Vec2::ZERO, Vec2::new(-49.0, 37.0), Vec2::new(12.3, -44.4)] {
                let f = m.at(p).eval(Vec3::new(0.3, 0.1, 0.95).normalize(), Vec3::new(-0.6, 0.0, 0.8).normalize());
                assert!(f.is_finite() && f.min_element() >= 0.0, "{name}: {f}");
            }
        }
        let s = Satin::golden();
        let n = 400;
        let weft = (0..n).filter(|k| s.is_weft(Vec2::new(*k as f32 * 0.37 - 70.0, *k as f32 * 0.91 - 50.0))).count();
        let frac = weft as f32 / n as f32;
        assert!((0.12..0.30).contains(&frac), "weft fraction {frac}");
        assert!(builtin("nonsense").is_none());
    }
}
