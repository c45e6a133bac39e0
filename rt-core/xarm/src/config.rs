//! Driver settings: the controller's address and ports, timeouts, back-off and the resume
//! tolerance after a reconnect.

use std::time::Duration;

use crate::report::{self, ReportKind};

/// Driver settings.
#[derive(Debug, Clone, PartialEq)]
pub struct XArmConfig {
    /// Controller address (host or IP).
    pub host: String,
    /// Command port (502).
    pub command_port: u16,
    /// Report stream to follow.
    pub report_kind: ReportKind,
    /// Its port (30003 for `Real`, 30000 for `RealTime`).
    pub report_port: u16,
    /// TCP connect timeout.
    pub connect_timeout: Duration,
    /// Timeout of blocking calls and of pipelined replies.
    pub reply_timeout: Duration,
    /// Most replies checked per non-blocking call.
    pub reply_budget: usize,
    /// State older than this is stale (ns).
    pub stale_after_ns: u64,
    /// First reconnect delay (ns); doubles up to `backoff_max_ns`.
    pub backoff_initial_ns: u64,
    /// Longest reconnect delay (ns).
    pub backoff_max_ns: u64,
    /// After a reconnect, the first target may differ from the actual joints by this much.
    pub max_resume_step_rad: f64,
}

impl XArmConfig {
    /// Defaults for a controller at `host` on the real ports (502, report 30003).
    pub fn new(host: &str) -> Self {
        Self {
            host: host.to_string(),
            command_port: 502,
            report_kind: ReportKind::Real,
            report_port: report::PORT_REPORT_REAL,
            connect_timeout: Duration::from_secs(1),
            reply_timeout: Duration::from_secs(2),
            reply_budget: 16,
            stale_after_ns: 200_000_000,
            backoff_initial_ns: 100_000_000,
            backoff_max_ns: 5_000_000_000,
            max_resume_step_rad: 0.05,
        }
    }

    /// Parses `HOST[:PORT]` (default port 502; report port stays the default).
    pub fn from_addr(addr: &str) -> Self {
        match addr.rsplit_once(':') {
            Some((h, p)) if !h.contains(':') || h.starts_with('[') => match p.parse::<u16>() {
                Ok(port) => Self {
                    command_port: port,
                    ..Self::new(h.trim_start_matches('[').trim_end_matches(']'))
                },
                Err(_) => Self::new(addr),
            },
            _ => Self::new(addr),
        }
    }
}
