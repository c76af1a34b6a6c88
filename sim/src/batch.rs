//! The simulated camera's pixels eight at a time (SIMD): the radiance of
//! every pixel whose surface is nothing, diffuse, or a microfacet surface
//! of one or two lobes, each Beckmann or a pile distribution (with any
//! Fresnel term the materials have), and every pixel's reading by the
//! sensor (noise and quantisation).
//!
//! The camera spends nearly all its time on a few transcendental functions
//! per pixel and light (the LED's `cos^m`, each lobe's `exp`, the projected
//! area's `erf` and `exp`) and on two normal draws per pixel. Evaluated one
//! pixel at a time (`camera::Lit::radiance`, which stays as the path for
//! every other surface and as the reference) it renders a 256 x 256 satin
//! frame in about 5 ms on two cores. Here the same formulas run on eight
//! pixels at once with polynomial `exp`, `ln` and `atan2` (`wide`) and
//! Abramowitz and Stegun's `erf` (7.1.26, absolute error below 1.5e-7,
//! sharing the `exp(-a^2)` the projected area needs anyway); the radiance
//! agrees with the reference to a few parts in a million (tested), far
//! below a DN.
//!
//! The pixels' constant data (position, view, shadow span, reflectance)
//! are kept as one array per quantity, so a batch is eight neighbours of a
//! row loaded side by side.

use std::sync::Arc;

use brdf::ndf::Sheen;
use glam::{Mat3, Vec3};
use wide::{CmpEq, CmpGe, CmpGt, CmpLe, f32x8};

use crate::reflect::{BatchLobe, BatchedFresnel, MAX_BATCHED_LOBES, Reflectance};

/// Pixels per batch.
pub(crate) const LANES: usize = 8;

/// [`PixelColumns`]'s kinds of Fresnel term.
const SCHLICK: f32 = 0.0;
const DIELECTRIC: f32 = 1.0;
const CONDUCTOR: f32 = 2.0;

/// One lobe's constants, per pixel (weight 0 where a pixel has fewer lobes).
#[derive(Default)]
struct LobeColumns {
    weight: Vec<f32>,
    /// Cosine and sine of the rotation into the lobe's frame.
    cos: Vec<f32>,
    sin: Vec<f32>,
    inv_ax2: Vec<f32>,
    inv_ay2: Vec<f32>,
    /// `ln(pi ax ay)`.
    ln_norm: Vec<f32>,
    ax: Vec<f32>,
    ay: Vec<f32>,
    /// 1 where the lobe is a pile distribution ([`BatchLobe::Sheen`]), 0
    /// where it is a Beckmann lobe; then its normalisation, amplitude,
    /// squared sharpness and table (an index into
    /// [`PixelColumns::sheens`]).
    sheen: Vec<f32>,
    sheen_norm: Vec<f32>,
    sheen_amplitude: Vec<f32>,
    sheen_s2: Vec<f32>,
    sheen_table: Vec<u32>,
}

/// What a pixel's radiance depends on, one column per quantity, for every
/// pixel of the sensor.
#[derive(Default)]
pub(crate) struct PixelColumns {
    /// Whether the eight pixels from this one on can be batched.
    batch_from: Vec<bool>,
    px: Vec<f32>,
    py: Vec<f32>,
    pz: Vec<f32>,
    ox: Vec<f32>,
    oy: Vec<f32>,
    oz: Vec<f32>,
    shadow_lo: Vec<f32>,
    shadow_hi: Vec<f32>,
    ambient: Vec<f32>,
    /// The sensor's response (vignetting, non-uniformity) and dark
    /// current (electrons per second) at the pixel.
    pub(crate) gain: Vec<f32>,
    pub(crate) dark_e_s: Vec<f32>,
    /// 1 where the surface reflects, 0 where nothing does.
    live: Vec<f32>,
    diffuse: Vec<f32>,
    ks: Vec<f32>,
    sigma_o: Vec<f32>,
    /// The Fresnel term: its kind ([`SCHLICK`], [`DIELECTRIC`] or
    /// [`CONDUCTOR`]), the index (dielectric, conductor's real part), the
    /// other parameter (the dielectric's scale, Schlick's `F0`, the
    /// conductor's extinction `k`) and its largest value.
    fresnel_kind: Vec<f32>,
    eta: Vec<f32>,
    f_param: Vec<f32>,
    f_max: Vec<f32>,
    lobes: [LobeColumns; MAX_BATCHED_LOBES],
    /// The distinct pile distributions of the pixels' lobes.
    sheens: Vec<Arc<Sheen>>,
}

/// One pixel's constants as [`PixelColumns::new`] takes them.
pub(crate) struct PixelIn<'a> {
    pub p: Vec3,
    pub o: Vec3,
    pub shadow: (f32, f32),
    pub ambient: f32,
    pub gain: f32,
    pub dark_e_s: f32,
    pub reflect: &'a Reflectance,
}

impl PixelColumns {
    pub(crate) fn new<'a>(pixels: impl ExactSizeIterator<Item = PixelIn<'a>>) -> Self {
        // Every pixel's lobe columns, whether it has the lobe or not.
        let mut c = PixelColumns::default();
        let mut batched = Vec::with_capacity(pixels.len());
        for px in pixels {
            let b = px.reflect.batched();
            batched.push(b.is_some());
            let b = b.unwrap_or_default();
            c.px.push(px.p.x);
            c.py.push(px.p.y);
            c.pz.push(px.p.z);
            c.ox.push(px.o.x);
            c.oy.push(px.o.y);
            c.oz.push(px.o.z);
            c.shadow_lo.push(px.shadow.0);
            c.shadow_hi.push(px.shadow.1);
            c.ambient.push(px.ambient);
            c.gain.push(px.gain);
            c.dark_e_s.push(px.dark_e_s);
            c.live.push(if b.black { 0.0 } else { 1.0 });
            c.diffuse.push(b.diffuse);
            c.ks.push(b.ks);
            c.sigma_o.push(b.sigma_o);
            let (kind, eta, f_param, f_max) = match b.fresnel {
                BatchedFresnel::Schlick { f0 } => (SCHLICK, 0.0, f0, f0.max(1.0)),
                BatchedFresnel::Dielectric { eta, scale } => (DIELECTRIC, eta, scale, scale),
                BatchedFresnel::Conductor { eta, k } => (CONDUCTOR, eta, k, 1.0),
            };
            c.fresnel_kind.push(kind);
            c.eta.push(eta);
            c.f_param.push(f_param);
            c.f_max.push(f_max);
            let tables: [u32; MAX_BATCHED_LOBES] = std::array::from_fn(|k| match b.lobes.get(k) {
                Some((_, BatchLobe::Sheen(sheen))) => c.sheen_index(sheen),
                _ => 0,
            });
            for (k, l) in c.lobes.iter_mut().enumerate() {
                // A lobe the pixel lacks weighs 0, and a lobe's constants of
                // the other kind only keep the arithmetic finite.
                let beckmann = ((1.0, 1.0), (0.0, 1.0), 0.0);
                let sheen = (0.0, 0.0, 0.0, 1.0);
                let (w, ((ax, ay), (sin, cos), ln_norm), (is_sheen, norm, amplitude, s2)) = match b.lobes.get(k) {
                    Some((w, BatchLobe::Beckmann(lobe))) => {
                        (*w, (lobe.alphas(), lobe.rotation(), lobe.ln_norm()), sheen)
                    }
                    Some((w, BatchLobe::Sheen(sh))) => {
                        (*w, beckmann, (1.0, sh.norm(), sh.amplitude, sh.sharpness * sh.sharpness))
                    }
                    None => (0.0, beckmann, sheen),
                };
                l.sheen.push(is_sheen);
                l.sheen_norm.push(norm);
                l.sheen_amplitude.push(amplitude);
                l.sheen_s2.push(s2);
                l.sheen_table.push(tables[k]);
                l.weight.push(w);
                l.cos.push(cos);
                l.sin.push(sin);
                l.inv_ax2.push(1.0 / (ax * ax));
                l.inv_ay2.push(1.0 / (ay * ay));
                l.ln_norm.push(ln_norm);
                l.ax.push(ax);
                l.ay.push(ay);
            }
        }
        c.batch_from =
            (0..batched.len()).map(|k| batched.get(k..k + LANES).is_some_and(|b| b.iter().all(|&x| x))).collect();
        c
    }

    /// The index of `sheen` in [`PixelColumns::sheens`], added if new
    /// (pixels of one material share one distribution).
    fn sheen_index(&mut self, sheen: &Arc<Sheen>) -> u32 {
        let found = self.sheens.iter().rposition(|s| Arc::ptr_eq(s, sheen) || **s == **sheen);
        let k = found.unwrap_or_else(|| {
            self.sheens.push(sheen.clone());
            self.sheens.len() - 1
        });
        k as u32
    }

    /// Whether the eight pixels from `k` on can be batched.
    #[inline]
    pub(crate) fn batched_from(&self, k: usize) -> bool {
        self.batch_from.get(k).copied().unwrap_or(false)
    }

    /// The radiance toward the camera at pixels `k..k + 8`
    /// ([`PixelColumns::batched_from`] must hold): ambient light plus each
    /// LED's light that the bar does not hide, from above the surface.
    /// `lights` are `(LED position, bar position, intensity)`; `to_sample`
    /// turns the rig frame into the surface's; the LEDs emit `cos^profile`
    /// about `axis`.
    pub(crate) fn radiance(
        &self,
        k: usize,
        lights: &[(Vec3, f32, f32)],
        to_sample: Mat3,
        axis: Vec3,
        profile: f32,
    ) -> [f32; LANES] {
        let at = |v: &[f32]| lanes(v, k);
        let zero = f32x8::ZERO;
        let mut radiance = at(&self.ambient);
        let live = at(&self.live).cmp_gt(zero);
        if !live.any() {
            return radiance.to_array();
        }
        let (px, py, pz) = (at(&self.px), at(&self.py), at(&self.pz));
        let (lo, hi) = (at(&self.shadow_lo), at(&self.shadow_hi));
        let surface = Surface::load(self, k);
        let [m0, m1, m2] = [to_sample.x_axis, to_sample.y_axis, to_sample.z_axis].map(|c| c.to_array());
        for &(led, bar_x, intensity) in lights {
            if !(intensity > 0.0) {
                continue;
            }
            let bar = f32x8::splat(bar_x);
            let shadowed = lo.cmp_le(bar) & bar.cmp_le(hi);
            let (dx, dy, dz) = (f32x8::splat(led.x) - px, f32x8::splat(led.y) - py, f32x8::splat(led.z) - pz);
            let r2 = dx * dx + dy * dy + dz * dz;
            let inv_r = f32x8::ONE / r2.sqrt();
            let (ix, iy, iz) = (dx * inv_r, dy * inv_r, dz * inv_r);
            // The direction in the surface's frame: `to_sample * i`.
            let lx = ix * m0[0] + iy * m1[0] + iz * m2[0];
            let ly = ix * m0[1] + iy * m1[1] + iz * m2[1];
            let lz = ix * m0[2] + iy * m1[2] + iz * m2[2];
            let cos_emit = -(ix * axis.x + iy * axis.y + iz * axis.z);
            let lit = live & !shadowed & iz.cmp_gt(zero) & lz.cmp_gt(zero) & cos_emit.cmp_gt(zero);
            if !lit.any() {
                continue;
            }
            let emit = (cos_emit.max(f32x8::splat(f32::MIN_POSITIVE)).ln() * profile).exp();
            let irradiance = emit * intensity * lz / r2;
            let f = surface.brdf([lx, ly, lz]);
            radiance += lit.blend(f * irradiance, zero);
        }
        radiance.to_array()
    }
}

/// What the sensor does to a pixel's radiance, fixed for a frame
/// (`camera` module doc for the model).
pub(crate) struct Exposure {
    /// Electrons per unit radiance at unit pixel gain: sensitivity times
    /// exposure time.
    pub e_per_radiance: f32,
    pub exposure_s: f32,
    pub full_well_e: f32,
    pub read_sd_e: f32,
    /// Analogue gain over electrons per DN.
    pub dn_per_e: f32,
    pub black_level_dn: f32,
    pub max_dn: f32,
}

/// One row's reading: `out[j]` for the pixel of radiance `signal[j]`,
/// response `gain[j]` and dark current `dark_e_s[j]`, eight pixels at a
/// time. Noise comes from the row's stream `seed` (`noise::word`): word `j`
/// gives pixel `j` its two normals (Box and Muller's transform of the
/// word's two 24-bit halves) for the Gaussian shot noise and the read
/// noise; a pixel of at most `POISSON_MAX_MEAN` electrons draws its shot
/// noise from the Poisson distribution instead, by a uniform of the
/// stream `seed ^ POISSON_STREAM`.
pub(crate) fn expose_row(x: &Exposure, seed: u64, signal: &[f32], gain: &[f32], dark_e_s: &[f32], out: &mut [u16]) {
    use crate::noise::{self, POISSON_MAX_MEAN, POISSON_STREAM};
    let n = out.len();
    let zero = f32x8::ZERO;
    let poisson_max = f32x8::splat(POISSON_MAX_MEAN as f32);
    let bits = 1.0 / (1u32 << 24) as f32;
    let mut j = 0;
    while j < n {
        let m = LANES.min(n - j);
        let padded = |v: &[f32]| {
            let mut a = [0.0; LANES];
            a[..m].copy_from_slice(&v[j..j + m]);
            f32x8::new(a)
        };
        // A radiance that is not a number gives no signal.
        let electrons = padded(signal) * x.e_per_radiance * padded(gain);
        let mean = electrons.is_nan().blend(zero, electrons).max(zero) + padded(dark_e_s) * x.exposure_s;
        let (mut u1, mut u2) = ([1.0f32; LANES], [0.0f32; LANES]);
        for l in 0..m {
            let w = noise::word(seed, (j + l) as u64);
            // `u1` in (0, 1], so its logarithm is finite.
            u1[l] = ((w >> 40) + 1) as f32 * bits;
            u2[l] = ((w >> 16) & 0xff_ffff) as f32 * bits;
        }
        let radius = (f32x8::new(u1).ln() * -2.0).max(zero).sqrt();
        let (z_read, z_shot) = (f32x8::new(u2) * std::f32::consts::TAU).sin_cos();
        let (z_shot, z_read) = (radius * z_shot, radius * z_read);
        let shot = (mean + mean.sqrt() * z_shot).min(f32x8::splat(x.full_well_e));
        let dn = quantise((shot + z_read * x.read_sd_e) * x.dn_per_e + x.black_level_dn, x.max_dn);
        for l in 0..m {
            out[j + l] = dn[l] as u16;
        }
        let dim = mean.cmp_le(poisson_max);
        if dim.any() {
            // Shot noise by the Poisson distribution for the dim pixels.
            let dim = dim.move_mask() & ((1 << m) - 1);
            let shot = poisson_lanes(mean.to_array(), dim, |l| noise::word(seed ^ POISSON_STREAM, (j + l) as u64));
            let z_read = z_read.to_array();
            for l in (0..m).filter(|l| dim & (1 << l) != 0) {
                let e = shot[l].min(x.full_well_e) + z_read[l] * x.read_sd_e;
                out[j + l] = noise::quantise(e * x.dn_per_e + x.black_level_dn, x.max_dn);
            }
        }
        j += LANES;
    }
}

/// Poisson draws (`noise::poisson`) for the lanes set in `lanes` (a bit
/// per lane), of means `mean`, from the words `word(lane)`; 0 elsewhere.
/// The fractions' `exp(-f)` are computed eight at a time.
pub(crate) fn poisson_lanes(mean: [f32; LANES], lanes: i32, word: impl Fn(usize) -> u64) -> [f32; LANES] {
    let mean = mean.map(crate::noise::poisson_mean);
    let whole = mean.map(|m| m as u32 as f32);
    let exp_neg_frac = (f32x8::new(whole) - f32x8::new(mean)).exp().to_array();
    let mut out = [0.0; LANES];
    for l in (0..LANES).filter(|l| lanes & (1 << l) != 0) {
        out[l] = crate::noise::poisson(mean[l], exp_neg_frac[l], word(l));
    }
    out
}

/// [`crate::noise::quantise`] of eight values at once.
#[inline]
fn quantise(v: f32x8, max_dn: f32) -> [i32; LANES] {
    // A NaN reads 0, as in `noise::quantise`.
    let c = v.is_nan().blend(f32x8::ZERO, v).max(f32x8::ZERO).min(f32x8::splat(max_dn));
    let t = c.trunc_int().round_float();
    let up = (c - t).cmp_ge(f32x8::splat(0.5));
    (t + up.blend(f32x8::ONE, f32x8::ZERO)).trunc_int().to_array()
}

/// Eight pixels' reflectance constants: those every light needs, loaded
/// once per batch; the lobes' are read from the columns as they are used.
struct Surface<'a> {
    columns: &'a PixelColumns,
    k: usize,
    diffuse: f32x8,
    ks: f32x8,
    sigma_o: f32x8,
    eta: f32x8,
    f_param: f32x8,
    f_max: f32x8,
    /// Lanes of each kind of Fresnel term.
    dielectric: f32x8,
    conductor: f32x8,
    o: [f32x8; 3],
    /// How many lobes any of the eight pixels has (lobes are filled in order).
    n_lobes: usize,
    specular: bool,
    /// Whether any lane with a specular term has each kind.
    any_dielectric: bool,
    any_conductor: bool,
    any_schlick: bool,
}

/// `1 / (2 sqrt(pi))`.
const INV_TWO_SQRT_PI: f32 = 0.282_094_8;

/// Columns `v[k..k + 8]` as a vector.
#[inline]
fn lanes(v: &[f32], k: usize) -> f32x8 {
    let mut a = [0.0; LANES];
    a.copy_from_slice(&v[k..k + LANES]);
    f32x8::new(a)
}

impl<'a> Surface<'a> {
    fn load(c: &'a PixelColumns, k: usize) -> Self {
        let zero = f32x8::ZERO;
        let ks = lanes(&c.ks, k);
        let kind = lanes(&c.fresnel_kind, k);
        let (dielectric, conductor) = (kind.cmp_eq(f32x8::splat(DIELECTRIC)), kind.cmp_eq(f32x8::splat(CONDUCTOR)));
        let has_specular = ks.cmp_gt(zero);
        Surface {
            columns: c,
            k,
            diffuse: lanes(&c.diffuse, k),
            ks,
            sigma_o: lanes(&c.sigma_o, k),
            eta: lanes(&c.eta, k),
            f_param: lanes(&c.f_param, k),
            f_max: lanes(&c.f_max, k),
            o: [lanes(&c.ox, k), lanes(&c.oy, k), lanes(&c.oz, k)],
            n_lobes: c.lobes.iter().take_while(|l| lanes(&l.weight, k).cmp_gt(zero).any()).count(),
            specular: has_specular.any(),
            any_dielectric: (has_specular & dielectric).any(),
            any_conductor: (has_specular & conductor).any(),
            any_schlick: (has_specular & !dielectric & !conductor).any(),
            dielectric,
            conductor,
        }
    }

    /// `kd / pi + ks F D / (4 sigma(i) sigma(o))` for light from `i` (the
    /// surface's frame, above it), as `brdf::model::Microfacet::eval` in the
    /// pixel's channel; 0 where that is not finite and positive.
    #[inline]
    fn brdf(&self, [ix, iy, iz]: [f32x8; 3]) -> f32x8 {
        let zero = f32x8::ZERO;
        let one = f32x8::ONE;
        if !self.specular {
            return self.diffuse;
        }
        let [ox, oy, oz] = self.o;
        let (hx, hy, hz) = (ix + ox, iy + oy, iz + oz);
        let len = (hx * hx + hy * hy + hz * hz).sqrt();
        let has_h = len.cmp_ge(f32x8::splat(brdf::frame::HALF_VECTOR_MIN_LEN));
        let inv_len = one / len;
        let (hx, hy, hz) = (hx * inv_len, hy * inv_len, hz * inv_len);
        let ln_hz = hz.ln();
        let inv_hz2 = one / (hz * hz);
        let k = self.k;
        let lobes = &self.columns.lobes[..self.n_lobes];
        // D: a Beckmann lobe in its own frame and in the log domain; a pile
        // distribution `N (1 + A exp(-cot^2 / s^2))` (`brdf::ndf::Sheen`).
        let mut d = zero;
        for l in lobes {
            let sheen = lanes(&l.sheen, k).cmp_gt(zero);
            let mut dl = zero;
            if !sheen.all() {
                let (cos, sin) = (lanes(&l.cos, k), lanes(&l.sin, k));
                let (ux, uy) = (cos * hx - sin * hy, sin * hx + cos * hy);
                let e = (ux * ux * lanes(&l.inv_ax2, k) + uy * uy * lanes(&l.inv_ay2, k)) * inv_hz2;
                dl = (-e - ln_hz * 4.0 - lanes(&l.ln_norm, k)).exp();
            }
            if sheen.any() {
                let norm = lanes(&l.sheen_norm, k);
                let s2 = hx * hx + hy * hy;
                let cot2 = hz * hz / s2;
                // Beyond -80 the exponential is below 2e-35 and adds nothing
                // to 1; the bound keeps the polynomial `exp` in its range.
                let x = (-cot2 / lanes(&l.sheen_s2, k)).max(f32x8::splat(-80.0));
                let ds = norm * (one + lanes(&l.sheen_amplitude, k) * x.exp());
                dl = sheen.blend(s2.cmp_gt(zero).blend(ds, norm), dl);
            }
            d += lanes(&l.weight, k) * dl;
        }
        // Far from every lobe the specular term is at most `F_max D / (4 iz
        // sigma(o))` (sigma(i) >= iz); below 1e-7 of the diffuse term in
        // every lane it changes no pixel, and the rest is skipped.
        let bound = self.ks * self.f_max * d / (iz * self.sigma_o * 4.0);
        if (bound.cmp_le(self.diffuse * 1e-7) | !has_h).all() {
            return (self.diffuse.is_finite() & self.diffuse.cmp_gt(zero)).blend(self.diffuse, zero);
        }
        let mut sigma_i = zero;
        for l in lobes {
            let sheen = lanes(&l.sheen, k).cmp_gt(zero);
            if sheen.any() {
                sigma_i += lanes(&l.weight, k) * self.sheen_sigma(l, sheen, [ix, iy, iz]);
                if sheen.all() {
                    continue;
                }
            }
            let (cos, sin) = (lanes(&l.cos, k), lanes(&l.sin, k));
            // The projected area sigma(i) = iz (1 + erf(a)) / 2 + r exp(-a^2) / (2 sqrt(pi)).
            let (vx, vy) = (cos * ix - sin * iy, sin * ix + cos * iy);
            let (sx, sy) = (vx * lanes(&l.ax, k), vy * lanes(&l.ay, k));
            let r = (sx * sx + sy * sy).sqrt();
            let a = iz / r;
            let ea = (-(a * a)).exp();
            // Abramowitz and Stegun 7.1.26: erf(a) = 1 - t (a1 + t (a2 + ...)) exp(-a^2), t = 1 / (1 + p a).
            let t = one / (a * 0.327_591_1 + one);
            let poly = t
                * (f32x8::splat(0.254_829_6)
                    + t * (f32x8::splat(-0.284_496_74)
                        + t * (f32x8::splat(1.421_413_8)
                            + t * (f32x8::splat(-1.453_152) + t * f32x8::splat(1.061_405_4)))));
            let erf = one - poly * ea;
            let sk = (iz * 0.5 * (one + erf) + r * ea * INV_TWO_SQRT_PI).max(iz);
            // r = 0 (a = inf): the area is iz, as the formula's limit.
            let sk = r.cmp_gt(zero).blend(sk, iz);
            sigma_i += lanes(&l.weight, k) * sheen.blend(zero, sk);
        }
        let sigma_i = sigma_i.max(iz);
        let cos_d = (ix * hx + iy * hy + iz * hz).max(zero).min(one);
        let fresnel = {
            let mut f = zero;
            if self.any_schlick {
                let m = one - cos_d;
                let m2 = m * m;
                f = self.f_param + (one - self.f_param) * m2 * m2 * m;
            }
            if self.any_dielectric {
                f = self.dielectric.blend(self.dielectric_fresnel(cos_d), f);
            }
            if self.any_conductor {
                f = self.conductor.blend(self.conductor_fresnel(cos_d), f);
            }
            f
        };
        let specular = fresnel * d / (sigma_i * self.sigma_o * 4.0);
        let has_specular = has_h & d.cmp_gt(zero) & self.ks.cmp_gt(zero);
        let f = self.diffuse + self.ks * has_specular.blend(specular, zero);
        (f.is_finite() & f.cmp_gt(zero)).blend(f, zero)
    }
}

impl Surface<'_> {
    /// A pile distribution's projected area `sigma(i)` in the lanes set in
    /// `sheen` (0 elsewhere): `theta_i` eight at a time, then each lane's
    /// table read one lane at a time (a gather) by
    /// `brdf::ndf::Sheen::projected_area_at`.
    fn sheen_sigma(&self, l: &LobeColumns, sheen: f32x8, [ix, iy, iz]: [f32x8; 3]) -> f32x8 {
        let theta = (ix * ix + iy * iy).sqrt().atan2(iz).to_array();
        let (iz, lanes_set) = (iz.to_array(), sheen.move_mask());
        let mut out = [0.0f32; LANES];
        for (j, o) in out.iter_mut().enumerate().filter(|(j, _)| lanes_set & (1 << j) != 0) {
            *o = self.columns.sheens[l.sheen_table[self.k + j] as usize].projected_area_at(theta[j], iz[j]);
        }
        f32x8::new(out)
    }

    /// `brdf::fresnel::dielectric` (index `eta`) times the lanes' scale.
    #[inline]
    fn dielectric_fresnel(&self, cos_d: f32x8) -> f32x8 {
        let (zero, one) = (f32x8::ZERO, f32x8::ONE);
        let eta = self.eta;
        let sin2_t = (one - cos_d * cos_d) / (eta * eta);
        let cos_t = (one - sin2_t).max(zero).sqrt();
        let rs = (cos_d - eta * cos_t) / (cos_d + eta * cos_t);
        let rp = (eta * cos_d - cos_t) / (eta * cos_d + cos_t);
        let f = ((rs * rs + rp * rp) * 0.5).max(zero).min(one);
        sin2_t.cmp_ge(one).blend(one, f) * self.f_param
    }

    /// `brdf::fresnel::conductor` (index `eta + i k`, `k` in `f_param`):
    /// `cos_t` the principal square root of `1 - sin^2_i / n^2`, and each
    /// polarisation's reflectance `|a - b|^2 / |a + b|^2`.
    #[inline]
    fn conductor_fresnel(&self, ci: f32x8) -> f32x8 {
        let (zero, one) = (f32x8::ZERO, f32x8::ONE);
        let (eta, k) = (self.eta, self.f_param);
        let sin2_i = one - ci * ci;
        // sin^2_t = sin^2_i / n^2, n^2 = (eta^2 - k^2) + i 2 eta k.
        let (n2r, n2i) = (eta * eta - k * k, eta * k * 2.0);
        let n2n = n2r * n2r + n2i * n2i;
        let (zr, zi) = (one - sin2_i * n2r / n2n, sin2_i * n2i / n2n);
        // The principal square root of z = 1 - sin^2_t.
        let norm = (zr * zr + zi * zi).sqrt();
        let t1 = ((norm + zr.abs()) * 0.5).sqrt();
        let t2 = zi * 0.5 / t1;
        let right = zr.cmp_ge(zero);
        let nonzero = norm.cmp_gt(zero);
        let cr = nonzero.blend(right.blend(t1, t2.abs()), zero);
        let cim = nonzero.blend(right.blend(t2, t1.copysign(zi)), zero);
        // Parallel: n ci against cos_t; perpendicular: ci against n cos_t.
        let (ar, ai) = (eta * ci, k * ci);
        let r_parl =
            ((ar - cr) * (ar - cr) + (ai - cim) * (ai - cim)) / ((ar + cr) * (ar + cr) + (ai + cim) * (ai + cim));
        let (br, bi) = (eta * cr - k * cim, eta * cim + k * cr);
        let r_perp = ((ci - br) * (ci - br) + bi * bi) / ((ci + br) * (ci + br) + bi * bi);
        let f = (r_parl + r_perp) * 0.5;
        f.is_finite().blend(f.max(zero).min(one), one)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The batch's rounding is the sensor's, value for value: half-way
    /// cases, the clip at both ends, values that are not numbers.
    #[test]
    fn batched_quantising_is_the_sensors() {
        let mut values: Vec<f32> = (0..200_000).map(|k| k as f32 * 0.0205 - 5.0).collect();
        values.extend([0.5, 1.5, 2.5, 0.49999997, 4094.5, 4095.0, 4096.0, 1e30, -1e30]);
        values.extend([f32::NAN, f32::INFINITY, f32::NEG_INFINITY]);
        for chunk in values.chunks(LANES) {
            let mut a = [0.0; LANES];
            a[..chunk.len()].copy_from_slice(chunk);
            let got = quantise(f32x8::new(a), 4095.0);
            for (l, &v) in chunk.iter().enumerate() {
                assert_eq!(got[l], crate::noise::quantise(v, 4095.0) as i32, "{v}");
            }
        }
    }
}
