//! The RGL tensor-file reader on files built here (the measured files in
//! `../shared/data/rgl` are for evaluation runs only): a well-formed file
//! parses to its fields, malformed ones are refused, and no input panics.

use material::rgl::{RglBrdf, parse_tensor_file};
use proptest::prelude::*;

/// A tensor file with `fields` (name, shape, f32 data).
fn tensor_file(fields: &[(&str, Vec<u64>, Vec<f32>)]) -> Vec<u8> {
    let mut header = Vec::new();
    header.extend_from_slice(b"tensor_file\0");
    header.extend_from_slice(&[1, 0]);
    header.extend_from_slice(&(fields.len() as u32).to_le_bytes());
    let header_len: usize = 18 + fields.iter().map(|(n, s, _)| 2 + n.len() + 2 + 1 + 8 + 8 * s.len()).sum::<usize>();
    let mut data = Vec::new();
    for (name, shape, values) in fields {
        header.extend_from_slice(&(name.len() as u16).to_le_bytes());
        header.extend_from_slice(name.as_bytes());
        header.extend_from_slice(&(shape.len() as u16).to_le_bytes());
        header.push(10);
        header.extend_from_slice(&((header_len + data.len()) as u64).to_le_bytes());
        for d in shape {
            header.extend_from_slice(&d.to_le_bytes());
        }
        for v in values {
            data.extend_from_slice(&v.to_le_bytes());
        }
    }
    assert_eq!(header.len(), header_len);
    header.extend_from_slice(&data);
    header
}

/// A minimal isotropic measurement: a constant NDF of 1/pi, sigma 1, a
/// uniform visible-NDF density and a constant rgb of 0.5, so that
/// `f = 0.5 / pi / 4` everywhere above the horizon.
fn constant_file() -> Vec<u8> {
    let (n, t, r) = (8usize, 2usize, 4usize);
    tensor_file(&[
        ("phi_i", vec![1], vec![0.0]),
        ("theta_i", vec![t as u64], vec![0.0, 1.5707964]),
        ("ndf", vec![2, n as u64], vec![std::f32::consts::FRAC_1_PI; 2 * n]),
        ("sigma", vec![2, n as u64], vec![1.0; 2 * n]),
        ("vndf", vec![1, t as u64, n as u64, n as u64], vec![1.0; t * n * n]),
        ("rgb", vec![1, t as u64, 3, r as u64, r as u64], vec![0.5; t * 3 * r * r]),
    ])
}

#[test]
fn a_constant_measurement_evaluates_to_its_constant() {
    use brdf::Brdf;
    use glam::Vec3;
    let b = RglBrdf::parse(&constant_file()).unwrap();
    let want = 0.5 * std::f32::consts::FRAC_1_PI / 4.0;
    for (i, o) in [(Vec3::Z, Vec3::Z), (Vec3::new(0.5, 0.0, 0.866), Vec3::new(-0.2, 0.7, 0.68))] {
        let f = b.eval(i.normalize(), o.normalize());
        assert!((f - Vec3::splat(want)).abs().max_element() < 1e-4, "{f:?} vs {want}");
    }
    assert_eq!(b.eval(Vec3::Z, Vec3::new(0.0, 0.0, -1.0)), Vec3::ZERO);
}

#[test]
fn malformed_files_are_refused_with_a_reason() {
    let good = constant_file();
    assert!(parse_tensor_file(&good).is_ok());
    let mut magic = good.clone();
    magic[0] = b'x';
    assert!(parse_tensor_file(&magic).unwrap_err().to_string().contains("magic"));
    let truncated = &good[..good.len() - 4];
    assert!(parse_tensor_file(truncated).unwrap_err().to_string().contains("outside the file"));
    let no_rgb = tensor_file(&[("phi_i", vec![1], vec![0.0])]);
    assert!(RglBrdf::parse(&no_rgb).unwrap_err().to_string().contains("theta_i"));
}

/// A file that is missing or not a tensor file is named once in the
/// message, with the reason once (the error has no separate source that a
/// printed chain would repeat).
#[test]
fn a_file_that_cannot_be_read_is_named_once() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.bsdf");
    let e = RglBrdf::read(&missing).unwrap_err();
    let m = e.to_string();
    assert!(std::error::Error::source(&e).is_none(), "{e:?}");
    assert_eq!(m.matches("missing.bsdf").count(), 1, "{m}");
    assert_eq!(m.matches("os error").count(), 1, "{m}");
    let junk = dir.path().join("junk.bsdf");
    std::fs::write(&junk, b"junk").unwrap();
    let m = RglBrdf::read(&junk).unwrap_err().to_string();
    assert!(m.starts_with(&format!("{}: ", junk.display())), "{m}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    /// Arbitrary bytes after a valid magic never panic the reader.
    #[test]
    fn arbitrary_bytes_never_panic(tail in proptest::collection::vec(any::<u8>(), 0..400)) {
        let mut b = b"tensor_file\0\x01\x00".to_vec();
        b.extend_from_slice(&tail);
        let _ = RglBrdf::parse(&b);
    }

    /// Corrupting any byte of a valid file never panics either.
    #[test]
    fn corrupted_valid_files_never_panic(at in 0usize..2000, byte in any::<u8>()) {
        let mut b = constant_file();
        let k = at % b.len();
        b[k] = byte;
        let _ = RglBrdf::parse(&b);
    }
}
