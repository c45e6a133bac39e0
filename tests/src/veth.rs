//! Two hosts on one machine: two network namespaces joined by a veth pair (`ip netns`, as
//! root), removed on drop. Shared memory is common to both: processes on the two sides use
//! different iceoryx2 prefixes so that the network is the only way across.

use std::path::Path;
use std::process::Command;

use crate::repo_root;

/// Runs `ip` with `args`.
///
/// # Errors
/// `ip` cannot run or fails (the message has its stderr).
pub fn ip(args: &[&str]) -> Result<(), String> {
    let out = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip {}: {e}", args.join(" ")))?;
    if out.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        ))
    }
}

/// Two namespaces joined by a veth pair, removed on drop.
pub struct TwoHosts {
    /// The robot PC's namespace.
    pub robot_ns: String,
    /// The learner host's namespace.
    pub learner_ns: String,
    robot_if: String,
    /// The learner host's address on the veth (the robot side's is `.1`).
    pub learner_addr: String,
}

impl TwoHosts {
    /// Makes them, or says why not (then a test is skipped). `tag` (a few characters)
    /// keeps two sets of one process apart.
    ///
    /// # Errors
    /// What `ip` said.
    pub fn make(tag: &str) -> Result<Self, String> {
        let id = std::process::id() % 100_000;
        let h = Self {
            robot_ns: format!("fs-robot-{tag}-{id}"),
            learner_ns: format!("fs-gpu-{tag}-{id}"),
            robot_if: format!("fsr{tag}{id}"),
            learner_addr: format!("10.231.{}.2", id % 250),
        };
        let learner_if = format!("fsl{tag}{id}");
        let robot_addr = format!("10.231.{}.1/24", id % 250);
        let learner_cidr = format!("{}/24", h.learner_addr);
        ip(&["netns", "add", &h.robot_ns])?;
        // From here on, drop removes what was made.
        ip(&["netns", "add", &h.learner_ns])?;
        ip(&[
            "link",
            "add",
            &h.robot_if,
            "type",
            "veth",
            "peer",
            "name",
            &learner_if,
        ])?;
        ip(&["link", "set", &h.robot_if, "netns", &h.robot_ns])?;
        ip(&["link", "set", &learner_if, "netns", &h.learner_ns])?;
        for (ns, dev, addr) in [
            (&h.robot_ns, &h.robot_if, &robot_addr),
            (&h.learner_ns, &learner_if, &learner_cidr),
        ] {
            ip(&["-n", ns, "addr", "add", addr, "dev", dev])?;
            ip(&["-n", ns, "link", "set", dev, "up"])?;
            ip(&["-n", ns, "link", "set", "lo", "up"])?;
        }
        Ok(h)
    }

    /// `program` run in namespace `ns`, from the repository root.
    pub fn exec(&self, ns: &str, program: &Path) -> Command {
        let mut c = Command::new("ip");
        c.args(["netns", "exec", ns]).arg(program);
        c.current_dir(repo_root());
        c
    }

    /// Takes the robot side's link down (`up = false`) or up again.
    ///
    /// # Panics
    /// If `ip` fails.
    pub fn link(&self, up: bool) {
        ip(&[
            "-n",
            &self.robot_ns,
            "link",
            "set",
            &self.robot_if,
            if up { "up" } else { "down" },
        ])
        .expect("switching the veth link");
    }
}

impl Drop for TwoHosts {
    fn drop(&mut self) {
        // Deleting a namespace deletes the veth pair with it.
        let _ = ip(&["netns", "del", &self.robot_ns]);
        let _ = ip(&["netns", "del", &self.learner_ns]);
    }
}
