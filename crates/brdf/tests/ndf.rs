//! NDF normalisation, published reference values, tabulated masking against
//! Smith's closed forms, and table resampling.

mod support;

use std::sync::Arc;

use brdf::ndf::{Beckmann, Ggx, MaskingOperator, Mixture, Ndf, NdfGrid, NdfTable, PowerCosine, Sheen, TabulatedNdf};
use glam::Vec3;
use support::{dir, integrate_hemisphere};

fn normalisation(n: &dyn Ndf) -> f64 {
    integrate_hemisphere(3000, 384, |h| n.d(h) as f64 * h.z as f64)
}

#[test]
fn every_analytic_ndf_is_normalised() {
    for &(ax, ay) in &[(0.01f32, 0.01f32), (0.05, 0.2), (0.3, 0.3), (0.5, 1.0), (1.0, 1.0)] {
        for angle in [0.0f32, 0.7] {
            let b = normalisation(&Beckmann::new(ax, ay, angle));
            let g = normalisation(&Ggx::new(ax, ay, angle));
            assert!((b - 1.0).abs() < 2e-3, "Beckmann {ax} {ay}: {b}");
            // GGX's tail holds mass up to the horizon; the ring quadrature
            // converges more slowly there.
            assert!((g - 1.0).abs() < 3e-3, "GGX {ax} {ay}: {g}");
        }
    }
    for &(nu, nv) in &[(1.0f32, 1.0f32), (10.0, 100.0), (500.0, 50.0), (5000.0, 5000.0)] {
        let p = normalisation(&PowerCosine::new(nu, nv, 0.3));
        assert!((p - 1.0).abs() < 2e-3, "power cosine {nu} {nv}: {p}");
    }
}

#[test]
fn tabulated_tables_are_normalised() {
    let grid = NdfGrid::DEFAULT;
    for alpha in [0.05f32, 0.2, 0.6] {
        let ndf = Beckmann::new(alpha, alpha * 1.5, 0.3);
        let mut table = NdfTable::from_ndf(grid, &ndf);
        // Cell averages preserve the integral before any normalisation.
        let before = table.integral_cos();
        assert!((before - 1.0).abs() < 5e-3, "alpha {alpha}: table integral {before}");
        table.normalize();
        assert!((table.integral_cos() - 1.0).abs() < 1e-5);
        // The interpolated NDF integrates to 1 within the interpolation error.
        let tab = TabulatedNdf::new(table, &MaskingOperator::new(grid));
        let n = normalisation(&tab);
        assert!((n - 1.0).abs() < 0.03, "alpha {alpha}: interpolated integral {n}");
    }
}

// Reference values from Mitsuba 3, src/render/tests/test_microfacet.py
// (data from Mitsuba 0.6): Beckmann alpha_u = 0.1, alpha_v = 0.3 and
// isotropic 0.1, along theta = linspace(0, pi, 20) at phi = pi/2, and along
// phi = linspace(0, 2 pi, 20) at theta = 0.1.
#[test]
fn beckmann_matches_mitsuba_reference_values() {
    let aniso = Beckmann::new(0.1, 0.3, 0.0);
    let iso = Beckmann::isotropic(0.1);
    let theta = |k: usize| std::f64::consts::PI * k as f64 / 19.0;
    let aniso_ref = [10.6103287, 8.22650051, 3.57923722, 0.684863329, 0.0326460004, 1.01964230e-4, 5.87322635e-10];
    for (k, &r) in aniso_ref.iter().enumerate() {
        let d = aniso.d(dir(theta(k), std::f64::consts::FRAC_PI_2)) as f64;
        assert!((d - r).abs() <= 1e-4 * r.max(1e-3), "theta {k}: {d} vs {r}");
    }
    let iso_ref = [31.8309879, 2.07673073, 3.02855828e-4];
    for (k, &r) in iso_ref.iter().enumerate() {
        let d = iso.d(dir(theta(k), std::f64::consts::FRAC_PI_2)) as f64;
        assert!((d - r).abs() <= 1e-4 * r.max(1e-3), "theta {k}: {d} vs {r}");
    }
    let phi_ref = [
        3.95569706, 4.34706259, 5.54415846, 7.4061389, 9.17129803, 9.62056446, 8.37803268, 6.42071199, 4.84459257,
        4.05276537,
    ];
    for (k, &r) in phi_ref.iter().enumerate() {
        let ph = 2.0 * std::f64::consts::PI * k as f64 / 19.0;
        let d = aniso.d(dir(0.1, ph)) as f64;
        assert!((d - r).abs() < 1e-4 * r, "phi {k}: {d} vs {r}");
        assert!((iso.d(dir(0.1, ph)) as f64 - 11.86709118).abs() < 1e-3);
    }
    // The value the design notes quote.
    assert!((iso.d(Vec3::Z) - 31.8310).abs() < 1e-3);
}

#[test]
fn smith_masking_matches_mitsuba_reference_values() {
    let theta = |k: usize| {
        std::f64::consts::FRAC_PI_3 + (std::f64::consts::FRAC_PI_2 - std::f64::consts::FRAC_PI_3) * k as f64 / 19.0
    };
    let y = std::f64::consts::FRAC_PI_2;
    let beckmann_aniso: [f64; 20] = [
        1.0,
        1.0,
        1.0,
        1.0000523,
        0.99941480,
        0.99757767,
        0.99420297,
        0.98884594,
        0.98091525,
        0.96961778,
        0.95387781,
        0.93222123,
        0.90260512,
        0.86216795,
        0.80686140,
        0.73091686,
        0.62609726,
        0.48074335,
        0.27883825,
        1.9197471e-06,
    ];
    let ggx_iso = [
        0.99261039,
        0.99160647,
        0.99042398,
        0.98901933,
        0.98733366,
        0.98528832,
        0.98277503,
        0.97964239,
        0.97567332,
        0.97054905,
        0.96378750,
        0.95463598,
        0.94187391,
        0.92344058,
        0.89569420,
        0.85189372,
        0.77902949,
        0.65144652,
        0.41989169,
        3.2584082e-06,
    ];
    let ggx_aniso = [
        0.94031686,
        0.93310797,
        0.92485082,
        0.91534841,
        0.90435863,
        0.89158219,
        0.87664890,
        0.85909742,
        0.83835226,
        0.81369340,
        0.78421932,
        0.74880326,
        0.70604056,
        0.65419233,
        0.59112519,
        0.51425743,
        0.42051861,
        0.30633566,
        0.16765384,
        1.0861372e-06,
    ];
    let b = Beckmann::new(0.1, 0.3, 0.0);
    let g = Ggx::isotropic(0.1);
    let ga = Ggx::new(0.1, 0.3, 0.0);
    for k in 0..20 {
        let v = dir(theta(k), y);
        // Mitsuba 0.6 evaluated Beckmann's Lambda with Walter et al.'s
        // rational approximation (error < 0.35%, exactly 1 for a >= 1.6);
        // ours uses erf, so the reference holds to that approximation's error.
        assert!((b.g1(v) as f64 - beckmann_aniso[k].min(1.0)).abs() < 4e-3, "beckmann {k}: {}", b.g1(v));
        assert!((g.g1(v) as f64 - ggx_iso[k]).abs() < 2e-5, "ggx {k}: {}", g.g1(v));
        assert!((ga.g1(v) as f64 - ggx_aniso[k]).abs() < 2e-5, "ggx aniso {k}: {}", ga.g1(v));
    }
    let v = dir(std::f64::consts::FRAC_PI_2 * 0.98, 0.0);
    assert!((Beckmann::isotropic(0.1).g1(v) - 0.67333597).abs() < 4e-3);
    assert!((Ggx::isotropic(0.1).g1(v) - 0.46130955).abs() < 2e-5);
}

#[test]
fn tabulated_masking_matches_smith_for_beckmann_and_ggx() {
    let grid = NdfGrid::DEFAULT;
    let op = MaskingOperator::new(grid);
    let analytic: Vec<(&str, Box<dyn Ndf>)> = vec![
        ("beckmann 0.2", Box::new(Beckmann::isotropic(0.2))),
        ("beckmann 0.5/0.2", Box::new(Beckmann::new(0.5, 0.2, 0.6))),
        ("ggx 0.2", Box::new(Ggx::isotropic(0.2))),
        ("ggx 0.4/0.15", Box::new(Ggx::new(0.4, 0.15, 1.1))),
    ];
    for (name, ndf) in &analytic {
        let mut table = NdfTable::from_ndf(grid, ndf);
        table.normalize();
        let tab = TabulatedNdf::new(table, &op);
        let mut worst: f32 = 0.0;
        for t_deg in [0.0f64, 20.0, 45.0, 60.0, 70.0, 80.0, 85.0, 88.0] {
            for phi in [0.0, 0.5, 1.3, 2.9, 4.0] {
                let v = dir(t_deg.to_radians(), phi);
                worst = worst.max((tab.g1(v) - ndf.g1(v)).abs());
            }
        }
        // Measured worst cases on the default grid are 0.002-0.0034
        // (the table resolves rings to a few degrees near the horizon and
        // truncates GGX's tail there); 0.005 leaves a small margin.
        assert!(worst < 0.005, "{name}: worst |S_table - S_smith| = {worst}");
    }
}

/// A direction's projected area is the table's values interpolated
/// between the two direction rings and the two sectors around it (rings at
/// `j / (n - 1) * pi/2`, sectors centred at `(q + 1/2) 2 pi / n_phi`), the
/// last sector's neighbour being the first: checked by hand on both sides
/// of that seam (where the located cell's second sector is not stored but
/// follows from the first) and away from it.
#[test]
fn masking_reads_between_sectors_across_the_azimuth_seam() {
    use std::f64::consts::{FRAC_PI_2, TAU};
    for grid in [NdfGrid::DEFAULT, NdfGrid::new(9, 27).unwrap()] {
        let op = MaskingOperator::new(grid);
        let mut table = NdfTable::from_ndf(grid, &Beckmann::new(0.5, 0.2, 0.6));
        table.normalize();
        let m = op.projected_areas(&table);
        let np = grid.n_phi as usize;
        let rings = m.values().len() / np;
        let dphi = TAU / np as f64;
        for theta_deg in [10.0f64, 33.0, 61.0, 84.0] {
            for phi in [0.1 * dphi, 0.45 * dphi, 0.55 * dphi, 3.2 * dphi, TAU - 0.3 * dphi, TAU - 0.02 * dphi] {
                let theta = theta_deg.to_radians();
                let x = theta / FRAC_PI_2 * (rings - 1) as f64;
                let (j0, fj) = (x.floor() as usize, x.fract());
                let y = phi / dphi - 0.5;
                let (q0, fq) = (y.floor().rem_euclid(np as f64) as usize, y - y.floor());
                let q1 = (q0 + 1) % np;
                let s = |j: usize, q: usize| m.values()[j * np + q] as f64;
                let ring = |j: usize| s(j, q0) * (1.0 - fq) + s(j, q1) * fq;
                let want = (ring(j0) * (1.0 - fj) + ring(j0 + 1) * fj).max(theta.cos());
                let got = m.projected_area(dir(theta, phi)) as f64;
                assert!(
                    (got - want).abs() <= 1e-4 * want,
                    "{grid:?} theta {theta_deg} phi {phi:.4}: {got} against {want} by hand"
                );
            }
        }
    }
}

#[test]
fn power_cosine_masking_approximation_error_is_bounded() {
    // The Beckmann equivalence used for the power-cosine projected area,
    // against numerical integration of the definition.
    for n in [10.0f32, 100.0, 1000.0] {
        let ndf = PowerCosine::isotropic(n);
        for t_deg in [30.0f64, 60.0, 80.0, 88.0] {
            let v = dir(t_deg.to_radians(), 0.4);
            let exact = integrate_hemisphere(2000, 256, |h| (h.dot(v).max(0.0) * ndf.d(h)) as f64);
            let approx = ndf.projected_area(v) as f64;
            let s_exact = v.z as f64 / exact;
            let s_approx = v.z as f64 / approx;
            assert!((s_exact - s_approx).abs() < 0.03, "n {n} theta {t_deg}: S {s_exact} vs {s_approx}");
        }
    }
}

#[test]
fn rotating_a_table_matches_rotating_the_ndf() {
    let grid = NdfGrid::DEFAULT;
    let angle = 5.0 * grid.dphi();
    let a = NdfTable::from_ndf(grid, &Beckmann::new(0.3, 0.1, 0.2));
    let b = NdfTable::from_ndf(grid, &Beckmann::new(0.3, 0.1, 0.2 + angle));
    let r = a.rotated(angle);
    let e = r.rel_l2(&b, None).unwrap();
    assert!(e < 1e-4, "{e}");
    // A fractional rotation interpolates: error bounded by the sector width.
    let half = a.rotated(0.5 * grid.dphi());
    let c = NdfTable::from_ndf(grid, &Beckmann::new(0.3, 0.1, 0.2 + 0.5 * grid.dphi()));
    assert!(half.rel_l2(&c, None).unwrap() < 0.05);
}

#[test]
fn mixture_and_sheen_are_normalised_and_masking_is_consistent() {
    let m = Mixture::new(vec![
        (0.7, Arc::new(Beckmann::new(0.1, 0.4, 0.0)) as Arc<dyn Ndf>),
        (0.3, Arc::new(Beckmann::new(0.1, 0.4, std::f32::consts::FRAC_PI_2))),
    ])
    .unwrap();
    assert!((normalisation(&m) - 1.0).abs() < 2e-3);
    let sheen = Sheen::new(0.3, 4.0);
    assert!((normalisation(&sheen) - 1.0).abs() < 5e-3, "{}", normalisation(&sheen));
    // Tabulated projected areas against direct integration of the definition.
    for ndf in [&m as &dyn Ndf, &sheen] {
        for t_deg in [0.0f64, 40.0, 75.0, 88.0] {
            let v = dir(t_deg.to_radians(), 0.7);
            let exact = integrate_hemisphere(1500, 256, |h| (h.dot(v).max(0.0) * ndf.d(h)) as f64);
            let s = ndf.projected_area(v) as f64;
            assert!((s - exact.max(v.z as f64)).abs() < 0.01 * exact.max(0.05), "theta {t_deg}: {s} vs {exact}");
        }
    }
}
