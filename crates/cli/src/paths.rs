//! Where the reflectometer keeps its files, and UTC timestamps.

use std::path::PathBuf;
use std::time::{SystemTime, UNIX_EPOCH};

/// Data directory: `$REFLECTOMETER_DATA`, else `$XDG_DATA_HOME/reflectometer`,
/// else `~/.local/share/reflectometer`.
pub fn data_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("REFLECTOMETER_DATA") {
        return PathBuf::from(d);
    }
    if let Some(d) = std::env::var_os("XDG_DATA_HOME") {
        return PathBuf::from(d).join("reflectometer");
    }
    match std::env::var_os("HOME") {
        Some(h) => PathBuf::from(h).join(".local/share/reflectometer"),
        None => PathBuf::from(".reflectometer"),
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
