//! The MERL reader and importer on a file encoded here from a known
//! microfacet BRDF (no MERL data ships with the project).

use std::sync::Arc;

use brdf::Brdf;
use brdf::fresnel::Fresnel;
use brdf::ndf::{Beckmann, NdfGrid, NdfTable};
use glam::Vec3;
use material::PointMaterial;
use material::merl::{MerlBrdf, import};

fn truth() -> PointMaterial {
    PointMaterial::microfacet(
        Vec3::new(0.3, 0.2, 0.1),
        Vec3::ONE,
        Arc::new(Beckmann::new(0.2, 0.2, 0.0)),
        Fresnel::Dielectric { eta: 1.5 },
    )
}

fn dir(t: f32, p: f32) -> Vec3 {
    let (t, p) = (t.to_radians(), p.to_radians());
    Vec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos())
}

#[test]
fn a_merl_file_round_trips_and_imports_to_its_ndf() {
    let t = truth();
    let bytes = MerlBrdf::encode(&t);
    assert_eq!(bytes.len(), 12 + 3 * 90 * 90 * 180 * 8);
    let m = MerlBrdf::parse(&bytes).unwrap();
    // Cell-centre values: within the tabulation's resolution of the truth.
    for (i, o) in
        [(dir(20.0, 0.0), dir(20.0, 180.0)), (dir(40.0, 10.0), dir(35.0, 200.0)), (dir(60.0, 0.0), dir(10.0, 90.0))]
    {
        let (a, b) = (m.eval(i, o), t.eval(i, o));
        assert!(((a - b).abs() / b.max(Vec3::splat(1e-3))).max_element() < 0.25, "{a:?} vs {b:?}");
    }
    // Reciprocity holds by construction of the parameterisation.
    let (i, o) = (dir(30.0, 20.0), dir(50.0, 170.0));
    assert_eq!(m.eval(i, o), m.eval(o, i));
    assert_eq!(m.eval(i, dir(95.0, 0.0)), Vec3::ZERO);

    let grid = NdfGrid::new(16, 48).unwrap();
    let (mat, summary) = import(&m, "beckmann", grid, 100.0);
    let mut want = NdfTable::from_ndf(grid, &Beckmann::new(0.2, 0.2, 0.0));
    want.normalize();
    let got = mat.ndf.as_ref().unwrap().get(0);
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for c in 0..grid.len() {
        let w = grid.cos_measure(c / grid.n_phi as usize) as f64;
        num += w * (got.values()[c] - want.values()[c]).powi(2) as f64;
        den += w * (want.values()[c] as f64).powi(2);
    }
    let err = (num / den).sqrt();
    eprintln!("{summary:?}; NDF error {err:.3}");
    assert!(err < 0.15, "NDF from the retro slice: relative L2 {err}");
    assert!((summary.kd[0] - 0.3).abs() < 0.05 && (summary.kd[2] - 0.1).abs() < 0.05, "{summary:?}");
    assert!(summary.residual < 0.2, "{summary:?}");
}

#[test]
fn malformed_merl_files_are_refused() {
    assert!(MerlBrdf::parse(&[0; 8]).is_err());
    let mut b = vec![0u8; 12];
    b[0] = 90;
    assert!(MerlBrdf::parse(&b).unwrap_err().to_string().contains("dimensions"));
    let mut b = Vec::new();
    for d in [90i32, 90, 180] {
        b.extend_from_slice(&d.to_le_bytes());
    }
    b.extend_from_slice(&[0; 100]);
    assert!(MerlBrdf::parse(&b).unwrap_err().to_string().contains("bytes"));
}
