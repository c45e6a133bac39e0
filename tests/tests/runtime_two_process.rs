//! Two processes over real iceoryx2 shared memory: this test publishes detections (30 Hz)
//! and policy blobs, the real `rt-core run` binary runs the twin thread and the control
//! cycle on the in-process simulated arm, and the test watches `TwinVerdict`,
//! `RetrainRequest` and `RobotState`. Each test has its own service prefix.
//!
//! The "good" policy is a real `PolicyBlob`: a ReLU MLP whose weights encode the task's
//! straight-line reach (so it passes the lookahead in a free scene and fails it when a tall
//! box stands in the way).

use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use foresight_tests::{ChildGuard, bin_path, repo_root, unique_prefix};
use iceoryx2::prelude::*;
use shm_schemas::services::create_node;
use shm_schemas::{
    Activation, DetectedObject, DetectionFrame, ObjectClass, PolicyBlob, PolicyBlobBuilder,
    RetrainRequest, RobotState, TwinVerdict, loan_zeroed, open_publisher, open_subscriber,
};
use twin::{ACT_DIM, OBS_DIM, TaskConfig};

const GOAL_M: [f32; 3] = [0.40, 0.15, 0.025];

/// Obstacles the detector publishes: (centre, size), m.
type Obstacles = Arc<Mutex<Vec<([f32; 3], [f32; 3])>>>;
const GOAL_SIZE_M: f32 = 0.05;

fn task() -> TaskConfig {
    TaskConfig::load(&repo_root().join("assets/task.toml")).expect("task.toml")
}

/// The straight-line reach as an MLP: 17 → 6 (ReLU) → 3 (identity), exact.
fn straight_line_blob(id: u64, task: &TaskConfig, z_offset_m: f64) -> PolicyBlobBuilder {
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

struct Rig {
    rt: ChildGuard,
    node: Node<ipc::Service>,
    policies: iceoryx2::port::publisher::Publisher<ipc::Service, PolicyBlob, ()>,
    verdicts: iceoryx2::port::subscriber::Subscriber<ipc::Service, TwinVerdict, ()>,
    retrains: iceoryx2::port::subscriber::Subscriber<ipc::Service, RetrainRequest, ()>,
    states: iceoryx2::port::subscriber::Subscriber<ipc::Service, RobotState, ()>,
    obstacles: Obstacles,
    stop: Arc<AtomicBool>,
    detector: Option<std::thread::JoinHandle<()>>,
    log: PathBuf,
    seen: Vec<(Instant, Seen)>,
}

#[derive(Debug, Clone, Copy)]
#[allow(clippy::large_enum_variant)] // a test log of fixed-size samples
enum Seen {
    Verdict(TwinVerdict),
    Retrain(RetrainRequest),
    State(RobotState),
}

impl Rig {
    fn start(test: &str) -> Self {
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
            Command::new(bin_path("rt-core"))
                .arg("run")
                .arg("--config")
                .arg(&cfg_path)
                .arg("--assets")
                .arg(repo_root().join("assets"))
                .arg("--no-mlock")
                .arg("--seconds")
                .arg("120")
                .stdout(Stdio::null())
                .stderr(Stdio::from(log_file)),
        );
        let obstacles: Obstacles = Arc::new(Mutex::new(Vec::new()));
        let stop = Arc::new(AtomicBool::new(false));
        let (obs, st, pfx) = (obstacles.clone(), stop.clone(), prefix.clone());
        let detector = std::thread::spawn(move || {
            let (node, _) = create_node::<ipc::Service>("test_detector").expect("node");
            let detections =
                open_publisher::<DetectionFrame, _>(&node, &pfx).expect("detection publisher");
            let mut seq = 0;
            while !st.load(Ordering::Acquire) {
                seq += 1;
                let mut frame = DetectionFrame {
                    sequence: seq,
                    capture_time_ns: rt_core::rt::rt_setup::monotonic_now_ns(),
                    camera_id: 1,
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
        });
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
        }
    }

    /// Writes the blob in place into a loaned sample; `corrupt` flips a weight after sealing.
    fn publish_policy(&self, blob: &PolicyBlobBuilder, corrupt: bool) {
        let mut sample = loan_zeroed(&self.policies).expect("loan");
        blob.write_into(sample.payload_mut()).expect("write blob");
        if corrupt {
            sample.payload_mut().weights[3] += 1.0;
        }
        sample.send().expect("send policy");
    }

    fn pump(&mut self) {
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
    fn wait<T>(
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
    fn finish(&mut self) -> String {
        let status = self.rt.interrupt_and_wait(Duration::from_secs(10));
        let log = std::fs::read_to_string(&self.log).unwrap_or_default();
        assert!(
            status.is_some_and(|s| s.success()),
            "rt-core run did not exit cleanly: {status:?}\n{log}"
        );
        log
    }

    fn last_state(&self) -> Option<RobotState> {
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

fn verdict_for(seen: &[(Instant, Seen)], policy: u64) -> Option<(Instant, TwinVerdict)> {
    seen.iter().find_map(|(t, s)| match s {
        Seen::Verdict(v) if v.policy_id == policy => Some((*t, *v)),
        _ => None,
    })
}

fn first_state_with_policy(seen: &[(Instant, Seen)], policy: u64) -> Option<(Instant, RobotState)> {
    seen.iter().find_map(|(t, s)| match s {
        Seen::State(st) if st.active_policy_id == policy => Some((*t, *st)),
        _ => None,
    })
}

#[test]
fn bad_blobs_are_rejected_while_the_loop_runs_and_hot_swaps_wait_for_a_passing_lookahead() {
    let task = task();
    let mut rig = Rig::start("rt_swap");
    rig.wait("the first robot state", Duration::from_secs(20), |s| {
        s.iter()
            .any(|(_, x)| matches!(x, Seen::State(_)))
            .then_some(())
    });

    // Policy 1 (straight line): passes, its plan reaches the arm.
    rig.publish_policy(&straight_line_blob(1, &task, 0.0), false);
    let (_, v1) = rig.wait("verdict of policy 1", Duration::from_secs(10), |s| {
        verdict_for(s, 1)
    });
    assert!(
        v1.is_task_ok() && v1.is_safe() && v1.is_plan_approved(),
        "{v1:?}"
    );
    rig.wait("policy 1 driving the arm", Duration::from_secs(10), |s| {
        first_state_with_policy(s, 1)
    });

    // A corrupted blob (bad checksum) and one for another task: rejected, no verdict, the
    // loop keeps running and policy 1 stays.
    rig.publish_policy(&straight_line_blob(2, &task, 0.0), true);
    let other_task = PolicyBlobBuilder::random(3, task.hash() ^ 1, OBS_DIM, &[8], ACT_DIM, 3);
    rig.publish_policy(&other_task, false);
    let cycles_before = rig.last_state().map_or(0, |s| s.cycle_count);
    std::thread::sleep(Duration::from_millis(700));
    rig.pump();
    assert!(verdict_for(&rig.seen, 2).is_none() && verdict_for(&rig.seen, 3).is_none());
    let st = rig.last_state().expect("state");
    assert!(
        st.cycle_count > cycles_before + 50,
        "the loop stalled: {} -> {}",
        cycles_before,
        st.cycle_count
    );
    assert_eq!(st.active_policy_id, 1);

    // Policy 4 does nothing (zero output): its lookahead fails (timeout), a retrain is
    // requested, and it never reaches the arm.
    let idle = PolicyBlobBuilder::new(4, task.hash())
        .activation(Activation::Relu)
        .output_activation(Activation::Identity)
        .layer(OBS_DIM, 2, &[0.0; 2 * OBS_DIM], &[0.0; 2])
        .layer(2, ACT_DIM, &[0.0; 2 * ACT_DIM], &[0.0; ACT_DIM]);
    rig.publish_policy(&idle, false);
    let (_, v4) = rig.wait("verdict of policy 4", Duration::from_secs(10), |s| {
        verdict_for(s, 4)
    });
    assert!(!v4.is_task_ok() && !v4.is_plan_approved(), "{v4:?}");
    rig.wait(
        "retrain request for policy 4",
        Duration::from_secs(5),
        |s| {
            s.iter().find_map(|(_, x)| match x {
                Seen::Retrain(r) if r.failed_policy_id == 4 => Some(()),
                _ => None,
            })
        },
    );

    // Policy 5 (straight line to a point 1.2 cm higher, within the success tolerance): a different plan, approved by its own
    // lookahead before the arm executes it.
    rig.publish_policy(&straight_line_blob(5, &task, 0.012), false);
    let (t_v5, v5) = rig.wait("verdict of policy 5", Duration::from_secs(10), |s| {
        verdict_for(s, 5)
    });
    assert!(v5.is_plan_approved(), "{v5:?}");
    let (t_s5, _) = rig.wait("policy 5 driving the arm", Duration::from_secs(10), |s| {
        first_state_with_policy(s, 5)
    });
    assert!(t_v5 <= t_s5, "policy 5 reached the arm before its verdict");
    assert!(
        first_state_with_policy(&rig.seen, 4).is_none(),
        "the failed policy reached the arm"
    );
    let st = rig.last_state().expect("state");
    assert_eq!(st.controlled_stop, 0, "{st:?}");
}

#[test]
fn a_scene_change_that_makes_the_plan_unsafe_stops_the_arm_and_requests_retraining() {
    let task = task();
    let mut rig = Rig::start("rt_unsafe");
    rig.wait("the first robot state", Duration::from_secs(20), |s| {
        s.iter()
            .any(|(_, x)| matches!(x, Seen::State(_)))
            .then_some(())
    });
    let home_q = rig.last_state().expect("state").joints_rad;
    rig.publish_policy(&straight_line_blob(1, &task, 0.0), false);
    rig.wait(
        "the arm moving under policy 1",
        Duration::from_secs(15),
        |s| {
            s.iter().find_map(|(_, x)| match x {
                Seen::State(st)
                    if st.active_policy_id == 1
                        && st.joint_velocities_rad_s.iter().any(|v| v.abs() > 1e-3) =>
                {
                    Some(())
                }
                _ => None,
            })
        },
    );
    // A tall box across the rest of the path (55 % of the way from the start TCP to the goal).
    let start_tcp = rig.last_state().expect("state").tcp_m;
    let c = [
        (0.45 * start_tcp[0] + 0.55 * f64::from(GOAL_M[0])) as f32,
        (0.45 * start_tcp[1] + 0.55 * f64::from(GOAL_M[1])) as f32,
        0.20,
    ];
    rig.obstacles
        .lock()
        .expect("lock")
        .push((c, [0.05, 0.05, 0.40]));
    let t_box = Instant::now();
    let (t_stop, st) = rig.wait("a controlled stop", Duration::from_secs(5), |s| {
        s.iter().find_map(|(t, x)| match x {
            Seen::State(st) if st.controlled_stop == 1 => Some((*t, *st)),
            _ => None,
        })
    });
    assert_eq!(
        st.stop_reason,
        shm_schemas::StopReason::ShieldViolation as u8,
        "{st:?}"
    );
    let r = rig.wait(
        "a retrain request carrying the box",
        Duration::from_secs(5),
        |s| {
            s.iter().find_map(|(_, x)| match x {
                Seen::Retrain(r) if r.failed_policy_id == 1 && r.obstacle_count == 1 => Some(*r),
                _ => None,
            })
        },
    );
    assert!(r.validate().is_ok());
    assert!((r.obstacles[0].size_m[2] - 0.40).abs() < 0.01, "{r:?}");
    // The arm then goes back along the path it came (clear of the box; the shield checks
    // it) to where the episode began, and waits there for a new policy: no episode plan for
    // this scene, and one retrain request for this policy and scene, not one per attempt.
    let home = rig.wait(
        "the arm back where the episode began, at rest",
        Duration::from_secs(20),
        |s| {
            s.iter().rev().find_map(|(_, x)| match x {
                Seen::State(st)
                    if max_gap(&st.joints_rad, &home_q) < 1e-3
                        && st.joint_velocities_rad_s.iter().all(|v| v.abs() < 1e-9) =>
                {
                    Some(*st)
                }
                _ => None,
            })
        },
    );
    std::thread::sleep(Duration::from_millis(1500));
    rig.pump();
    let last = rig.last_state().expect("state");
    assert!(
        max_gap(&last.joints_rad, &home.joints_rad) < 1e-6,
        "{last:?}"
    );
    let requests = rig
        .seen
        .iter()
        .filter(|(_, x)| matches!(x, Seen::Retrain(r) if r.failed_policy_id == 1))
        .count();
    assert_eq!(requests, 1, "one retrain request per policy and scene");
    println!(
        "box published -> controlled stop seen after {:.1} ms",
        (t_stop - t_box).as_secs_f64() * 1e3
    );
    let log = rig.finish();
    let find = |needle: &str| {
        log.lines()
            .find(|l| l.contains(needle))
            .unwrap_or_default()
            .to_owned()
    };
    let fin = find("rt-core run finished");
    assert!(
        fin.contains("allocations_in_cycle=0"),
        "the cycle allocated during the run: {fin}"
    );
    println!("{}", find("detection capture -> visible"));
    println!("{fin}");
}

/// The largest joint difference, rad.
fn max_gap(a: &[f64; 5], b: &[f64; 5]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}
