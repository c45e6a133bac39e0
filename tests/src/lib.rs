//! Helpers shared by Foresight's system tests: finding the workspace's built binaries,
//! unique iceoryx2 service prefixes, child processes that are killed when a test ends,
//! running a test body inside a private network namespace (for DDS and real xArm ports), and
//! the launcher's run folders ([`runs`]).

#![forbid(unsafe_code)]
// Test rigs: a failed unwrap or expect here is a failed test, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

pub mod bounded;
pub mod rt_rig;
pub mod runs;
pub mod sim_proc;
pub mod veth;

use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

/// The repository root (for `assets/…`): the parent of this crate's folder, as cargo
/// gives it to the running test (`CARGO_MANIFEST_DIR` at run time), else as it was at build
/// time.
pub fn repo_root() -> PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR")
        .map_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")), PathBuf::from)
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from(".."))
}

/// A file under `assets/`.
pub fn asset(rel: &str) -> PathBuf {
    repo_root().join("assets").join(rel)
}

/// Path of a binary built from this workspace (`rt-core`, `xarm-sim`, `learner`, …), found
/// next to the running test executable (`target/<profile>/deps/<test>` →
/// `target/<profile>/<name>`).
///
/// # Panics
/// If the binary has not been built (run `cargo build --release --workspace --bins`).
pub fn bin_path(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("current test executable");
    let profile_dir = exe
        .parent()
        .and_then(Path::parent)
        .expect("test executable lives in target/<profile>/deps");
    let path = profile_dir.join(name);
    assert!(
        path.is_file(),
        "{} is not built; run `cargo build --release --workspace --bins` first",
        path.display()
    );
    path
}

/// A service-name prefix unique to this process and call, so tests running in parallel
/// (and leftovers of crashed runs) never share iceoryx2 services.
pub fn unique_prefix(test: &str) -> String {
    static COUNTER: AtomicU32 = AtomicU32::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.subsec_nanos())
        .unwrap_or(0);
    format!("t{}_{}_{n}_{nanos:x}", std::process::id(), test)
}

/// A child process that is killed (SIGKILL) and reaped when dropped, so a failing test
/// never leaves servers behind.
#[derive(Debug)]
pub struct ChildGuard {
    /// The child.
    pub child: Child,
    name: String,
}

impl ChildGuard {
    /// Spawns `cmd`.
    ///
    /// # Panics
    /// If the process cannot be started.
    pub fn spawn(name: &str, cmd: &mut Command) -> Self {
        let child = cmd
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {name}: {e}"));
        Self {
            child,
            name: name.to_owned(),
        }
    }

    /// Sends SIGINT (a clean stop request) and waits up to `timeout` for the exit.
    /// Returns the output status if it exited in time.
    pub fn interrupt_and_wait(&mut self, timeout: Duration) -> Option<std::process::ExitStatus> {
        let pid = self.child.id().to_string();
        let _ = Command::new("kill").args(["-INT", &pid]).status();
        let deadline = Instant::now() + timeout;
        while Instant::now() < deadline {
            if let Ok(Some(status)) = self.child.try_wait() {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        None
    }

    /// Waits for the exit (at most `limit`) and returns the exit code (-1 for a signal).
    ///
    /// # Panics
    /// If the child does not exit within `limit`, or waiting fails.
    pub fn wait_exit(&mut self, limit: Duration) -> i32 {
        let deadline = Instant::now() + limit;
        loop {
            if let Some(status) = self
                .child
                .try_wait()
                .unwrap_or_else(|e| panic!("waiting for {}: {e}", self.name))
            {
                return status.code().unwrap_or(-1);
            }
            assert!(
                Instant::now() < deadline,
                "{} did not finish within {limit:?}",
                self.name
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// The name given at spawn.
    pub fn name(&self) -> &str {
        &self.name
    }
}

impl Drop for ChildGuard {
    fn drop(&mut self) {
        if let Ok(None) = self.child.try_wait() {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

/// Environment variable marking a test process already inside its private namespace.
pub const NETNS_MARKER: &str = "FORESIGHT_IN_NETNS";

/// How [`run_in_private_netns`] ran the test.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NetnsOutcome {
    /// We are the re-executed child inside the namespace: run the test body now.
    InsideRunBody,
    /// The body ran (and passed) in a child inside a namespace; the caller returns.
    RanInChild,
}

/// Runs the named test of the current test binary again inside a private network namespace
/// (`unshare -n` as root, else `unshare -rn`), with `lo` up and MULTICAST enabled — DDS
/// discovery needs multicast on loopback, and the real xArm port numbers are free there.
/// Returns [`NetnsOutcome::InsideRunBody`] in the child, which then runs the body.
///
/// # Panics
/// If no namespace can be made (the message says why), or the child fails.
pub fn run_in_private_netns(test_name: &str) -> NetnsOutcome {
    if std::env::var_os(NETNS_MARKER).is_some() {
        return NetnsOutcome::InsideRunBody;
    }
    let exe = std::env::current_exe().expect("current test executable");
    let root = running_as_root();
    let unshare_args: &[&str] = if root { &["-n"] } else { &["-rn"] };
    let script = r#"ip link set lo up && ip link set lo multicast on && exec "$0" "$@""#;
    let output = Command::new("unshare")
        .args(unshare_args)
        .args(["sh", "-c", script])
        .arg(&exe)
        .args([test_name, "--exact", "--nocapture", "--test-threads", "1"])
        .env(NETNS_MARKER, "1")
        .output()
        .unwrap_or_else(|e| {
            panic!("cannot run unshare (util-linux) for a private network namespace: {e}")
        });
    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    print!("{stdout}");
    eprint!("{stderr}");
    assert!(
        output.status.success(),
        "test {test_name} inside a private network namespace failed ({})",
        output.status
    );
    assert!(
        stdout.contains("1 passed"),
        "test {test_name} did not run inside the namespace (filter matched nothing?)"
    );
    NetnsOutcome::RanInChild
}

fn running_as_root() -> bool {
    Command::new("id")
        .arg("-u")
        .output()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim() == "0")
        .unwrap_or(false)
}

/// Polls `f` every 10 ms until it returns `Some` or `timeout` passes.
pub fn wait_for<T>(timeout: Duration, mut f: impl FnMut() -> Option<T>) -> Option<T> {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(v) = f() {
            return Some(v);
        }
        if Instant::now() >= deadline {
            return None;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}
