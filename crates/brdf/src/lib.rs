//! Reflectance models and microfacet normal distributions.
//!
//! # Conventions
//!
//! - **Frame.** Everything is evaluated in the local shading frame: normal
//!   `+z`, tangent `+x` along the sample's x axis (the gantry's travel),
//!   `+y = z x x`. See [`frame`].
//! - **Directions.** `i` points from the surface toward the light, `o` from
//!   the surface toward the camera, both unit vectors. `h = normalize(i + o)`.
//!   A direction with `z <= 0` reflects nothing.
//! - **Units.** A BRDF `f(i, o)` is in 1/sr per RGB channel (linear, relative
//!   to the light's spectrum); reflected radiance is `f cos(theta_i)` times
//!   irradiance-normal radiance. Angles are radians. Colours are [`Rgb`].
//! - **NDFs.** `integral over the hemisphere of D(h) cos(theta_h) dw = 1`.
//!   Smith masking is `S(v) = cos(theta_v) / sigma(v)` with the projected area
//!   `sigma(v) = integral of max(0, h . v) D(h) dw`.
//! - **Microfacet BRDF.** `f = kd / pi + ks D(h) S(i) S(o) F(i . h) / (4 cos_i cos_o)`
//!   (the talk's model); see [`model::Microfacet`].
//! - **Numerics.** No public function returns NaN, infinity, or a negative
//!   reflectance. Each guard sits next to the formula it protects and each
//!   epsilon is a named constant with the reason for its value.
//!
//! # Map
//!
//! - [`ndf`]: Beckmann, GGX, power-cosine (Blinn, Ashikhmin-Shirley) and the
//!   tabulated NDF with its coverage mask, masking by integration, rotation
//!   and sampling.
//! - [`model`]: Lambert, Phong (original and modified), Blinn-Phong, Ward
//!   (two normalisations), Lafortune, Cook-Torrance, Ashikhmin-Shirley, the
//!   generic microfacet model, He et al.
//! - [`fresnel`]: exact dielectric, Schlick, exact conductor.

pub mod catalog;
pub mod frame;
pub mod fresnel;
pub mod model;
pub mod ndf;
pub mod params;

pub use model::{Brdf, BrdfSample};
pub use ndf::Ndf;

/// Linear RGB triple.
pub type Rgb = glam::Vec3;

/// Floor for a cosine in a denominator of a model that divides by it
/// (original Phong, original Ward, Cook-Torrance, Ashikhmin-Shirley, He).
/// `1e-4` is 0.006 degrees above the horizon: the radiance these models
/// predict, `f cos(theta_i)`, is unaffected above that, and below it the
/// models' own divergence is cut to a finite value (at most `1e4` times the
/// unclamped scale) instead of overflowing.
pub const COS_FLOOR: f32 = 1e-4;
