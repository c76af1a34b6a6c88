//! Which cameras this machine has (`capture --list-cameras`).
//!
//! `nokhwa` finds the V4L2 capture devices and their names. It cannot be
//! asked about the formats that matter here (it does not know GREY, 16-bit
//! or Bayer formats), so each device's formats and sizes are read with `v4l`
//! and judged by the same rules the capture uses.

use std::path::PathBuf;

use nokhwa::utils::{ApiBackend, CameraIndex};
use serde::Serialize;
use v4l::video::Capture;

use super::pixel::{self, PixelFormat};

/// One camera as the operator sees it in the listing.
#[derive(Clone, Debug, Serialize)]
pub struct CameraListing {
    pub name: String,
    pub path: PathBuf,
    /// Driver and bus, if the device could be opened.
    pub driver: Option<String>,
    pub formats: Vec<FormatListing>,
    /// Why the device could not be examined (permissions, busy).
    pub error: Option<String>,
}

#[derive(Clone, Debug, Serialize)]
pub struct FormatListing {
    #[serde(skip)]
    pub format: PixelFormat,
    pub code: String,
    pub description: String,
    /// `true` if a capture may use it (YUYV is usable, with a warning).
    pub usable: bool,
    pub note: Option<String>,
    /// Discrete sizes, or a range as text.
    pub sizes: Vec<String>,
}

impl CameraListing {
    /// The format a capture would choose on its own ([`pixel::choose`]).
    pub fn preferred(&self) -> Option<&FormatListing> {
        let offered: Vec<PixelFormat> = self.formats.iter().map(|f| f.format).collect();
        let best = pixel::choose(&offered, None).ok()?;
        self.formats.iter().find(|f| f.format == best)
    }
}

/// Every V4L2 capture device. An empty list means none is plugged in (or
/// this kernel has no V4L2); a device that cannot be opened is listed with
/// the reason.
pub fn list_cameras() -> Result<Vec<CameraListing>, String> {
    let found = match nokhwa::query(ApiBackend::Video4Linux) {
        Ok(v) => v,
        Err(e) => return Err(format!("cannot list V4L2 devices: {e}")),
    };
    let mut out = Vec::new();
    for info in found {
        let CameraIndex::Index(i) = info.index() else { continue };
        let path = PathBuf::from(format!("/dev/video{i}"));
        let mut l = CameraListing {
            name: info.human_name(),
            path: path.clone(),
            driver: None,
            formats: Vec::new(),
            error: None,
        };
        match examine(&path) {
            Ok(Some((driver, formats))) => {
                l.driver = Some(driver);
                l.formats = formats;
            }
            // Metadata and output nodes of a camera are not cameras.
            Ok(None) => continue,
            Err(e) => l.error = Some(e),
        }
        out.push(l);
    }
    out.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(out)
}

fn examine(path: &std::path::Path) -> Result<Option<(String, Vec<FormatListing>)>, String> {
    let dev = v4l::Device::with_path(path).map_err(|e| match e.raw_os_error() {
        Some(libc::EACCES) | Some(libc::EPERM) => format!("{e}: add this user to the 'video' group"),
        Some(libc::EBUSY) => format!("{e}: another program is using it"),
        _ => e.to_string(),
    })?;
    let caps = dev.query_caps().map_err(|e| e.to_string())?;
    if !caps.capabilities.contains(v4l::capability::Flags::VIDEO_CAPTURE) {
        return Ok(None);
    }
    let driver = format!("{} ({})", caps.driver, caps.bus);
    let mut formats = Vec::new();
    for d in dev.enum_formats().map_err(|e| e.to_string())? {
        let pf = PixelFormat::from_fourcc(d.fourcc.repr);
        let refusal = pf.refusal();
        let note = refusal.clone().or_else(|| pf.warning()).map(|s| s.split(';').next().unwrap_or("").to_string());
        formats.push(FormatListing {
            format: pf,
            sizes: frame_sizes(&dev, d.fourcc),
            code: pf.name().trim_end().to_string(),
            description: d.description.clone(),
            usable: refusal.is_none(),
            note,
        });
    }
    Ok(Some((driver, formats)))
}

/// The frame sizes a device offers in one format, as text: `"640x480"`, or
/// `"16x16 to 1920x1080"` for a range. Empty if the driver will not say.
pub fn frame_sizes(dev: &v4l::Device, fourcc: v4l::FourCC) -> Vec<String> {
    let Ok(sizes) = dev.enum_framesizes(fourcc) else { return Vec::new() };
    sizes
        .into_iter()
        .map(|f| match f.size {
            v4l::framesize::FrameSizeEnum::Discrete(s) => format!("{}x{}", s.width, s.height),
            v4l::framesize::FrameSizeEnum::Stepwise(s) => {
                format!("{}x{} to {}x{}", s.min_width, s.min_height, s.max_width, s.max_height)
            }
        })
        .collect()
}

/// The listing as the operator reads it.
pub fn render_listing(cams: &[CameraListing]) -> String {
    use std::fmt::Write;
    let mut s = String::new();
    if cams.is_empty() {
        s.push_str("no V4L2 cameras found (is the camera plugged in? `ls /dev/video*` should show it)\n");
        return s;
    }
    for c in cams {
        let _ = writeln!(s, "{}  {}", c.path.display(), c.name);
        if let Some(d) = &c.driver {
            let _ = writeln!(s, "    driver: {d}");
        }
        if let Some(e) = &c.error {
            let _ = writeln!(s, "    cannot open: {e}");
            continue;
        }
        match c.preferred() {
            Some(p) => {
                let _ = writeln!(s, "    capture would use: {}", p.code);
            }
            None => {
                let _ = writeln!(s, "    NOT USABLE for measurement: no raw format (GREY, Y10/Y12/Y16, Bayer) or YUYV");
            }
        }
        for f in &c.formats {
            let mark = if !f.usable {
                "x"
            } else if f.note.is_some() {
                "!"
            } else {
                " "
            };
            let sizes = if f.sizes.len() > 6 {
                format!("{} ... {} ({} sizes)", f.sizes[0], f.sizes[f.sizes.len() - 1], f.sizes.len())
            } else {
                f.sizes.join(", ")
            };
            let _ = writeln!(s, "  {mark} {:5} {:28} {sizes}", f.code, f.description);
            if let Some(n) = &f.note {
                let _ = writeln!(s, "          {n}");
            }
        }
    }
    s.push_str("(x: refused for measurement; !: usable with a warning)\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn listing_marks_refused_and_preferred_formats() {
        let f = |code: &str, usable: bool, note: Option<&str>| FormatListing {
            format: PixelFormat::from_fourcc(pixel::fourcc_from_name(code).unwrap()),
            code: code.into(),
            description: code.into(),
            usable,
            note: note.map(str::to_string),
            sizes: vec!["640x480".into()],
        };
        let cam = CameraListing {
            name: "Test cam".into(),
            path: "/dev/video0".into(),
            driver: Some("uvcvideo (usb-1)".into()),
            formats: vec![
                f("MJPG", false, Some("MJPG is lossy")),
                f("YUYV", true, Some("YUYV IS NOT RADIOMETRIC")),
                f("Y16", true, None),
            ],
            error: None,
        };
        let text = render_listing(std::slice::from_ref(&cam));
        assert!(text.contains("capture would use: Y16"), "{text}");
        assert!(text.contains("  x MJPG"), "{text}");
        assert!(text.contains("  ! YUYV"), "{text}");
        let mjpeg_only = CameraListing { formats: vec![f("MJPG", false, None)], ..cam };
        assert!(render_listing(&[mjpeg_only]).contains("NOT USABLE"));
        assert!(render_listing(&[]).contains("no V4L2 cameras found"));
    }
}
