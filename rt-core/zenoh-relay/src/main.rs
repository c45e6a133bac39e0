//! `zenoh-relay`: carries retrain requests, retrain progress and policies between the robot
//! PC and a learner host over Zenoh (see the library docs and docs/components.md, "Two hosts").
//!
//! - `zenoh-relay controller --prefix P --peer tcp/GPU-BOX:7447` beside rt-core (the
//!   launcher's `foresight --learner-host` starts it);
//! - `zenoh-relay learner-host --listen tcp/0.0.0.0:7447` on the GPU box: `learner serve`
//!   plus the learner side of the relay;
//! - `zenoh-relay learner --prefix P …`: the learner side alone, beside a `learner serve`
//!   started by hand with the same prefix;
//! - `zenoh-relay keygen --out DIR`: the link's keys, once (`DIR/robot-pc` for the robot PC,
//!   `DIR/learner-host` for the GPU box; each side's `--link-keys`).

#![forbid(unsafe_code)]

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use zenoh_relay::learner_host::{LearnerArgs, LearnerChild};
use zenoh_relay::link::LinkArgs;
use zenoh_relay::relay::{self, RelayConfig};
use zenoh_relay::wire::Side;

#[derive(Debug, Parser)]
#[command(
    name = "zenoh-relay",
    version,
    about = "Carry Foresight's retraining services between the robot PC and a learner host over Zenoh"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// The robot PC's side, beside rt-core.
    Controller(SideArgs),
    /// The learner host's side, beside a `learner serve` with the same `--prefix`.
    Learner(SideArgs),
    /// The learner host: `learner serve` (supervised) plus the learner side of the relay.
    LearnerHost(LearnerHostArgs),
    /// Make the link's keys: a shared credential and one signing key per host, in
    /// `OUT/robot-pc` and `OUT/learner-host` (never overwrites).
    Keygen {
        /// Where to write the two folders.
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(Debug, clap::Args)]
struct SideArgs {
    /// iceoryx2 service prefix of this host's processes.
    #[arg(long, default_value = "")]
    prefix: String,
    /// Keep a status file here (JSON, rewritten atomically).
    #[arg(long)]
    status: Option<PathBuf>,
    /// Learner side: the task configuration the local learner trains for; requests for
    /// another task are refused.
    #[arg(long)]
    task: Option<PathBuf>,
    #[command(flatten)]
    link: LinkArgs,
}

/// The hash of a task configuration, as requests and policies carry it.
fn task_hash(path: &std::path::Path) -> Result<u64> {
    let task = twin::TaskConfig::load(path)
        .with_context(|| format!("loading the task configuration {}", path.display()))?;
    Ok(task.hash())
}

#[derive(Debug, clap::Args)]
struct LearnerHostArgs {
    /// iceoryx2 service prefix of the learner here (default: private to this process).
    #[arg(long)]
    prefix: Option<String>,
    /// Keep a status file here (JSON, rewritten atomically).
    #[arg(long)]
    status: Option<PathBuf>,
    #[command(flatten)]
    link: LinkArgs,
    #[command(flatten)]
    learner: LearnerArgs,
}

fn stop_flag() -> Result<Arc<AtomicBool>> {
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, Arc::clone(&stop))
            .context("installing signal handlers")?;
    }
    Ok(stop)
}

fn tie_to_parent() {
    if let Err(e) = shm_schemas::process_ties::stop_with_parent() {
        tracing::warn!("prctl(PR_SET_PDEATHSIG): {e}");
    }
}

fn run_side(side: Side, a: SideArgs) -> Result<()> {
    // The keys before anything else: no unauthenticated start.
    a.link
        .load_keys(side)
        .with_context(|| format!("zenoh-relay {}", side_name(side)))?;
    tie_to_parent();
    let stop = stop_flag()?;
    let cfg = RelayConfig {
        side,
        prefix: a.prefix,
        link: a.link,
        status_path: a.status,
        task_hash: a.task.as_deref().map(task_hash).transpose()?,
    };
    relay::run(cfg, &stop).context("zenoh-relay")?;
    Ok(())
}

fn side_name(side: Side) -> &'static str {
    match side {
        Side::Controller => "controller",
        Side::Learner => "learner",
    }
}

fn run_learner_host(a: LearnerHostArgs) -> Result<()> {
    // The keys before the learner starts: no unauthenticated start.
    a.link
        .load_keys(Side::Learner)
        .context("zenoh-relay learner-host")?;
    let hash = task_hash(&a.learner.task)?;
    let stop = stop_flag()?;
    let prefix = a
        .prefix
        .unwrap_or_else(|| format!("fs-learner-host-{}", std::process::id()));
    let program = a.learner.learner_bin().context("locating `learner`")?;
    let mut learner = LearnerChild::start(program, a.learner.serve_args(&prefix))
        .context("starting learner serve")?;
    let cfg = RelayConfig {
        side: Side::Learner,
        prefix,
        link: a.link,
        status_path: a.status,
        task_hash: Some(hash),
    };
    let relay_stop = Arc::clone(&stop);
    let relay_thread = std::thread::Builder::new()
        .name("relay".into())
        .spawn(move || relay::run(cfg, &relay_stop))
        .context("starting the relay thread")?;
    while !stop.load(Ordering::Relaxed) && !relay_thread.is_finished() {
        learner.poll();
        std::thread::sleep(Duration::from_millis(100));
    }
    stop.store(true, Ordering::Relaxed);
    learner.stop();
    match relay_thread.join() {
        Ok(r) => {
            r.context("zenoh-relay")?;
        }
        Err(_) => anyhow::bail!("the relay thread panicked"),
    }
    Ok(())
}

fn keygen(out: &std::path::Path) -> Result<()> {
    let g = zenoh_relay::keys::generate(out).context("zenoh-relay keygen")?;
    println!(
        "wrote the link keys:\n  {}  (robot PC: foresight --learner-host --link-keys {0})\n    this host's key {}\n  {}  (learner host: zenoh-relay learner-host --link-keys {2}; make learner-host LINK_KEYS=…)\n    this host's key {}\nCopy each folder to its host only (it holds that host's secret key and the link credential; mode 0600).",
        g.robot_pc.display(),
        g.controller_key,
        g.learner_host.display(),
        g.learner_key
    );
    Ok(())
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env()
                .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info,zenoh=warn")),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().cmd {
        Cmd::Controller(a) => run_side(Side::Controller, a),
        Cmd::Learner(a) => run_side(Side::Learner, a),
        Cmd::LearnerHost(a) => run_learner_host(a),
        Cmd::Keygen { out } => keygen(&out),
    }
}
