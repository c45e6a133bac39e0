//! The run's recording: every run is written to `runs/<run>/run.mcap` by the `recorder`
//! crate (a normal thread of the launcher subscribed to the run's services, never a process
//! of the real-time path), with the simulated arm's referee figures added as the launcher
//! reads them. The run folder is a rosbag2 bag: the recorder writes its `metadata.yaml`
//! beside `run.mcap` ([`recorder::bag`]), so `ros2 bag info runs/<run>` and
//! `ros2 bag play runs/<run>` open it. `--no-record` turns it off. A recording that cannot
//! start or ends badly is a note in the report, never the end of a run.

use shm_schemas::error_chain::error_chain;
use std::path::Path;

use recorder::{Recorder, RecorderConfig, RefereeClearance};

use crate::args::LaunchArgs;

/// The file name of a run's recording in its folder.
pub const RUN_MCAP: &str = "run.mcap";

/// The rosbag2 metadata beside it, which makes the run folder a bag.
pub const BAG_METADATA: &str = recorder::bag::METADATA_FILE;

/// Starts recording the run `prefix` into `<run_dir>/run.mcap` (and `<run_dir>` as a rosbag2
/// bag), unless `--no-record`. On failure the reason is pushed to `notes` and the run goes on
/// unrecorded.
pub fn start(
    args: &LaunchArgs,
    run_dir: &Path,
    prefix: &str,
    notes: &mut Vec<String>,
) -> Option<Recorder> {
    if args.no_record {
        return None;
    }
    let urdf = match std::fs::read_to_string(&args.urdf) {
        Ok(text) => text,
        Err(e) => {
            notes.push(format!(
                "not recorded: cannot read {}: {e}",
                args.urdf.display()
            ));
            return None;
        }
    };
    let mut cfg = RecorderConfig::new(run_dir.join(RUN_MCAP), prefix, urdf);
    // The run folder holds this recording alone: it is the bag.
    cfg.bag_metadata = true;
    cfg.max_bytes = args.record_max_mib.saturating_mul(1024 * 1024);
    match Recorder::start(cfg) {
        Ok(r) => Some(r),
        Err(e) => {
            notes.push(format!("not recorded: {}", error_chain(&e)));
            None
        }
    }
}

/// Closes the recording; what went wrong, if anything, becomes a note.
pub fn stop(recording: Option<Recorder>, notes: &mut Vec<String>) {
    let Some(r) = recording else { return };
    let path = r.path().display().to_string();
    match r.stop() {
        Ok(stats) if stats.limit_reached => notes.push(format!(
            "the recording {path} reached its size limit (--record-max-mib); {} message(s) after it were not recorded",
            stats.dropped_at_limit
        )),
        Ok(_) => {}
        Err(e) => notes.push(format!(
            "the recording {path} ended badly: {}",
            error_chain(&e)
        )),
    }
}

/// The referee's figures in `xarm-sim`'s status JSON (`"referee": {…}`), if present.
pub fn referee_from_status(status: &serde_json::Value) -> Option<RefereeClearance> {
    let r = status.get("referee")?;
    let text = |k: &str| r.get(k).and_then(|v| v.as_str()).unwrap_or("").to_owned();
    Some(RefereeClearance {
        contacts: r.get("contacts")?.as_u64()?,
        steps: r
            .get("steps")
            .and_then(serde_json::Value::as_u64)
            .unwrap_or(0),
        min_clearance_m: r.get("min_clearance_m").and_then(serde_json::Value::as_f64),
        min_link: text("min_link"),
        min_other: text("min_other"),
        min_scene: text("min_scene"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_referee_figures_are_read_from_the_sim_status() {
        let status = serde_json::json!({
            "collisions": 0,
            "referee": {"steps": 120, "contacts": 0, "min_clearance_m": 0.0234,
                        "min_link": "link4", "min_other": "obstacle 2", "min_scene": "tall_box"}
        });
        let r = referee_from_status(&status).unwrap();
        assert_eq!((r.contacts, r.steps), (0, 120));
        assert_eq!(r.min_clearance_m, Some(0.0234));
        assert_eq!(
            (r.min_link.as_str(), r.min_other.as_str()),
            ("link4", "obstacle 2")
        );
        let before =
            serde_json::json!({"referee": {"steps": 0, "contacts": 0, "min_clearance_m": null}});
        assert_eq!(referee_from_status(&before).unwrap().min_clearance_m, None);
        assert!(referee_from_status(&serde_json::json!({"collisions": 0})).is_none());
    }
}
