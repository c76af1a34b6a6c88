//! The fitter's named floors and tolerances. Each is a guard, not a tuning
//! knob: it keeps a division or a logarithm finite, or says when an
//! iteration has converged, at a value far outside anything a capture can
//! produce, so no fitted figure depends on it.

/// Floor of a sample's variance (reflectance squared, 1/sr^2): a noiseless
/// sample still gets a finite inverse-variance weight. Real variances,
/// from read and shot noise, are above 1e-12.
pub const MIN_VARIANCE: f32 = 1e-20;

/// Floor of a gain, electrons per DN or Fresnel reflectance at normal
/// incidence before dividing by it. Settings are range-checked well above
/// it (`setup::valid`); this only keeps a zero read from a damaged file
/// from dividing by zero.
pub const MIN_DIVISOR: f32 = 1e-6;

/// Floor of a calibrated LED's relative brightness (a dead LED's samples
/// are flagged unusable by the calibration; this keeps its scale finite).
pub const MIN_LED_SCALE: f32 = 1e-9;

/// Floor of the flat-field factor: a pixel the white scan saw as black is
/// weighted as one a thousand times dimmer than the mean, not infinitely.
pub const MIN_FLAT: f32 = 1e-3;

/// Shortest light-to-point distance (mm) and shortest `|i + o|` (unitless)
/// the half-vector spacing divides by: the LEDs are centimetres from the
/// sample and `i + o` vanishes only at exact retro-reflection from the
/// horizon, which the rig cannot produce.
pub const MIN_DISTANCE_MM: f32 = 1e-3;
pub const MIN_HALF_SUM: f32 = 1e-3;

/// Narrowest splatting kernel (radians, 0.06 degrees): far below any
/// table cell, it only keeps a zero spacing from a degenerate geometry
/// finite.
pub const MIN_KERNEL_RAD: f32 = 1e-3;

/// Smallest `sin(theta)` of a ring the splatting kernel's azimuth reach is
/// divided by (the ring at the pole has `sin = 0`).
pub const MIN_RING_SIN: f32 = 1e-4;

/// Relative change at which the robust diffuse estimate has converged
/// (f32 resolution is about 1.2e-7).
pub const DIFFUSE_CONVERGED: f32 = 1e-6;

/// A reflectance (1/sr) far below any a sensor resolves: the absolute
/// floor of relative tolerances on reflectance.
pub const TINY_REFLECTANCE: f32 = 1e-12;

/// Floor of a relative colour's luminance before dividing by it.
pub const MIN_LUMINANCE: f32 = 1e-6;

/// Floor of a Fresnel reflectance whose logarithm is taken.
pub const MIN_FRESNEL_LOG: f32 = 1e-9;

/// Floor of a Fresnel factor relative to normal incidence, `F(c)/F(1)`:
/// dividing a sample by a smaller one would amplify its noise a
/// thousandfold.
pub const MIN_FRESNEL_RATIO: f32 = 1e-3;

/// Floor of an NDF's missing mass in the synthesis scores (tables are
/// normalised to 1; 1e-9 is below f32 resolution of that).
pub const MIN_MISSING_MASS: f64 = 1e-9;

/// Relative size of the determinant of the 2x2 diffuse/specular system
/// below which it is singular (`|det| <= SINGULAR_REL * dd * ss`), and the
/// absolute floor of that scale.
pub const SINGULAR_REL: f64 = 1e-12;
pub const SINGULAR_ABS: f64 = 1e-30;

/// Floor of a specular albedo's luminance used as the analytic fits'
/// starting `k_s`.
pub const MIN_KS_START: f32 = 1e-4;

/// Floor of the robust residual scale (median absolute deviation) in the
/// calibration's outlier rejection.
pub const MIN_MAD: f64 = 1e-6;
