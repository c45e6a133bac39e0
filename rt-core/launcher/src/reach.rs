//! `foresight reach --goal X,Y`: drives the ROS 2 `Reach` action (`/foresight/reach`,
//! served by the `ros-bridge` of a run started with `foresight --ros --goal-source action`)
//! as a plain DDS client, for people without ROS: prints the feedback and the result; the
//! exit status says the outcome ([`exit_code`]). SIGINT cancels the goal (and waits for the
//! arm to come to rest).

use std::net::IpAddr;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use ros_bridge::reach_client::{ReachClientOptions, ReachEnd, ReachEvent, reach};
use ros_bridge::reach_msgs::{ReachGoal, ReachOutcome};
use shm_schemas::cli_bounds::{f64_within, int_within};

/// Command line of `foresight reach`.
#[derive(Debug, Clone, clap::Parser)]
#[command(
    name = "foresight reach",
    about = "Send the arm a goal on the table through the ROS 2 Reach action (needs a run \
             started with `foresight --ros --goal-source action`)"
)]
pub struct ReachArgs {
    /// Target on the table, `X,Y` in the base (world) frame, m.
    #[arg(long, value_parser = parse_xy, allow_negative_numbers = true)]
    pub goal: [f64; 2],
    /// TCP height above the table over the target, m (0 = the task's default: as over a
    /// goal cube on the table). Otherwise 0.05..=0.5.
    #[arg(long, default_value_t = 0.0, value_parser = f64_within(0.0, 0.5), allow_negative_numbers = true)]
    pub approach_height_m: f64,
    /// Give up after this long from acceptance (the goal ends `stopped`), s; 0 = no deadline.
    #[arg(long, default_value_t = 0.0, value_parser = f64_within(0.0, 86_400.0), allow_negative_numbers = true)]
    pub deadline_s: f64,
    /// Cancel the goal this long after it was accepted, s (0 = never; SIGINT cancels too).
    #[arg(long, default_value_t = 0.0, value_parser = f64_within(0.0, 86_400.0), allow_negative_numbers = true)]
    pub cancel_after_s: f64,
    /// Give up when no action server answers within this long, s.
    #[arg(long, default_value_t = 30.0, value_parser = f64_within(1.0, 3600.0), allow_negative_numbers = true)]
    pub connect_timeout_s: f64,
    /// DDS domain id (defaults to $ROS_DOMAIN_ID, else 0).
    #[arg(long, env = "ROS_DOMAIN_ID", default_value_t = 0, value_parser = int_within(0u16, 232), allow_negative_numbers = true)]
    pub domain_id: u16,
    /// Interface address DDS may use (repeatable). Default: loopback only, like the bridge.
    #[arg(long = "ros-network", default_value = "127.0.0.1")]
    pub networks: Vec<IpAddr>,
}

/// `X,Y` as two finite numbers within ±10 m (the server checks the real bounds).
fn parse_xy(text: &str) -> Result<[f64; 2], String> {
    let (x, y) = text
        .split_once(',')
        .ok_or_else(|| format!("--goal wants X,Y (metres), got {text:?}"))?;
    let num = |v: &str, axis: &str| -> Result<f64, String> {
        let n: f64 = v
            .trim()
            .parse()
            .map_err(|_| format!("--goal: {axis} = {v:?} is not a number"))?;
        if n.is_finite() && n.abs() <= 10.0 {
            Ok(n)
        } else {
            Err(format!(
                "--goal: {axis} = {v} must be finite and within ±10 m"
            ))
        }
    };
    Ok([num(x, "X")?, num(y, "Y")?])
}

/// The exit status of an outcome: 0 reached, 3 infeasible, 4 stopped, 5 cancelled,
/// 6 pre-empted, 7 refused, 8 unknown (2 is `foresight`'s error status: no server).
pub fn exit_code(end: &ReachEnd) -> u8 {
    match end.result.outcome() {
        Some(ReachOutcome::Reached) => 0,
        Some(ReachOutcome::Infeasible) => 3,
        Some(ReachOutcome::Stopped) => 4,
        Some(ReachOutcome::Cancelled) => 5,
        Some(ReachOutcome::Preempted) => 6,
        Some(ReachOutcome::Refused) => 7,
        None => 8,
    }
}

/// Runs `foresight reach`; returns the exit status.
///
/// # Errors
/// DDS cannot be set up, or no server answered.
pub fn run_reach(args: &ReachArgs) -> anyhow::Result<u8> {
    let interrupt = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGINT, signal_hook::consts::SIGTERM] {
        signal_hook::flag::register(sig, interrupt.clone())?;
    }
    let goal = ReachGoal {
        x_m: args.goal[0],
        y_m: args.goal[1],
        approach_height_m: args.approach_height_m,
        deadline_s: args.deadline_s,
    };
    let opts = ReachClientOptions {
        domain_id: args.domain_id,
        networks: args.networks.clone(),
        connect_timeout: Duration::from_secs_f64(args.connect_timeout_s),
        cancel_after: (args.cancel_after_s > 0.0)
            .then(|| Duration::from_secs_f64(args.cancel_after_s)),
    };
    println!(
        "reach: goal ({:.3}, {:.3}) m, approach height {} m, deadline {} s",
        goal.x_m,
        goal.y_m,
        if goal.approach_height_m == 0.0 {
            "default".to_owned()
        } else {
            format!("{:.3}", goal.approach_height_m)
        },
        if goal.deadline_s == 0.0 {
            "none".to_owned()
        } else {
            goal.deadline_s.to_string()
        }
    );
    let mut last_phase = String::new();
    let end = reach(goal, &opts, &interrupt, |event| match event {
        ReachEvent::Accepted => println!("reach: accepted"),
        ReachEvent::Rejected => println!("reach: rejected"),
        ReachEvent::Cancelling => println!("reach: cancelling"),
        ReachEvent::Feedback(f) => {
            // One line per phase change, and the distance now and then.
            if f.phase != last_phase {
                println!(
                    "feedback: phase {}, executor {}, {:.3} m to go; {}",
                    f.phase, f.executor, f.distance_m, f.verdict
                );
                last_phase.clone_from(&f.phase);
            }
        }
    })?;
    let outcome = end.result.outcome().map_or("unknown", ReachOutcome::name);
    println!(
        "result: {outcome}: {} (status {:?}, {:.3} m from the target)",
        end.result.reason, end.status, end.result.distance_m
    );
    Ok(exit_code(&end))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[test]
    fn the_goal_is_two_finite_numbers() {
        let a = ReachArgs::try_parse_from(["reach", "--goal", "0.4,-0.1"]).unwrap();
        assert_eq!(a.goal, [0.4, -0.1]);
        for bad in ["0.4", "NaN,0", "0.4,inf", "x,1", "20,0"] {
            let e = ReachArgs::try_parse_from(["reach", "--goal", bad]).unwrap_err();
            assert!(e.to_string().contains("--goal"), "{bad}: {e}");
        }
        assert!(
            ReachArgs::try_parse_from(["reach", "--goal", "0.4,0", "--deadline-s", "-1"]).is_err()
        );
    }
}
