//! Chi-square tests of every sampling routine against its pdf: the NDF
//! samplers (analytic and tabulated) over microfacet normals, and every
//! model's BRDF sampler over incident directions. Seeds are fixed; the
//! significance level is 1e-3 per test (Bonferroni over ~50 tests gives a
//! family-wise false-alarm rate below 5%).

mod support;

use brdf::catalog;
use std::sync::Arc;

use brdf::ndf::{Beckmann, Ggx, MaskingOperator, Mixture, Ndf, NdfGrid, NdfTable, PowerCosine, Sheen, TabulatedNdf};
use support::{chi2_test, dir};

const SAMPLES: usize = 200_000;
const ALPHA_SIG: f64 = 1e-3;

fn check_ndf(name: &str, n: &dyn Ndf, seed: u64) {
    let (p, info) = chi2_test(SAMPLES, seed, |u| Some(n.sample_h(u)), |h| n.pdf_h(h) as f64);
    assert!(p > ALPHA_SIG, "{name}: p = {p:.2e} ({info})");
}

#[test]
fn analytic_ndf_samplers_match_their_pdf() {
    for (k, &(ax, ay)) in [(0.1f32, 0.1f32), (0.1, 0.3), (0.5, 0.2), (0.9, 0.9)].iter().enumerate() {
        check_ndf(&format!("beckmann {ax}/{ay}"), &Beckmann::new(ax, ay, 0.5), 10 + k as u64);
        check_ndf(&format!("ggx {ax}/{ay}"), &Ggx::new(ax, ay, 0.5), 20 + k as u64);
    }
    for (k, &(nu, nv)) in [(5.0f32, 5.0f32), (10.0, 100.0), (200.0, 20.0)].iter().enumerate() {
        check_ndf(&format!("power cosine {nu}/{nv}"), &PowerCosine::new(nu, nv, 0.5), 30 + k as u64);
    }
    let mix = Mixture::new(vec![
        (0.6, Arc::new(Beckmann::new(0.1, 0.4, 0.3)) as Arc<dyn Ndf>),
        (0.4, Arc::new(Ggx::new(0.2, 0.2, 0.0))),
    ])
    .unwrap();
    check_ndf("mixture", &mix, 50);
    check_ndf("sheen", &Sheen::new(0.3, 4.0), 51);
}

#[test]
fn tabulated_ndf_sampler_matches_its_pdf() {
    for (k, grid) in [NdfGrid::DEFAULT, NdfGrid::new(16, 48).unwrap()].into_iter().enumerate() {
        let mut table = NdfTable::from_ndf(grid, &Beckmann::new(0.3, 0.12, 0.8));
        table.normalize();
        let tab = TabulatedNdf::new(table, &MaskingOperator::new(grid));
        check_ndf(&format!("tabulated {grid:?}"), &tab, 40 + k as u64);
    }
}

#[test]
fn brdf_samplers_match_their_pdf() {
    for (k, alpha) in [0.15f32, 0.5].into_iter().enumerate() {
        for e in catalog::models(alpha, 2.0, 0.3, 0.7, Some(NdfGrid::DEFAULT)) {
            for (j, t_deg) in [20.0f64, 70.0].into_iter().enumerate() {
                let o = dir(t_deg.to_radians(), 0.3);
                let (p, info) = chi2_test(
                    SAMPLES,
                    100 + (k * 10 + j) as u64,
                    |u| e.brdf.sample(o, u).map(|s| s.i),
                    |i| e.brdf.pdf(o, i) as f64,
                );
                assert!(p > ALPHA_SIG, "{} alpha {alpha} theta_o {t_deg}: p = {p:.2e} ({info})", e.name);
            }
        }
    }
}

#[test]
fn chi_square_detects_a_mismatched_pdf() {
    // Negative control: sampling alpha = 0.3 against the pdf of 0.33 must fail.
    let sampler = Beckmann::isotropic(0.3);
    let wrong = Beckmann::isotropic(0.33);
    let (p, info) = chi2_test(SAMPLES, 1, |u| Some(sampler.sample_h(u)), |h| wrong.pdf_h(h) as f64);
    assert!(p < 1e-6, "a 10% roughness error went unnoticed: p = {p:.2e} ({info})");
}
