//! `zenoh-relay learner-host`: what the GPU box runs — `learner serve` (the binary beside
//! this one) under a private service prefix, restarted when it dies, plus the learner side
//! of the relay. Training uses CUDA when libtorch has it (`make setup TORCH_VARIANT=cuda`);
//! `learner serve` picks the device itself.
//!
//! The learner is tied to this process (`PR_SET_PDEATHSIG`) and stopped with SIGTERM (then
//! SIGKILL after [`LEARNER_STOP_GRACE`]) when the relay stops.

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use shm_schemas::cli_bounds::{f64_within, int_within};
use shm_schemas::process_ties::{self, ChildTies};

/// How long `learner serve` gets to exit after SIGTERM.
pub const LEARNER_STOP_GRACE: Duration = Duration::from_secs(5);
/// Pause before restarting a learner that exited.
pub const RESTART_PAUSE: Duration = Duration::from_secs(2);

/// `learner serve`'s settings on the learner host.
#[derive(Debug, Clone, PartialEq, clap::Args)]
pub struct LearnerArgs {
    /// The `learner` executable (default: the one beside `zenoh-relay`).
    #[arg(long)]
    pub learner_bin: Option<PathBuf>,
    /// Base checkpoint retraining resumes from (the same policy as the controller's:
    /// `foresight`'s default, the distilled generalist).
    #[arg(long, default_value = "assets/policy-distilled")]
    pub checkpoint: PathBuf,
    /// Task configuration (must be the controller's: requests carry its hash).
    #[arg(long, default_value = "assets/task.toml")]
    pub task: PathBuf,
    /// Where retraining runs are written.
    #[arg(long, default_value = "runs/learner-host")]
    pub out: PathBuf,
    /// Retraining wall-time budget per request (s), as `foresight --retrain-budget-s`.
    #[arg(long, default_value_t = 30.0, value_parser = f64_within(0.1, 86_400.0), allow_negative_numbers = true)]
    pub time_budget_s: f64,
    /// Retraining step budget per request, as `foresight --retrain-steps`.
    #[arg(long, default_value_t = 400_000, value_parser = int_within(1u64, 10_000_000_000), allow_negative_numbers = true)]
    pub max_steps: u64,
    /// More `learner serve` flags, after `--`.
    #[arg(last = true)]
    pub extra: Vec<String>,
}

impl LearnerArgs {
    /// The `learner serve` command line for service prefix `prefix`.
    pub fn serve_args(&self, prefix: &str) -> Vec<String> {
        let s = |p: &Path| p.display().to_string();
        let mut a = vec![
            "serve".to_owned(),
            "--checkpoint".to_owned(),
            s(&self.checkpoint),
            "--prefix".to_owned(),
            prefix.to_owned(),
            "--task".to_owned(),
            s(&self.task),
            "--out".to_owned(),
            s(&self.out),
            "--time-budget-s".to_owned(),
            self.time_budget_s.to_string(),
            "--max-steps".to_owned(),
            self.max_steps.to_string(),
        ];
        a.extend(self.extra.iter().cloned());
        a
    }

    /// The learner executable.
    ///
    /// # Errors
    /// This executable's folder cannot be found.
    pub fn learner_bin(&self) -> std::io::Result<PathBuf> {
        match &self.learner_bin {
            Some(p) => Ok(p.clone()),
            None => {
                let exe = std::env::current_exe()?;
                Ok(exe.with_file_name("learner"))
            }
        }
    }
}

/// A supervised `learner serve`.
pub struct LearnerChild {
    program: PathBuf,
    args: Vec<String>,
    child: Option<Child>,
    exited_at: Option<Instant>,
    /// Restarts so far.
    pub restarts: u32,
}

impl LearnerChild {
    /// Starts it.
    ///
    /// # Errors
    /// The executable cannot be started (the error names it).
    pub fn start(program: PathBuf, args: Vec<String>) -> std::io::Result<Self> {
        let mut c = Self {
            program,
            args,
            child: None,
            exited_at: None,
            restarts: 0,
        };
        c.spawn()?;
        Ok(c)
    }

    fn spawn(&mut self) -> std::io::Result<()> {
        let mut cmd = Command::new(&self.program);
        cmd.args(&self.args);
        process_ties::tie_child(
            &mut cmd,
            ChildTies {
                own_process_group: false,
                refuse_if_orphaned: false,
            },
        );
        let child = cmd.spawn().map_err(|e| {
            std::io::Error::new(
                e.kind(),
                format!("starting {}: {e}", self.program.display()),
            )
        })?;
        tracing::info!(pid = child.id(), "learner serve started");
        self.child = Some(child);
        self.exited_at = None;
        Ok(())
    }

    /// Notices an exit and restarts after [`RESTART_PAUSE`].
    pub fn poll(&mut self) {
        if let Some(child) = self.child.as_mut()
            && let Ok(Some(status)) = child.try_wait()
        {
            tracing::warn!("learner serve exited ({status}); restarting in {RESTART_PAUSE:?}");
            self.child = None;
            self.exited_at = Some(Instant::now());
        }
        if self.child.is_none() && self.exited_at.is_some_and(|t| t.elapsed() >= RESTART_PAUSE) {
            match self.spawn() {
                Ok(()) => self.restarts += 1,
                Err(e) => {
                    tracing::error!("{e}");
                    self.exited_at = Some(Instant::now());
                }
            }
        }
    }

    /// SIGTERM, then SIGKILL after [`LEARNER_STOP_GRACE`].
    pub fn stop(&mut self) {
        let Some(mut child) = self.child.take() else {
            return;
        };
        // Our own child, not yet reaped: the pid is still its.
        let _ = process_ties::signal_process(child.id(), libc::SIGTERM);
        let deadline = Instant::now() + LEARNER_STOP_GRACE;
        while Instant::now() < deadline {
            if let Ok(Some(_)) = child.try_wait() {
                return;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        tracing::warn!("learner serve did not stop within {LEARNER_STOP_GRACE:?}: killed");
        let _ = child.kill();
        let _ = child.wait();
    }
}

impl Drop for LearnerChild {
    fn drop(&mut self) {
        self.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_learner_gets_the_private_prefix_the_budgets_and_extra_flags() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            learner: LearnerArgs,
        }
        let cli = Cli::parse_from(["x", "--time-budget-s", "60", "--", "--workers", "4"]);
        let a = cli.learner.serve_args("lh-1");
        let after = |flag: &str| a.iter().position(|x| x == flag).map(|i| a[i + 1].as_str());
        assert_eq!(a[0], "serve");
        assert_eq!(after("--prefix"), Some("lh-1"));
        assert_eq!(after("--time-budget-s"), Some("60"));
        assert_eq!(after("--max-steps"), Some("400000"));
        assert_eq!(after("--checkpoint"), Some("assets/policy-distilled"));
        assert_eq!(&a[a.len() - 2..], ["--workers", "4"]);
    }
}
