//! A cycle over the production parts on the real protocol (included with `#[path]`): the
//! twin's shield model ([`TwinModel`]), the xArm link (driver and TCP check), and `xarm-sim`
//! in this process, reached through a TCP proxy that can cut the link and rewrite what the
//! controller says (its version string, the TCP pose in its reports); stepped on this thread
//! at the real period (4 ms), with a fresh scene every cycle and plans handed over directly.

#![allow(dead_code, missing_docs)]

use std::io::{Read, Write};
use std::net::{Shutdown, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use rt_core::config::RuntimeConfig;
use rt_core::cycle::brake::Brake;
use rt_core::cycle::plan::Plan;
use rt_core::cycle::shield::{Shield, ShieldLimits};
use rt_core::cycle::twin_model::TwinModel;
use rt_core::cycle::xarm_link::{MAX_TCP_GAP_M, TcpCheck, XArmLink};
use rt_core::cycle::{self, Cycle, CycleConfig, CycleEvent, SceneUpdate, TwinIo};
use rt_core::rt::clock::{Clock, MonotonicClock};
use rt_core::rt::rt_log::RtLogDrain;
use twin::{DOF, Goal, Joints, RobotModel, Scene};
use xarm::driver::{XArmConfig, XArmDriver};
use xarm::report::ReportKind;
use xarm_sim::{SimOptions, SimPorts, SimServer, SimSummary};

/// What a proxy changes in the controller's bytes (controller → client).
#[derive(Debug, Clone, Default)]
pub enum Rewrite {
    /// Nothing.
    #[default]
    None,
    /// The command port: every `GET_VERSION` reply carries this version string instead.
    Version(String),
    /// A report port: the reported TCP's x is moved by this many mm (an `f64` in the bits
    /// of the atomic; 0 = unchanged), switchable while connected.
    TcpOffsetMm(Arc<AtomicU64>),
}

impl Rewrite {
    /// A switchable TCP offset, starting at `mm`.
    pub fn tcp_offset(mm: f64) -> (Self, Arc<AtomicU64>) {
        let a = Arc::new(AtomicU64::new(mm.to_bits()));
        (Self::TcpOffsetMm(a.clone()), a)
    }

    /// The length of the first whole frame/packet in `buf`, if there is one.
    fn frame_len(&self, buf: &[u8]) -> Option<usize> {
        let n = match self {
            Self::None => buf.len(),
            Self::Version(_) => 6 + usize::from(u16::from_be_bytes([*buf.get(4)?, *buf.get(5)?])),
            Self::TcpOffsetMm(_) => {
                u32::from_be_bytes([*buf.first()?, *buf.get(1)?, *buf.get(2)?, *buf.get(3)?])
                    as usize
            }
        };
        (n > 0 && n <= buf.len()).then_some(n)
    }

    /// Changes one whole frame/packet in place.
    fn apply(&self, frame: &mut [u8]) {
        match self {
            Self::None => {}
            Self::Version(v) => {
                // Register 0x01 (GET_VERSION): 40 bytes of text from offset 8.
                if frame.len() >= 48 && frame[6] == 0x01 {
                    let mut text = [0u8; 40];
                    let n = v.len().min(40);
                    text[..n].copy_from_slice(&v.as_bytes()[..n]);
                    frame[8..48].copy_from_slice(&text);
                }
            }
            Self::TcpOffsetMm(mm) => {
                let mm = f64::from_bits(mm.load(Ordering::Acquire));
                // Reported TCP x at [35..39), f32 LE, in every report stream but 30000's.
                if mm != 0.0 && frame.len() >= 39 {
                    let x = f32::from_le_bytes([frame[35], frame[36], frame[37], frame[38]]);
                    frame[35..39].copy_from_slice(&((f64::from(x) + mm) as f32).to_le_bytes());
                }
            }
        }
    }
}

/// Copies `from` to `to`, rewriting each whole frame/packet with `rule`. While `held` is
/// set, what arrives is kept back; once it is cleared, everything kept goes out (oldest
/// first) with the next bytes that arrive.
fn pump(mut from: TcpStream, mut to: TcpStream, rule: Rewrite, held: Arc<AtomicBool>) {
    let mut buf = [0_u8; 4096];
    let mut pending: Vec<u8> = Vec::new();
    let mut out = Vec::new();
    while let Ok(n) = from.read(&mut buf) {
        if n == 0 {
            break;
        }
        pending.extend_from_slice(&buf[..n]);
        while let Some(len) = rule.frame_len(&pending) {
            let mut frame: Vec<u8> = pending.drain(..len).collect();
            rule.apply(&mut frame);
            out.extend_from_slice(&frame);
        }
        if held.load(Ordering::Acquire) {
            continue;
        }
        if to.write_all(&out).is_err() {
            break;
        }
        out.clear();
    }
    let _ = to.shutdown(Shutdown::Both);
    let _ = from.shutdown(Shutdown::Both);
}

/// A TCP proxy in front of one port that can cut every connection and refuse new ones
/// for a while (a pulled cable, a switch reboot), and rewrite what the controller sends.
pub struct Proxy {
    pub port: u16,
    conns: Arc<Mutex<Vec<TcpStream>>>,
    refuse_until_ns: Arc<AtomicU64>,
    origin: Instant,
    stop: Arc<AtomicBool>,
    held: Arc<AtomicBool>,
}

impl Proxy {
    pub fn start(upstream: u16) -> Self {
        Self::rewriting(upstream, Rewrite::None)
    }

    /// A proxy that rewrites the controller's bytes with `rule`.
    pub fn rewriting(upstream: u16, rule: Rewrite) -> Self {
        let listener = TcpListener::bind(("127.0.0.1", 0)).expect("proxy bind");
        let port = listener.local_addr().expect("addr").port();
        listener.set_nonblocking(true).expect("nonblocking");
        let conns: Arc<Mutex<Vec<TcpStream>>> = Arc::default();
        let refuse_until_ns = Arc::new(AtomicU64::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let held = Arc::new(AtomicBool::new(false));
        let origin = Instant::now();
        let (c, r, s, h) = (
            conns.clone(),
            refuse_until_ns.clone(),
            stop.clone(),
            held.clone(),
        );
        std::thread::spawn(move || {
            while !s.load(Ordering::Acquire) {
                match listener.accept() {
                    Ok((client, _)) => {
                        let now = origin.elapsed().as_nanos() as u64;
                        if now < r.load(Ordering::Acquire) {
                            drop(client);
                            continue;
                        }
                        let _ = client.set_nonblocking(false);
                        let _ = client.set_nodelay(true);
                        let Ok(server) = TcpStream::connect(("127.0.0.1", upstream)) else {
                            continue;
                        };
                        let _ = server.set_nodelay(true);
                        for (from, to, rule, held) in [
                            (
                                client.try_clone().expect("clone"),
                                server.try_clone().expect("clone"),
                                Rewrite::None,
                                Arc::new(AtomicBool::new(false)),
                            ),
                            (
                                server.try_clone().expect("clone"),
                                client.try_clone().expect("clone"),
                                rule.clone(),
                                h.clone(),
                            ),
                        ] {
                            std::thread::spawn(move || pump(from, to, rule, held));
                        }
                        if let Ok(mut v) = c.lock() {
                            v.push(client);
                            v.push(server);
                        }
                    }
                    Err(_) => std::thread::sleep(Duration::from_micros(200)),
                }
            }
        });
        Self {
            port,
            conns,
            refuse_until_ns,
            origin,
            stop,
            held,
        }
    }

    /// Holds back what the controller sends (`true`: a stalled stream, e.g. a controller
    /// starved of CPU or a congested path; the connection stays up) or lets it through
    /// again, everything held back first (`false`).
    pub fn hold(&self, held: bool) {
        self.held.store(held, Ordering::Release);
    }

    /// Cuts every connection now and refuses new ones for `for_dur`.
    pub fn cut(&self, for_dur: Duration) {
        let until = self.origin.elapsed() + for_dur;
        self.refuse_until_ns
            .store(until.as_nanos() as u64, Ordering::Release);
        if let Ok(mut v) = self.conns.lock() {
            for s in v.drain(..) {
                let _ = s.shutdown(Shutdown::Both);
            }
        }
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        self.cut(Duration::ZERO);
    }
}

pub struct XRig {
    pub cfg: RuntimeConfig,
    pub sim: Option<SimServer>,
    pub command_proxy: Proxy,
    pub report_proxy: Proxy,
    pub cycle: Cycle<TwinModel, XArmLink>,
    pub twin_io: TwinIo<Scene>,
    pub log: RtLogDrain<CycleEvent>,
    pub clock: MonotonicClock,
    pub scene: Scene,
    next_plan_id: u64,
    deadline_ns: u64,
}

pub fn urdf() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .ancestors()
        .map(|d| d.join("assets/xarm5.urdf"))
        .find(|p| p.is_file())
        .expect("assets/xarm5.urdf above the crate")
}

/// The rig's cycle thread's `SCHED_FIFO` priority (rt-core's default cycle priority is
/// higher; any real-time priority outranks the machine's ordinary load).
const RIG_FIFO_PRIORITY: i32 = 10;

impl XRig {
    /// A cycle in servo mode on a fresh `xarm-sim` at the arm's home pose. `auto_resume`:
    /// the link's return needs no acknowledgement (and the driver re-enters servo mode).
    pub fn start(auto_resume: bool) -> Self {
        Self::start_rewriting(auto_resume, Rewrite::None)
    }

    /// [`XRig::start`] with the reports rewritten by `report_rule`.
    ///
    /// The calling thread, which runs the cycle, asks for `SCHED_FIFO` as rt-core's cycle
    /// thread does in production (`cycle::thread`): without it, on a loaded 2-core machine
    /// (the suite's other tests, or `../shared/tools/under-load`), the test thread was
    /// descheduled for more than the freeze bound and the cycle latched `Frozen` — a stop
    /// that is right for a real process and not what these tests are about. Where the
    /// priority is refused (no CAP_SYS_NICE), the rig runs at normal priority.
    pub fn start_rewriting(auto_resume: bool, report_rule: Rewrite) -> Self {
        let _ = rt_core::rt::rt_setup::set_fifo(RIG_FIFO_PRIORITY);
        let cfg = RuntimeConfig::xarm5_default();
        let model = RobotModel::load(&urdf()).expect("urdf");
        let (sim, command_proxy, report_proxy) = sim_behind_proxies(Rewrite::None, report_rule);
        let mut xcfg = XArmConfig::new("127.0.0.1");
        xcfg.command_port = command_proxy.port;
        xcfg.report_port = report_proxy.port;
        xcfg.report_kind = ReportKind::Real;
        xcfg.backoff_initial_ns = 2_000_000;
        xcfg.backoff_max_ns = 50_000_000;
        xcfg.resume_after_reconnect = auto_resume;
        xcfg.max_resume_step_rad = max_step_rad(&cfg);
        let mut driver = XArmDriver::connect(xcfg).expect("connect");
        driver.enter_servo_mode().expect("servo mode");
        let link = XArmLink::new(driver, TcpCheck::new(model.clone(), MAX_TCP_GAP_M), None);
        let (twin_io, cycle_io, log) = cycle::wire::<Scene>();
        let mut cycle_cfg = CycleConfig::from_runtime(&cfg);
        cycle_cfg.auto_resume_after_link_loss = auto_resume;
        // The rig's cycle runs on wall time on the test's thread, without real-time
        // priority, beside the whole suite: it keeps the 100 ms freeze bound it was written
        // for (its freeze tests stall past it). The production bound, 10 periods (40 ms at
        // 250 Hz, issue 41 item 5), is tested on the manual clock (`runtime/safety.rs`); on
        // a loaded 2-core machine this rig's cycle was late by more than that 3 times of 3.
        cycle_cfg.max_cycle_gap_ns = cycle_cfg.max_cycle_gap_ns.max(100_000_000);
        let mut cycle = Cycle::new(
            cycle_cfg,
            Shield::new(
                TwinModel::new(model),
                ShieldLimits::from_config(&cfg.limits, &cfg.shield),
            ),
            Brake::new(&cfg.limits),
            link,
            cycle_io,
        );
        let clock = MonotonicClock::new();
        let mut started = cycle.start(clock.now_ns());
        for _ in 0..100 {
            if started.is_ok() {
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
            started = cycle.start(clock.now_ns());
        }
        started.expect("the cycle reads the arm");
        let scene = Scene::empty(
            0.0,
            Goal {
                center_m: [0.35, 0.15, 0.025],
                size_m: 0.05,
            },
        );
        let deadline_ns = clock.now_ns();
        Self {
            cfg,
            sim: Some(sim),
            command_proxy,
            report_proxy,
            cycle,
            twin_io,
            log,
            clock,
            scene,
            next_plan_id: 1,
            deadline_ns,
        }
    }

    pub fn period_ns(&self) -> u64 {
        self.cfg.period_ns()
    }

    /// One cycle at the next deadline (sleeping until it), with a fresh scene.
    pub fn cycle_once(&mut self) {
        self.deadline_ns += self.period_ns();
        self.clock.sleep_until_ns(self.deadline_ns);
        let now = self.clock.now_ns();
        self.twin_io.scenes.send(SceneUpdate {
            scene: self.scene,
            stamp_ns: now,
            refused: false,
            intruders: rt_core::cycle::Intruders::NONE,
        });
        self.cycle.process(now);
        self.twin_io.plans.collect_returned();
        let _ = self.twin_io.reports.latest();
    }

    /// Runs for `dur` of real time.
    pub fn run_for(&mut self, dur: Duration) {
        let n = dur.as_nanos() as u64 / self.period_ns();
        self.deadline_ns = self.deadline_ns.max(self.clock.now_ns());
        for _ in 0..n {
            self.cycle_once();
        }
    }

    /// Hands over a plan from where the arm stands to `delta` away (cosine profile over
    /// `duration_s`, within the velocity limit); returns its id.
    pub fn send_plan(&mut self, delta: Joints, duration_s: f64) -> u64 {
        let q0 = self.cycle.report().measured_q_rad;
        let dt = 1.0 / self.cfg.rate_hz;
        let id = self.next_plan_id;
        self.next_plan_id += 1;
        let n = (duration_s / dt).ceil() as usize;
        let mut plan = Plan::with_capacity(id, 1, dt, n + 1);
        let w = std::f64::consts::PI / duration_s;
        for i in 0..=n {
            let t = i as f64 * dt;
            let (mut q, mut dq, mut ddq) = ([0.0; DOF], [0.0; DOF], [0.0; DOF]);
            for j in 0..DOF {
                q[j] = q0[j] + delta[j] * 0.5 * (1.0 - (w * t).cos());
                dq[j] = delta[j] * 0.5 * w * (w * t).sin();
                ddq[j] = delta[j] * 0.5 * w * w * (w * t).cos();
            }
            plan.push(q, dq, ddq);
        }
        assert!(
            self.twin_io.plans.send(Box::new(plan)).is_ok(),
            "plan slot full"
        );
        id
    }

    /// Hands over `plan` as built by the caller (e.g. a faulty one); returns its id.
    pub fn send_raw_plan(&mut self, mut plan: Plan) -> u64 {
        plan.id = self.next_plan_id;
        self.next_plan_id += 1;
        let id = plan.id;
        assert!(
            self.twin_io.plans.send(Box::new(plan)).is_ok(),
            "plan slot full"
        );
        id
    }

    pub fn sim_summary(&self) -> SimSummary {
        self.sim.as_ref().expect("sim").summary()
    }
}

/// A fresh `xarm-sim` (in this process) at the arm's home pose, reached through a proxy on
/// its command port (rewriting with `command_rule`) and one on its "real" report port
/// (`report_rule`).
pub fn sim_behind_proxies(
    command_rule: Rewrite,
    report_rule: Rewrite,
) -> (SimServer, Proxy, Proxy) {
    let model = RobotModel::load(&urdf()).expect("urdf");
    let sim = SimServer::start(SimOptions {
        ports: SimPorts::ephemeral(),
        urdf: urdf(),
        q0_rad: model.home(),
        ..SimOptions::default()
    })
    .expect("sim starts");
    let ports = sim.ports();
    let command_proxy = Proxy::rewriting(ports.command, command_rule);
    let report_proxy = Proxy::rewriting(ports.report(ReportKind::Real), report_rule);
    (sim, command_proxy, report_proxy)
}

/// The most one joint may move between two targets: one period at its velocity limit.
pub fn max_step_rad(cfg: &RuntimeConfig) -> f64 {
    ShieldLimits::from_config(&cfg.limits, &cfg.shield).max_step_rad(1.0 / cfg.rate_hz)
}

/// A move that peaks at about 0.75 rad/s on joint 1 over 2.5 s.
pub const MOVE: Joints = [1.2, 0.25, -0.25, 0.2, 0.3];
