//! Writing images: linear EXR and tone-mapped PNG; comparison sheets with
//! labels.

use std::path::Path;

use ab_glyph::{Font, FontRef, PxScale, ScaleFont, point};
use exr::prelude::WritableImage;
use glam::Vec3;
use thiserror::Error;

use crate::render::Image;

#[derive(Debug, Error)]
pub enum ImageError {
    #[error("{path}: {reason}")]
    Write { path: String, reason: String },
}

fn err(path: &Path, e: impl std::fmt::Display) -> ImageError {
    ImageError::Write { path: path.display().to_string(), reason: e.to_string() }
}

/// Linear RGB EXR (f32).
pub fn write_exr(path: &Path, img: &Image) -> Result<(), ImageError> {
    let w = img.width as usize;
    let px = |x: usize, y: usize| {
        let c = img.pixels[y * w + x];
        (c.x, c.y, c.z)
    };
    exr::prelude::Image::from_channels(
        (w, img.height as usize),
        exr::prelude::SpecificChannels::rgb(|pos: exr::prelude::Vec2<usize>| px(pos.0, pos.1)),
    )
    .write()
    .to_file(path)
    .map_err(|e| err(path, e))
}

/// Exposure that maps the 99.5th percentile of luminance to 0.8.
pub fn auto_exposure(img: &Image) -> f32 {
    let mut l: Vec<f32> =
        img.pixels.iter().map(|c| 0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z).filter(|v| *v > 0.0).collect();
    if l.is_empty() {
        return 1.0;
    }
    let k = ((l.len() as f32 * 0.995) as usize).min(l.len() - 1);
    let v = *l.select_nth_unstable_by(k, |a, b| a.total_cmp(b)).1;
    if v > 0.0 { 0.8 / v } else { 1.0 }
}

/// Linear `[0, 1]` to an 8-bit sRGB code (IEC 61966-2-1 transfer curve).
pub fn srgb(v: f32) -> u8 {
    let v = v.clamp(0.0, 1.0);
    let s = if v <= 0.003_130_8 { 12.92 * v } else { 1.055 * v.powf(1.0 / 2.4) - 0.055 };
    (s * 255.0 + 0.5) as u8
}

/// 8-bit sRGB pixels after exposure.
pub fn tonemap(img: &Image, exposure: f32) -> Vec<u8> {
    img.pixels
        .iter()
        .flat_map(|c| {
            let c = *c * exposure;
            [srgb(c.x), srgb(c.y), srgb(c.z)]
        })
        .collect()
}

/// Tone-mapped PNG with the given exposure.
pub fn write_png(path: &Path, img: &Image, exposure: f32) -> Result<(), ImageError> {
    let bytes = tonemap(img, exposure);
    image::save_buffer(path, &bytes, img.width, img.height, image::ExtendedColorType::Rgb8).map_err(|e| err(path, e))
}

/// Draw `text` in white on an 8-bit RGB buffer at `(x, y)` (top-left).
pub fn draw_text(buf: &mut [u8], width: u32, height: u32, x: i32, y: i32, size: f32, text: &str) {
    let Ok(font) = FontRef::try_from_slice(dejavu::sans::regular()) else { return };
    let scaled = font.as_scaled(PxScale::from(size));
    let mut caret = x as f32;
    let base = y as f32 + scaled.ascent();
    for ch in text.chars() {
        let id = font.glyph_id(ch);
        let glyph = id.with_scale_and_position(PxScale::from(size), point(caret, base));
        caret += scaled.h_advance(id);
        if let Some(outline) = font.outline_glyph(glyph) {
            let bounds = outline.px_bounds();
            outline.draw(|gx, gy, cov| {
                let px = bounds.min.x as i32 + gx as i32;
                let py = bounds.min.y as i32 + gy as i32;
                if px >= 0 && py >= 0 && (px as u32) < width && (py as u32) < height {
                    let k = ((py as u32 * width + px as u32) * 3) as usize;
                    for c in 0..3 {
                        let v = buf[k + c] as f32;
                        buf[k + c] = (v + (255.0 - v) * cov.clamp(0.0, 1.0)) as u8;
                    }
                }
            });
        }
    }
}

/// A comparison sheet: panels side by side with a label under each, all
/// with one exposure (the first panel's), so brightness compares honestly.
pub fn write_sheet(path: &Path, panels: &[(&str, &Image)]) -> Result<(), ImageError> {
    let Some((_, first)) = panels.first() else { return Err(err(path, "no panels")) };
    let exposure = auto_exposure(first);
    let (pw, ph) = (first.width, first.height);
    let label_h = 28u32;
    let gap = 6u32;
    let w = panels.len() as u32 * (pw + gap) - gap;
    let h = ph + label_h;
    let mut buf = vec![24u8; (w * h * 3) as usize];
    for (k, (label, img)) in panels.iter().enumerate() {
        if img.width != pw || img.height != ph {
            return Err(err(path, "panels differ in size"));
        }
        let t = tonemap(img, exposure);
        let x0 = k as u32 * (pw + gap);
        for y in 0..ph {
            let src = &t[(y * pw * 3) as usize..((y + 1) * pw * 3) as usize];
            let dst = ((y * w + x0) * 3) as usize;
            buf[dst..dst + src.len()].copy_from_slice(src);
        }
        draw_text(&mut buf, w, h, x0 as i32 + 4, ph as i32 + 4, 18.0, label);
    }
    image::save_buffer(path, &buf, w, h, image::ExtendedColorType::Rgb8).map_err(|e| err(path, e))
}

/// Relative RMS error `sqrt(sum (a - b)^2 / sum b^2)` over pixels and
/// channels of image pairs (model, truth); `None` if the truth is black.
pub fn rel_rmse(pairs: &[(&Image, &Image)]) -> Option<f64> {
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (a, b) in pairs {
        for (x, y) in a.pixels.iter().zip(&b.pixels) {
            let d: Vec3 = *x - *y;
            num += (d.x * d.x + d.y * d.y + d.z * d.z) as f64;
            den += (y.x * y.x + y.y * y.y + y.z * y.z) as f64;
        }
    }
    (den > 0.0).then(|| (num / den).sqrt())
}
