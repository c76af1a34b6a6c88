//! Creating, writing, reading and resuming a capture directory.

use std::collections::HashSet;
use std::fs::{self, File, OpenOptions};
use std::io::{self, BufRead, BufReader, Write};
use std::path::{Path, PathBuf};

use frame::{Frame, MonoNs};
use rayon::prelude::*;
use thiserror::Error;

use crate::format::{CAPTURE_FORMAT_VERSION, CaptureInfo, CaptureStatus, FrameKind, ManifestEntry};

#[derive(Debug, Error)]
pub enum StoreError {
    #[error(
        "{dir} already holds a capture of '{sample}' made {created}; choose another --out, or continue it with --resume {dir}"
    )]
    AnotherCapture { dir: String, sample: String, created: String },
    #[error(
        "{0} exists and is a file or a directory holding something, not a capture; choose an empty or new directory \
         (nothing was changed)"
    )]
    NotEmpty(String),
    #[error("{0} is not a capture directory (no capture.json)")]
    NotACapture(String),
    #[error("{path} is damaged or not a capture description: {reason}")]
    BadCaptureJson { path: String, reason: String },
    #[error("{path} was written by format version {found}; this program reads version {CAPTURE_FORMAT_VERSION}")]
    Version { path: String, found: u32 },
    #[error(
        "the disk holding {dir} is full; free some space, then continue with --resume {dir} (nothing stored so far is lost)"
    )]
    DiskFull { dir: String },
    #[error("{what} {path}: {source}")]
    Io { what: &'static str, path: String, source: io::Error },
    #[error(
        "{dir} is in use by another process (a capture, a resume or a fit is writing it); wait for it to end, \
         or stop it (Ctrl-C, `refl daemon --cancel`)"
    )]
    Locked { dir: String },
    #[error("frame {path} is damaged: {reason}")]
    BadFrame { path: String, reason: String },
    #[error("{path} is not a calibration ({reason}); delete it or run `capture --calibrate` again")]
    BadCalibration { path: String, reason: String },
}

fn io_err(what: &'static str, path: &Path, source: io::Error, dir: &Path) -> StoreError {
    if source.raw_os_error() == Some(28) {
        // ENOSPC
        return StoreError::DiskFull { dir: dir.display().to_string() };
    }
    StoreError::Io { what, path: path.display().to_string(), source }
}

/// Write `bytes` to `path` atomically: a temporary file in the same
/// directory, then a rename over the target.
pub(crate) fn write_atomic(path: &Path, bytes: &[u8], dir: &Path) -> Result<(), StoreError> {
    let tmp = path.with_file_name(format!(
        ".{}.tmp",
        path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
    ));
    let r = (|| -> io::Result<()> {
        let mut f = File::create(&tmp)?;
        f.write_all(bytes)?;
        f.flush()?;
        drop(f);
        fs::rename(&tmp, path)
    })();
    if let Err(e) = r {
        let _ = fs::remove_file(&tmp);
        return Err(io_err("writing", path, e, dir));
    }
    Ok(())
}

/// An exclusive advisory lock (`flock`) on a capture directory, held by
/// whoever writes it (a capture, a resume, a refit) until dropped. The
/// kernel releases it when the process ends, however it ends.
#[derive(Debug)]
pub struct DirLock {
    _dir: File,
}

impl DirLock {
    /// Take the lock on `root` without waiting: another writer means
    /// [`StoreError::Locked`].
    pub fn acquire(root: &Path) -> Result<Self, StoreError> {
        Self::take(root, File::try_lock)
    }

    /// Take a shared lock on `root` without waiting: readers that write
    /// only their own files beside the capture (the tiles of a fit spread
    /// over machines) hold it together; a writer holding the lock (a
    /// capture in progress) means [`StoreError::Locked`].
    pub fn acquire_shared(root: &Path) -> Result<Self, StoreError> {
        Self::take(root, File::try_lock_shared)
    }

    fn take(root: &Path, lock: fn(&File) -> Result<(), fs::TryLockError>) -> Result<Self, StoreError> {
        let dir = File::open(root).map_err(|e| io_err("opening", root, e, root))?;
        match lock(&dir) {
            Ok(()) => Ok(Self { _dir: dir }),
            Err(fs::TryLockError::WouldBlock) => Err(StoreError::Locked { dir: root.display().to_string() }),
            Err(fs::TryLockError::Error(e)) => Err(io_err("locking", root, e, root)),
        }
    }
}

/// What a resume found.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ResumeState {
    /// Shots (by plan index) stored and verified.
    pub done_shots: HashSet<u32>,
    /// Dark frames stored and verified.
    pub dark_frames: Vec<FrameKind>,
    /// Entries whose frame was missing or did not match its checksum (dropped).
    pub damaged: Vec<String>,
    /// Whether the manifest's last line was torn (ignored).
    pub torn_tail: bool,
}

/// An open capture directory.
#[derive(Debug)]
pub struct CaptureDir {
    root: PathBuf,
    info: CaptureInfo,
    manifest: File,
    entries: Vec<ManifestEntry>,
    _lock: DirLock,
}

impl CaptureDir {
    pub const INFO: &'static str = "capture.json";
    pub const MANIFEST: &'static str = "manifest.jsonl";
    pub const FRAMES: &'static str = "frames";

    /// Can a new capture start in `root`? Refuses another capture, a file,
    /// and a directory holding anything. Touches nothing, so a caller can
    /// check before it starts devices and calibrations.
    pub fn check_new(root: &Path) -> Result<(), StoreError> {
        if root.join(Self::INFO).exists() {
            let other = Self::read_info(root)?;
            return Err(StoreError::AnotherCapture {
                dir: root.display().to_string(),
                sample: other.sample,
                created: other.created_utc,
            });
        }
        match fs::symlink_metadata(root) {
            Err(_) => Ok(()),
            Ok(m) if !m.is_dir() => Err(StoreError::NotEmpty(root.display().to_string())),
            Ok(_) => {
                let non_empty = fs::read_dir(root).map_err(|e| io_err("reading", root, e, root))?.next().is_some();
                if non_empty { Err(StoreError::NotEmpty(root.display().to_string())) } else { Ok(()) }
            }
        }
    }

    /// Start a new capture in `root` (created if missing). Refuses a
    /// directory that holds another capture or anything else.
    pub fn create(root: &Path, info: CaptureInfo) -> Result<Self, StoreError> {
        Self::check_new(root)?;
        fs::create_dir_all(root.join(Self::FRAMES)).map_err(|e| io_err("creating", root, e, root))?;
        let lock = DirLock::acquire(root)?;
        if root.join(Self::INFO).exists() {
            // Another process created a capture here since the check above.
            return Err(StoreError::Locked { dir: root.display().to_string() });
        }
        write_info(root, &info)?;
        let manifest = OpenOptions::new()
            .create(true)
            .append(true)
            .open(root.join(Self::MANIFEST))
            .map_err(|e| io_err("creating", &root.join(Self::MANIFEST), e, root))?;
        Ok(Self { root: root.to_path_buf(), info, manifest, entries: Vec::new(), _lock: lock })
    }

    /// Read `capture.json` without opening the directory for writing.
    pub fn read_info(root: &Path) -> Result<CaptureInfo, StoreError> {
        let path = root.join(Self::INFO);
        if !path.exists() {
            return Err(StoreError::NotACapture(root.display().to_string()));
        }
        let bytes = fs::read(&path).map_err(|e| io_err("reading", &path, e, root))?;
        let v: serde_json::Value = serde_json::from_slice(&bytes)
            .map_err(|e| StoreError::BadCaptureJson { path: path.display().to_string(), reason: e.to_string() })?;
        let found = v.get("format_version").and_then(|x| x.as_u64()).unwrap_or(0) as u32;
        if found != CAPTURE_FORMAT_VERSION {
            return Err(StoreError::Version { path: path.display().to_string(), found });
        }
        serde_json::from_value(v)
            .map_err(|e| StoreError::BadCaptureJson { path: path.display().to_string(), reason: e.to_string() })
    }

    /// Read the manifest's entries (a torn last line is skipped; a damaged
    /// line elsewhere is an error, since lines are only ever appended).
    pub fn read_manifest(root: &Path) -> Result<(Vec<ManifestEntry>, bool), StoreError> {
        let path = root.join(Self::MANIFEST);
        let f = match File::open(&path) {
            Ok(f) => f,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok((Vec::new(), false)),
            Err(e) => return Err(io_err("reading", &path, e, root)),
        };
        let lines: Vec<String> =
            BufReader::new(f).lines().collect::<Result<_, _>>().map_err(|e| io_err("reading", &path, e, root))?;
        let mut out = Vec::with_capacity(lines.len());
        let mut torn = false;
        for (k, line) in lines.iter().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            match serde_json::from_str::<ManifestEntry>(line) {
                Ok(e) => out.push(e),
                Err(_) if k + 1 == lines.len() => torn = true,
                Err(e) => {
                    return Err(StoreError::BadCaptureJson {
                        path: path.display().to_string(),
                        reason: format!("line {}: {e}", k + 1),
                    });
                }
            }
        }
        Ok((out, torn))
    }

    /// Open an existing capture to continue it: verify every stored frame
    /// and rewrite the manifest with only the good entries.
    pub fn resume(root: &Path) -> Result<(Self, ResumeState), StoreError> {
        let info = Self::read_info(root)?;
        let lock = DirLock::acquire(root)?;
        let (entries, torn_tail) = Self::read_manifest(root)?;
        let checks: Vec<(ManifestEntry, Result<(), String>)> = entries
            .into_par_iter()
            .map(|e| {
                let r = verify_file(&root.join(&e.file), e.crc32);
                (e, r)
            })
            .collect();
        let mut state = ResumeState { torn_tail, ..ResumeState::default() };
        let mut good = Vec::new();
        let mut seen = HashSet::new();
        for (e, r) in checks {
            match r {
                Ok(()) if seen.insert(e.frame) => {
                    match e.frame {
                        FrameKind::Shot(shot) => {
                            state.done_shots.insert(shot.index);
                        }
                        FrameKind::Dark { .. } => state.dark_frames.push(e.frame),
                    }
                    good.push(e);
                }
                Ok(()) => {}
                Err(reason) => {
                    tracing::warn!(file = e.file, reason, "dropping a stored frame that does not verify");
                    let _ = fs::remove_file(root.join(&e.file));
                    state.damaged.push(e.file.clone());
                }
            }
        }
        // Leftover temporary files of a frame that was being written.
        if let Ok(rd) = fs::read_dir(root.join(Self::FRAMES)) {
            for ent in rd.flatten() {
                if ent.file_name().to_string_lossy().ends_with(".tmp") {
                    let _ = fs::remove_file(ent.path());
                }
            }
        }
        let mut text = String::new();
        for e in &good {
            text.push_str(&serde_json::to_string(e).unwrap_or_default());
            text.push('\n');
        }
        write_atomic(&root.join(Self::MANIFEST), text.as_bytes(), root)?;
        let manifest = OpenOptions::new()
            .append(true)
            .open(root.join(Self::MANIFEST))
            .map_err(|e| io_err("opening", &root.join(Self::MANIFEST), e, root))?;
        Ok((Self { root: root.to_path_buf(), info, manifest, entries: good, _lock: lock }, state))
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn info(&self) -> &CaptureInfo {
        &self.info
    }

    pub fn entries(&self) -> &[ManifestEntry] {
        &self.entries
    }

    pub fn set_status(&mut self, status: CaptureStatus) -> Result<(), StoreError> {
        self.info.status = status;
        self.rewrite_info()
    }

    /// Set the status of a capture nobody has open (a refit, or a client
    /// whose daemon died): takes the directory's lock for the rewrite.
    pub fn set_status_of(root: &Path, status: CaptureStatus) -> Result<(), StoreError> {
        let lock = DirLock::acquire(root)?;
        Self::set_status_locked(root, &lock, status)
    }

    /// Set the status of a capture whose lock the caller holds.
    pub fn set_status_locked(root: &Path, _lock: &DirLock, status: CaptureStatus) -> Result<(), StoreError> {
        let mut info = Self::read_info(root)?;
        info.status = status;
        write_info(root, &info)
    }

    /// Replace the recorded camera settings (after configuring the device).
    pub fn set_camera(&mut self, camera: frame::AppliedSettings) -> Result<(), StoreError> {
        self.info.camera = Some(camera);
        self.rewrite_info()
    }

    fn rewrite_info(&self) -> Result<(), StoreError> {
        write_info(&self.root, &self.info)
    }

    /// Store a frame losslessly and record it.
    pub fn write_frame(
        &mut self,
        kind: FrameKind,
        f: &Frame,
        lit_at: Option<MonoNs>,
        clipped: Option<u32>,
    ) -> Result<ManifestEntry, StoreError> {
        let png = encode_png(f).map_err(|e| StoreError::BadFrame { path: kind.file_name(), reason: e })?;
        let rel = format!("{}/{}", Self::FRAMES, kind.file_name());
        let path = self.root.join(&rel);
        write_atomic(&path, &png, &self.root)?;
        let entry = ManifestEntry {
            frame: kind,
            file: rel,
            crc32: crc32fast::hash(&png),
            bytes: png.len() as u64,
            width: f.width,
            height: f.height,
            layout: f.layout,
            bit_depth: f.bit_depth,
            meta: f.meta,
            lit_at_ns: lit_at.map(|m| m.0),
            clipped,
        };
        let mut line = serde_json::to_string(&entry).map_err(|e| StoreError::Io {
            what: "encoding",
            path: Self::MANIFEST.into(),
            source: io::Error::other(e),
        })?;
        line.push('\n');
        let mpath = self.root.join(Self::MANIFEST);
        self.manifest.write_all(line.as_bytes()).map_err(|e| io_err("appending to", &mpath, e, &self.root))?;
        self.manifest.flush().map_err(|e| io_err("appending to", &mpath, e, &self.root))?;
        self.entries.push(entry.clone());
        Ok(entry)
    }

    /// Read a stored frame back, checking its checksum.
    pub fn read_frame(root: &Path, e: &ManifestEntry) -> Result<Frame, StoreError> {
        let path = root.join(&e.file);
        let bytes = fs::read(&path).map_err(|err| io_err("reading", &path, err, root))?;
        if crc32fast::hash(&bytes) != e.crc32 {
            return Err(StoreError::BadFrame { path: path.display().to_string(), reason: "checksum mismatch".into() });
        }
        decode_png(&bytes, e).map_err(|reason| StoreError::BadFrame { path: path.display().to_string(), reason })
    }

    /// Flush the manifest to stable storage.
    pub fn sync(&self) -> Result<(), StoreError> {
        self.manifest.sync_data().map_err(|e| io_err("syncing", &self.root.join(Self::MANIFEST), e, &self.root))
    }
}

/// Write `capture.json` atomically.
fn write_info(root: &Path, info: &CaptureInfo) -> Result<(), StoreError> {
    let bytes = serde_json::to_vec_pretty(info).map_err(|e| StoreError::Io {
        what: "encoding",
        path: CaptureDir::INFO.into(),
        source: io::Error::other(e),
    })?;
    write_atomic(&root.join(CaptureDir::INFO), &bytes, root)
}

fn verify_file(path: &Path, crc: u32) -> Result<(), String> {
    let bytes = fs::read(path).map_err(|e| e.to_string())?;
    if crc32fast::hash(&bytes) == crc { Ok(()) } else { Err("checksum mismatch".into()) }
}

/// Raw samples as a 16-bit grayscale PNG (interleaved RGB frames as
/// 16-bit RGB). Values are stored as the sensor gave them (right-aligned).
fn encode_png(f: &Frame) -> Result<Vec<u8>, String> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let mut out = Vec::with_capacity(f.data.len() * 2);
    let enc = PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Sub);
    // The encoder takes 16-bit samples in native byte order.
    let bytes: Vec<u8> = f.data.iter().flat_map(|v| v.to_ne_bytes()).collect();
    let color = match f.layout {
        frame::Layout::Rgb => image::ExtendedColorType::Rgb16,
        _ => image::ExtendedColorType::L16,
    };
    enc.write_image(&bytes, f.width, f.height, color).map_err(|e| e.to_string())?;
    Ok(out)
}

fn decode_png(bytes: &[u8], e: &ManifestEntry) -> Result<Frame, String> {
    let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Png).map_err(|e| e.to_string())?;
    let data: Vec<u16> = match e.layout {
        frame::Layout::Rgb => img.into_rgb16().into_raw(),
        _ => img.into_luma16().into_raw(),
    };
    let want = (e.width * e.height) as usize * e.layout.samples_per_pixel();
    if data.len() != want {
        return Err(format!("holds {} samples, the manifest says {want}", data.len()));
    }
    Ok(Frame { width: e.width, height: e.height, layout: e.layout, bit_depth: e.bit_depth, data, meta: e.meta })
}

#[cfg(test)]
mod disk_full {
    use super::*;

    /// A real ENOSPC (writing to /dev/full) becomes the disk-full error,
    /// which tells the operator what to do and that nothing is lost.
    #[test]
    fn a_full_disk_is_named_with_what_to_do() {
        let e = std::fs::write("/dev/full", b"frame").expect_err("/dev/full accepts nothing");
        let err = io_err("cannot write frame", Path::new("/x/frames/f.png"), e, Path::new("/x"));
        assert!(matches!(err, StoreError::DiskFull { .. }), "{err:?}");
        let msg = err.to_string();
        assert!(msg.contains("full") && msg.contains("--resume /x") && msg.contains("nothing stored"), "{msg}");
    }
}
