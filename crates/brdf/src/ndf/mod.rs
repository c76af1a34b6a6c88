//! Microfacet normal distributions (NDFs).
//!
//! An NDF `D(h)` is a density of microfacet normals per unit solid angle of
//! the normal, normalised so that the projected microfacet area equals the
//! macro-surface area: `integral over the hemisphere of D(h) cos(theta_h) dw = 1`.
//! Every implementation here satisfies that (tested), and [`Ndf::sample_h`]
//! draws normals with exactly that density, so `pdf_h = D(h) cos(theta_h)`
//! unless a type says otherwise.
//!
//! Shadowing and masking follow Smith's separable model written with the
//! projected area of the microsurface (Ashikhmin, Premoze and Shirley 2000;
//! Dupuy et al. 2015):
//! `sigma(v) = integral of max(0, h . v) D(h) dw` and `S(v) = cos(theta_v) / sigma(v)`.
//! `sigma` is what every model uses internally, because `S(v) / cos(theta_v) = 1 / sigma(v)`
//! stays finite at grazing angles where `S` and `cos` both vanish.

mod beckmann;
mod ggx;
mod masking;
mod mixture;
mod power_cosine;
mod set;
mod sheen;
mod table;
mod tabulated;

pub use beckmann::{Beckmann, BeckmannLobe};
pub use ggx::Ggx;
pub use masking::{MaskingCell, MaskingOperator, MaskingTable};
pub use mixture::Mixture;
pub use power_cosine::PowerCosine;
pub use set::{PackedTables, TableSet, TableSlot};
pub use sheen::Sheen;
pub use table::{Bilinear, Coverage, NdfGrid, NdfTable, TableError, bit, rotation_sources, split_shift, wrap};
pub use tabulated::TabulatedNdf;

use glam::{Vec2, Vec3};

/// A microfacet normal distribution with its Smith projected area.
pub trait Ndf: Send + Sync {
    /// `D(h)` for a unit half vector in the local frame; 0 for `h.z <= 0`.
    fn d(&self, h: Vec3) -> f32;

    /// Projected area of the microsurface seen from `v`,
    /// `sigma(v) = integral of max(0, h . v) D(h) dw`, never less than `v.z`
    /// (the visible projected area cannot be smaller than the macro surface's).
    /// Finite and positive for every `v` with `v.z > 0`.
    fn projected_area(&self, v: Vec3) -> f32;

    /// Smith masking `S(v) = cos(theta_v) / sigma(v)` in `[0, 1]`.
    fn g1(&self, v: Vec3) -> f32 {
        if v.z <= 0.0 { 0.0 } else { (v.z / self.projected_area(v)).clamp(0.0, 1.0) }
    }

    /// Draw a microfacet normal with density [`Ndf::pdf_h`] from two uniform
    /// numbers in `[0, 1)`.
    fn sample_h(&self, u: Vec2) -> Vec3;

    /// Density of [`Ndf::sample_h`] per unit solid angle of `h`.
    fn pdf_h(&self, h: Vec3) -> f32 {
        self.d(h) * h.z.max(0.0)
    }

    /// The distribution as weighted anisotropic Beckmann lobes, when it is
    /// exactly that (one [`Beckmann`], or a [`Mixture`] of them): a
    /// renderer can then prepare each lobe once ([`BeckmannLobe`]) and
    /// evaluate it for many directions. `None` for anything else.
    fn beckmann_lobes(&self) -> Option<Vec<(f32, Beckmann)>> {
        None
    }

    /// The distribution as weighted lobes of closed form ([`Lobe`]), when
    /// it is exactly that: one lobe, or a [`Mixture`] of single lobes. A
    /// renderer that evaluates many pixels at once (the simulated camera's
    /// batch) can then hold each lobe's constants as plain numbers. The
    /// default is [`Ndf::beckmann_lobes`]'s.
    fn closed_form_lobes(&self) -> Option<Vec<(f32, Lobe)>> {
        Some(self.beckmann_lobes()?.into_iter().map(|(w, b)| (w, Lobe::Beckmann(b))).collect())
    }
}

/// A lobe of [`Ndf::closed_form_lobes`].
#[derive(Clone, Debug, PartialEq)]
pub enum Lobe {
    Beckmann(Beckmann),
    Sheen(Sheen),
}

impl<N: Ndf + ?Sized> Ndf for &N {
    fn d(&self, h: Vec3) -> f32 {
        (**self).d(h)
    }
    fn projected_area(&self, v: Vec3) -> f32 {
        (**self).projected_area(v)
    }
    fn sample_h(&self, u: Vec2) -> Vec3 {
        (**self).sample_h(u)
    }
    fn pdf_h(&self, h: Vec3) -> f32 {
        (**self).pdf_h(h)
    }
    fn beckmann_lobes(&self) -> Option<Vec<(f32, Beckmann)>> {
        (**self).beckmann_lobes()
    }
    fn closed_form_lobes(&self) -> Option<Vec<(f32, Lobe)>> {
        (**self).closed_form_lobes()
    }
}

impl<N: Ndf + ?Sized> Ndf for std::sync::Arc<N> {
    fn d(&self, h: Vec3) -> f32 {
        (**self).d(h)
    }
    fn projected_area(&self, v: Vec3) -> f32 {
        (**self).projected_area(v)
    }
    fn sample_h(&self, u: Vec2) -> Vec3 {
        (**self).sample_h(u)
    }
    fn pdf_h(&self, h: Vec3) -> f32 {
        (**self).pdf_h(h)
    }
    fn beckmann_lobes(&self) -> Option<Vec<(f32, Beckmann)>> {
        (**self).beckmann_lobes()
    }
    fn closed_form_lobes(&self) -> Option<Vec<(f32, Lobe)>> {
        (**self).closed_form_lobes()
    }
}

impl<N: Ndf + ?Sized> Ndf for Box<N> {
    fn d(&self, h: Vec3) -> f32 {
        (**self).d(h)
    }
    fn projected_area(&self, v: Vec3) -> f32 {
        (**self).projected_area(v)
    }
    fn sample_h(&self, u: Vec2) -> Vec3 {
        (**self).sample_h(u)
    }
    fn pdf_h(&self, h: Vec3) -> f32 {
        (**self).pdf_h(h)
    }
    fn beckmann_lobes(&self) -> Option<Vec<(f32, Beckmann)>> {
        (**self).beckmann_lobes()
    }
    fn closed_form_lobes(&self) -> Option<Vec<(f32, Lobe)>> {
        (**self).closed_form_lobes()
    }
}

/// Smallest roughness any analytic NDF accepts. At `alpha = 1e-4` the peak
/// `1 / (pi alpha^2) = 3.2e7` is still far inside f32 range and its square
/// (which appears in fits) is below 1.1e15; smaller values would only model
/// a mirror, which a camera with finite pixels cannot resolve anyway.
pub const MIN_ALPHA: f32 = 1e-4;

/// Clamp a roughness parameter into the supported range `[MIN_ALPHA, 4]`,
/// mapping NaN to `MIN_ALPHA`.
pub fn clamp_alpha(alpha: f32) -> f32 {
    if alpha.is_nan() { MIN_ALPHA } else { alpha.clamp(MIN_ALPHA, 4.0) }
}

/// Rotate a direction from the sample frame into a lobe frame whose x axis
/// is at `angle_rad` from the sample's x axis.
#[inline]
pub(crate) fn to_lobe_frame(v: Vec3, angle_rad: f32) -> Vec3 {
    if angle_rad == 0.0 { v } else { crate::frame::rotate_z(v, -angle_rad) }
}

/// Rotate a direction from a lobe frame back into the sample frame.
#[inline]
pub(crate) fn from_lobe_frame(v: Vec3, angle_rad: f32) -> Vec3 {
    if angle_rad == 0.0 { v } else { crate::frame::rotate_z(v, angle_rad) }
}

/// A normal built from slopes `(sx, sy)`: `normalize(-sx, -sy, 1)`.
#[inline]
pub(crate) fn normal_from_slopes(sx: f32, sy: f32) -> Vec3 {
    Vec3::new(-sx, -sy, 1.0).normalize()
}
