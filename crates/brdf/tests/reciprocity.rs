//! `f(i, o) = f(o, i)` for every model documented as reciprocal, over random
//! directions and roughness (property test), and the original Phong model is
//! shown not to be.

use brdf::catalog;
use brdf::ndf::NdfGrid;
use glam::Vec3;
use proptest::prelude::*;

fn unit(theta: f32, phi: f32) -> Vec3 {
    Vec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]
    #[test]
    fn reciprocal_models_are_symmetric(
        alpha in 0.02f32..1.0,
        anis in 1.0f32..4.0,
        ti in 0.0f32..1.55, pi in 0.0f32..6.28,
        to in 0.0f32..1.55, po in 0.0f32..6.28,
    ) {
        let (i, o) = (unit(ti, pi), unit(to, po));
        for e in catalog::models(alpha, anis, 0.3, 0.7, Some(NdfGrid::new(16, 32).unwrap())) {
            if !e.reciprocal { continue; }
            let (a, b) = (e.brdf.eval(i, o), e.brdf.eval(o, i));
            let scale = a.max_element().max(b.max_element()).max(1e-6);
            prop_assert!((a - b).abs().max_element() <= 2e-4 * scale,
                "{}: f(i,o) = {:?} but f(o,i) = {:?}", e.name, a, b);
        }
    }
}

#[test]
fn original_phong_is_not_reciprocal() {
    let e = catalog::models(0.3, 1.0, 0.3, 0.7, None).into_iter().find(|e| e.name == "phong_original").unwrap();
    let (i, o) = (unit(1.2, 0.0), unit(0.3, 3.14));
    let (a, b) = (e.brdf.eval(i, o), e.brdf.eval(o, i));
    assert!((a - b).abs().max_element() > 0.1 * a.max_element(), "{a:?} {b:?}");
}
