//! The simulated sensor's random numbers and quantisation.
//!
//! Every pixel's noise comes from a counter-based stream: the 64-bit word
//! for counter `j` of stream `seed` is SplitMix64's output function
//! (Steele, Lea and Flood 2014, the mixing constants of Stafford's
//! "Mix13") applied to `seed + j * golden`. Pixels thus draw in any order
//! and in parallel, and a pixel's noise depends on the shot and on where
//! it is, never on what was rendered before.
//!
//! Photon shot noise at or below [`POISSON_MAX_MEAN`] electrons is a
//! Poisson draw ([`poisson`]) from tables made once.

use std::sync::LazyLock;

/// The stream the Poisson draws' uniforms come from, beside the one for
/// normal pairs (xored into the row's seed).
pub const POISSON_STREAM: u64 = 0x5be0_cd19_137e_2179;

/// Word `counter` of stream `seed`.
#[inline]
pub fn word(seed: u64, counter: u64) -> u64 {
    let mut z = seed.wrapping_add(counter.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The DN a sensor reads for `v` (DN before rounding): rounded half away
/// from zero and clipped to `0..=max_dn`; a non-finite value reads 0.
#[inline]
pub fn quantise(v: f32, max_dn: f32) -> u16 {
    // `max` first: a NaN becomes 0.
    let c = v.max(0.0).min(max_dn);
    // `c as i32` truncates (NaN gives 0) in one instruction, for the codes
    // of any sensor (below 2^31); `c - t` is exact below 2^23.
    let t = c as i32;
    (t + i32::from(c - t as f32 >= 0.5)) as u16
}

/// The largest mean [`poisson`] serves: above it the camera draws shot
/// noise as a Gaussian (`camera` module doc).
pub const POISSON_MAX_MEAN: f64 = 30.0;

/// Outcomes tabulated per whole mean: beyond them the probability is below
/// 1e-24 even at the largest mean.
const OUTCOMES: usize = 112;

/// Buckets of each guide table: at most a step or two of search per draw.
const GUIDE: usize = 128;

/// For each whole mean `m` up to [`POISSON_MAX_MEAN`], the cumulative
/// distribution of the Poisson distribution of mean `m` (its last entry 1)
/// and a guide table: `guide[b]` is the first outcome whose cumulative
/// probability exceeds `b / GUIDE`.
struct WholeMeans {
    cdf: Vec<[f64; OUTCOMES]>,
    guide: Vec<[u8; GUIDE]>,
}

static WHOLE_MEANS: LazyLock<WholeMeans> = LazyLock::new(|| {
    let n = POISSON_MAX_MEAN as usize + 1;
    let mut cdf = vec![[1.0; OUTCOMES]; n];
    let mut guide = vec![[0u8; GUIDE]; n];
    for m in 1..n {
        let mean = m as f64;
        let mut p = (-mean).exp();
        let mut c = p;
        for k in 0..OUTCOMES - 1 {
            cdf[m][k] = c;
            p *= mean / (k + 1) as f64;
            c += p;
        }
        let mut k = 0;
        for (b, g) in guide[m].iter_mut().enumerate() {
            while cdf[m][k] <= b as f64 / GUIDE as f64 {
                k += 1;
            }
            *g = k as u8;
        }
    }
    WholeMeans { cdf, guide }
});

/// `mean` as [`poisson`] takes it: clamped into `0..=POISSON_MAX_MEAN`, 0
/// for a mean that is not a number.
#[inline]
pub fn poisson_mean(mean: f32) -> f32 {
    if mean.is_nan() { 0.0 } else { mean.clamp(0.0, POISSON_MAX_MEAN as f32) }
}

/// A Poisson draw of mean `mean` (through [`poisson_mean`]) from the
/// 64-bit random `word`, given `exp_neg_frac = exp(-(mean - floor(mean)))`
/// (which the camera computes eight pixels at a time).
///
/// A Poisson variable of mean `m + f` is the sum of independent ones of
/// means `m` and `f`. The whole part `m` is drawn by inversion of the
/// word's high 32 bits through its tabulated distribution ([`WholeMeans`],
/// the guide table starting the search a step or two from the answer); the
/// fraction `f` by inversion of the low 32 bits from 0 up (0 with
/// probability `exp(-f)`, above 0.37). Exact but for the uniforms' 32-bit
/// resolution (outcomes of probability below 2.3e-10 are not drawn) and
/// `exp_neg_frac`'s rounding.
#[inline]
pub fn poisson(mean: f32, exp_neg_frac: f32, word: u64) -> f32 {
    let whole = mean as usize;
    let frac = (mean - whole as f32) as f64;
    let scale = 1.0 / (1u64 << 32) as f64;
    let mut draw = 0;
    if whole > 0 {
        let t = &*WHOLE_MEANS;
        let u = (word >> 32) as f64 * scale;
        let mut k = t.guide[whole][(u * GUIDE as f64) as usize] as usize;
        while t.cdf[whole][k] <= u {
            k += 1;
        }
        draw = k;
    }
    if frac > 0.0 {
        let u = (word & 0xffff_ffff) as f64 * scale;
        let mut p = exp_neg_frac as f64;
        let mut c = p;
        let mut k = 0;
        while c <= u && k < 16 {
            k += 1;
            p *= frac / k as f64;
            c += p;
        }
        draw += k;
    }
    draw as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rounding half away from zero, clipping, and nothing odd at the
    /// edges of a DN or for a value that is not a number.
    #[test]
    fn quantising_rounds_half_away_from_zero_and_clips() {
        for (v, dn) in
            [(0.0, 0), (0.49999997, 0), (0.5, 1), (1.4999999, 1), (2.5, 3), (-3.0, 0), (4094.6, 4095), (1e9, 4095)]
        {
            assert_eq!(quantise(v, 4095.0), dn, "{v}");
        }
        assert_eq!(quantise(f32::NAN, 4095.0), 0);
        for k in 0..100_000u32 {
            let v = k as f32 * 0.040_96;
            assert_eq!(quantise(v, 4095.0), v.round().clamp(0.0, 4095.0) as u16, "{v}");
        }
    }

    /// The chi-square statistic's value that a correct sampler exceeds with
    /// probability 1e-6, for `dof` degrees of freedom (Wilson and Hilferty's
    /// cube-root normal approximation; z = 4.753 is the normal's 1 - 1e-6
    /// quantile).
    fn chi2_limit(dof: f64) -> f64 {
        let c = 2.0 / (9.0 * dof);
        dof * (1.0 - c + 4.753 * c.sqrt()).powi(3)
    }

    /// Pearson's test of the draws against the Poisson probabilities, over
    /// means across the range the camera uses (tiny, below one, small,
    /// either side of a whole number, the top), with the tail beyond the
    /// last well-filled outcome as one bin.
    #[test]
    fn draws_follow_the_poisson_distribution() {
        let n = 400_000usize;
        for (seed, mean) in [1e-6f32, 0.04, 0.7, 1.0, 3.0, 7.5, 11.999, 12.0, 19.3, 29.99, 30.0].into_iter().enumerate()
        {
            let stream = word(seed as u64 + 100, 0);
            let mut counts = vec![0usize; 200];
            // Through the camera's path: lanes of this mean beside lanes of
            // others, as a row's pixels are, and lanes left out.
            let others = [0.3, 29.0, 5.5, f32::NAN, 1e3, 14.0, 0.0];
            for j in (0..n).step_by(2) {
                let means = [mean, others[j / 2 % 7], mean, 2.0, 8.0, 1e-3, 17.0, 25.0];
                let draws = crate::batch::poisson_lanes(means, 0b1111_0111, |l| word(stream, (j * 8 + l) as u64));
                assert_eq!(draws[3], 0.0, "a lane left out draws nothing");
                for k in [draws[0], draws[2]] {
                    assert!(k >= 0.0 && k.fract() == 0.0, "mean {mean}: draw {k}");
                    counts[(k as usize).min(199)] += 1;
                }
            }
            // Probabilities by the recurrence from k = 0, in f64.
            let mean = mean as f64;
            let mut p = vec![(-mean).exp()];
            for k in 1..200 {
                p.push(p[k - 1] * mean / k as f64);
            }
            let mut chi2 = 0.0;
            let mut bins = 0;
            let (mut tail_count, mut tail_p) = (0.0, 0.0);
            for k in 0..200 {
                let expected = p[k] * n as f64;
                if expected >= 20.0 {
                    chi2 += (counts[k] as f64 - expected).powi(2) / expected;
                    bins += 1;
                } else {
                    tail_count += counts[k] as f64;
                    tail_p += p[k];
                }
            }
            let tail_expected = tail_p * n as f64;
            if tail_expected >= 20.0 {
                chi2 += (tail_count - tail_expected).powi(2) / tail_expected;
                bins += 1;
            } else {
                assert!(
                    tail_count <= 20.0 + 10.0 * tail_expected,
                    "mean {mean}: {tail_count} draws in a tail of {tail_expected}"
                );
            }
            if bins >= 2 {
                let dof = (bins - 1) as f64;
                assert!(chi2 < chi2_limit(dof), "mean {mean}: chi-square {chi2:.1} over {dof} degrees of freedom");
            } else {
                // A tiny mean: all but a handful of draws are 0.
                assert!(counts[0] as f64 >= n as f64 * (1.0 - 2.0 * mean) - 10.0, "mean {mean}: {} zeros", counts[0]);
            }
        }
    }
}
