//! The run folder: `runs/<UTC time>/` with `runs/latest` pointing at the newest, and atomic
//! file writes (temporary file + fsync + rename) for everything a run leaves behind.
//!
//! Two launchers started in the same second never share a folder: the run's folder is made
//! with one `mkdir` (never "exists? then create", which two can pass at once), the next
//! suffix tried when it is taken; a file a run streams into (`timeline.jsonl`) is created
//! new ([`RunDir::create_new_file`]), never truncated.

use std::fs::{self, File};
use std::io::{ErrorKind, Write};
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
        let now = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map(|d| d.as_secs())
            .unwrap_or(0);
        Self::create_at(root, now)
    }

    /// [`RunDir::create`] for the Unix time `unix_s`: `root/<stamp>`, or `root/<stamp>-<n>`
    /// with the first `n` not taken. Each candidate is made with one `mkdir`, which fails
    /// when the folder exists, so two launchers in the same second get two folders.
    ///
    /// # Errors
    /// I/O errors creating the folder or the link.
    pub fn create_at(root: &Path, unix_s: u64) -> std::io::Result<Self> {
        fs::create_dir_all(root)?;
        let stamp = utc_stamp(unix_s);
        let mut path = root.join(&stamp);
        let mut n = 1u32;
        loop {
            match fs::create_dir(&path) {
                Ok(()) => break,
                Err(e) if e.kind() == ErrorKind::AlreadyExists && n < 10_000 => {
                    path = root.join(format!("{stamp}-{n}"));
                    n += 1;
                }
                Err(e) => return Err(e),
            }
        }
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
        // Named after the run, unique now that every run has its own folder: two runs made
        // at once (threads of one process share the pid) never take each other's link.
        let tmp = root.join(format!(
            ".latest.{}.{}",
            std::process::id(),
            name.to_string_lossy()
        ));
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

    /// Creates the file `rel` inside the run folder (sub-folders are created); fails with
    /// [`ErrorKind::AlreadyExists`] rather than truncate a file that is there.
    ///
    /// # Errors
    /// I/O errors, [`ErrorKind::AlreadyExists`] when the file exists.
    pub fn create_new_file(&self, rel: &str) -> std::io::Result<File> {
        File::options()
            .write(true)
            .create_new(true)
            .open(self.file(rel)?)
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

    /// Issue 41 item 5: launchers started in the same second raced through "exists? then
    /// create_dir_all": two could pass the check together and share (and truncate) one run.
    /// Here 16 threads create their run folders at the same second at once: every one gets
    /// a folder of its own, and a file in one is never truncated by another.
    #[test]
    fn run_folders_created_in_the_same_second_never_clash_or_truncate() {
        let root = std::env::temp_dir().join(format!("foresight-race-{}", std::process::id()));
        let _ = fs::remove_dir_all(&root);
        let t = 1_795_290_400;
        let first = RunDir::create_at(&root, t).unwrap();
        fs::write(first.file("timeline.jsonl").unwrap(), b"first run").unwrap();
        for round in 0..4 {
            let start = std::sync::Arc::new(std::sync::Barrier::new(16));
            let runs: Vec<RunDir> = (0..16)
                .map(|_| {
                    let (root, start) = (root.clone(), start.clone());
                    std::thread::spawn(move || {
                        start.wait();
                        let run = RunDir::create_at(&root, t).unwrap();
                        let mut f = run.create_new_file("timeline.jsonl").unwrap();
                        f.write_all(run.path.to_string_lossy().as_bytes()).unwrap();
                        run
                    })
                })
                .collect::<Vec<_>>()
                .into_iter()
                .map(|h| h.join().unwrap())
                .collect();
            let mut paths: Vec<&PathBuf> = runs.iter().map(|r| &r.path).collect();
            paths.sort();
            paths.dedup();
            assert_eq!(paths.len(), 16, "round {round}: runs shared a folder");
            for r in &runs {
                assert_ne!(r.path, first.path);
                assert_eq!(
                    fs::read_to_string(r.path.join("timeline.jsonl")).unwrap(),
                    r.path.to_string_lossy(),
                    "round {round}: a run's file was written by another"
                );
            }
        }
        assert_eq!(
            fs::read(first.path.join("timeline.jsonl")).unwrap(),
            b"first run"
        );
        // A file a run streams into is created new, never truncated.
        let e = first.create_new_file("timeline.jsonl").unwrap_err();
        assert_eq!(e.kind(), ErrorKind::AlreadyExists);
        assert_eq!(
            fs::read(first.path.join("timeline.jsonl")).unwrap(),
            b"first run"
        );
        fs::remove_dir_all(&root).ok();
    }
}
