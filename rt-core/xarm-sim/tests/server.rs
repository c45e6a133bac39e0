//! The `xarm-sim` binary: starts on ephemeral ports, applies a `--swap-scene-at` schedule,
//! takes scene changes over its control port, and prints a JSON summary on SIGINT.

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

fn asset(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../assets")
        .join(rel)
}

struct Kill(Child);
impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn control(port: u16, cmd: &str) -> String {
    let mut s = TcpStream::connect(("127.0.0.1", port)).expect("control port");
    writeln!(s, "{cmd}").expect("write");
    let mut line = String::new();
    BufReader::new(s).read_line(&mut line).expect("reply");
    line.trim().to_string()
}

#[test]
fn swaps_scenes_on_schedule_and_on_request_and_summarises_at_exit() {
    let (mut child, mut out, ctl) = start_listening(&[
        "--bind",
        "127.0.0.1",
        "--scene",
        &asset("scenes/small_box.toml").to_string_lossy(),
        "--swap-scene-at",
        "0.5s",
        &asset("scenes/tall_box.toml").to_string_lossy(),
    ]);
    assert_ne!(ctl, 0);

    let status: serde_json::Value = serde_json::from_str(&control(ctl, "status")).expect("status");
    assert_eq!(status["scene"], "small_box");
    std::thread::sleep(Duration::from_millis(800));
    let status: serde_json::Value = serde_json::from_str(&control(ctl, "status")).expect("status");
    assert_eq!(status["scene"], "tall_box", "the scheduled swap happened");

    let small = asset("scenes/small_box.toml");
    assert_eq!(control(ctl, &format!("scene {}", small.display())), "ok");
    assert!(control(ctl, "scene /nonexistent.toml").starts_with("error:"));
    assert!(control(ctl, "bogus").starts_with("error:"));
    std::thread::sleep(Duration::from_millis(100));
    let status: serde_json::Value = serde_json::from_str(&control(ctl, "status")).expect("status");
    assert_eq!(status["scene"], "small_box", "the requested swap happened");

    let pid = child.0.id().to_string();
    Command::new("kill")
        .args(["-INT", &pid])
        .status()
        .expect("kill");
    let status = child.0.wait().expect("exit");
    assert!(status.success());
    let mut summary = String::new();
    out.read_line(&mut summary).expect("summary");
    let s: serde_json::Value = serde_json::from_str(&summary).expect("summary JSON");
    assert_eq!(s["event"], "summary");
    assert_eq!(s["scene_swaps"], 2);
    assert_eq!(s["collisions"], 0);
}

// ---- protective faults and injected errors (in-process server) -------------------------------

use std::io::Read;
use std::time::Instant;

use twin::RobotModel;
use xarm::codec::{JointTarget, Request, Response, STATUS_ERROR, STATUS_NOT_READY};
use xarm::codes::ControllerError;
use xarm::report::{self, ReportKind};
use xarm_sim::{ProtectiveFault, SimOptions, SimPorts, SimServer};

fn home() -> [f64; 5] {
    RobotModel::load(&asset("xarm5.urdf")).expect("urdf").home()
}

fn in_process_sim() -> SimServer {
    SimServer::start(SimOptions {
        ports: SimPorts::ephemeral(),
        urdf: asset("xarm5.urdf"),
        q0_rad: home(),
        ..SimOptions::default()
    })
    .expect("sim starts")
}

/// A bare command-port client: one request, one reply.
struct Client {
    s: TcpStream,
    tid: u16,
}

impl Client {
    fn connect(port: u16) -> Self {
        let s = TcpStream::connect(("127.0.0.1", port)).expect("command port");
        s.set_read_timeout(Some(Duration::from_secs(2)))
            .expect("timeout");
        Self { s, tid: 0 }
    }

    /// Sends `req`, returns the status byte and the data.
    fn ask(&mut self, req: Request) -> (u8, Vec<u8>) {
        self.tid += 1;
        let mut buf = [0u8; 64];
        let n = req.encode(self.tid, 3, &mut buf).expect("encode");
        self.s.write_all(&buf[..n]).expect("send");
        let mut head = [0u8; 6];
        self.s.read_exact(&mut head).expect("reply head");
        let len = usize::from(u16::from_be_bytes([head[4], head[5]]));
        let mut frame = head.to_vec();
        frame.resize(6 + len, 0);
        self.s.read_exact(&mut frame[6..]).expect("reply body");
        let r = Response::parse(&frame).expect("reply");
        r.check(self.tid, 3, u8::from(req.register()))
            .expect("matching reply");
        (r.status, r.data.to_vec())
    }

    fn servo_j(&mut self, q: &[f64; 5]) -> u8 {
        self.ask(Request::ServoJ(JointTarget::xarm5(q))).0
    }

    fn joints(&mut self) -> [f32; 5] {
        let (_, d) = self.ask(Request::GetJointPos(None));
        std::array::from_fn(|i| {
            f32::from_le_bytes([d[4 * i], d[4 * i + 1], d[4 * i + 2], d[4 * i + 3]])
        })
    }

    /// The SDK's sequence: clean error, enable, mode 1, state 0.
    fn start_servo_mode(&mut self) {
        self.ask(Request::CleanError);
        self.ask(Request::MotionEnable {
            servo_id: 8,
            enable: true,
        });
        self.ask(Request::SetMode {
            mode: 1,
            detection: Some(0),
        });
        self.ask(Request::SetState(0));
        assert_eq!(self.ask(Request::GetState).1, vec![2]);
    }
}

/// Reads normal reports (5 Hz) until one shows `error`, or 3 s pass; returns it.
fn normal_report_with_error(port: u16, error: u8) -> report::ArmReport {
    let mut s = TcpStream::connect(("127.0.0.1", port)).expect("report port");
    s.set_read_timeout(Some(Duration::from_secs(2)))
        .expect("timeout");
    let mut buf = [0u8; report::NORMAL_LEN];
    let deadline = Instant::now() + Duration::from_secs(3);
    loop {
        s.read_exact(&mut buf).expect("normal report");
        let r = report::decode(ReportKind::Normal, &buf).expect("decodes");
        if r.error_code == Some(error) || Instant::now() > deadline {
            return r;
        }
    }
}

#[test]
fn a_joint_speed_fault_reaches_get_error_the_reports_and_the_summary() {
    let sim = in_process_sim();
    let mut c = Client::connect(sim.ports().command);
    c.start_servo_mode();
    let q0 = home();
    // A slow 250 Hz stream: 0.002 rad per 4 ms target on J1 (0.5 rad/s).
    let mut q = q0;
    for k in 1..=50 {
        q = q0;
        q[0] += 0.002 * f64::from(k);
        assert_eq!(c.servo_j(&q), 0, "target {k}");
        std::thread::sleep(Duration::from_millis(4));
    }
    // State 1 for 100 ms after the last target, then 2.
    std::thread::sleep(Duration::from_millis(300));
    let s = sim.summary();
    assert_eq!(
        (s.protective_faults, s.error_code, s.state, s.mode),
        (0, 0, 2, 1)
    );
    assert!((s.max_joint_step_rad - 0.002).abs() < 1e-6, "{s:?}");
    assert!(s.max_tcp_step_m > 0.0 && s.max_tcp_step_m < 0.005, "{s:?}");

    // 0.018 rad in one target: faults, and is not executed.
    let at = c.joints();
    let mut jump = q;
    jump[1] += 0.018;
    let st = c.servo_j(&jump);
    assert_eq!(
        st & (STATUS_ERROR | STATUS_NOT_READY),
        STATUS_ERROR | STATUS_NOT_READY
    );
    assert_eq!(c.ask(Request::GetError).1, vec![24, 0]);
    assert_eq!(c.ask(Request::GetState).1, vec![4]);
    for _ in 0..10 {
        assert_ne!(
            c.servo_j(&q) & STATUS_ERROR,
            0,
            "motion refused until cleared"
        );
        std::thread::sleep(Duration::from_millis(4));
    }
    std::thread::sleep(Duration::from_millis(100));
    let after = c.joints();
    for i in 0..5 {
        assert!(
            (after[i] - at[i]).abs() < 1e-6,
            "joint {i} did not move: {at:?} → {after:?}"
        );
    }
    let r = normal_report_with_error(sim.ports().report_normal, 24);
    assert_eq!((r.error_code, r.state), (Some(24), 4));

    let s = sim.summary();
    assert_eq!(
        (
            s.protective_faults,
            s.joint_speed_faults,
            s.tcp_speed_faults
        ),
        (1, 1, 0)
    );
    assert_eq!((s.error_code, s.state, s.collisions), (24, 4, 0));
    assert!((s.max_joint_step_rad - 0.018).abs() < 1e-6, "{s:?}");
    assert!(matches!(
        s.last_protective_fault,
        Some(ProtectiveFault::JointSpeed { joint: 1, .. })
    ));
    assert_eq!(s.counters.servo_accepted, 50);
    assert_eq!(s.clean_error_requests, 1);

    // CLEAN_ERR and re-enable: the stream resumes from where the arm stands.
    c.start_servo_mode();
    let mut resume = q;
    resume[0] += 0.002;
    assert_eq!(c.servo_j(&resume), 0);
    assert_eq!(c.ask(Request::GetError).1, vec![0, 0]);
    c.ask(Request::SetState(4));
    let s = sim.shutdown();
    assert_eq!(s.counters.servo_accepted, 51);
    assert_eq!(
        (s.clean_error_requests, s.stop_requests, s.state),
        (2, 1, 4)
    );
    assert_eq!(s.protective_faults, 1, "no further fault");
}

#[test]
fn the_first_target_far_from_the_arm_faults_and_tcp_speed_faults_too() {
    let sim = in_process_sim();
    let mut c = Client::connect(sim.ports().command);
    c.start_servo_mode();
    let mut far = home();
    far[0] += 0.3;
    assert_ne!(c.servo_j(&far) & STATUS_ERROR, 0);
    assert_eq!(c.ask(Request::GetError).1, vec![24, 0]);

    // Each joint within its step, the TCP beyond 5 mm: the linear speed error, 60.
    c.start_servo_mode();
    let model = RobotModel::load(&asset("xarm5.urdf")).expect("urdf");
    let q0 = home();
    let dq = 0.014;
    let fast = (0..8u8)
        .map(|signs| {
            let mut q = q0;
            for (j, v) in q.iter_mut().take(3).enumerate() {
                *v += if signs >> j & 1 == 1 { dq } else { -dq };
            }
            q
        })
        .max_by(|a, b| {
            let d = |q: &[f64; 5]| (model.tcp_m(q) - model.tcp_m(&q0)).norm();
            d(a).total_cmp(&d(b))
        })
        .expect("a candidate");
    assert!(
        (model.tcp_m(&fast) - model.tcp_m(&q0)).norm() > 0.0055,
        "precondition"
    );
    assert_ne!(c.servo_j(&fast) & STATUS_ERROR, 0);
    assert_eq!(c.ask(Request::GetError).1, vec![60, 0]);
    let s = sim.shutdown();
    assert_eq!(
        (
            s.protective_faults,
            s.joint_speed_faults,
            s.tcp_speed_faults
        ),
        (2, 1, 1)
    );
    assert_eq!(s.error_code, 60);
    assert!(matches!(
        s.last_protective_fault,
        Some(ProtectiveFault::TcpSpeed { .. })
    ));
    assert_eq!(s.counters.servo_accepted, 0);
}

#[test]
fn an_injected_collision_raises_c31_and_stops_until_cleared() {
    let sim = in_process_sim();
    let mut c = Client::connect(sim.ports().command);
    c.start_servo_mode();
    let q = home();
    assert_eq!(c.servo_j(&q), 0);
    sim.inject_error(ControllerError::Collision);
    assert_ne!(c.servo_j(&q) & STATUS_ERROR, 0);
    assert_eq!(c.ask(Request::GetError).1, vec![31, 0]);
    let r = normal_report_with_error(sim.ports().report_normal, 31);
    assert_eq!((r.error_code, r.state), (Some(31), 4));
    let s = sim.summary();
    assert_eq!((s.collisions, s.error_code, s.state), (1, 31, 4));
    assert_eq!(s.protective_faults, 0);
    c.start_servo_mode();
    assert_eq!(c.servo_j(&q), 0, "resumes after CLEAN_ERR and re-enable");
    c.ask(Request::SetState(4));
    let s = sim.shutdown();
    assert_eq!((s.error_code, s.state, s.stop_requests), (0, 4, 1));
}

// ---- the binary's fault flags and control commands -------------------------------------------

fn sim_command(extra: &[&str]) -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_xarm-sim"));
    for flag in [
        "--command-port",
        "--report-rt-port",
        "--report-normal-port",
        "--report-rich-port",
        "--report-real-port",
        "--control-port",
    ] {
        cmd.args([flag, "0"]);
    }
    cmd.arg("--urdf").arg(asset("xarm5.urdf")).args(extra);
    cmd
}

/// Starts the binary with `extra` and reads its `listening` line: the child, its stdout
/// (for the summary) and the control port.
fn start_listening(extra: &[&str]) -> (Kill, BufReader<std::process::ChildStdout>, u16) {
    let mut child = Kill(
        sim_command(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("xarm-sim starts"),
    );
    let mut out = BufReader::new(child.0.stdout.take().expect("stdout"));
    let mut line = String::new();
    out.read_line(&mut line).expect("listening line");
    let v: serde_json::Value = serde_json::from_str(&line).expect("JSON");
    assert_eq!(v["event"], "listening");
    let ctl = v["ports"]["control"].as_u64().expect("control port") as u16;
    (child, out, ctl)
}

#[test]
fn bad_fault_flags_are_refused_naming_the_flag() {
    for (flag, value) in [
        ("--servo-period-ms", "0"),
        ("--max-joint-speed-rad-s", "-1"),
        ("--max-tcp-speed-m-s", "inf"),
        ("--fault-tolerance", "NaN"),
        ("--fault-tolerance", "-0.1"),
        // Positive and finite, but refused by the library's range check (0.1 ms … 1 s).
        ("--servo-period-ms", "2000"),
        ("--servo-period-ms", "1e-320"),
    ] {
        let mut child = Kill(
            sim_command(&[flag, value])
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .expect("xarm-sim runs"),
        );
        // A refused flag exits at once; a simulator still running after 5 s accepted it.
        let deadline = std::time::Instant::now() + Duration::from_secs(5);
        let status = loop {
            if let Some(st) = child.0.try_wait().expect("wait") {
                break st;
            }
            assert!(
                std::time::Instant::now() < deadline,
                "{flag} {value} accepted"
            );
            std::thread::sleep(Duration::from_millis(20));
        };
        let mut err = String::new();
        child
            .0
            .stderr
            .take()
            .expect("stderr")
            .read_to_string(&mut err)
            .expect("stderr text");
        assert!(!status.success(), "{flag} {value} accepted");
        assert!(err.contains(flag), "{flag} {value}: {err}");
    }
}

#[test]
fn control_port_injects_errors_and_status_shows_the_fault_figures() {
    let (mut child, _out, ctl) =
        start_listening(&["--no-protective-faults", "--servo-period-ms", "8"]);
    let status: serde_json::Value = serde_json::from_str(&control(ctl, "status")).expect("status");
    assert_eq!(status["protective_limits"]["enabled"], false);
    assert_eq!(status["protective_limits"]["servo_period_s"], 0.008);
    assert_eq!(status["protective_faults"], 0);
    assert_eq!(status["state"], 4);
    assert!(control(ctl, "error 0").starts_with("error:"));
    assert!(control(ctl, "error x").starts_with("error:"));
    assert_eq!(control(ctl, "error 31"), "ok");
    let status: serde_json::Value = serde_json::from_str(&control(ctl, "status")).expect("status");
    assert_eq!(status["error_code"], 31);
    assert_eq!(status["collisions"], 1);
    assert_eq!(status["state"], 4);
    for key in [
        "joint_speed_faults",
        "tcp_speed_faults",
        "max_joint_step_rad",
        "max_tcp_step_m",
        "clean_error_requests",
        "stop_requests",
        "mode",
    ] {
        assert!(status.get(key).is_some(), "{key} in {status}");
    }
    assert_eq!(control(ctl, "shutdown"), "ok");
    assert!(child.0.wait().expect("exit").success());
}

// ---- the independent referee -----------------------------------------------------------------

fn scene_file(boxes: &[([f64; 3], [f64; 3])]) -> shm_schemas::scene_file::SceneFile {
    use shm_schemas::scene_file::{BoxSpec, GoalSpec, SceneFile, TableSpec};
    SceneFile {
        name: "referee-test".into(),
        table: TableSpec { height_m: 0.0 },
        goal: GoalSpec {
            center_m: [0.3, 0.25, 0.025],
            size_m: 0.05,
        },
        obstacles: boxes
            .iter()
            .map(|(center_m, size_m)| BoxSpec {
                center_m: *center_m,
                size_m: *size_m,
                path: Default::default(),
            })
            .collect(),
    }
}

/// Polls the summary until `done` holds or 3 s pass; returns the last one.
fn summary_when(
    sim: &SimServer,
    done: impl Fn(&xarm_sim::SimSummary) -> bool,
) -> xarm_sim::SimSummary {
    let deadline = Instant::now() + Duration::from_secs(3);
    loop {
        let s = sim.summary();
        if done(&s) || Instant::now() > deadline {
            return s;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn a_box_only_the_referee_sees_raises_error_31_and_the_summary_names_it() {
    // Zero pose with a small box just beyond the wrist's corner: the twin's straight wrist
    // capsule misses it, the referee's L-shaped wrist touches it.
    let sim = SimServer::start(SimOptions {
        ports: SimPorts::ephemeral(),
        urdf: asset("xarm5.urdf"),
        q0_rad: [0.0; 5],
        scenes: vec![(0.0, scene_file(&[([0.235, 0.0, 0.235], [0.04; 3])]))],
        ..SimOptions::default()
    })
    .expect("sim starts");
    let s = summary_when(&sim, |s| s.collisions > 0);
    assert_eq!((s.collisions, s.error_code), (1, 31), "{s:?}");
    let r = &s.referee;
    assert_eq!(r.contacts, 1, "{r:?}");
    assert_eq!(
        (r.contacts_at_rest, r.contacts_while_moving),
        (1, 0),
        "the arm never moved: {r:?}"
    );
    assert!(r.steps > 0 && r.evaluations >= 2 * r.steps, "{r:?}");
    assert_eq!(
        (r.min_link.as_deref(), r.min_other.as_deref()),
        (Some("link4"), Some("obstacle 0")),
        "{r:?}"
    );
    let min = r.min_clearance_m.expect("a minimum");
    assert!((min - (0.01 - 0.04)).abs() < 1e-5, "{min}");
    assert_eq!(r.min_scene.as_deref(), Some("referee-test"));
    // The status JSON carries it too.
    let v = serde_json::to_value(&s).expect("json");
    assert_eq!(v["referee"]["contacts"], 1);
    assert_eq!(v["referee"]["min_link"], "link4");
    sim.shutdown();
}

#[test]
fn folding_the_elbow_into_the_shoulder_is_a_collision_and_the_arm_stops() {
    // From the zero pose, J3 is streamed towards its upper limit (0.19 rad) at 0.5 rad/s:
    // the forearm folds down along the upper arm and the wrist runs into the shoulder
    // housing, a self-collision the twin does not model.
    let sim = SimServer::start(SimOptions {
        ports: SimPorts::ephemeral(),
        urdf: asset("xarm5.urdf"),
        q0_rad: [0.0; 5],
        ..SimOptions::default()
    })
    .expect("sim starts");
    let mut c = Client::connect(sim.ports().command);
    c.start_servo_mode();
    let start = sim.summary().referee.min_clearance_m.expect("judged");
    assert!(start > 0.0, "the zero pose is clear: {start}");
    let mut q = [0.0; 5];
    let mut refused = false;
    for _ in 0..95 {
        q[2] += 0.002;
        if c.servo_j(&q) & STATUS_ERROR != 0 {
            refused = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(4));
    }
    assert!(refused, "a target was refused with the error bit");
    let s = summary_when(&sim, |s| s.collisions > 0);
    assert_eq!((s.collisions, s.error_code, s.state), (1, 31, 4), "{s:?}");
    let r = &s.referee;
    assert_eq!(r.contacts, 1, "{r:?}");
    assert_eq!(
        (r.contacts_while_moving, r.contacts_at_rest),
        (1, 0),
        "the arm ran into itself: {r:?}"
    );
    assert!(r.min_clearance_m.is_some_and(|m| m <= 0.0), "{r:?}");
    let other = r.min_other.as_deref().unwrap_or("");
    assert!(other.starts_with("link"), "a self-collision: {r:?}");
    // The arm stopped where the referee called it, short of the limit.
    let at = c.joints();
    assert!(f64::from(at[2]) < 0.19, "{at:?}");
    sim.shutdown();
}

/// A live scene file: a 6 cm box beside the flange of the task's start posture that waits
/// until `wait_s` after the scene came into force, then slides into the arm within 1 s.
fn write_sliding_box(path: &Path, in_force_since_ns: Option<u64>, wait_s: f64) {
    use shm_schemas::scene_file::{BoxPath, BoxSpec, Keyframe, LiveScene};
    let mut scene = scene_file(&[]);
    scene.name = "sliding".into();
    let at = |at_s, y| Keyframe {
        at_s,
        center_m: [0.30, y, 0.20],
    };
    scene.obstacles.push(BoxSpec {
        path: BoxPath::new(&[at(wait_s, 0.40), at(wait_s + 1.0, 0.0)]).unwrap(),
        ..BoxSpec::fixed([0.30, 0.40, 0.20], [0.06, 0.06, 0.40])
    });
    let live = LiveScene {
        scene,
        in_force_since_monotonic_ns: in_force_since_ns,
    };
    std::fs::write(path, live.to_toml_string()).unwrap();
}

#[test]
fn a_moving_box_follows_its_path_from_the_live_files_time_origin_and_hits_the_arm_at_rest() {
    let start_q = [0.0, -0.383, -0.371, 0.855, 0.0];
    let sim = SimServer::start(SimOptions {
        ports: SimPorts::ephemeral(),
        urdf: asset("xarm5.urdf"),
        q0_rad: start_q,
        ..SimOptions::default()
    })
    .expect("sim starts");
    let ctl = sim.ports().control;
    let dir = std::env::temp_dir().join(format!("xarm-sim-moving-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let live = dir.join("live.toml");
    // Without a time origin the path starts when the file is read: the box waits 30 s.
    write_sliding_box(&live, None, 30.0);
    assert_eq!(control(ctl, &format!("scene {}", live.display())), "ok");
    std::thread::sleep(Duration::from_millis(300));
    let s = sim.summary();
    assert_eq!((s.scene.as_str(), s.collisions), ("sliding", 0), "{s:?}");
    // The same box, in force since 40 s ago: it already stands in the arm.
    let now = shm_schemas::clock::monotonic_now_ns();
    write_sliding_box(&live, Some(now.saturating_sub(40_000_000_000)), 30.0);
    assert_eq!(control(ctl, &format!("scene {}", live.display())), "ok");
    let s = summary_when(&sim, |s| s.collisions > 0);
    assert_eq!((s.collisions, s.error_code), (1, 31), "{s:?}");
    let r = &s.referee;
    assert_eq!(
        (r.contacts, r.contacts_at_rest, r.contacts_while_moving),
        (1, 1, 0),
        "a box walked into the arm at rest: {r:?}"
    );
    assert_eq!(r.min_other.as_deref(), Some("obstacle 0"), "{r:?}");
    let v = serde_json::to_value(&s).expect("json");
    assert_eq!(v["referee"]["contacts_at_rest"], 1);
    assert_eq!(v["referee"]["contacts_while_moving"], 0);
    assert!(
        v["referee"]["clearance_m"]
            .as_f64()
            .is_some_and(|m| m <= 0.0),
        "{v}"
    );
    sim.shutdown();
    std::fs::remove_dir_all(&dir).ok();
}
