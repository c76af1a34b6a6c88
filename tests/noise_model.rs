//! The fitter's noise model (`fit::points::SampleNoise`: each sample's
//! variance from read and shot noise, carried through the demosaic, the
//! bilinear sample and the luminance weights, plus the dark level's own
//! noise) against the simulated sensor: the true material's luminance
//! residual on the calibrated samples is the noise itself, so its RMS over
//! the model's predicted RMS is 1 for an exact model.
//!
//! Both sides matter. The choice's margin and pooling's Akaike test read
//! the model's variance as the noise: a model that understates it makes
//! them take complex models on noise; one that overstates it (as the
//! one-pixel model did, by about 2x in RMS) makes them keep simple models
//! that the data reject. The bound is 5% either way: with 150,000 samples
//! the ratio's own sampling error is 0.2%, and what the model leaves out is
//! smaller than that margin: quantisation (1/12 DN^2 against a read
//! variance of 4 DN^2, 1% in RMS at most) and the pixel's footprint on the
//! sample (a deterministic blur, not noise).

// Shared with the NDF tests; this file does not compare tables.
#[allow(dead_code)]
#[path = "support/simfit.rs"]
mod simfit;

use brdf::Brdf;
use fit::FitSettings;
use fit::partial::LUMA;
use simfit::{Scenario, run};

#[test]
fn the_noise_model_predicts_the_sensors_noise() {
    for name in ["white", "ward"] {
        let s = Scenario {
            material: sim::materials::builtin(name).unwrap(),
            camera_px: 128,
            grid: 24,
            steps: 32,
            led_stride: 2,
            exposures_us: vec![20_000],
            seed: 5,
        };
        let f = run(&s, FitSettings::default());
        let lum = |v: [f32; 3]| LUMA.iter().zip(v).map(|(w, x)| (w * x) as f64).sum::<f64>();
        let (mut residual, mut predicted, mut n) = (0.0f64, 0.0f64, 0usize);
        for p in 0..f.ctx.n_points() {
            let ps = fit::points::gather(&f.ctx, &f.store, p, &f.settings);
            let truth = s.material.at(f.ctx.positions[p].truncate());
            for x in &ps.samples {
                residual += (lum(truth.eval(x.i, ps.o).to_array()) - lum(x.rho)).powi(2);
                predicted += x.var as f64;
                n += 1;
            }
        }
        let ratio = (residual / predicted).sqrt();
        eprintln!("{name}: {n} samples, true residual RMS / modelled noise RMS = {ratio:.3}");
        assert!(n > 100_000, "{name}: {n} samples");
        assert!((0.95..=1.05).contains(&ratio), "{name}: the noise is {ratio:.3} times what the model predicts");
    }
}
