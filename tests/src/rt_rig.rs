//! The runtime rig of the system tests: the real `rt-core run` binary (on its in-process
//! simulated arm, or on `xarm-sim` over TCP), a detector thread publishing detections at
//! 30 Hz over real iceoryx2, policy blobs published in place, and subscribers to
//! `TwinVerdict`, `RetrainRequest` and `RobotState`. Each rig has its own service prefix.
//!
//! The "good" policy is a real `PolicyBlob`: a ReLU MLP whose weights encode the task's
//! straight-line reach (so it passes the lookahead in a free scene and fails it when a tall
//! box stands in the way).

#![allow(missing_docs, clippy::missing_panics_doc, clippy::unwrap_used)]

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::{ChildGuard, bin_path, repo_root, unique_prefix};
use iceoryx2::prelude::*;
use shm_schemas::services::create_node;
use shm_schemas::{
    Activation, DetectedObject, DetectionFrame, ObjectClass, PolicyBlob, PolicyBlobBuilder,
    RetrainRequest, RobotState, TwinVerdict, loan_zeroed, open_publisher, open_subscriber,
};
use twin::{ACT_DIM, OBS_DIM, TaskConfig};

pub const GOAL_M: [f32; 3] = [0.40, 0.15, 0.025];

/// Obstacles the detector publishes: (centre, size), m.
pub type Obstacles = Arc<Mutex<Vec<([f32; 3], [f32; 3])>>>;
pub const GOAL_SIZE_M: f32 = 0.05;

pub fn task() -> TaskConfig {
    TaskConfig::load(&repo_root().join("assets/task.toml")).expect("task.toml")
}

/// The straight-line reach as an MLP: 17 → 6 (ReLU) → 3 (identity), exact.
pub fn straight_line_blob(id: u64, task: &TaskConfig, z_offset_m: f64) -> PolicyBlobBuilder {
    let s = task.action.scale_m as f32;
    let target_z = (f64::from(GOAL_M[2])
        + f64::from(GOAL_SIZE_M) / 2.0
        + task.success.goal_hover_m
        + z_offset_m) as f32;
    let mut w1 = vec![0.0f32; 6 * OBS_DIM];
    let mut b1 = vec![0.0f32; 6];
    // rows: +dx, -dx, +dy, -dy, +dz, -dz (d = (target - tcp) / scale)
    for (k, (goal_idx, tcp_idx)) in [(Some(1), 3), (Some(2), 4), (None, 5)]
        .into_iter()
        .enumerate()
    {
        for (sign, row) in [(1.0f32, 2 * k), (-1.0, 2 * k + 1)] {
            if let Some(g) = goal_idx {
                w1[row * OBS_DIM + g] = sign / s;
            } else {
                b1[row] = sign * target_z / s;
            }
            w1[row * OBS_DIM + tcp_idx] = -sign / s;
        }
    }
    let mut w2 = vec![0.0f32; ACT_DIM * 6];
    for k in 0..3 {
        w2[k * 6 + 2 * k] = 1.0;
        w2[k * 6 + 2 * k + 1] = -1.0;
    }
    PolicyBlobBuilder::new(id, task.hash())
        .activation(Activation::Relu)
        .output_activation(Activation::Identity)
        .layer(OBS_DIM, 6, &w1, &b1)
        .layer(6, ACT_DIM, &w2, &[0.0; ACT_DIM])
}

pub struct Rig {
    pub rt: ChildGuard,
    pub node: Node<ipc::Service>,
    pub policies: iceoryx2::port::publisher::Publisher<ipc::Service, PolicyBlob, ()>,
    pub verdicts: iceoryx2::port::subscriber::Subscriber<ipc::Service, TwinVerdict, ()>,
    pub retrains: iceoryx2::port::subscriber::Subscriber<ipc::Service, RetrainRequest, ()>,
    pub states: iceoryx2::port::subscriber::Subscriber<ipc::Service, RobotState, ()>,
    pub obstacles: Obstacles,
    pub stop: Arc<AtomicBool>,
    pub detector: Option<std::thread::JoinHandle<()>>,
    pub log: PathBuf,
    pub seen: Vec<(Instant, Seen)>,
    /// The test's iceoryx2 service prefix.
    pub prefix: String,
}

#[derive(Debug, Clone, Copy)]
#[allow(clippy::large_enum_variant)] // a test log of fixed-size samples
pub enum Seen {
    Verdict(TwinVerdict),
    Retrain(RetrainRequest),
    State(RobotState),
}

impl Rig {
    pub fn start(test: &str) -> Self {
        Self::start_with(test, &[])
    }

    /// A rig whose `rt-core run` gets `extra` arguments (e.g. `--link xarm --robot …`).
    pub fn start_with(test: &str, extra: &[String]) -> Self {
        Self::start_with_bin(test, &bin_path("rt-core"), extra)
    }

    /// [`Rig::start_with`] with the `rt-core` binary at `rt_core` (e.g. the deploy build).
    pub fn start_with_bin(test: &str, rt_core: &std::path::Path, extra: &[String]) -> Self {
        Self::start_with_bin_stderr(test, rt_core, extra, None)
    }

    /// [`Rig::start_with_bin`] with rt-core's stderr sent to `stderr` (e.g. `/dev/full`)
    /// instead of the log file (`None`: the log file).
    pub fn start_with_bin_stderr(
        test: &str,
        rt_core: &std::path::Path,
        extra: &[String],
        stderr: Option<Stdio>,
    ) -> Self {
        let prefix = unique_prefix(test);
        let dir = std::env::temp_dir().join(&prefix);
        std::fs::create_dir_all(&dir).expect("temp dir");
        let cfg = std::fs::read_to_string(repo_root().join("assets/runtime.toml"))
            .expect("runtime.toml")
            .replace(
                "service_prefix = \"foresight\"",
                &format!("service_prefix = \"{prefix}\""),
            );
        assert!(cfg.contains(&prefix));
        let cfg_path = dir.join("runtime.toml");
        std::fs::write(&cfg_path, cfg).expect("config");
        let log = dir.join("rt-core.log");
        let log_file = std::fs::File::create(&log).expect("log");
        let (node, _) = create_node::<ipc::Service>("test_publisher").expect("node");
        // Open our ports first (the services are created with the schema attribute).
        let policies = open_publisher::<PolicyBlob, _>(&node, &prefix).expect("policy publisher");
        let verdicts = open_subscriber::<TwinVerdict, _>(&node, &prefix).expect("verdicts");
        let retrains = open_subscriber::<RetrainRequest, _>(&node, &prefix).expect("retrains");
        let states = open_subscriber::<RobotState, _>(&node, &prefix).expect("states");
        let rt = ChildGuard::spawn(
            "rt-core run",
            Command::new(rt_core)
                .arg("run")
                .arg("--config")
                .arg(&cfg_path)
                .arg("--assets")
                .arg(repo_root().join("assets"))
                .arg("--no-mlock")
                .arg("--seconds")
                .arg("120")
                .args(extra)
                .stdout(Stdio::null())
                .stderr(stderr.unwrap_or_else(|| Stdio::from(log_file))),
        );
        let obstacles: Obstacles = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let (obs, st, pfx) = (obstacles.clone(), stop.clone(), prefix.clone());
        let detector = std::thread::spawn(move || detector_loop(&obs, &st, &pfx));
        Self {
            rt,
            node,
            policies,
            verdicts,
            retrains,
            states,
            obstacles,
            stop,
            detector: Some(detector),
            log,
            seen: Vec::new(),
            prefix,
        }
    }

    /// Writes the blob in place into a loaned sample; `corrupt` flips a weight after sealing.
    pub fn publish_policy(&self, blob: &PolicyBlobBuilder, corrupt: bool) {
        let mut sample = loan_zeroed(&self.policies).expect("loan");
        blob.write_into(sample.payload_mut()).expect("write blob");
        if corrupt {
            sample.payload_mut().weights[3] += 1.0;
        }
        sample.send().expect("send policy");
    }

    pub fn pump(&mut self) {
        let now = Instant::now();
        while let Ok(Some(s)) = self.verdicts.receive() {
            self.seen.push((now, Seen::Verdict(*s.payload())));
        }
        while let Ok(Some(s)) = self.retrains.receive() {
            self.seen.push((now, Seen::Retrain(*s.payload())));
        }
        while let Ok(Some(s)) = self.states.receive() {
            self.seen.push((now, Seen::State(*s.payload())));
        }
    }

    /// Pumps until `f` finds something in what was seen, or panics with the log after `timeout`.
    pub fn wait<T>(
        &mut self,
        what: &str,
        timeout: Duration,
        f: impl Fn(&[(Instant, Seen)]) -> Option<T>,
    ) -> T {
        let deadline = Instant::now() + timeout;
        loop {
            self.pump();
            if let Some(v) = f(&self.seen) {
                return v;
            }
            if Instant::now() > deadline {
                let log = std::fs::read_to_string(&self.log).unwrap_or_default();
                let tail: String = log
                    .chars()
                    .rev()
                    .take(6000)
                    .collect::<Vec<_>>()
                    .into_iter()
                    .rev()
                    .collect();
                panic!("timed out waiting for {what}\n--- rt-core log tail ---\n{tail}");
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }

    /// Stops `rt-core run` with SIGINT and returns its log.
    pub fn finish(&mut self) -> String {
        let status = self.rt.interrupt_and_wait(Duration::from_secs(10));
        let log = std::fs::read_to_string(&self.log).unwrap_or_default();
        assert!(
            status.is_some_and(|s| s.success()),
            "rt-core run did not exit cleanly: {status:?}\n{log}"
        );
        log
    }

    pub fn last_state(&self) -> Option<RobotState> {
        self.seen.iter().rev().find_map(|(_, s)| match s {
            Seen::State(st) => Some(*st),
            _ => None,
        })
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(h) = self.detector.take() {
            let _ = h.join();
        }
        let _ = &self.node;
    }
}

pub fn verdict_for(seen: &[(Instant, Seen)], policy: u64) -> Option<(Instant, TwinVerdict)> {
    seen.iter().find_map(|(t, s)| match s {
        Seen::Verdict(v) if v.policy_id == policy => Some((*t, *v)),
        _ => None,
    })
}

pub fn first_state_with_policy(
    seen: &[(Instant, Seen)],
    policy: u64,
) -> Option<(Instant, RobotState)> {
    seen.iter().find_map(|(t, s)| match s {
        Seen::State(st) if st.active_policy_id == policy => Some((*t, *st)),
        _ => None,
    })
}

/// The rig's detector: publishes a settled frame with the goal and the current `obstacles`
/// every 33 ms under `prefix` until `stop`.
fn detector_loop(obs: &Obstacles, st: &AtomicBool, pfx: &str) {
    let (node, _) = create_node::<ipc::Service>("test_detector").expect("node");
    let detections = open_publisher::<DetectionFrame, _>(&node, pfx).expect("detection publisher");
    let mut seq = 0;
    while !st.load(Ordering::Acquire) {
        seq += 1;
        let mut frame = DetectionFrame {
            sequence: seq,
            capture_time_ns: shm_schemas::clock::monotonic_now_ns(),
            camera_id: 1,
            flags: DetectionFrame::FRAME_SETTLED,
            ..DetectionFrame::default()
        };
        frame.push(DetectedObject::new(
            1,
            ObjectClass::Goal,
            0.99,
            GOAL_M,
            [GOAL_SIZE_M; 3],
        ));
        for (i, (c, s)) in obs
            .lock()
            .map(|v| v.clone())
            .unwrap_or_default()
            .iter()
            .enumerate()
        {
            frame.push(DetectedObject::new(
                10 + i as u32,
                ObjectClass::Obstacle,
                0.9,
                *c,
                *s,
            ));
        }
        if let Ok(mut sample) = loan_zeroed(&detections) {
            *sample.payload_mut() = frame;
            let _ = sample.send();
        }
        std::thread::sleep(Duration::from_millis(33));
    }
}
