//! No model returns NaN, infinity or a negative value anywhere: normal
//! incidence, grazing (89.9 degrees and exactly 90), below the horizon,
//! roughness from 1e-4 to 1, zero specular, coincident and opposite
//! directions. Sampling stays finite too.

mod support;

use brdf::catalog;
use brdf::ndf::NdfGrid;
use glam::{Vec2, Vec3};
use support::dir;

const ROUGHNESS: [f32; 7] = [1e-4, 1e-3, 0.01, 0.05, 0.2, 0.5, 1.0];

fn directions() -> Vec<Vec3> {
    let deg = |d: f64| d.to_radians();
    let thetas = [
        0.0,
        1e-6,
        1e-4,
        0.01,
        deg(10.0),
        deg(30.0),
        deg(45.0),
        deg(60.0),
        deg(80.0),
        deg(89.0),
        deg(89.9),
        deg(90.0),
        deg(90.1),
        deg(120.0),
        deg(180.0),
    ];
    let phis = [0.0, 0.3, std::f64::consts::FRAC_PI_2, 2.0, std::f64::consts::PI, 4.5];
    let mut v = Vec::new();
    for &t in &thetas {
        for &p in &phis {
            v.push(dir(t, p));
        }
    }
    // Exactly on the horizon, exactly the normal, exactly the antipode.
    v.extend([Vec3::X, Vec3::Y, -Vec3::X, Vec3::Z, -Vec3::Z]);
    v
}

fn assert_valid(name: &str, alpha: f32, i: Vec3, o: Vec3, f: Vec3) {
    for c in f.to_array() {
        assert!(c.is_finite() && c >= 0.0, "{name} alpha {alpha}: f({i:?}, {o:?}) = {f:?}");
    }
    if i.z <= 0.0 || o.z <= 0.0 {
        assert_eq!(f, Vec3::ZERO, "{name}: nonzero below horizon for i {i:?} o {o:?}");
    }
}

#[test]
fn every_model_is_finite_and_non_negative_over_the_extreme_grid() {
    let dirs = directions();
    for &alpha in &ROUGHNESS {
        for (kd, ks) in [(0.3, 0.7), (0.0, 1.0), (0.5, 0.0)] {
            for anis in [1.0, 4.0] {
                for e in catalog::models(alpha, anis, kd, ks, Some(NdfGrid::new(16, 32).unwrap())) {
                    for &i in &dirs {
                        for &o in &dirs {
                            assert_valid(e.name, alpha, i, o, e.brdf.eval(i, o));
                        }
                        // Coincident, mirror and opposite pairs.
                        let mirror = Vec3::new(-i.x, -i.y, i.z);
                        assert_valid(e.name, alpha, i, i, e.brdf.eval(i, i));
                        assert_valid(e.name, alpha, i, mirror, e.brdf.eval(i, mirror));
                        assert_valid(e.name, alpha, i, -i, e.brdf.eval(i, -i));
                    }
                }
            }
        }
    }
}

#[test]
fn sampling_is_finite_at_the_extremes() {
    let dirs = directions();
    let us =
        [Vec2::ZERO, Vec2::new(0.5, 0.5), Vec2::new(0.999_999, 0.999_999), Vec2::new(1e-7, 0.7), Vec2::new(0.3, 1e-7)];
    for &alpha in &ROUGHNESS {
        for e in catalog::models(alpha, 3.0, 0.3, 0.7, Some(NdfGrid::new(16, 32).unwrap())) {
            for &o in &dirs {
                for &u in &us {
                    if let Some(s) = e.brdf.sample(o, u) {
                        assert!(s.i.is_finite() && s.pdf.is_finite() && s.pdf > 0.0, "{} alpha {alpha}: {s:?}", e.name);
                        assert!((s.i.length() - 1.0).abs() < 1e-3, "{}: unnormalised sample {s:?}", e.name);
                    }
                    let p = e.brdf.pdf(o, Vec3::new(0.3, 0.2, 0.93).normalize());
                    assert!(p.is_finite() && p >= 0.0, "{} pdf {p}", e.name);
                }
            }
        }
    }
}

#[test]
fn analytic_ndfs_are_finite_for_extreme_roughness() {
    use brdf::ndf::{Beckmann, Ggx, Ndf, PowerCosine};
    let dirs = directions();
    for &alpha in &[1e-6f32, 1e-4, 1e-2, 1.0, 4.0, 100.0, f32::NAN] {
        let ndfs: Vec<Box<dyn Ndf>> = vec![
            Box::new(Beckmann::new(alpha, alpha * 2.0, 1.0)),
            Box::new(Ggx::new(alpha, alpha * 2.0, 1.0)),
            Box::new(PowerCosine::new(2.0 / (alpha * alpha), 1.0 / alpha, 1.0)),
        ];
        for n in &ndfs {
            for &h in &dirs {
                let d = n.d(h);
                let s = n.projected_area(h);
                let g = n.g1(h);
                assert!(d.is_finite() && d >= 0.0, "alpha {alpha}: D({h:?}) = {d}");
                assert!(s.is_finite() && s > 0.0, "alpha {alpha}: sigma({h:?}) = {s}");
                assert!((0.0..=1.0).contains(&g), "alpha {alpha}: G1({h:?}) = {g}");
            }
            for u in [Vec2::ZERO, Vec2::new(0.999_999_9, 0.5), Vec2::new(0.5, 0.25)] {
                let h = n.sample_h(u);
                assert!(h.is_finite() && h.z >= 0.0, "alpha {alpha}: sample {h:?}");
            }
        }
    }
}
