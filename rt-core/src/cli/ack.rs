//! `rt-core ack --robot HOST[:PORT]`: the operator's acknowledgement of a protective stop,
//! sent to the one rt-core that owns that arm and to no other process.
//!
//! The owner is read from the arm's lock ([`xarm::owner::owner_of`]: the pid the kernel's
//! lock table gives for the lock file of the controller's canonical address), checked to be
//! an `rt-core` process, and sent SIGUSR1, the runtime's acknowledgement. An arm that no
//! process owns, or whose owner cannot be named for sure, gets nothing (exit status 1).
//! rt-core takes the acknowledgement only while a protective stop is latched, the link is
//! up and the arm at rest; one given earlier is dropped, not kept.

use std::process::ExitCode;

use clap::Args;
use xarm::config::XArmConfig;
use xarm::owner::owner_of;

/// Arguments of `ack`.
#[derive(Debug, Args)]
pub struct AckArgs {
    /// The controller whose protective stop is acknowledged, as given to `rt-core run
    /// --robot` (any spelling of the same address).
    #[arg(long)]
    robot: String,
}

/// Sends the acknowledgement.
pub fn run(args: AckArgs) -> ExitCode {
    match acknowledge(&args.robot) {
        Ok(msg) => {
            println!("{msg}");
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("rt-core ack: {e:#}");
            ExitCode::FAILURE
        }
    }
}

fn acknowledge(robot: &str) -> anyhow::Result<String> {
    let owner = owner_of(&XArmConfig::from_addr(robot))?;
    let comm = std::fs::read_to_string(format!("/proc/{}/comm", owner.pid)).unwrap_or_default();
    if comm.trim() != "rt-core" {
        anyhow::bail!(
            "the xArm at {robot} is owned by pid {} ({:?}), not an rt-core: no acknowledgement sent",
            owner.pid,
            comm.trim()
        );
    }
    let pid = libc::pid_t::try_from(owner.pid)?;
    // The pid is the owner the kernel's lock table names, checked to be an rt-core above.
    if let Err(e) = shm_schemas::process_ties::signal_process(owner.pid, libc::SIGUSR1) {
        anyhow::bail!("sending SIGUSR1 to rt-core pid {pid}: {e}");
    }
    Ok(format!(
        "acknowledgement sent to rt-core pid {pid}, the owner of the xArm at {robot} ({})",
        owner.addr
    ))
}
