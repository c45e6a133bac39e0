//! The launcher's line to `xarm-sim`: the ports it announced in its log, and its control
//! port (scene changes, status with the ground-truth collision count).

use std::io::{BufRead, BufReader, Write};
use std::net::TcpStream;
use std::path::Path;
use std::time::Duration;

use anyhow::Context;

/// Sends one line to `xarm-sim`'s control port and returns its one-line reply.
pub fn sim_control(port: u16, line: &str) -> anyhow::Result<String> {
    let mut stream = TcpStream::connect(("127.0.0.1", port))
        .with_context(|| format!("connecting to xarm-sim control port {port}"))?;
    stream.set_read_timeout(Some(Duration::from_secs(5)))?;
    writeln!(stream, "{line}")?;
    let mut reply = String::new();
    BufReader::new(stream).read_line(&mut reply)?;
    Ok(reply.trim().to_owned())
}

/// The ports `xarm-sim` announced.
#[derive(Debug, Clone, Copy)]
pub struct SimPortsSeen {
    /// Command port.
    pub command: u16,
    /// Real-time report port (30003 on a real controller).
    pub report_real: u16,
    /// Control port (scene changes, status).
    pub control: u16,
}

/// The ports in `xarm-sim`'s `{"event":"listening","ports":{…}}` line, once it is in its log.
pub fn read_sim_ports(log: &Path) -> Option<SimPortsSeen> {
    let text = std::fs::read_to_string(log).ok()?;
    text.lines().find_map(|l| {
        let v: serde_json::Value = serde_json::from_str(l.trim()).ok()?;
        if v["event"] != "listening" {
            return None;
        }
        let port = |k: &str| v["ports"][k].as_u64().and_then(|p| u16::try_from(p).ok());
        Some(SimPortsSeen {
            command: port("command")?,
            report_real: port("report_real")?,
            control: port("control")?,
        })
    })
}

/// `xarm-sim`'s `status` reply (JSON), if it answers.
pub fn sim_status(port: u16) -> Option<serde_json::Value> {
    sim_control(port, "status")
        .ok()
        .and_then(|r| serde_json::from_str::<serde_json::Value>(&r).ok())
}
