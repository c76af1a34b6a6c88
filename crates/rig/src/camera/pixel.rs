//! V4L2 pixel formats as the measurement sees them: which ones are
//! radiometric, which one to prefer, and how a buffer becomes a [`Frame`]'s
//! samples. Pure code (no device), so every decoder is unit-tested and
//! fuzzed on this machine, whose kernel has no V4L2.

use frame::{BayerPattern, Layout};

/// A capture format, named by its V4L2 four-character code.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    /// 8-bit greyscale (`GREY`).
    Grey,
    /// 10, 12 or 16 significant bits of greyscale in 16-bit little-endian
    /// words, right-aligned (`Y10 `, `Y12 `, `Y16 `).
    Mono16 { bits: u8 },
    /// 8-bit raw Bayer (`BA81`, `GBRG`, `GRBG`, `RGGB`).
    Bayer8(BayerPattern),
    /// Raw Bayer in 16-bit little-endian words with `bits` significant bits
    /// (`BG10`/`BG12`/`BYR2` and the other three tiles).
    Bayer16 { pattern: BayerPattern, bits: u8 },
    /// Packed 4:2:2 YUV (`YUYV`): only its luma is kept. It has been through
    /// the camera's tone curve and is not radiometric.
    Yuyv,
    /// Motion JPEG (`MJPG`, `JPEG`): lossy and tone-mapped, refused.
    Mjpeg,
    /// Anything else, by its code.
    Other([u8; 4]),
}

/// Every code the reflectometer knows, one row per format (`MJPG` before
/// its alias `JPEG`, so that is the code a format is named by).
const CODES: [([u8; 4], PixelFormat); 23] = {
    use BayerPattern::*;
    use PixelFormat::*;
    [
        (*b"GREY", Grey),
        (*b"Y10 ", Mono16 { bits: 10 }),
        (*b"Y12 ", Mono16 { bits: 12 }),
        (*b"Y16 ", Mono16 { bits: 16 }),
        (*b"BA81", Bayer8(Bggr)),
        (*b"GBRG", Bayer8(Gbrg)),
        (*b"GRBG", Bayer8(Grbg)),
        (*b"RGGB", Bayer8(Rggb)),
        (*b"BG10", Bayer16 { pattern: Bggr, bits: 10 }),
        (*b"GB10", Bayer16 { pattern: Gbrg, bits: 10 }),
        (*b"BA10", Bayer16 { pattern: Grbg, bits: 10 }),
        (*b"RG10", Bayer16 { pattern: Rggb, bits: 10 }),
        (*b"BG12", Bayer16 { pattern: Bggr, bits: 12 }),
        (*b"GB12", Bayer16 { pattern: Gbrg, bits: 12 }),
        (*b"BA12", Bayer16 { pattern: Grbg, bits: 12 }),
        (*b"RG12", Bayer16 { pattern: Rggb, bits: 12 }),
        (*b"BYR2", Bayer16 { pattern: Bggr, bits: 16 }),
        (*b"GB16", Bayer16 { pattern: Gbrg, bits: 16 }),
        (*b"GR16", Bayer16 { pattern: Grbg, bits: 16 }),
        (*b"RG16", Bayer16 { pattern: Rggb, bits: 16 }),
        (*b"YUYV", Yuyv),
        (*b"MJPG", Mjpeg),
        (*b"JPEG", Mjpeg),
    ]
};

impl PixelFormat {
    pub fn from_fourcc(code: [u8; 4]) -> Self {
        CODES.iter().find(|(c, _)| *c == code).map_or(PixelFormat::Other(code), |&(_, f)| f)
    }

    /// The format's code. A depth no driver offers (a hand-made
    /// `Mono16 { bits: 14 }`) is named by its 16-bit container.
    pub fn fourcc(self) -> [u8; 4] {
        let named = match self {
            PixelFormat::Other(c) => return c,
            PixelFormat::Mono16 { bits } if !matches!(bits, 10 | 12) => PixelFormat::Mono16 { bits: 16 },
            PixelFormat::Bayer16 { pattern, bits } if !matches!(bits, 10 | 12) => {
                PixelFormat::Bayer16 { pattern, bits: 16 }
            }
            f => f,
        };
        CODES.iter().find(|(_, f)| *f == named).map_or([b'?'; 4], |&(c, _)| c)
    }

    /// The code as text (`"Y16 "` keeps its space).
    pub fn name(self) -> String {
        fourcc_text(self.fourcc())
    }

    /// How much the measurement wants this format: more significant bits
    /// first, mono before Bayer (no demosaicing, full resolution), YUYV
    /// last. `None` for formats it cannot use at all.
    pub fn preference(self) -> Option<u32> {
        Some(match self {
            PixelFormat::Mono16 { bits } => 300 + bits as u32,
            PixelFormat::Bayer16 { bits, .. } => 200 + bits as u32,
            PixelFormat::Grey => 108,
            PixelFormat::Bayer8(_) => 100,
            PixelFormat::Yuyv => 1,
            PixelFormat::Mjpeg | PixelFormat::Other(_) => return None,
        })
    }

    /// Significant bits per sample in the decoded frame.
    pub fn bit_depth(self) -> u8 {
        match self {
            PixelFormat::Grey | PixelFormat::Bayer8(_) | PixelFormat::Yuyv => 8,
            PixelFormat::Mono16 { bits } | PixelFormat::Bayer16 { bits, .. } => bits,
            PixelFormat::Mjpeg | PixelFormat::Other(_) => 0,
        }
    }

    pub fn layout(self) -> Layout {
        match self {
            PixelFormat::Bayer8(pattern) | PixelFormat::Bayer16 { pattern, .. } => Layout::Bayer { pattern },
            _ => Layout::Mono,
        }
    }

    /// Bytes one pixel occupies in a buffer line.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Grey | PixelFormat::Bayer8(_) => 1,
            _ => 2,
        }
    }

    /// Why this format must not be used for measurement, if it must not.
    pub fn refusal(self) -> Option<String> {
        match self {
            PixelFormat::Mjpeg => Some(
                "MJPG is lossy and tone-mapped and cannot be used for measurement; choose a raw format \
                 (GREY, Y10/Y12/Y16 or Bayer) or a camera that offers one"
                    .into(),
            ),
            PixelFormat::Other(c) => Some(format!(
                "pixel format '{}' is not one the reflectometer can decode (GREY, Y10/Y12/Y16, Bayer 8/10/12/16-bit, YUYV)",
                fourcc_text(c)
            )),
            _ => None,
        }
    }

    /// A warning the operator must see when capturing in this format.
    pub fn warning(self) -> Option<String> {
        (self == PixelFormat::Yuyv).then(|| {
            "YUYV IS NOT RADIOMETRIC: its luma went through the camera's tone curve, so measured \
             reflectance will be wrong by an unknown curve. Use GREY, Y10/Y12/Y16 or Bayer for real measurements."
                .to_string()
        })
    }

    /// The samples of one frame, right-aligned to [`Self::bit_depth`]:
    /// `data` is the buffer (of which `bytes_used` are valid) with lines
    /// `stride` bytes apart. Errors say why a buffer cannot be a frame
    /// (too short, bad stride); the caller treats such a buffer as damaged.
    pub fn decode(
        self,
        data: &[u8],
        bytes_used: usize,
        width: u32,
        height: u32,
        stride: usize,
    ) -> Result<Vec<u16>, String> {
        if let Some(why) = self.refusal() {
            return Err(why);
        }
        let (w, h) = (width as usize, height as usize);
        let line = w.checked_mul(self.bytes_per_pixel()).ok_or("frame width overflows")?;
        if stride < line {
            return Err(format!("stride {stride} is shorter than a line of {line} bytes"));
        }
        let needed = if h == 0 { Some(0) } else { stride.checked_mul(h - 1).and_then(|n| n.checked_add(line)) };
        let needed = needed.ok_or("frame size overflows")?;
        let valid = bytes_used.min(data.len());
        if valid < needed {
            return Err(format!("buffer holds {valid} bytes, a {w}x{h} frame needs {needed}"));
        }
        let mut out = Vec::with_capacity(w * h);
        for y in 0..h {
            let row = &data[y * stride..y * stride + line];
            match self {
                PixelFormat::Grey | PixelFormat::Bayer8(_) => out.extend(row.iter().map(|&b| b as u16)),
                PixelFormat::Mono16 { bits } | PixelFormat::Bayer16 { bits, .. } => {
                    // Drivers leave the unused high bits zero; a stray one
                    // must not turn into a value above the sensor's maximum.
                    let mask = ((1u32 << bits.min(16)) - 1) as u16;
                    out.extend(row.chunks_exact(2).map(|p| u16::from_le_bytes([p[0], p[1]]) & mask))
                }
                PixelFormat::Yuyv => out.extend(row.chunks_exact(2).map(|p| p[0] as u16)),
                PixelFormat::Mjpeg | PixelFormat::Other(_) => unreachable!("refused above"),
            }
        }
        Ok(out)
    }
}

/// The format to capture in: the one asked for by name if given (and
/// offered), else the most preferred one offered. Errors say what was
/// offered.
pub fn choose(offered: &[PixelFormat], asked: Option<&str>) -> Result<PixelFormat, String> {
    let list = || offered.iter().map(|f| f.name().trim_end().to_string()).collect::<Vec<_>>().join(", ");
    if let Some(name) = asked {
        let want = PixelFormat::from_fourcc(fourcc_from_name(name)?);
        if !offered.contains(&want) {
            return Err(format!("the camera does not offer {name}; it offers: {}", list()));
        }
        if let Some(why) = want.refusal() {
            return Err(why);
        }
        return Ok(want);
    }
    offered.iter().copied().filter(|f| f.preference().is_some()).max_by_key(|f| f.preference()).ok_or_else(|| {
        format!(
            "the camera offers no format usable for measurement (it offers: {}); MJPG-only webcams cannot be used",
            list()
        )
    })
}

/// A four-character code as text. V4L2 marks big-endian variants by setting
/// the top bit of the last byte (`v4l2_fourcc_be`); those print as `"Y16 -BE"`
/// rather than as a replacement character.
pub fn fourcc_text(code: [u8; 4]) -> String {
    let mut bytes = code;
    let big_endian = bytes[3] & 0x80 != 0;
    bytes[3] &= 0x7f;
    let text: String = bytes.iter().map(|&b| if b.is_ascii_graphic() || b == b' ' { b as char } else { '?' }).collect();
    if big_endian { format!("{text}-BE") } else { text }
}

/// `"Y16"` or `"Y16 "` as a four-character code.
pub fn fourcc_from_name(name: &str) -> Result<[u8; 4], String> {
    let b = name.as_bytes();
    if b.is_empty() || b.len() > 4 || !b.iter().all(|c| c.is_ascii_graphic()) {
        return Err(format!("'{name}' is not a four-character pixel format code (e.g. Y16, GREY, BA81)"));
    }
    let mut code = [b' '; 4];
    code[..b.len()].copy_from_slice(b);
    Ok(code)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn codes_round_trip() {
        for code in [
            b"GREY", b"Y10 ", b"Y12 ", b"Y16 ", b"BA81", b"GBRG", b"GRBG", b"RGGB", b"BG10", b"GB10", b"BA10", b"RG10",
            b"BG12", b"GB12", b"BA12", b"RG12", b"BYR2", b"GB16", b"GR16", b"RG16", b"YUYV", b"MJPG", b"NV12",
        ] {
            assert_eq!(&PixelFormat::from_fourcc(*code).fourcc(), code);
        }
    }

    #[test]
    fn deepest_mono_format_is_chosen_and_mjpeg_never() {
        let offered = [PixelFormat::Yuyv, PixelFormat::Mjpeg, PixelFormat::Grey, PixelFormat::Mono16 { bits: 12 }];
        assert_eq!(choose(&offered, None), Ok(PixelFormat::Mono16 { bits: 12 }));
        let bayer =
            [PixelFormat::Bayer8(BayerPattern::Rggb), PixelFormat::Bayer16 { pattern: BayerPattern::Rggb, bits: 12 }];
        assert_eq!(choose(&bayer, None), Ok(PixelFormat::Bayer16 { pattern: BayerPattern::Rggb, bits: 12 }));
        assert_eq!(choose(&[PixelFormat::Yuyv, PixelFormat::Mjpeg], None), Ok(PixelFormat::Yuyv));
        let e = choose(&[PixelFormat::Mjpeg], None).unwrap_err();
        assert!(e.contains("MJPG"), "{e}");
        let e = choose(&offered, Some("MJPG")).unwrap_err();
        assert!(e.contains("lossy"), "{e}");
        let e = choose(&offered, Some("BA81")).unwrap_err();
        assert!(e.contains("offers: YUYV, MJPG, GREY, Y12"), "{e}");
        assert_eq!(choose(&offered, Some("GREY")), Ok(PixelFormat::Grey));
        assert!(choose(&offered, Some("TOOLONG")).is_err());
    }

    #[test]
    fn only_yuyv_warns() {
        assert!(PixelFormat::Yuyv.warning().unwrap().contains("NOT RADIOMETRIC"));
        assert!(PixelFormat::Grey.warning().is_none());
        assert!(PixelFormat::Mono16 { bits: 16 }.warning().is_none());
    }

    #[test]
    fn decodes_padded_lines_and_masks_stray_bits() {
        // 3x2 Y10 with 8-byte lines (2 bytes of padding).
        let mut buf = vec![0xEEu8; 16];
        let px = [1u16, 1023, 0xFC05, 7, 512, 0];
        for (i, v) in px.iter().enumerate() {
            let (x, y) = (i % 3, i / 3);
            buf[y * 8 + x * 2..y * 8 + x * 2 + 2].copy_from_slice(&v.to_le_bytes());
        }
        let got = PixelFormat::Mono16 { bits: 10 }.decode(&buf, 16, 3, 2, 8).unwrap();
        assert_eq!(got, vec![1, 1023, 5, 7, 512, 0]);
        // The last line needs no padding after it.
        assert!(PixelFormat::Mono16 { bits: 10 }.decode(&buf, 14, 3, 2, 8).is_ok());
        let e = PixelFormat::Mono16 { bits: 10 }.decode(&buf, 13, 3, 2, 8).unwrap_err();
        assert!(e.contains("needs 14"), "{e}");
        assert!(PixelFormat::Grey.decode(&buf, 16, 9, 2, 8).unwrap_err().contains("stride"));
    }

    #[test]
    fn yuyv_keeps_luma() {
        let buf = [10u8, 128, 20, 130, 30, 128, 40, 120];
        assert_eq!(PixelFormat::Yuyv.decode(&buf, 8, 4, 1, 8).unwrap(), vec![10, 20, 30, 40]);
    }

    #[test]
    fn bayer_keeps_its_tile() {
        let f = PixelFormat::from_fourcc(*b"RG12");
        assert_eq!(f.layout(), Layout::Bayer { pattern: BayerPattern::Rggb });
        assert_eq!(f.bit_depth(), 12);
        assert_eq!(PixelFormat::from_fourcc(*b"BA81").layout(), Layout::Bayer { pattern: BayerPattern::Bggr });
    }

    #[test]
    fn big_endian_codes_are_named_and_refused() {
        let be = [b'Y', b'1', b'6', b' ' | 0x80];
        assert_eq!(fourcc_text(be), "Y16 -BE");
        assert!(PixelFormat::from_fourcc(be).refusal().unwrap().contains("Y16 -BE"));
        assert_eq!(fourcc_text(*b"GREY"), "GREY");
    }

    #[test]
    fn every_code_names_its_format_and_back() {
        for (code, f) in CODES {
            assert_eq!(PixelFormat::from_fourcc(code), f);
            if code != *b"JPEG" {
                assert_eq!(f.fourcc(), code, "{f:?}");
            }
        }
        assert_eq!(PixelFormat::Mono16 { bits: 14 }.fourcc(), *b"Y16 ");
        assert_eq!(PixelFormat::from_fourcc(*b"JPEG").fourcc(), *b"MJPG");
    }
}
