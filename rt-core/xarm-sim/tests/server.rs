//! The `xarm-sim` binary: starts on ephemeral ports, applies a `--swap-scene-at` schedule,
//! takes scene changes over its control port, and prints a JSON summary on SIGINT.

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
    let mut child = Kill(
        Command::new(env!("CARGO_BIN_EXE_xarm-sim"))
            .args(["--bind", "127.0.0.1"])
            .args([
                "--command-port",
                "0",
                "--report-rt-port",
                "0",
                "--report-normal-port",
                "0",
            ])
            .args([
                "--report-rich-port",
                "0",
                "--report-real-port",
                "0",
                "--control-port",
                "0",
            ])
            .arg("--urdf")
            .arg(asset("xarm5.urdf"))
            .arg("--scene")
            .arg(asset("scenes/small_box.toml"))
            .arg("--swap-scene-at")
            .arg("0.5s")
            .arg(asset("scenes/tall_box.toml"))
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
