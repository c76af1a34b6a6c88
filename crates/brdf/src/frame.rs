//! The local shading frame and the trigonometry every model shares.
//!
//! Convention (one for the whole project): the surface normal is `+z`, the
//! tangent `+x` is the sample's x axis (the gantry's direction of travel), and
//! `+y` completes a right-handed frame. `i` points from the surface toward the
//! light, `o` from the surface toward the camera; both are unit vectors.
//! A direction with `z <= 0` is at or below the horizon and reflects nothing.
//!
//! Trigonometric helpers compute `sin^2` from the x and y components rather
//! than as `1 - cos^2`, which would cancel catastrophically near the normal
//! (where very sharp lobes live).

use glam::{Vec2, Vec3};

/// Cosine of the polar angle.
#[inline]
pub fn cos_theta(v: Vec3) -> f32 {
    v.z
}

/// Squared sine of the polar angle, free of cancellation near the pole.
#[inline]
pub fn sin2_theta(v: Vec3) -> f32 {
    v.x * v.x + v.y * v.y
}

/// Squared tangent of the polar angle. Infinite on the horizon; callers that
/// can meet the horizon must use [`sin2_theta`] and `z` directly.
#[inline]
pub fn tan2_theta(v: Vec3) -> f32 {
    sin2_theta(v) / (v.z * v.z)
}

/// `(cos^2 phi, sin^2 phi)` of a direction; `(1, 0)` on the pole where phi is
/// undefined (any value gives the same result in every formula that uses it,
/// because it is multiplied by `sin^2 theta = 0`).
#[inline]
pub fn cos2_sin2_phi(v: Vec3) -> (f32, f32) {
    let s2 = sin2_theta(v);
    if s2 <= 0.0 { (1.0, 0.0) } else { (v.x * v.x / s2, v.y * v.y / s2) }
}

/// Polar angle of a direction from the normal (`+z`), in `[0, pi]`.
#[inline]
pub fn polar(v: Vec3) -> f32 {
    sin2_theta(v).sqrt().atan2(v.z)
}

/// Azimuth in `[0, 2 pi)`.
#[inline]
pub fn phi(v: Vec3) -> f32 {
    let p = v.y.atan2(v.x);
    if p < 0.0 { p + std::f32::consts::TAU } else { p }
}

/// `x.floor()`, bit for bit (the sign of zero too), without the library
/// call that `floor` is on the baseline x86-64 target (no SSE4.1): the
/// tables' and kernels' inner loops floor a coordinate per sample.
#[inline]
pub fn floor(x: f32) -> f32 {
    if x.abs() < 8_388_608.0 {
        // Below 2^23 a float may have a fraction; truncate, step down
        // where truncation went up (negative non-integers).
        let t = (x as i32) as f32;
        (if t > x { t - 1.0 } else { t }).copysign(x)
    } else {
        x.floor()
    }
}

/// `x.ceil()`, bit for bit, as [`floor`].
#[inline]
pub fn ceil(x: f32) -> f32 {
    -floor(-x)
}

/// True when a direction lies strictly above the horizon.
#[inline]
pub fn above(v: Vec3) -> bool {
    v.z > 0.0
}

/// Unit direction from polar angle `theta` and azimuth `phi` (radians).
#[inline]
pub fn spherical(theta_rad: f32, phi_rad: f32) -> Vec3 {
    let (st, ct) = theta_rad.sin_cos();
    let (sp, cp) = phi_rad.sin_cos();
    Vec3::new(st * cp, st * sp, ct)
}

/// Mirror direction of `v` about the normal.
#[inline]
pub fn reflect_about_normal(v: Vec3) -> Vec3 {
    Vec3::new(-v.x, -v.y, v.z)
}

/// Mirror direction of `v` about an arbitrary unit vector `m`.
#[inline]
pub fn reflect(v: Vec3, m: Vec3) -> Vec3 {
    2.0 * v.dot(m) * m - v
}

/// Below this length `i + o` has no usable direction (i and o opposite).
/// Chosen far above f32 rounding of a sum of unit vectors (~1e-7) and far
/// below any pair of directions that both lie above the horizon by more than
/// a micro-radian.
pub const HALF_VECTOR_MIN_LEN: f32 = 1e-6;

/// Normalised half vector of `i` and `o`, or `None` when they are opposite.
#[inline]
pub fn half_vector(i: Vec3, o: Vec3) -> Option<Vec3> {
    let h = i + o;
    let len = h.length();
    if len < HALF_VECTOR_MIN_LEN { None } else { Some(h / len) }
}

/// Rotate a direction about the normal by `angle` (radians, counter-clockwise
/// seen from above).
#[inline]
pub fn rotate_z(v: Vec3, angle_rad: f32) -> Vec3 {
    let (s, c) = angle_rad.sin_cos();
    Vec3::new(c * v.x - s * v.y, s * v.x + c * v.y, v.z)
}

/// Cosine-weighted hemisphere sample (Malley's method on a concentric disk).
/// The pdf is `cos theta / pi`.
pub fn sample_cosine_hemisphere(u: Vec2) -> Vec3 {
    let d = concentric_disk(u);
    let z = (1.0 - d.length_squared()).max(0.0).sqrt();
    Vec3::new(d.x, d.y, z)
}

/// Shirley-Chiu concentric map from the unit square to the unit disk.
pub fn concentric_disk(u: Vec2) -> Vec2 {
    let a = 2.0 * u - Vec2::ONE;
    if a.x == 0.0 && a.y == 0.0 {
        return Vec2::ZERO;
    }
    let (r, theta) = if a.x.abs() > a.y.abs() {
        (a.x, std::f32::consts::FRAC_PI_4 * (a.y / a.x))
    } else {
        (a.y, std::f32::consts::FRAC_PI_2 - std::f32::consts::FRAC_PI_4 * (a.x / a.y))
    };
    let (s, c) = theta.sin_cos();
    Vec2::new(r * c, r * s)
}

/// Pdf of [`sample_cosine_hemisphere`] in solid angle.
#[inline]
pub fn cosine_hemisphere_pdf(v: Vec3) -> f32 {
    v.z.max(0.0) * std::f32::consts::FRAC_1_PI
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn floor_and_ceil_are_the_librarys_bit_for_bit() {
        let mut xs = vec![0.0f32, -0.0, 0.5, -0.5, 1.0, -1.0, 2.5, -2.5, 1e-30, -1e-30, 8_388_607.5, -8_388_607.5];
        xs.extend([8_388_608.0, -8_388_608.0, 1e20, -1e20, f32::INFINITY, f32::NEG_INFINITY, f32::MAX, f32::MIN]);
        // Every float near the integers and halves of a few periods.
        for k in -400i32..400 {
            let c = k as f32 * 0.5;
            let mut v = c;
            for _ in 0..8 {
                v = v.next_up();
                xs.push(v);
            }
            let mut v = c;
            for _ in 0..8 {
                v = v.next_down();
                xs.push(v);
            }
        }
        // And a spread of magnitudes.
        let mut u = 0x1234_5678u32;
        for _ in 0..200_000 {
            u ^= u << 13;
            u ^= u >> 17;
            u ^= u << 5;
            let x = f32::from_bits(u);
            if !x.is_nan() {
                xs.push(x);
            }
        }
        for x in xs {
            assert_eq!(floor(x).to_bits(), x.floor().to_bits(), "floor({x:e})");
            assert_eq!(ceil(x).to_bits(), x.ceil().to_bits(), "ceil({x:e})");
        }
        assert!(floor(f32::NAN).is_nan() && ceil(f32::NAN).is_nan());
    }

    #[test]
    fn sin2_is_accurate_near_the_pole() {
        let v = spherical(1e-4, 0.3);
        let s2 = sin2_theta(v);
        assert!((s2 - 1e-8).abs() < 1e-12, "{s2}");
    }

    #[test]
    fn half_vector_of_opposite_directions_is_none() {
        assert!(half_vector(Vec3::X, -Vec3::X).is_none());
        let h = half_vector(Vec3::Z, Vec3::X).unwrap();
        assert!((h.length() - 1.0).abs() < 1e-6);
    }

    #[test]
    fn rotation_about_normal_keeps_z() {
        let v = spherical(0.7, 0.2);
        let r = rotate_z(v, 1.0);
        assert!((r.z - v.z).abs() < 1e-7);
        assert!((phi(r) - 1.2).abs() < 1e-5);
    }
}
