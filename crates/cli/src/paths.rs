//! Where the reflectometer keeps its files, and UTC timestamps.

use std::path::PathBuf;
use std::time::{SystemTime, UNIX_EPOCH};

/// Data directory: `$REFLECTOMETER_DATA`, else `$XDG_DATA_HOME/reflectometer`,
/// else `$HOME/.local/share/reflectometer`, with `HOME` from the password
/// database when the environment lacks it (as under some service
/// managers). Relative `XDG_DATA_HOME` and `HOME` are ignored, as the XDG
/// specification says; with no absolute home at all it is an error, never
/// a directory relative to wherever the command was started.
pub fn data_dir() -> anyhow::Result<PathBuf> {
    if let Some(d) = std::env::var_os("REFLECTOMETER_DATA") {
        return Ok(PathBuf::from(d));
    }
    let absolute = |v: Option<std::ffi::OsString>| v.map(PathBuf::from).filter(|p| p.is_absolute());
    if let Some(d) = absolute(std::env::var_os("XDG_DATA_HOME")) {
        return Ok(d.join("reflectometer"));
    }
    match absolute(std::env::var_os("HOME")).or_else(home_from_passwd) {
        Some(h) => Ok(h.join(".local/share/reflectometer")),
        None => Err(crate::usage(anyhow::anyhow!(
            "no home directory to keep calibrations in (HOME is unset or relative, and the password database has \
             none for this user): set REFLECTOMETER_DATA, XDG_DATA_HOME or HOME to an absolute path, or pass \
             --calib-dir"
        ))),
    }
}

/// The calibrations of rig `rig_name`: under `--calib-dir` if given, else
/// under the data directory's `calibration/`.
pub fn calibrations(calib_dir: Option<&std::path::Path>, rig_name: &str) -> anyhow::Result<store::CalibrationStore> {
    let base = match calib_dir {
        Some(b) => b.to_path_buf(),
        None => data_dir()?.join("calibration"),
    };
    Ok(store::CalibrationStore::new(&base, rig_name))
}

/// This user's home directory from the password database.
fn home_from_passwd() -> Option<PathBuf> {
    use std::ffi::CStr;
    use std::os::unix::ffi::OsStrExt;
    let mut buf = vec![0 as libc::c_char; 16 * 1024];
    // SAFETY: passwd is plain old data; getpwuid_r writes into `pw` and
    // `buf` (whose length we pass) and sets `out` to `&pw` on success.
    unsafe {
        let mut pw: libc::passwd = std::mem::zeroed();
        let mut out: *mut libc::passwd = std::ptr::null_mut();
        let rc = libc::getpwuid_r(libc::getuid(), &mut pw, buf.as_mut_ptr(), buf.len(), &mut out);
        if rc != 0 || out.is_null() || pw.pw_dir.is_null() {
            return None;
        }
        let dir = std::ffi::OsStr::from_bytes(CStr::from_ptr(pw.pw_dir).to_bytes());
        Some(PathBuf::from(dir)).filter(|p| p.is_absolute())
    }
}

/// Directory for sockets and device links: `$XDG_RUNTIME_DIR/reflectometer`
/// or `/tmp/reflectometer-<uid>`.
pub fn runtime_dir() -> PathBuf {
    match std::env::var_os("XDG_RUNTIME_DIR") {
        Some(d) => PathBuf::from(d).join("reflectometer"),
        // SAFETY: getuid has no preconditions.
        None => PathBuf::from(format!("/tmp/reflectometer-{}", unsafe { libc::getuid() })),
    }
}

/// Current time as `YYYYMMDDTHHMMSSZ`.
pub fn utc_stamp() -> String {
    let secs = SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
    stamp_from_unix(secs)
}

/// Days since the Unix epoch of a stamp's date (`YYYYMMDD...`), by
/// Howard Hinnant's days-from-civil; `None` if it does not start with a
/// date.
pub fn stamp_days(stamp: &str) -> Option<i64> {
    let num = |r: std::ops::Range<usize>| stamp.get(r).and_then(|t| t.parse::<i64>().ok());
    let (y, m, d) = (num(0..4)?, num(4..6)?, num(6..8)?);
    if !(1..=12).contains(&m) || !(1..=31).contains(&d) {
        return None;
    }
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let doy = (153 * (if m > 2 { m - 3 } else { m + 9 }) + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    Some(era * 146_097 + doe - 719_468)
}

/// Civil date from a Unix time (Howard Hinnant's days-from-civil inverse).
pub fn stamp_from_unix(secs: u64) -> String {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let y = yoe + era * 400;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = if m <= 2 { y + 1 } else { y };
    format!("{y:04}{m:02}{d:02}T{:02}{:02}{:02}Z", rem / 3600, (rem % 3600) / 60, rem % 60)
}

#[cfg(test)]
mod tests {
    #[test]
    fn known_dates() {
        assert_eq!(super::stamp_from_unix(0), "19700101T000000Z");
        assert_eq!(super::stamp_from_unix(1_795_305_600), "20261122T000000Z");
        assert_eq!(super::stamp_from_unix(951_782_400 + 3661), "20000229T010101Z");
    }
}

#[cfg(test)]
mod stamp_tests {
    use super::*;

    #[test]
    fn stamp_days_inverts_stamp_from_unix() {
        for days in [0u64, 59, 60, 365, 10_957, 20_787, 21_000] {
            let stamp = stamp_from_unix(days * 86_400 + 3_723);
            assert_eq!(stamp_days(&stamp), Some(days as i64), "{stamp}");
        }
        assert_eq!(stamp_days("nominal"), None);
        assert_eq!(stamp_days("20261399T000000Z"), None);
    }
}
