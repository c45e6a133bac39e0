//! The run folder: `runs/<UTC time>/` with `runs/latest` pointing at the newest, and atomic
//! file writes (temporary file + fsync + rename) for everything a run leaves behind.

use std::fs::{self, File};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

/// A run's folder.
#[derive(Debug, Clone)]
pub struct RunDir {
    /// `runs/<time>`.
    pub path: PathBuf,
}

/// `YYYYmmdd-HHMMSS` (UTC) of a Unix time, without a date library.
pub fn utc_stamp(unix_s: u64) -> String {
    let days = unix_s / 86_400;
    let secs = unix_s % 86_400;
    // Civil-from-days (Howard Hinnant's algorithm), valid for the Gregorian calendar.
    let z = days as i64 + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}{m:02}{d:02}-{:02}{:02}{:02}",
        secs / 3600,
        (secs / 60) % 60,
        secs % 60
    )
}

impl RunDir {
    /// Creates `root/<UTC time>` (with a numeric suffix if it exists) and points
    /// `root/latest` at it.
    ///
    /// # Errors
    /// I/O errors creating the folder or the link.
    pub fn create(root: &Path) -> std::io::Result<Self> {
        fs::create_dir_all(root)?;
        let now = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        let stamp = utc_stamp(now);
        let mut path = root.join(&stamp);
        let mut n = 1;
        while path.exists() {
            path = root.join(format!("{stamp}-{n}"));
            n += 1;
        }
        fs::create_dir_all(&path)?;
        let dir = Self { path };
        dir.point_latest(root)?;
        Ok(dir)
    }

    /// Atomically replaces `root/latest` with a link to this run.
    fn point_latest(&self, root: &Path) -> std::io::Result<()> {
        let name = self
            .path
            .file_name()
            .map(PathBuf::from)
            .unwrap_or_else(|| self.path.clone());
        let tmp = root.join(format!(".latest.{}", std::process::id()));
        let _ = fs::remove_file(&tmp);
        std::os::unix::fs::symlink(&name, &tmp)?;
        fs::rename(&tmp, root.join("latest"))
    }

    /// A path inside the run folder (sub-folders are created).
    ///
    /// # Errors
    /// I/O errors creating the parent folder.
    pub fn file(&self, rel: &str) -> std::io::Result<PathBuf> {
        let p = self.path.join(rel);
        if let Some(parent) = p.parent() {
            fs::create_dir_all(parent)?;
        }
        Ok(p)
    }
}

/// Writes `bytes` to `path` atomically: a temporary file beside it, fsync, rename. A crash
/// leaves either the old file or the new one, never a torn one.
///
/// # Errors
/// I/O errors.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    fs::create_dir_all(dir)?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "file".into());
    let tmp = dir.join(format!(".{name}.tmp.{}", std::process::id()));
    {
        let mut f = File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    fs::rename(&tmp, path)?;
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_stamp_matches_known_dates() {
        assert_eq!(utc_stamp(0), "19700101-000000");
        // 2026-11-21 19:46:40 UTC
        assert_eq!(utc_stamp(1_795_290_400), "20261121-194640");
        // Leap day 2024-02-29 12:00:00 UTC
        assert_eq!(utc_stamp(1_709_208_000), "20240229-120000");
    }

    #[test]
    fn run_dir_points_latest_at_the_newest_run() {
        let root = std::env::temp_dir().join(format!("foresight-runs-{}", std::process::id()));
        let a = RunDir::create(&root).unwrap();
        let b = RunDir::create(&root).unwrap();
        assert_ne!(a.path, b.path);
        let latest = fs::read_link(root.join("latest")).unwrap();
        assert_eq!(root.join(latest), b.path);
        let f = b.file("plots/x.txt").unwrap();
        write_atomic(&f, b"one").unwrap();
        write_atomic(&f, b"two").unwrap();
        assert_eq!(fs::read(&f).unwrap(), b"two");
        let leftovers: Vec<_> = fs::read_dir(f.parent().unwrap())
            .unwrap()
            .filter_map(Result::ok)
            .filter(|e| e.file_name().to_string_lossy().contains(".tmp."))
            .collect();
        assert!(leftovers.is_empty());
        fs::remove_dir_all(&root).ok();
    }
}
