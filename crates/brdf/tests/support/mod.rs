//! Shared numerical helpers for the property tests: hemisphere quadrature,
//! directional albedo, and Pearson's chi-square test of a sampler.
#![allow(dead_code)]

use std::f64::consts::{FRAC_PI_2, TAU};

use brdf::Brdf;
use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

pub fn rng(seed: u64) -> Pcg64 {
    Pcg64::seed_from_u64(seed)
}

pub fn dir(theta: f64, phi: f64) -> Vec3 {
    Vec3::new((theta.sin() * phi.cos()) as f32, (theta.sin() * phi.sin()) as f32, theta.cos() as f32)
}

/// Integral of `f` over the upper hemisphere with rings warped toward the
/// pole (`theta = u^2 pi/2`), which resolves lobes down to alpha ~ 1e-3.
pub fn integrate_hemisphere(n_theta: usize, n_phi: usize, f: impl Fn(Vec3) -> f64) -> f64 {
    let mut acc = 0.0;
    for a in 0..n_theta {
        let u0 = a as f64 / n_theta as f64;
        let u1 = (a + 1) as f64 / n_theta as f64;
        let (t0, t1) = (u0 * u0 * FRAC_PI_2, u1 * u1 * FRAC_PI_2);
        let tm = 0.5 * (t0 + t1);
        let w_theta = t0.cos() - t1.cos();
        for b in 0..n_phi {
            let ph = (b as f64 + 0.5) / n_phi as f64 * TAU;
            acc += f(dir(tm, ph)) * w_theta * TAU / n_phi as f64;
        }
    }
    acc
}

/// Directional albedo `integral f(i, o) cos(theta_i) dw_i` by stratified
/// importance sampling with the model's own sampler (`n x n` strata).
pub fn albedo_sampled(b: &dyn Brdf, o: Vec3, n: usize, seed: u64) -> f64 {
    let mut r = rng(seed);
    let mut acc = 0.0;
    for a in 0..n {
        for c in 0..n {
            let u = Vec2::new((a as f32 + r.random::<f32>()) / n as f32, (c as f32 + r.random::<f32>()) / n as f32);
            if let Some(s) = b.sample(o, u.min(Vec2::splat(0.999_999))) {
                let f = b.eval(s.i, o);
                acc += (f.x as f64) * s.i.z as f64 / s.pdf as f64;
            }
        }
    }
    acc / (n * n) as f64
}

/// Directional albedo by deterministic quadrature.
pub fn albedo_quadrature(b: &dyn Brdf, o: Vec3, n_theta: usize, n_phi: usize) -> f64 {
    integrate_hemisphere(n_theta, n_phi, |i| b.eval(i, o).x as f64 * i.z as f64)
}

/// Regularised upper incomplete gamma `Q(a, x)` (series for `x < a + 1`,
/// Lentz continued fraction otherwise).
pub fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let gln = libm::lgamma(a);
    if x < a + 1.0 {
        let (mut sum, mut del, mut ap) = (1.0 / a, 1.0 / a, a);
        for _ in 0..10_000 {
            ap += 1.0;
            del *= x / ap;
            sum += del;
            if del.abs() < sum.abs() * 1e-15 {
                break;
            }
        }
        1.0 - sum * (-x + a * x.ln() - gln).exp()
    } else {
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            if d.abs() < tiny {
                d = tiny;
            }
            c = b + an / c;
            if c.abs() < tiny {
                c = tiny;
            }
            d = 1.0 / d;
            let del = d * c;
            h *= del;
            if (del - 1.0).abs() < 1e-15 {
                break;
            }
        }
        (-x + a * x.ln() - gln).exp() * h
    }
}

/// Pearson chi-square test that `sample` draws directions with density `pdf`
/// (per unit solid angle) over the upper hemisphere. Bins are warped rings
/// by sectors; expected counts come from integrating `pdf` over each bin
/// with a 12 x 12 midpoint rule; bins expecting fewer than 5 samples are
/// pooled. Returns the p-value.
pub fn chi2_test(
    n_samples: usize,
    seed: u64,
    sample: impl Fn(Vec2) -> Option<Vec3>,
    pdf: impl Fn(Vec3) -> f64,
) -> (f64, String) {
    const NT: usize = 16;
    const NP: usize = 24;
    const SUB: usize = 12;
    let ring = |t: f64| {
        let u = (t / FRAC_PI_2).clamp(0.0, 1.0).sqrt();
        ((u * NT as f64) as usize).min(NT - 1)
    };
    let mut observed = vec![0.0f64; NT * NP + 1];
    let mut r = rng(seed);
    for _ in 0..n_samples {
        let u = Vec2::new(r.random::<f32>(), r.random::<f32>());
        match sample(u) {
            Some(v) if v.z > 0.0 => {
                let th = ((v.x * v.x + v.y * v.y) as f64).sqrt().atan2(v.z as f64);
                let ph = (v.y as f64).atan2(v.x as f64).rem_euclid(TAU);
                let b = ring(th) * NP + ((ph / TAU * NP as f64) as usize).min(NP - 1);
                observed[b] += 1.0;
            }
            _ => observed[NT * NP] += 1.0,
        }
    }
    let mut expected = vec![0.0f64; NT * NP + 1];
    let mut total = 0.0;
    for a in 0..NT {
        for b in 0..NP {
            let mut acc = 0.0;
            for sa in 0..SUB {
                let u0 = (a as f64 + sa as f64 / SUB as f64) / NT as f64;
                let u1 = (a as f64 + (sa + 1) as f64 / SUB as f64) / NT as f64;
                let (t0, t1) = (u0 * u0 * FRAC_PI_2, u1 * u1 * FRAC_PI_2);
                let w = t0.cos() - t1.cos();
                for sb in 0..SUB {
                    let ph = (b as f64 + (sb as f64 + 0.5) / SUB as f64) / NP as f64 * TAU;
                    acc += pdf(dir(0.5 * (t0 + t1), ph)) * w * TAU / (NP * SUB) as f64;
                }
            }
            expected[a * NP + b] = acc * n_samples as f64;
            total += acc;
        }
    }
    // Samples that fail or land below the horizon are the missing mass.
    expected[NT * NP] = ((1.0 - total) * n_samples as f64).max(0.0);
    let mut pairs: Vec<(f64, f64)> = expected.iter().copied().zip(observed.iter().copied()).collect();
    pairs.sort_by(|a, b| a.0.partial_cmp(&b.0).unwrap());
    let (mut chi2, mut dof, mut pool_e, mut pool_o) = (0.0, 0usize, 0.0, 0.0);
    for (e, o) in pairs {
        if e < 5.0 {
            pool_e += e;
            pool_o += o;
            continue;
        }
        chi2 += (o - e) * (o - e) / e;
        dof += 1;
    }
    if pool_e > 0.0 {
        chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e.max(5.0);
        dof += 1;
    }
    let dof = dof.saturating_sub(1).max(1);
    let p = gamma_q(dof as f64 / 2.0, chi2 / 2.0);
    (p, format!("chi2 = {chi2:.1}, dof = {dof}, integral of pdf = {total:.4}"))
}
