//! `rt-core run` rides out a controller restart: `xarm-sim` is killed under a running
//! `rt-core run --link xarm` and started again on the same ports. The cycle keeps running
//! while the link is down (the reconnect happens on a helper thread), the link comes back,
//! the cycle streams hold targets to the new controller again, and nothing in the cycle
//! allocated. Needs the workspace's binaries built (`cargo build --release --workspace --bins`).

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use foresight_tests::{ChildGuard, bin_path, repo_root, unique_prefix, wait_for};

/// `xarm-sim`'s port options and the keys of its `listening` line.
const PORTS: [(&str, &str); 6] = [
    ("--command-port", "command"),
    ("--report-rt-port", "report_rt"),
    ("--report-normal-port", "report_normal"),
    ("--report-rich-port", "report_rich"),
    ("--report-real-port", "report_real"),
    ("--control-port", "control"),
];

/// The ports `xarm-sim` announced, in the order of [`PORTS`].
type SimPorts = [u16; 6];

/// Starts `xarm-sim` on `ports` (0: the OS picks) and reads the ports it announced.
fn start_sim(ports: SimPorts) -> (ChildGuard, BufReader<std::process::ChildStdout>, SimPorts) {
    let root = repo_root();
    let mut cmd = Command::new(bin_path("xarm-sim"));
    for ((flag, _), port) in PORTS.iter().zip(ports) {
        cmd.arg(flag).arg(port.to_string());
    }
    cmd.arg("--urdf")
        .arg(root.join("assets/xarm5.urdf"))
        .arg("--scene")
        .arg(root.join("assets/scenes/small_box.toml"))
        .stdout(Stdio::piped())
        .stderr(Stdio::null());
    let mut sim = ChildGuard::spawn("xarm-sim", &mut cmd);
    let mut out = BufReader::new(sim.child.stdout.take().expect("sim stdout"));
    let mut line = String::new();
    out.read_line(&mut line).expect("listening line");
    let v: serde_json::Value = serde_json::from_str(&line).expect("xarm-sim's listening line");
    assert_eq!(v["event"], "listening", "{line}");
    let announced = PORTS.map(|(_, key)| {
        v["ports"][key]
            .as_u64()
            .and_then(|p| u16::try_from(p).ok())
            .unwrap_or_else(|| panic!("no {key} port in {line}"))
    });
    (sim, out, announced)
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_default()
}

#[test]
fn rt_core_run_rides_out_a_controller_restart() {
    let dir = std::env::temp_dir().join(unique_prefix("xarm_reconnect"));
    std::fs::create_dir_all(&dir).expect("scratch dir");
    let log = dir.join("rt-core.log");
    let (mut sim, _out, ports) = start_sim([0; 6]);
    let (command_port, report_real_port) = (ports[0], ports[4]);

    let mut rt = ChildGuard::spawn(
        "rt-core",
        Command::new(bin_path("rt-core"))
            .current_dir(repo_root())
            .args(["run", "--link", "xarm", "--no-mlock", "--seconds", "60"])
            .arg("--robot")
            .arg(format!("127.0.0.1:{command_port}"))
            .arg("--report-port")
            .arg(report_real_port.to_string())
            .arg("--prefix")
            .arg(unique_prefix("reconnect"))
            .env("NO_COLOR", "1")
            .stdout(Stdio::piped())
            .stderr(std::fs::File::create(&log).expect("log file")),
    );
    let wait_log = |needle: &str, secs: u64| {
        wait_for(Duration::from_secs(secs), || {
            read(&log).contains(needle).then_some(())
        })
        .unwrap_or_else(|| panic!("no {needle:?} in the rt-core log:\n{}", read(&log)));
    };
    wait_log("iceoryx2 node up", 30);
    std::thread::sleep(Duration::from_millis(500));

    // The controller dies (power cut, crash): the cycle stops commanding and keeps running.
    let _ = sim.child.kill();
    let _ = sim.child.wait();
    wait_log("reconnecting off the cycle", 10);
    std::thread::sleep(Duration::from_millis(500));
    assert!(
        matches!(rt.child.try_wait(), Ok(None)),
        "rt-core must survive a lost controller:\n{}",
        read(&log)
    );

    // The controller comes back on the same ports.
    let (mut sim2, mut out2, _) = start_sim(ports);
    wait_log("xArm link re-established", 20);
    std::thread::sleep(Duration::from_millis(500));

    let status = rt.interrupt_and_wait(Duration::from_secs(10));
    assert!(
        status.is_some_and(|s| s.success()),
        "rt-core stops cleanly: {status:?}\n{}",
        read(&log)
    );
    let mut stdout = String::new();
    let _ = std::io::Read::read_to_string(
        rt.child.stdout.as_mut().expect("rt-core stdout"),
        &mut stdout,
    );
    let summary: serde_json::Value = stdout
        .lines()
        .rev()
        .find_map(|l| serde_json::from_str(l).ok())
        .unwrap_or_else(|| panic!("no JSON summary from rt-core: {stdout}"));
    assert_eq!(summary["allocations_in_cycle"], 0, "{summary}");
    assert!(summary["cycles"].as_u64().unwrap_or(0) > 0, "{summary}");

    // The new controller got the cycle's hold targets after the reconnect.
    assert!(sim2.interrupt_and_wait(Duration::from_secs(5)).is_some());
    let mut sim_summary = String::new();
    out2.read_line(&mut sim_summary)
        .expect("xarm-sim summary line");
    let sim_summary: serde_json::Value =
        serde_json::from_str(&sim_summary).expect("xarm-sim summary JSON");
    assert!(
        sim_summary["counters"]["servo_accepted"]
            .as_u64()
            .unwrap_or(0)
            > 0,
        "{sim_summary}"
    );
    assert_eq!(sim_summary["collisions"], 0, "{sim_summary}");
    let _ = std::fs::remove_dir_all(&dir);
}
