//! `xarm-sim` as a child process for the system tests: started on given ports (0: the OS
//! picks) with the workspace's URDF and a scene, its `listening` line read for the ports it
//! announced, and its summary line read when it is interrupted. Like the launcher, it gives
//! each simulator a fresh secret in `FORESIGHT_SIM_SECRET` ([`SimProc::secret`]): an
//! `rt-core run` asked for simulation-only rights (`--auto-resume`, `--no-lookahead`) needs
//! the same in its environment ([`SIM_SECRET_ENV`]).

use std::io::{BufRead, BufReader};
use std::process::{ChildStdout, Command, Stdio};
use std::time::Duration;

use crate::{ChildGuard, bin_path, repo_root};

/// `xarm-sim`'s port options and the keys of its `listening` line.
pub const PORTS: [(&str, &str); 6] = [
    ("--command-port", "command"),
    ("--report-rt-port", "report_rt"),
    ("--report-normal-port", "report_normal"),
    ("--report-rich-port", "report_rich"),
    ("--report-real-port", "report_real"),
    ("--control-port", "control"),
];

/// The ports `xarm-sim` announced, in the order of [`PORTS`].
pub type SimPorts = [u16; 6];

/// The environment variable that carries a run's simulator secret
/// (`xarm::sim_identity::SIM_SECRET_ENV`).
pub const SIM_SECRET_ENV: &str = "FORESIGHT_SIM_SECRET";

/// A fresh secret as 64 hex digits, from the OS random source.
///
/// # Panics
/// When `/dev/urandom` cannot be read.
pub fn fresh_secret() -> String {
    let mut b = [0u8; 32];
    std::io::Read::read_exact(
        &mut std::fs::File::open("/dev/urandom").expect("/dev/urandom"),
        &mut b,
    )
    .expect("32 random bytes");
    b.iter().map(|x| format!("{x:02x}")).collect()
}

/// A running `xarm-sim`.
pub struct SimProc {
    /// The child (killed when dropped).
    pub guard: ChildGuard,
    /// Its stdout after the `listening` line.
    pub out: BufReader<ChildStdout>,
    /// The ports it announced.
    pub ports: SimPorts,
    /// The secret it proves its identity with (`None`: started without one; it then passes
    /// for a real arm).
    pub secret: Option<String>,
}

impl SimProc {
    /// Starts `xarm-sim` on `ports` with `assets/scenes/small_box.toml`, `extra` args and
    /// a fresh secret.
    ///
    /// # Panics
    /// When it does not start or announce its ports.
    pub fn start(ports: SimPorts, extra: &[&str]) -> Self {
        Self::start_with_secret(ports, extra, Some(fresh_secret()))
    }

    /// [`Self::start`] with the given secret (the same as an earlier simulator's, to stand
    /// in for it after a restart), or none: it then answers the identity challenge as a
    /// real controller does, and is a real arm to rt-core.
    ///
    /// # Panics
    /// When it does not start or announce its ports.
    pub fn start_with_secret(ports: SimPorts, extra: &[&str], secret: Option<String>) -> Self {
        let root = repo_root();
        let mut cmd = Command::new(bin_path("xarm-sim"));
        for ((flag, _), port) in PORTS.iter().zip(ports) {
            cmd.arg(flag).arg(port.to_string());
        }
        cmd.arg("--urdf")
            .arg(root.join("assets/xarm5.urdf"))
            .arg("--scene")
            .arg(root.join("assets/scenes/small_box.toml"))
            .args(extra)
            .env_remove(SIM_SECRET_ENV)
            .stdout(Stdio::piped())
            .stderr(Stdio::null());
        if let Some(s) = &secret {
            cmd.env(SIM_SECRET_ENV, s);
        }
        let mut guard = ChildGuard::spawn("xarm-sim", &mut cmd);
        let mut out = BufReader::new(guard.child.stdout.take().expect("sim stdout"));
        let mut line = String::new();
        out.read_line(&mut line).expect("listening line");
        let v: serde_json::Value = serde_json::from_str(&line).expect("xarm-sim's listening line");
        assert_eq!(v["event"], "listening", "{line}");
        let ports = PORTS.map(|(_, key)| {
            v["ports"][key]
                .as_u64()
                .and_then(|p| u16::try_from(p).ok())
                .unwrap_or_else(|| panic!("no {key} port in {line}"))
        });
        Self {
            guard,
            out,
            ports,
            secret,
        }
    }

    /// The secret it was started with (for `rt-core`'s [`SIM_SECRET_ENV`]).
    ///
    /// # Panics
    /// When it was started without one.
    pub fn secret(&self) -> &str {
        self.secret.as_deref().expect("started with a secret")
    }

    /// The command port.
    pub fn command_port(&self) -> u16 {
        self.ports[0]
    }

    /// The real-time report port (30003's stand-in).
    pub fn report_real_port(&self) -> u16 {
        self.ports[4]
    }

    /// `rt-core run --link xarm` against this simulator for 60 s at most, from the
    /// repository root, with `extra` options, the simulator's secret in its environment,
    /// a fresh service prefix, stdout piped and stderr into `log`.
    ///
    /// # Panics
    /// When `log` cannot be created.
    pub fn rt_core_run(&self, extra: &[&str], log: &std::path::Path) -> Command {
        let mut cmd = Command::new(bin_path("rt-core"));
        cmd.current_dir(repo_root())
            .args(["run", "--link", "xarm", "--no-mlock", "--seconds", "60"])
            .args(extra)
            .arg("--robot")
            .arg(format!("127.0.0.1:{}", self.command_port()))
            .arg("--report-port")
            .arg(self.report_real_port().to_string())
            .arg("--prefix")
            .arg(crate::unique_prefix("rtcore"))
            .env("NO_COLOR", "1")
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(log).expect("rt-core log file"));
        if let Some(secret) = &self.secret {
            cmd.env(SIM_SECRET_ENV, secret);
        }
        cmd
    }

    /// Interrupts it and returns its summary (the last JSON line on stdout).
    ///
    /// # Panics
    /// When it does not stop or print a summary.
    pub fn finish(mut self) -> serde_json::Value {
        assert!(
            self.guard
                .interrupt_and_wait(Duration::from_secs(5))
                .is_some(),
            "xarm-sim did not stop"
        );
        let mut last = None;
        let mut line = String::new();
        while self.out.read_line(&mut line).is_ok_and(|n| n > 0) {
            if let Ok(v) = serde_json::from_str::<serde_json::Value>(&line) {
                last = Some(v);
            }
            line.clear();
        }
        last.expect("xarm-sim summary line")
    }
}
