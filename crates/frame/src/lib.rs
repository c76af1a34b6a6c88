//! Camera frames as the rest of the system sees them: raw sensor values
//! (`u16`, right-aligned to `bit_depth`) in a mono, Bayer or RGB layout,
//! with the metadata that ties a frame to an LED: monotonic exposure
//! timestamps, sequence number, exposure, gain and error flags.
//! Demosaicing to linear RGB happens here, once, for every consumer.

use serde::{Deserialize, Serialize};

/// Nanoseconds of `CLOCK_MONOTONIC` (the time base of V4L2 buffers and of
/// every event the host records; conversions live in `rig::clock`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(transparent)]
pub struct MonoNs(pub u64);

/// The 2x2 colour-filter tile of a Bayer sensor, named by its first row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BayerPattern {
    Rggb,
    Bggr,
    Grbg,
    Gbrg,
}

impl BayerPattern {
    /// Colour channel (0 R, 1 G, 2 B) of pixel `(x, y)`.
    #[inline]
    pub fn channel(self, x: u32, y: u32) -> usize {
        let (ox, oy) = ((x & 1) as usize, (y & 1) as usize);
        let tile: [[usize; 2]; 2] = match self {
            BayerPattern::Rggb => [[0, 1], [1, 2]],
            BayerPattern::Bggr => [[2, 1], [1, 0]],
            BayerPattern::Grbg => [[1, 0], [2, 1]],
            BayerPattern::Gbrg => [[1, 2], [0, 1]],
        };
        tile[oy][ox]
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Layout {
    Mono,
    Bayer {
        pattern: BayerPattern,
    },
    /// Interleaved RGB.
    Rgb,
}

impl Layout {
    pub fn samples_per_pixel(self) -> usize {
        match self {
            Layout::Rgb => 3,
            _ => 1,
        }
    }

    /// How the sensor's pixel noise reaches a weighted sum of channels read
    /// at `(x, y)` of a `width` x `height` frame: `sum_c weights[c] * s_c`,
    /// where `s` is [`RgbImage::sample`] of [`Frame::to_rgb`]. That sum is
    /// linear in the raw samples, `sum_j b_j raw_j`; this returns, for each
    /// colour of raw sample, `sum b_j^2` over the raw samples of that
    /// colour, so that independent raw noise of variance `v_c` per colour
    /// gives the sum the variance `sum_c out[c] v_c` (a mono sensor's
    /// samples count as green). `None` where
    /// `RgbImage::sample` has no value.
    ///
    /// For Bayer data this is well below one pixel's variance: the
    /// bilinear sample averages four demosaiced pixels, and each of those
    /// averages up to four sensor pixels of a missing colour.
    pub fn sample_footprint(self, width: u32, height: u32, x: f32, y: f32, weights: [f32; 3]) -> Option<[f32; 3]> {
        let mut out = [0.0f32; 3];
        for t in self.sample_weights(width, height, x, y, weights)? {
            out[t.colour] += t.b * t.b;
        }
        Some(out)
    }

    /// The coefficients `b_j` of that weighted sum (see
    /// [`Layout::sample_footprint`]): every raw sample it reads, with its
    /// pixel, its colour and `b_j`, non-zero only. Where on the sample
    /// those pixels look is what the point measures (its footprint).
    pub fn sample_weights(self, width: u32, height: u32, x: f32, y: f32, weights: [f32; 3]) -> Option<Vec<RawTap>> {
        let (fx, fy) = (x - 0.5, y - 0.5);
        if !(fx >= 0.0 && fy >= 0.0) {
            return None;
        }
        let (x0, y0) = (fx as i64, fy as i64);
        let (w, h) = (width as i64, height as i64);
        if x0 + 1 >= w || y0 + 1 >= h {
            return None;
        }
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let taps = [
            (x0, y0, (1.0 - tx) * (1.0 - ty)),
            (x0 + 1, y0, tx * (1.0 - ty)),
            (x0, y0 + 1, (1.0 - tx) * ty),
            (x0 + 1, y0 + 1, tx * ty),
        ];
        let tap = |x: i64, y: i64, colour: usize, b: f32| RawTap { x: x as u32, y: y as u32, colour, b };
        let mut out = Vec::new();
        match self {
            Layout::Mono => {
                // Every channel is the raw sample itself; a mono sensor's
                // one colour is counted in the green slot (as
                // `fit::calibrate::dark_statistics` does).
                let sum: f32 = weights.iter().sum();
                out.extend(taps.iter().map(|t| tap(t.0, t.1, 1, t.2 * sum)));
            }
            Layout::Rgb => {
                // Three raw samples per pixel, each reaching one channel.
                for t in &taps {
                    out.extend((0..3).map(|c| tap(t.0, t.1, c, weights[c] * t.2)));
                }
            }
            Layout::Bayer { pattern } => {
                // Raw pixels within one pixel of the taps: a 4 x 4 window.
                let mut coef = [[0.0f32; 4]; 4];
                for &(tx, ty, wt) in &taps {
                    let own = pattern.channel(tx as u32, ty as u32);
                    for (c, &wc) in weights.iter().enumerate() {
                        if c == own {
                            coef[(ty - y0 + 1) as usize][(tx - x0 + 1) as usize] += wt * wc;
                            continue;
                        }
                        // The demosaic's mean of that colour's neighbours.
                        let near = |dx: i64, dy: i64| {
                            let (xx, yy) = (tx + dx, ty + dy);
                            xx >= 0 && yy >= 0 && xx < w && yy < h && pattern.channel(xx as u32, yy as u32) == c
                        };
                        let n = (-1..=1)
                            .flat_map(|dy| (-1..=1).map(move |dx| (dx, dy)))
                            .filter(|&(dx, dy)| near(dx, dy))
                            .count();
                        if n == 0 {
                            continue;
                        }
                        for dy in -1..=1 {
                            for dx in -1..=1 {
                                if near(dx, dy) {
                                    coef[(ty + dy - y0 + 1) as usize][(tx + dx - x0 + 1) as usize] +=
                                        wt * wc / n as f32;
                                }
                            }
                        }
                    }
                }
                for (r, row) in coef.iter().enumerate() {
                    for (k, &b) in row.iter().enumerate() {
                        let (xx, yy) = (x0 - 1 + k as i64, y0 - 1 + r as i64);
                        if xx >= 0 && yy >= 0 && xx < w && yy < h {
                            out.push(tap(xx, yy, pattern.channel(xx as u32, yy as u32), b));
                        }
                    }
                }
            }
        }
        out.retain(|t| t.b != 0.0);
        Some(out)
    }
}

/// One raw sample's share of a value read from a frame
/// ([`Layout::sample_weights`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RawTap {
    /// The sensor pixel.
    pub x: u32,
    pub y: u32,
    /// The colour of the raw sample (a mono sensor's is green, 1).
    pub colour: usize,
    /// Its coefficient in the value.
    pub b: f32,
}

/// Frame flags.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameFlags {
    /// The driver marked the buffer as damaged (V4L2_BUF_FLAG_ERROR).
    pub error: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameMeta {
    /// Driver sequence number (gaps mean dropped frames).
    pub sequence: u64,
    /// Start and end of the exposure.
    pub exposure_start: MonoNs,
    pub exposure_end: MonoNs,
    pub exposure_us: u32,
    pub gain: f32,
    pub flags: FrameFlags,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub width: u32,
    pub height: u32,
    pub layout: Layout,
    /// Significant bits per sample (values are right-aligned).
    pub bit_depth: u8,
    pub data: Vec<u16>,
    pub meta: FrameMeta,
}

impl Frame {
    /// Largest value the sensor can report; a sample at it is clipped.
    pub fn max_value(&self) -> u16 {
        ((1u32 << self.bit_depth.min(16)) - 1) as u16
    }

    /// Pixels in the window `x0..x1` x `y0..y1` (clamped to the frame)
    /// with any sample at [`Frame::max_value`]: what a capture looks at to
    /// decide whether a shorter exposure is needed.
    pub fn clipped_in(&self, x0: u32, y0: u32, x1: u32, y1: u32) -> u32 {
        let max = self.max_value();
        let per = self.layout.samples_per_pixel();
        let (x1, y1) = (x1.min(self.width), y1.min(self.height));
        let mut n = 0;
        for y in y0.min(y1)..y1 {
            let row = (y * self.width) as usize * per;
            let px = &self.data[row + x0.min(x1) as usize * per..row + x1 as usize * per];
            n += px.chunks_exact(per).filter(|p| p.iter().any(|&v| v >= max)).count() as u32;
        }
        n
    }

    /// Linear RGB planes (bilinear demosaicing for Bayer data; replicated
    /// for mono) and a per-pixel clipped flag (set if the pixel or any
    /// sensor pixel that contributed to it reached [`Frame::max_value`]).
    pub fn to_rgb(&self) -> RgbImage {
        let (w, h) = (self.width as usize, self.height as usize);
        let max = self.max_value();
        let mut img = RgbImage {
            width: self.width,
            height: self.height,
            r: vec![0.0; w * h],
            g: vec![0.0; w * h],
            b: vec![0.0; w * h],
            clipped: vec![false; w * h],
        };
        match self.layout {
            Layout::Mono => {
                for i in 0..w * h {
                    let v = self.data[i] as f32;
                    img.r[i] = v;
                    img.g[i] = v;
                    img.b[i] = v;
                    img.clipped[i] = self.data[i] >= max;
                }
            }
            Layout::Rgb => {
                for i in 0..w * h {
                    img.r[i] = self.data[3 * i] as f32;
                    img.g[i] = self.data[3 * i + 1] as f32;
                    img.b[i] = self.data[3 * i + 2] as f32;
                    img.clipped[i] = self.data[3 * i..3 * i + 3].iter().any(|&v| v >= max);
                }
            }
            Layout::Bayer { pattern } => demosaic_bilinear(self, pattern, &mut img),
        }
        img
    }
}

/// Bilinear demosaicing: each missing channel is the mean of the nearest
/// sensor pixels of that colour in the 3x3 neighbourhood. Simple and
/// linear (it never invents contrast), which is what radiometry needs; it
/// softens edges by about a pixel, which the fitter's bilinear sampling
/// does anyway.
fn demosaic_bilinear(f: &Frame, pattern: BayerPattern, img: &mut RgbImage) {
    let (w, h) = (f.width as i64, f.height as i64);
    let max = f.max_value();
    for y in 0..h {
        for x in 0..w {
            let mut sum = [0.0f32; 3];
            let mut n = [0u32; 3];
            let mut clipped = false;
            let own = pattern.channel(x as u32, y as u32);
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (xx, yy) = (x + dx, y + dy);
                    if xx < 0 || yy < 0 || xx >= w || yy >= h {
                        continue;
                    }
                    let c = pattern.channel(xx as u32, yy as u32);
                    // The pixel's own channel comes from itself only.
                    if c == own && (dx != 0 || dy != 0) {
                        continue;
                    }
                    let v = f.data[(yy * w + xx) as usize];
                    sum[c] += v as f32;
                    n[c] += 1;
                    clipped |= v >= max;
                }
            }
            let i = (y * w + x) as usize;
            let get = |c: usize| if n[c] > 0 { sum[c] / n[c] as f32 } else { 0.0 };
            img.r[i] = get(0);
            img.g[i] = get(1);
            img.b[i] = get(2);
            img.clipped[i] = clipped;
        }
    }
}

/// Linear RGB planes in sensor units (DN), with a clipped flag per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub r: Vec<f32>,
    pub g: Vec<f32>,
    pub b: Vec<f32>,
    pub clipped: Vec<bool>,
}

impl RgbImage {
    /// Bilinear sample at continuous pixel coordinates (pixel centres at
    /// +0.5). `None` outside the image. The clipped flag is set if any of
    /// the four pixels involved is clipped.
    pub fn sample(&self, x: f32, y: f32) -> Option<([f32; 3], bool)> {
        let (fx, fy) = (x - 0.5, y - 0.5);
        if !(fx >= 0.0 && fy >= 0.0) {
            return None;
        }
        let (x0, y0) = (fx as usize, fy as usize);
        let (w, h) = (self.width as usize, self.height as usize);
        if x0 + 1 >= w || y0 + 1 >= h {
            return None;
        }
        let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
        let idx = [y0 * w + x0, y0 * w + x0 + 1, (y0 + 1) * w + x0, (y0 + 1) * w + x0 + 1];
        let wts = [(1.0 - tx) * (1.0 - ty), tx * (1.0 - ty), (1.0 - tx) * ty, tx * ty];
        let mut out = [0.0f32; 3];
        let mut clipped = false;
        for k in 0..4 {
            out[0] += wts[k] * self.r[idx[k]];
            out[1] += wts[k] * self.g[idx[k]];
            out[2] += wts[k] * self.b[idx[k]];
            clipped |= self.clipped[idx[k]];
        }
        Some((out, clipped))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meta() -> FrameMeta {
        FrameMeta {
            sequence: 0,
            exposure_start: MonoNs(0),
            exposure_end: MonoNs(1),
            exposure_us: 1,
            gain: 1.0,
            flags: FrameFlags::default(),
        }
    }

    #[test]
    fn demosaic_of_a_flat_colour_is_exact() {
        let (w, h) = (8u32, 6u32);
        let colour = [300u16, 200, 100];
        let data = (0..h).flat_map(|y| (0..w).map(move |x| colour[BayerPattern::Rggb.channel(x, y)])).collect();
        let f = Frame {
            width: w,
            height: h,
            layout: Layout::Bayer { pattern: BayerPattern::Rggb },
            bit_depth: 12,
            data,
            meta: meta(),
        };
        let img = f.to_rgb();
        for i in 0..(w * h) as usize {
            assert_eq!((img.r[i], img.g[i], img.b[i]), (300.0, 200.0, 100.0));
            assert!(!img.clipped[i]);
        }
        let (s, c) = img.sample(3.2, 2.7).unwrap();
        assert!((s[0] - 300.0).abs() < 1e-3 && !c);
    }

    /// The weights and footprint against the real demosaic and sampler: a
    /// frame that is 1 at one raw sample and 0 elsewhere reads `b_j` there,
    /// which `sample_weights` must give for that sample, and the sum of
    /// `b_j^2` over every raw sample of a colour is what
    /// `sample_footprint` must give for that colour.
    #[test]
    fn sample_weights_and_footprint_are_the_demosaic_and_samplers_own() {
        let (w, h) = (9u32, 8u32);
        let weights = [0.2126f32, 0.7152, 0.0722];
        let layouts = [
            Layout::Bayer { pattern: BayerPattern::Rggb },
            Layout::Bayer { pattern: BayerPattern::Gbrg },
            Layout::Mono,
            Layout::Rgb,
        ];
        for layout in layouts {
            for &(x, y) in &[(3.5f32, 3.5f32), (4.2, 3.7), (1.1, 6.9), (7.9, 1.6), (0.6, 0.5)] {
                let spp = layout.samples_per_pixel();
                let mut want = [0.0f64; 3];
                let taps = layout.sample_weights(w, h, x, y, weights).unwrap();
                for j in 0..(w * h) as usize * spp {
                    let mut data = vec![0u16; (w * h) as usize * spp];
                    data[j] = 1;
                    let f = Frame { width: w, height: h, layout, bit_depth: 12, data, meta: meta() };
                    let (s, _) = f.to_rgb().sample(x, y).unwrap();
                    let b: f32 = s.iter().zip(&weights).map(|(v, w)| v * w).sum();
                    let (px, py) = (((j / spp) as u32) % w, ((j / spp) as u32) / w);
                    let colour = match layout {
                        Layout::Bayer { pattern } => pattern.channel(px, py),
                        Layout::Rgb => j % 3,
                        Layout::Mono => 1,
                    };
                    want[colour] += (b as f64).powi(2);
                    // Each raw sample's own coefficient, not only the sums.
                    let got_b = taps.iter().find(|t| (t.x, t.y, t.colour) == (px, py, colour)).map_or(0.0, |t| t.b);
                    assert!((got_b - b).abs() <= 1e-6, "{layout:?} at ({x}, {y}), raw sample {j}: {got_b} against {b}");
                }
                let got = layout.sample_footprint(w, h, x, y, weights).unwrap();
                for c in 0..3 {
                    let expect = want[c];
                    assert!(
                        (got[c] as f64 - expect).abs() <= 1e-6 * expect.max(1e-3),
                        "{layout:?} at ({x}, {y}), colour {c}: {} against {expect}",
                        got[c]
                    );
                }
            }
        }
        assert_eq!(Layout::Mono.sample_footprint(w, h, 0.2, 3.0, weights), None);
        assert_eq!(Layout::Mono.sample_footprint(w, h, 8.6, 3.0, weights), None);
    }

    #[test]
    fn clipping_propagates_to_neighbours() {
        let mut data = vec![100u16; 16];
        data[5] = 4095;
        let f = Frame {
            width: 4,
            height: 4,
            layout: Layout::Bayer { pattern: BayerPattern::Rggb },
            bit_depth: 12,
            data,
            meta: meta(),
        };
        let img = f.to_rgb();
        assert!(img.clipped[5] && img.clipped[0] && img.clipped[10]);
        assert!(!img.clipped[15]);
        // Counted in the raw frame: the one clipped sensor pixel, inside
        // a window and not outside it.
        assert_eq!(f.clipped_in(0, 0, 4, 4), 1);
        assert_eq!(f.clipped_in(0, 0, 100, 100), 1);
        assert_eq!(f.clipped_in(2, 2, 4, 4), 0);
    }
}

/// What a camera accepted, read back after setting it: recorded in the
/// capture's metadata (`capture.json`), so a capture says what the camera
/// really did.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct AppliedSettings {
    pub device: String,
    pub driver: String,
    pub format: String,
    pub width: u32,
    pub height: u32,
    pub bit_depth: u8,
    /// How the frames' samples are laid out (absent from captures made
    /// before it was recorded).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub layout: Option<Layout>,
    pub exposure_us: u32,
    pub gain: f32,
    /// Every control set, with the value read back.
    pub controls: std::collections::BTreeMap<String, i64>,
    /// Warnings for the operator (e.g. a non-radiometric format).
    pub warnings: Vec<String>,
}
