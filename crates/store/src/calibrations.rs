//! Where a rig's calibrations are kept: one JSON file per calibration,
//! named by its id (a UTC timestamp), so the newest sorts last.

use std::path::{Path, PathBuf};

use setup::Calibration;

use crate::StoreError;

/// The error of an IO step on `path`, for `map_err`.
fn io(what: &'static str, path: &Path) -> impl FnOnce(std::io::Error) -> StoreError {
    let path = path.display().to_string();
    move |source| StoreError::Io { what, path, source }
}

/// The calibrations of one rig, newest last by id.
#[derive(Clone, Debug)]
pub struct CalibrationStore {
    dir: PathBuf,
}

impl CalibrationStore {
    /// The calibrations of rig `rig_name` under `base` (one folder per rig).
    pub fn new(base: &Path, rig_name: &str) -> Self {
        Self { dir: base.join(rig_name) }
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The newest calibration, with its file.
    pub fn newest(&self) -> Result<Option<(PathBuf, Calibration)>, StoreError> {
        let rd = match std::fs::read_dir(&self.dir) {
            Ok(r) => r,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(io("cannot read", &self.dir)(e)),
        };
        let mut files: Vec<PathBuf> =
            rd.flatten().map(|e| e.path()).filter(|p| p.extension().is_some_and(|x| x == "json")).collect();
        files.sort();
        let Some(p) = files.pop() else { return Ok(None) };
        let text = std::fs::read_to_string(&p).map_err(io("cannot read", &p))?;
        let c: Calibration = serde_json::from_str(&text)
            .map_err(|e| StoreError::BadCalibration { path: p.display().to_string(), reason: e.to_string() })?;
        Ok(Some((p, c)))
    }

    /// Store `c` (written to a temporary file, then renamed into place).
    pub fn save(&self, c: &Calibration) -> Result<PathBuf, StoreError> {
        std::fs::create_dir_all(&self.dir).map_err(io("cannot create", &self.dir))?;
        let p = self.dir.join(format!("{}.json", c.id));
        let tmp = self.dir.join(format!(".{}.tmp", c.id));
        let bytes = serde_json::to_vec_pretty(c).map_err(|e| std::io::Error::other(e.to_string()));
        bytes.and_then(|b| std::fs::write(&tmp, b)).map_err(io("cannot write", &tmp))?;
        std::fs::rename(&tmp, &p).map_err(io("cannot write", &p))?;
        Ok(p)
    }
}
