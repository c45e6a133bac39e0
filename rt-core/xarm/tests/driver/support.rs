//! Shared helpers of the driver tests: an in-test `xarm-sim` on ephemeral loopback ports, a
//! driver configured for it, a clock and waits. Used by `xarm`'s driver tests and, through
//! `#[path]`, by rt-core's zero-allocation tests (one counting allocator, rt-core's).

#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use shm_schemas::scene_file::SceneFile;
use twin::RobotModel;
use xarm::driver::{XArmConfig, XArmDriver, XArmError};
use xarm::report::ReportKind;
use xarm_sim::{SimOptions, SimPorts, SimServer};

/// The bundled URDF, found from the crate folder upward (this file is shared by the `xarm`
/// and `rt-core` test binaries).
pub fn urdf() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .ancestors()
        .map(|d| d.join("assets/xarm5.urdf"))
        .find(|p| p.is_file())
        .expect("assets/xarm5.urdf above the crate")
}

pub fn home() -> [f64; 5] {
    RobotModel::load(&urdf()).expect("urdf").home()
}

pub fn sim(scenes: Vec<(f64, SceneFile)>) -> SimServer {
    SimServer::start(SimOptions {
        ports: SimPorts::ephemeral(),
        urdf: urdf(),
        scenes,
        q0_rad: home(),
        ..SimOptions::default()
    })
    .expect("sim starts")
}

pub fn cfg(s: &SimServer) -> XArmConfig {
    let p = s.ports();
    let mut c = XArmConfig::new("127.0.0.1");
    c.command_port = p.command;
    c.report_port = p.report_real;
    c.report_kind = ReportKind::Real;
    c.backoff_initial_ns = 10_000_000;
    c
}

pub struct Clock(pub Instant);
impl Clock {
    pub fn ns(&self) -> u64 {
        self.0.elapsed().as_nanos() as u64
    }
}

pub fn sleep_until(deadline: Instant) {
    let now = Instant::now();
    if deadline > now {
        std::thread::sleep(deadline - now);
    }
}

/// Waits (up to 5 s) for `read_state` to answer with a state; panics on other errors.
pub fn wait_for_state(d: &mut XArmDriver, clock: &Clock) -> xarm::driver::DriverState {
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        match d.read_state(clock.ns()) {
            Ok(st) => return st,
            Err(XArmError::Disconnected | XArmError::NoState) if Instant::now() < deadline => {
                std::thread::sleep(Duration::from_millis(5));
            }
            Err(e) => panic!("no state (reconnect failed?): {e:?}"),
        }
    }
}

pub fn driver(cfg: XArmConfig) -> XArmDriver {
    XArmDriver::connect(cfg).expect("connect")
}
