//! The command log: one CSV line per cycle that followed a plan, from the cycle's reports
//! (written by the twin thread; the cycle only fills its report). Lines are whole; the file
//! is flushed at least every 100 ms and at the end. A log never replaces another: an
//! existing file at the path is refused, named, and left as it is (a previous run's log is
//! not truncated); a device or FIFO there (`/dev/full`, a pipe) is written without truncation.

// The log writer runs on the twin thread (not real-time): it flushes by wall time.
#![allow(clippy::disallowed_methods)]

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::cycle::{CycleReport, Mode};

/// Why the command log could not be written.
#[derive(Debug, thiserror::Error)]
#[error("command log {path}")]
pub struct CommandLogError {
    /// The file.
    pub path: PathBuf,
    /// The I/O error.
    pub source: std::io::Error,
}

/// An open command log.
#[derive(Debug)]
pub struct CommandLog {
    path: PathBuf,
    out: std::io::BufWriter<std::fs::File>,
    last_cycle: u64,
    lines: u64,
    flushed: Instant,
}

impl CommandLog {
    /// Creates the log and writes its header. The file must not exist yet (a regular file
    /// already there is refused and left untouched); an existing device or FIFO is opened
    /// for writing as it is.
    ///
    /// # Errors
    /// [`CommandLogError`] when the file exists, cannot be created or written.
    pub fn create(path: &Path) -> Result<Self, CommandLogError> {
        let err = |source| CommandLogError {
            path: path.to_path_buf(),
            source,
        };
        let special = std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir());
        let file = if special {
            std::fs::OpenOptions::new().write(true).open(path)
        } else {
            std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(path)
                .map_err(|e| {
                    if e.kind() == std::io::ErrorKind::AlreadyExists {
                        std::io::Error::new(
                            e.kind(),
                            "already exists (a previous run's log?): refusing to overwrite \
                             it; move it away or give another --command-log",
                        )
                    } else {
                        e
                    }
                })
        }
        .map_err(err)?;
        let mut out = std::io::BufWriter::new(file);
        writeln!(out, "t_ns,cycle,plan_id,q0_rad,q1_rad,q2_rad,q3_rad,q4_rad").map_err(err)?;
        tracing::info!(path = %path.display(), "logging computed commands");
        Ok(Self {
            path: path.to_path_buf(),
            out,
            last_cycle: 0,
            lines: 0,
            flushed: Instant::now(),
        })
    }

    fn err(&self, source: std::io::Error) -> CommandLogError {
        CommandLogError {
            path: self.path.clone(),
            source,
        }
    }

    /// Logs the report's command if it is a new cycle that followed a plan.
    ///
    /// # Errors
    /// [`CommandLogError`] on a write error (a full disk, say).
    pub fn record(&mut self, r: &CycleReport) -> Result<(), CommandLogError> {
        if r.cycles == self.last_cycle {
            return Ok(());
        }
        self.last_cycle = r.cycles;
        if r.mode == Mode::Following {
            if self.lines == 0 {
                // The 100 ms flush period counts from the first command line.
                self.flushed = Instant::now();
            }
            let q = r.cmd.q_rad;
            writeln!(
                self.out,
                "{},{},{},{:.6},{:.6},{:.6},{:.6},{:.6}",
                r.t_ns, r.cycles, r.plan_id, q[0], q[1], q[2], q[3], q[4]
            )
            .map_err(|e| self.err(e))?;
            self.lines += 1;
        }
        if self.flushed.elapsed() >= Duration::from_millis(100) {
            self.out.flush().map_err(|e| self.err(e))?;
            self.flushed = Instant::now();
        }
        Ok(())
    }

    /// Flushes and closes the log; the number of command lines written.
    ///
    /// # Errors
    /// [`CommandLogError`] when the last flush fails.
    pub fn finish(mut self) -> Result<u64, CommandLogError> {
        self.out.flush().map_err(|e| self.err(e))?;
        Ok(self.lines)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_existing_log_is_refused_by_name_and_left_untouched() {
        let dir = std::env::temp_dir().join(format!("foresight-cmdlog-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("commands.csv");
        std::fs::write(&path, "a previous run's lines\n").unwrap();
        let e = CommandLog::create(&path).unwrap_err();
        assert_eq!(e.source.kind(), std::io::ErrorKind::AlreadyExists);
        assert!(e.to_string().contains("commands.csv"), "{e}");
        assert_eq!(
            std::fs::read_to_string(&path).unwrap(),
            "a previous run's lines\n",
            "the previous log is kept"
        );
        let fresh = dir.join("fresh.csv");
        let log = CommandLog::create(&fresh).unwrap();
        assert_eq!(log.finish().unwrap(), 0);
        assert!(
            std::fs::read_to_string(&fresh)
                .unwrap()
                .starts_with("t_ns,cycle")
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
