//! `rt-core ack --robot HOST[:PORT] [--clears N]`: the operator's acknowledgement of a
//! protective stop, sent to the one rt-core that owns that arm, naming the stop it clears.
//!
//! The owner is read from the arm's lock ([`xarm::owner::owner_of`]: the pid the kernel's
//! lock table gives for the lock file of the controller's canonical address) and checked
//! to be an `rt-core` process that owns the channel's socket beside the lock
//! ([`rt_core::operator_ack`]). The channel tells which stop is latched; the operator
//! confirms it by its number (typed at the terminal, or `--clears N` in a script they
//! answer for), and rt-core clears that stop only if it is still the one latched and the
//! peer's user is one of its operators. An arm that no process owns, or a channel that
//! cannot be trusted, gets nothing (exit status 1).

use std::io::{BufRead, IsTerminal, Write};
use std::os::unix::fs::MetadataExt;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use rt_core::operator_ack::{self, AckOutcome};
use shm_schemas::cli_bounds::int_within;
use xarm::config::XArmConfig;
use xarm::owner::{lock_path, owner_of};

/// Arguments of `ack`.
#[derive(Debug, Args)]
pub struct AckArgs {
    /// The controller whose protective stop is acknowledged, as given to `rt-core run
    /// --robot` (any spelling of the same address).
    #[arg(long)]
    robot: String,
    /// The number of the stop you clear, as `rt-core ack` shows it ("stop #N"): for
    /// scripts the operator answers for. Without it, the stop is shown and its number must
    /// be typed at the terminal.
    #[arg(long, value_parser = int_within(1u64, u64::MAX >> 8), allow_negative_numbers = true)]
    clears: Option<u64>,
}

/// Sends the acknowledgement.
pub fn run(args: AckArgs) -> ExitCode {
    match acknowledge(&args) {
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

/// The user id a process runs as (the real one, from `/proc`).
fn process_uid(pid: u32) -> Option<u32> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("Uid:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|euid| euid.parse().ok())
}

fn acknowledge(args: &AckArgs) -> anyhow::Result<String> {
    let robot = args.robot.as_str();
    let cfg = XArmConfig::from_addr(robot);
    let owner = owner_of(&cfg)?;
    let comm = std::fs::read_to_string(format!("/proc/{}/comm", owner.pid)).unwrap_or_default();
    if comm.trim() != "rt-core" {
        anyhow::bail!(
            "the xArm at {robot} is owned by pid {} ({:?}), not an rt-core: no acknowledgement sent",
            owner.pid,
            comm.trim()
        );
    }
    let socket = operator_ack::socket_path(&lock_path(&cfg)?);
    let meta = std::fs::symlink_metadata(&socket).with_context(|| {
        format!(
            "the owner (rt-core pid {}) has no acknowledgement channel at {} (an rt-core older \
             than the channel, or not on an xArm link)",
            owner.pid,
            socket.display()
        )
    })?;
    // The socket must be the owner's: anything another user put there is not rt-core.
    let owner_uid = process_uid(owner.pid);
    if owner_uid != Some(meta.uid()) {
        anyhow::bail!(
            "{} belongs to uid {}, but the arm's owner (pid {}) runs as {:?}: not its channel, \
             no acknowledgement sent",
            socket.display(),
            meta.uid(),
            owner.pid,
            owner_uid
        );
    }
    let Some(stop) = operator_ack::query(&socket)? else {
        anyhow::bail!(
            "no protective stop is latched on the xArm at {robot} (rt-core pid {}): nothing to acknowledge",
            owner.pid
        );
    };
    println!(
        "latched on the xArm at {robot} (rt-core pid {}): {stop}",
        owner.pid
    );
    let named = match args.clears {
        Some(n) => n,
        None if std::io::stdin().is_terminal() => {
            print!(
                "Check the arm and its surroundings. Type {} and Enter to clear {stop}: ",
                stop.seq
            );
            std::io::stdout().flush()?;
            let mut line = String::new();
            std::io::stdin().lock().read_line(&mut line)?;
            line.trim().parse().unwrap_or(0)
        }
        None => anyhow::bail!(
            "name the stop you clear: --clears {} (stdin is not a terminal to confirm at)",
            stop.seq
        ),
    };
    if named != stop.seq {
        anyhow::bail!("you named stop #{named}, but {stop} is latched: nothing acknowledged");
    }
    match operator_ack::acknowledge(&socket, stop)? {
        AckOutcome::Cleared => Ok(format!(
            "cleared {stop} on the xArm at {robot} (rt-core pid {}); motion resumes with the next checked plan",
            owner.pid
        )),
        AckOutcome::NotCleared(why) => anyhow::bail!("{stop} not cleared: {why}"),
    }
}
