//! Driver settings: the controller's address and ports, timeouts, back-off and the resume
//! tolerance after a reconnect.

use std::io::ErrorKind;
use std::net::{IpAddr, ToSocketAddrs};
use std::time::Duration;

use crate::report::{self, ReportKind};
use crate::sim_identity::{CommandEndpoint, SimSecret};

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
    /// After a reconnect, the first target may differ from the actual joints by this much
    /// (the runtime sets one period at the joint velocity limit).
    pub max_resume_step_rad: f64,
    /// After a reconnect, re-enter servo mode on the helper thread without an operator's
    /// acknowledgement. Off by default: a real arm resumes only after the operator
    /// acknowledges; `xarm-sim` runs may opt in.
    pub resume_after_reconnect: bool,
    /// While the controller reports an error, ask `GET_ERROR` this often (ns) until it
    /// reads cleared (the 30003 report carries no error code).
    pub error_poll_ns: u64,
    /// Set when a simulation-only right is asked for (blind mode, `--auto-resume`, the
    /// synthetic camera): every connection, the first and each reconnect, then requires the
    /// controller to prove it is `xarm-sim` holding this secret
    /// ([`crate::sim_identity`]) before anything else is sent after `GET_VERSION`. `None`
    /// (the default): no challenge, the arm is driven as a real arm.
    pub sim_secret: Option<SimSecret>,
}

impl<'a> From<&'a XArmConfig> for CommandEndpoint<'a> {
    fn from(cfg: &'a XArmConfig) -> Self {
        Self {
            host: &cfg.host,
            command_port: cfg.command_port,
            connect_timeout: cfg.connect_timeout,
            reply_timeout: cfg.reply_timeout,
        }
    }
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
            resume_after_reconnect: false,
            error_poll_ns: 100_000_000,
            sim_secret: None,
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

    /// Checks, without connecting and without sending anything to the controller, that
    /// `host` stands only for addresses of this machine's loopback interface (127.0.0.0/8,
    /// `::1`, or 127.0.0.0/8 mapped into IPv6). An IP literal (brackets allowed) is judged
    /// as written; a name is resolved as the driver resolves it (the system resolver:
    /// `/etc/hosts`, possibly DNS), and *every* address it resolves to must be loopback.
    ///
    /// # Errors
    /// [`LoopbackCheckError`]: the first address off this machine, or a name that does not
    /// resolve (or resolves to nothing).
    pub fn check_loopback_only(&self) -> Result<(), LoopbackCheckError> {
        self.check_loopback_only_with(|host, port| {
            Ok((host, port).to_socket_addrs()?.map(|a| a.ip()).collect())
        })
    }

    /// [`Self::check_loopback_only`] with the name resolution injected (`resolve(host,
    /// port)`; it is not called for an IP literal).
    ///
    /// # Errors
    /// As [`Self::check_loopback_only`].
    pub fn check_loopback_only_with<R>(&self, resolve: R) -> Result<(), LoopbackCheckError>
    where
        R: FnOnce(&str, u16) -> std::io::Result<Vec<IpAddr>>,
    {
        let literal = self.host.trim_start_matches('[').trim_end_matches(']');
        let ips = match literal.parse::<IpAddr>() {
            Ok(ip) => vec![ip],
            Err(_) => resolve(&self.host, self.command_port)
                .map_err(|e| LoopbackCheckError::Unresolved(e.kind()))?,
        };
        if ips.is_empty() {
            return Err(LoopbackCheckError::NoAddress);
        }
        match ips.into_iter().find(|ip| !ip.to_canonical().is_loopback()) {
            Some(ip) => Err(LoopbackCheckError::NotLoopback(ip)),
            None => Ok(()),
        }
    }
}

/// Why a controller address is not known to stay on this machine
/// ([`XArmConfig::check_loopback_only`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum LoopbackCheckError {
    /// It is, or resolves to, an address that is not loopback.
    #[error("{0} is not a loopback address")]
    NotLoopback(IpAddr),
    /// The name does not resolve.
    #[error("the name does not resolve ({0})")]
    Unresolved(ErrorKind),
    /// The name resolves to no address.
    #[error("the name resolves to no address")]
    NoAddress,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(addr: &str) -> Result<(), LoopbackCheckError> {
        XArmConfig::from_addr(addr).check_loopback_only_with(|host, _| {
            panic!("an IP literal is never resolved (asked for {host})")
        })
    }

    #[test]
    fn loopback_literals_pass_without_resolution() {
        for a in [
            "127.0.0.1",
            "127.0.0.1:5020",
            "127.1.2.3",
            "::1",
            "[::1]:502",
            "::ffff:127.0.0.1",
        ] {
            assert_eq!(check(a), Ok(()), "{a}");
        }
    }

    #[test]
    fn other_literals_are_refused_without_resolution() {
        for (a, ip) in [
            ("10.0.0.2", "10.0.0.2"),
            ("192.168.1.195:502", "192.168.1.195"),
            ("0.0.0.0", "0.0.0.0"),
            ("::", "::"),
            ("[fe80::1]:502", "fe80::1"),
            ("::ffff:10.0.0.2", "::ffff:10.0.0.2"),
        ] {
            let ip: IpAddr = ip.parse().unwrap();
            assert_eq!(check(a), Err(LoopbackCheckError::NotLoopback(ip)), "{a}");
        }
    }

    #[test]
    fn a_name_must_resolve_only_to_loopback() {
        let lo: IpAddr = "127.0.0.1".parse().unwrap();
        let far: IpAddr = "192.168.1.195".parse().unwrap();
        let cfg = XArmConfig::from_addr("robot.lab:502");
        let with = |ips: Vec<IpAddr>| {
            cfg.check_loopback_only_with(move |host, port| {
                assert_eq!((host, port), ("robot.lab", 502));
                Ok(ips)
            })
        };
        assert_eq!(with(vec![lo, "::1".parse().unwrap()]), Ok(()));
        assert_eq!(with(vec![far]), Err(LoopbackCheckError::NotLoopback(far)));
        assert_eq!(
            with(vec![lo, far]),
            Err(LoopbackCheckError::NotLoopback(far))
        );
        assert_eq!(with(vec![]), Err(LoopbackCheckError::NoAddress));
        assert_eq!(
            cfg.check_loopback_only_with(|_, _| Err(ErrorKind::NotFound.into())),
            Err(LoopbackCheckError::Unresolved(ErrorKind::NotFound))
        );
    }

    #[test]
    fn localhost_resolves_to_loopback() {
        assert_eq!(
            XArmConfig::from_addr("localhost").check_loopback_only(),
            Ok(())
        );
    }
}
