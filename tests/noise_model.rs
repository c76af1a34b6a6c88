//! The fitter's noise model (`fit::points::gather`: each sample's variance
//! from read noise and shot noise) against the simulated sensor: the true
//! material's luminance residual on the calibrated samples is the noise
//! itself, so its RMS over the model's predicted RMS is 1 for an exact
//! model. The choice's margin and pooling's Akaike test read the model's
//! variance as the noise: a model that understates the noise makes them
//! take complex models on noise. The bound is 1.05: with 150,000 samples
//! the ratio's own sampling error is 0.2%.
//!
//! The model overstates the luminance noise (the ratio printed is about
//! 0.5, issue 16's note): it gives each sample one raw pixel's variance at
//! the sample's luminance, while the luminance mixes three channels and
//! the demosaicing and bilinear sample average neighbouring pixels.

// Shared with the NDF tests; this file does not compare tables.
#[allow(dead_code)]
#[path = "support/simfit.rs"]
mod simfit;

use brdf::Brdf;
use fit::FitSettings;
use fit::partial::LUMA;
use simfit::{Scenario, run};

#[test]
fn the_noise_model_does_not_understate_the_noise() {
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
        assert!(ratio <= 1.05, "{name}: the noise is {ratio:.3} times what the model predicts");
    }
}
