//! The launcher's run folders as system tests see them: a scratch folder per test, the
//! newest run folder in it, and the tail of every process log printed when a test fails.

use std::path::{Path, PathBuf};

/// A fresh scratch folder `foresight-<kind>-<test>-<pid>-<ns>` in the temporary folder,
/// removed when the test passes (a launcher run leaves about 4 MB there) and kept, its path
/// printed, when it fails ([`ScratchDir`]).
///
/// # Panics
/// If it cannot be created.
pub fn scratch_dir(kind: &str, test: &str) -> ScratchDir {
    let dir = std::env::temp_dir().join(format!(
        "foresight-{kind}-{test}-{}-{}",
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0)
    ));
    std::fs::create_dir_all(&dir).expect("scratch dir");
    ScratchDir(dir)
}

/// A test's scratch folder ([`scratch_dir`]): dropped while the test passes, it is
/// removed; dropped while it panics (the test fails), it is kept for a look and its path
/// printed. Keep it alive for the whole test (`let out = scratch_dir(..)`, never `let _`).
#[derive(Debug)]
pub struct ScratchDir(PathBuf);

impl std::ops::Deref for ScratchDir {
    type Target = Path;

    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for ScratchDir {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<std::ffi::OsStr> for ScratchDir {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.as_os_str()
    }
}

impl Drop for ScratchDir {
    fn drop(&mut self) {
        if std::thread::panicking() {
            println!(
                "---- kept the failed test's scratch folder {}",
                self.0.display()
            );
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// The newest run folder under `out` (`runs/latest`, a symlink beside them, is skipped).
pub fn newest_run(out: &Path) -> Option<PathBuf> {
    std::fs::read_dir(out)
        .ok()?
        .filter_map(Result::ok)
        .map(|e| e.path())
        .filter(|p| p.is_dir() && !p.is_symlink())
        .max()
}

/// On a failing test, prints the last lines of `extra` and of every process log of the
/// newest run under `runs` (the output then says why a process stopped, not only that it
/// did).
pub struct LogsOnFailure {
    /// The launcher's `--out` folder.
    pub runs: PathBuf,
    /// More log files to show (e.g. a process started outside the launcher).
    pub extra: Vec<PathBuf>,
}

impl Drop for LogsOnFailure {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            return;
        }
        let mut logs = self.extra.clone();
        if let Some(run) = newest_run(&self.runs)
            && let Ok(rd) = std::fs::read_dir(run.join("logs"))
        {
            logs.extend(rd.filter_map(Result::ok).map(|e| e.path()));
        }
        for log in logs {
            let text = std::fs::read_to_string(&log).unwrap_or_default();
            let lines: Vec<&str> = text.lines().collect();
            println!("---- last lines of {}", log.display());
            for line in &lines[lines.len().saturating_sub(30)..] {
                println!("  {line}");
            }
        }
    }
}
