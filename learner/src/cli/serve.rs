//! `learner serve`: the retraining service (see [`learner::service`]): the flags of a
//! retraining ([`RetrainFlags`], which `learner retrain` shares) plus the service's own.

use anyhow::Result;
use learner::retrain::RetrainFlags;
use learner::service::{self, ServiceConfig};

/// Arguments of `learner serve`.
#[derive(Debug, Clone, clap::Args)]
pub struct ServeArgs {
    /// Service-name prefix (unique per run/test).
    #[arg(long, default_value = "")]
    pub prefix: String,
    /// Exit after answering this many requests (0: serve forever).
    #[arg(long, default_value_t = 0, allow_negative_numbers = true)]
    pub max_requests: u64,
    /// Hold each retrained policy this long before publishing it, s: a test aid that makes
    /// the learner as slow as on a slower machine (`foresight --learner-delay-s`).
    #[arg(long, default_value_t = 0.0, value_parser = shm_schemas::cli_bounds::f64_within(0.0, 600.0), allow_negative_numbers = true)]
    pub publish_delay_s: f64,
    /// The checkpoint, task, output folder and each retraining's settings.
    #[command(flatten)]
    pub retrain: RetrainFlags,
}

impl ServeArgs {
    /// The service's set-up.
    pub fn service_config(&self) -> ServiceConfig {
        let r = &self.retrain;
        ServiceConfig {
            checkpoint: r.checkpoint.clone(),
            prefix: self.prefix.clone(),
            task: r.task.clone(),
            out: r.out.clone(),
            max_requests: self.max_requests,
            retrain: r.settings(),
            feasibility: r.feasibility(),
            publish_delay_s: self.publish_delay_s,
        }
    }
}

/// Runs `learner serve` (one torch thread; rollouts use the checkpoint's worker threads).
///
/// # Errors
/// Set-up failures of the service (task, checkpoint, iceoryx2).
pub fn run(args: ServeArgs, device: tch::Device) -> Result<()> {
    tch::set_num_threads(1);
    service::serve(&args.service_config(), device)?;
    Ok(())
}
