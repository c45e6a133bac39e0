//! The simulator's sockets and threads: the command port (request/response), the four report
//! ports (streamed at their real rates), a physics thread (250 Hz integration, ground-truth
//! contact check with every moving box placed at the tick's time, scheduled scene swaps) and
//! a line-based control port.
//!
//! Control port protocol (one command per line, one reply line each):
//! `scene <path>` swaps the scene now (`ok` / `error: …`; a live scene file's
//! `in_force_since_monotonic_ns` is the origin of its boxes' paths, else the moment the file
//! was read: [`shm_schemas::scene_file::live`]), `status` prints the summary JSON,
//! `error <code>` raises a controller error now (e.g. `error 31`, a collision; `ok` /
//! `error: …`), `state <s>` sends `SET_STATE(s)` as another client would (the pendant's
//! stop is `state 4`), `freeze on|off` freezes the arm (targets accepted, joints still: a
//! fault injection), `shutdown` asks the simulator to exit.

use std::io::{BufRead, BufReader, ErrorKind, Read, Write};
use std::net::{IpAddr, Ipv4Addr, SocketAddr, TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use shm_schemas::clock::monotonic_now_ns;
use shm_schemas::scene_file::{LiveScene, SceneFile};

use super::controller::{
    Controller, ControllerCounters, ProtectiveFault, ProtectiveLimits, ProtectiveLimitsError,
};
use super::world::{RefereeSummary, World, WorldError, tcp_pose_report};
use xarm::codec::{self, MAX_FRAME_LEN};
use xarm::codes::ControllerError;
use xarm::report::{self, ReportKind, RichExtras};

/// Physics (integration and contact check) rate (Hz).
pub const PHYSICS_HZ: f64 = 250.0;
/// Default control port (line-based scene control), before any offset.
pub const DEFAULT_CONTROL_PORT: u16 = 30010;

/// The ports the simulator listens on (0 = pick a free one).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct SimPorts {
    /// Command port (502 on the arm).
    pub command: u16,
    /// 250 Hz real-time report (30000).
    pub report_rt: u16,
    /// Normal report (30001).
    pub report_normal: u16,
    /// Rich report (30002).
    pub report_rich: u16,
    /// Real report (30003).
    pub report_real: u16,
    /// Control port.
    pub control: u16,
}

impl SimPorts {
    /// The controller's real ports (plus [`DEFAULT_CONTROL_PORT`]) shifted by `offset`.
    pub fn with_offset(offset: u16) -> Self {
        Self {
            command: 502u16.wrapping_add(offset),
            report_rt: report::PORT_REPORT_RT.wrapping_add(offset),
            report_normal: report::PORT_REPORT_NORMAL.wrapping_add(offset),
            report_rich: report::PORT_REPORT_RICH.wrapping_add(offset),
            report_real: report::PORT_REPORT_REAL.wrapping_add(offset),
            control: DEFAULT_CONTROL_PORT.wrapping_add(offset),
        }
    }

    /// All ports 0: the OS picks free ones (for tests); read them back from the server.
    pub fn ephemeral() -> Self {
        Self {
            command: 0,
            report_rt: 0,
            report_normal: 0,
            report_rich: 0,
            report_real: 0,
            control: 0,
        }
    }

    /// The port of a report stream.
    pub fn report(&self, kind: ReportKind) -> u16 {
        match kind {
            ReportKind::RealTime => self.report_rt,
            ReportKind::Normal => self.report_normal,
            ReportKind::Rich => self.report_rich,
            ReportKind::Real => self.report_real,
        }
    }
}

/// How to start the simulator.
#[derive(Debug, Clone)]
pub struct SimOptions {
    /// Address to bind.
    pub bind: IpAddr,
    /// Ports.
    pub ports: SimPorts,
    /// Robot model for FK and contact.
    pub urdf: PathBuf,
    /// Scene timeline: `(at_s, scene)` from the start, ascending. Empty: no obstacles. A
    /// scene's boxes count time on their paths from its `at_s`.
    pub scenes: Vec<(f64, SceneFile)>,
    /// When the scene at 0 s came into force (`CLOCK_MONOTONIC`, ns: a live scene file's
    /// `in_force_since_monotonic_ns`); `None`: when the simulator starts.
    pub first_scene_in_force_since_ns: Option<u64>,
    /// Contact margin (m); 0 is touching.
    pub contact_margin_m: f64,
    /// Initial joints (rad).
    pub q0_rad: [f64; 5],
    /// The servo-mode protective check (joint and TCP speed faults); on by default.
    pub protective: ProtectiveLimits,
    /// The run's secret ([`xarm::sim_identity`]): with it the simulator proves it is
    /// `xarm-sim` and may be given simulation-only rights (blind mode, auto-resume, the
    /// synthetic camera); `None` (the default): it passes for a real arm.
    pub sim_secret: Option<xarm::sim_identity::SimSecret>,
}

impl Default for SimOptions {
    fn default() -> Self {
        Self {
            bind: IpAddr::V4(Ipv4Addr::LOCALHOST),
            ports: SimPorts::with_offset(0),
            urdf: default_urdf(),
            scenes: Vec::new(),
            first_scene_in_force_since_ns: None,
            contact_margin_m: 0.0,
            q0_rad: [0.0; 5],
            protective: ProtectiveLimits::default(),
            sim_secret: None,
        }
    }
}

/// `assets/xarm5.urdf` relative to the working directory if it exists there, else the
/// repository's copy.
pub fn default_urdf() -> PathBuf {
    let local = PathBuf::from("assets/xarm5.urdf");
    if local.exists() {
        return local;
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/xarm5.urdf")
}

/// Why the simulator could not start or change its scene.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A port could not be bound.
    #[error("cannot bind {addr}")]
    Bind {
        /// Address.
        addr: SocketAddr,
        /// OS error.
        source: std::io::Error,
    },
    /// The world (model or scene) was rejected.
    #[error(transparent)]
    World(#[from] WorldError),
    /// A thread could not be spawned.
    #[error("cannot spawn thread: {0}")]
    Spawn(std::io::Error),
    /// The protective limits are invalid.
    #[error(transparent)]
    Limits(#[from] ProtectiveLimitsError),
}

/// What the simulator did, printed as one JSON line at exit.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SimSummary {
    /// Seconds since start.
    pub uptime_s: f64,
    /// Collisions raised.
    pub collisions: u64,
    /// Controller counters.
    pub counters: ControllerCounters,
    /// Reports sent per stream: rt, normal, rich, real.
    pub reports_sent: [u64; 4],
    /// Scene swaps applied.
    pub scene_swaps: u64,
    /// Scene in force.
    pub scene: String,
    /// Command connections accepted.
    pub connections: u64,
    /// Final joints (rad).
    pub q_rad: [f64; 5],
    /// Final error code.
    pub error_code: u8,
    /// Controller state (1 moving, 2 ready, 3 paused, 4 stopped).
    pub state: u8,
    /// Controller mode (1 = servo).
    pub mode: u8,
    /// Protective faults raised (joint speed + TCP speed).
    pub protective_faults: u64,
    /// Joint speed faults (error 24).
    pub joint_speed_faults: u64,
    /// TCP speed faults (error 60).
    pub tcp_speed_faults: u64,
    /// The last protective fault, with the step that caused it and the limit.
    pub last_protective_fault: Option<ProtectiveFault>,
    /// Largest per-joint step between consecutive `servo_j` targets received (rad).
    pub max_joint_step_rad: f64,
    /// Largest TCP step between consecutive `servo_j` targets received (m).
    pub max_tcp_step_m: f64,
    /// `CLEAN_ERR` requests received.
    pub clean_error_requests: u64,
    /// `SET_STATE(4)` requests received.
    pub stop_requests: u64,
    /// The protective limits in force.
    pub protective_limits: ProtectiveLimits,
    /// The independent referee's figures: contacts and the smallest clearance seen, with
    /// the link and what it was near ([`crate::referee`]).
    pub referee: RefereeSummary,
}

struct Shared {
    controller: Mutex<Controller>,
    world: Mutex<World>,
    /// A scene to swap in at the next tick, with when it came into force (ns).
    pending_scene: Mutex<Option<(SceneFile, u64)>>,
    shutdown: AtomicBool,
    shutdown_requested: AtomicBool,
    reports_sent: [AtomicU64; 4],
    scene_swaps: AtomicU64,
    connections: AtomicU64,
    start: Instant,
    /// `start` on `CLOCK_MONOTONIC` (ns): the origin of the scene timeline.
    start_ns: u64,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

impl Shared {
    fn now_s(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }
}

/// A running simulator. Dropping it without [`SimServer::shutdown`] leaves threads running
/// until the process exits.
pub struct SimServer {
    shared: Arc<Shared>,
    ports: SimPorts,
    threads: Vec<JoinHandle<()>>,
}

fn bind(ip: IpAddr, port: u16) -> Result<(TcpListener, u16), SimError> {
    let addr = SocketAddr::new(ip, port);
    let l = TcpListener::bind(addr).map_err(|source| SimError::Bind { addr, source })?;
    l.set_nonblocking(true)
        .map_err(|source| SimError::Bind { addr, source })?;
    let port = l.local_addr().map(|a| a.port()).unwrap_or(port);
    Ok((l, port))
}

/// Loads the robot model and applies the first scene when it is scheduled at or before 0 s
/// (in force since `opts.first_scene_in_force_since_ns`, else `start_ns`); returns the world
/// and the rest of the schedule, in time order.
fn load_world(
    opts: &SimOptions,
    start_ns: u64,
) -> Result<(World, Vec<(f64, SceneFile)>), SimError> {
    let mut world = World::load(&opts.urdf, opts.contact_margin_m)?;
    let mut schedule = opts.scenes.clone();
    schedule.sort_by(|a, b| a.0.total_cmp(&b.0));
    if let Some((at, first)) = schedule.first()
        && *at <= 0.0
    {
        world.set_scene_since(
            first,
            opts.first_scene_in_force_since_ns.unwrap_or(start_ns),
        )?;
        schedule.remove(0);
    }
    Ok((world, schedule))
}

/// The listeners of one simulated arm: the ports actually bound (0 asks the OS for one),
/// the command listener, one listener per report kind and the control listener.
type Listeners = (
    SimPorts,
    TcpListener,
    Vec<(ReportKind, TcpListener)>,
    TcpListener,
);

/// Binds the command, report and control ports on `ip`.
fn bind_all(ip: IpAddr, asked: SimPorts) -> Result<Listeners, SimError> {
    let (cmd_l, command) = bind(ip, asked.command)?;
    let mut ports = SimPorts { command, ..asked };
    let mut report_listeners = Vec::new();
    for kind in [
        ReportKind::RealTime,
        ReportKind::Normal,
        ReportKind::Rich,
        ReportKind::Real,
    ] {
        let (l, p) = bind(ip, asked.report(kind))?;
        match kind {
            ReportKind::RealTime => ports.report_rt = p,
            ReportKind::Normal => ports.report_normal = p,
            ReportKind::Rich => ports.report_rich = p,
            ReportKind::Real => ports.report_real = p,
        }
        report_listeners.push((kind, l));
    }
    let (ctl_l, control) = bind(ip, asked.control)?;
    ports.control = control;
    Ok((ports, cmd_l, report_listeners, ctl_l))
}

fn spawn(
    threads: &mut Vec<JoinHandle<()>>,
    name: &str,
    f: impl FnOnce() + Send + 'static,
) -> Result<(), SimError> {
    let h = std::thread::Builder::new()
        .name(name.into())
        .spawn(f)
        .map_err(SimError::Spawn)?;
    threads.push(h);
    Ok(())
}

const POLL: Duration = Duration::from_millis(5);

impl SimServer {
    /// Binds every port and starts the threads.
    ///
    /// # Errors
    /// [`SimError`] when a port is taken, the model or first scene or the protective limits
    /// are invalid.
    pub fn start(opts: SimOptions) -> Result<Self, SimError> {
        opts.protective.validate()?;
        let (start, start_ns) = (Instant::now(), monotonic_now_ns());
        let (world, schedule) = load_world(&opts, start_ns)?;
        let mut controller = Controller::new(opts.q0_rad);
        controller.set_model(world.model().clone());
        controller.set_protective_limits(opts.protective);
        controller.set_sim_secret(opts.sim_secret.clone());
        controller.set_tcp_pose(tcp_pose_report(&opts.q0_rad));
        let shared = Arc::new(Shared {
            controller: Mutex::new(controller),
            world: Mutex::new(world),
            pending_scene: Mutex::new(None),
            shutdown: AtomicBool::new(false),
            shutdown_requested: AtomicBool::new(false),
            reports_sent: Default::default(),
            scene_swaps: AtomicU64::new(0),
            connections: AtomicU64::new(0),
            start,
            start_ns,
        });
        let (ports, cmd_l, report_listeners, ctl_l) = bind_all(opts.bind, opts.ports)?;

        let mut threads = Vec::new();
        let s = shared.clone();
        spawn(&mut threads, "sim-command", move || {
            command_acceptor(&s, &cmd_l)
        })?;
        for (kind, l) in report_listeners {
            let s = shared.clone();
            spawn(&mut threads, "sim-report", move || {
                report_loop(&s, kind, &l)
            })?;
        }
        let s = shared.clone();
        spawn(&mut threads, "sim-physics", move || {
            physics_loop(&s, schedule)
        })?;
        let s = shared.clone();
        spawn(&mut threads, "sim-control", move || {
            control_acceptor(&s, &ctl_l)
        })?;
        tracing::info!(?ports, "xarm-sim listening");
        Ok(Self {
            shared,
            ports,
            threads,
        })
    }

    /// The ports actually bound.
    pub fn ports(&self) -> SimPorts {
        self.ports
    }

    /// Whether a client asked for shutdown over the control port.
    pub fn shutdown_requested(&self) -> bool {
        self.shared.shutdown_requested.load(Ordering::Relaxed)
    }

    /// Queues a scene swap (applied by the physics thread within one tick), in force from
    /// now.
    pub fn set_scene(&self, scene: SceneFile) {
        self.set_scene_since(scene, monotonic_now_ns());
    }

    /// Queues a scene swap (applied by the physics thread within one tick), in force since
    /// `in_force_since_ns` (`CLOCK_MONOTONIC`): the origin of its boxes' paths.
    pub fn set_scene_since(&self, scene: SceneFile, in_force_since_ns: u64) {
        *lock(&self.shared.pending_scene) = Some((scene, in_force_since_ns));
    }

    /// Raises a controller error now, as the arm does (e.g. [`ControllerError::Collision`]):
    /// error code set, motion stopped, state 4, motion refused until `CLEAN_ERR`. A collision
    /// code counts as a collision. [`ControllerError::None`] is ignored.
    pub fn inject_error(&self, code: ControllerError) {
        lock(&self.shared.controller).raise_error(code);
    }

    /// `SET_STATE(state)` from another client (the pendant's or the SDK's stop is 4).
    pub fn inject_state(&self, state: u8) {
        lock(&self.shared.controller).request_state(state);
    }

    /// Freezes the arm (targets accepted, joints still) or lets it move again.
    pub fn freeze(&self, frozen: bool) {
        lock(&self.shared.controller).set_frozen(frozen);
    }

    /// The summary so far.
    pub fn summary(&self) -> SimSummary {
        summary(&self.shared)
    }

    /// Stops every thread and returns the final summary.
    pub fn shutdown(self) -> SimSummary {
        self.shared.shutdown.store(true, Ordering::Relaxed);
        for t in self.threads {
            let _ = t.join();
        }
        summary(&self.shared)
    }
}

fn summary(s: &Shared) -> SimSummary {
    // One world lock, taken and released before the controller's (a second guard on the
    // same mutex inside the struct expression below would deadlock).
    let (scene, referee) = {
        let w = lock(&s.world);
        (w.scene_name().to_string(), w.referee_summary().clone())
    };
    let c = lock(&s.controller);
    let counters = c.counters();
    let stream = c.servo_stream();
    SimSummary {
        uptime_s: s.now_s(),
        collisions: counters.collisions,
        counters,
        reports_sent: [0, 1, 2, 3].map(|i| s.reports_sent[i].load(Ordering::Relaxed)),
        scene_swaps: s.scene_swaps.load(Ordering::Relaxed),
        scene,
        connections: s.connections.load(Ordering::Relaxed),
        q_rad: c.q_rad(),
        error_code: u8::from(c.error()),
        state: c.state(),
        mode: c.mode(),
        protective_faults: counters.protective_faults,
        joint_speed_faults: counters.joint_speed_faults,
        tcp_speed_faults: counters.tcp_speed_faults,
        last_protective_fault: stream.last_fault,
        max_joint_step_rad: stream.max_joint_step_rad,
        max_tcp_step_m: stream.max_tcp_step_m,
        clean_error_requests: counters.clean_error_requests,
        stop_requests: counters.stop_requests,
        protective_limits: c.protective_limits(),
        referee,
    }
}

fn apply_scene(s: &Shared, scene: &SceneFile, in_force_since_ns: u64) {
    match lock(&s.world).set_scene_since(scene, in_force_since_ns) {
        Ok(()) => {
            s.scene_swaps.fetch_add(1, Ordering::Relaxed);
            tracing::info!(scene = %scene.name, "scene swapped");
        }
        Err(e) => tracing::warn!("scene swap refused: {e}"),
    }
}

fn physics_loop(s: &Shared, mut schedule: Vec<(f64, SceneFile)>) {
    let period = Duration::from_secs_f64(1.0 / PHYSICS_HZ);
    let mut next = Instant::now();
    while !s.shutdown.load(Ordering::Relaxed) {
        let now_s = s.now_s();
        while schedule.first().is_some_and(|(at, _)| *at <= now_s) {
            let (at_s, scene) = schedule.remove(0);
            // In force since its scheduled time, however late this tick applies it.
            let since_ns = s.start_ns.saturating_add((at_s.max(0.0) * 1e9) as u64);
            apply_scene(s, &scene, since_ns);
        }
        let pending = lock(&s.pending_scene).take();
        if let Some((scene, since_ns)) = pending {
            apply_scene(s, &scene, since_ns);
        }
        let q = {
            let mut c = lock(&s.controller);
            c.step(now_s);
            c.q_rad()
        };
        let check = lock(&s.world).check_at(&q, monotonic_now_ns());
        {
            let mut c = lock(&s.controller);
            c.set_tcp_pose(check.tcp_pose);
            if check.new_contact {
                // Raised whether the arm moved into the box or a box walked into the arm at
                // rest, as a real xArm's collision detection trips when a stopped arm is
                // pushed; the referee's summary tells the two apart.
                tracing::warn!(
                    ?q,
                    clearance = ?check.clearance,
                    arm_moving = check.arm_moving,
                    "collision (referee)"
                );
                c.raise_error(ControllerError::Collision);
            }
        }
        next += period;
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        } else {
            next = now;
        }
    }
}

fn command_acceptor(s: &Arc<Shared>, l: &TcpListener) {
    let mut handlers: Vec<JoinHandle<()>> = Vec::new();
    while !s.shutdown.load(Ordering::Relaxed) {
        match l.accept() {
            Ok((stream, peer)) => {
                tracing::info!(%peer, "command connection");
                s.connections.fetch_add(1, Ordering::Relaxed);
                let s2 = s.clone();
                if let Ok(h) = std::thread::Builder::new()
                    .name("sim-conn".into())
                    .spawn(move || serve_commands(&s2, stream))
                {
                    handlers.push(h);
                }
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => std::thread::sleep(POLL),
            Err(e) => {
                tracing::warn!("accept: {e}");
                std::thread::sleep(POLL);
            }
        }
        handlers.retain(|h| !h.is_finished());
    }
    for h in handlers {
        let _ = h.join();
    }
}

fn serve_commands(s: &Shared, mut stream: TcpStream) {
    let _ = stream.set_nonblocking(false);
    let _ = stream.set_nodelay(true);
    let _ = stream.set_read_timeout(Some(Duration::from_millis(50)));
    let mut buf = [0u8; 4 * MAX_FRAME_LEN];
    let mut len = 0usize;
    let mut out = [0u8; MAX_FRAME_LEN];
    while !s.shutdown.load(Ordering::Relaxed) {
        match stream.read(&mut buf[len..]) {
            Ok(0) => return,
            Ok(n) => len += n,
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => continue,
            Err(e) if e.kind() == ErrorKind::Interrupted => continue,
            Err(_) => return,
        }
        let mut start = 0;
        loop {
            match codec::frame_len(&buf[start..len], 1) {
                Ok(Some(n)) => {
                    let frame = &buf[start..start + n];
                    start += n;
                    let reply = lock(&s.controller).handle(frame, &mut out);
                    match reply {
                        Ok(0) => {}
                        Ok(m) => {
                            if stream.write_all(&out[..m]).is_err() {
                                return;
                            }
                        }
                        Err(e) => tracing::warn!("bad command frame: {e}"),
                    }
                }
                Ok(None) => break,
                Err(e) => {
                    // The stream is out of step: a controller drops such a connection.
                    tracing::warn!("closing command connection: {e}");
                    return;
                }
            }
        }
        buf.copy_within(start..len, 0);
        len -= start;
    }
}

fn report_loop(s: &Shared, kind: ReportKind, l: &TcpListener) {
    let idx = match kind {
        ReportKind::RealTime => 0,
        ReportKind::Normal => 1,
        ReportKind::Rich => 2,
        ReportKind::Real => 3,
    };
    let period = Duration::from_secs_f64(1.0 / kind.rate_hz());
    let mut clients: Vec<TcpStream> = Vec::new();
    let mut next = Instant::now();
    let mut extras = RichExtras::default();
    let mut rt = [0u8; report::RT_LEN];
    let mut normal = [0u8; report::NORMAL_LEN];
    let mut rich = [0u8; report::RICH_LEN];
    let mut real = [0u8; report::REAL_LEN];
    while !s.shutdown.load(Ordering::Relaxed) {
        while let Ok((c, _)) = l.accept() {
            let _ = c.set_nonblocking(false);
            let _ = c.set_nodelay(true);
            let _ = c.set_write_timeout(Some(Duration::from_millis(200)));
            clients.push(c);
        }
        let now = Instant::now();
        if now < next {
            std::thread::sleep((next - now).min(Duration::from_millis(20)));
            continue;
        }
        next += period;
        if next + 10 * period < now {
            // Far behind (suspended, overloaded): resynchronise instead of bursting.
            next = now + period;
        }
        if clients.is_empty() {
            continue;
        }
        let ts_us = s.start.elapsed().as_micros() as u64;
        let r = lock(&s.controller).report(kind, ts_us);
        let bytes: &[u8] = match kind {
            ReportKind::RealTime => {
                report::encode_rt(&r, &mut rt);
                &rt
            }
            ReportKind::Normal => {
                report::encode_normal(&r, &extras, &mut normal);
                &normal
            }
            ReportKind::Rich => {
                extras.counter = extras.counter.wrapping_add(1);
                report::encode_rich(&r, &extras, &mut rich);
                &rich
            }
            ReportKind::Real => {
                report::encode_real(&r, &mut real);
                &real
            }
        };
        clients.retain_mut(|c| c.write_all(bytes).is_ok());
        s.reports_sent[idx].fetch_add(1, Ordering::Relaxed);
    }
}

fn control_acceptor(s: &Arc<Shared>, l: &TcpListener) {
    while !s.shutdown.load(Ordering::Relaxed) {
        match l.accept() {
            Ok((stream, _)) => {
                let s2 = s.clone();
                let _ = std::thread::Builder::new()
                    .name("sim-control-conn".into())
                    .spawn(move || serve_control(&s2, stream));
            }
            Err(_) => std::thread::sleep(Duration::from_millis(20)),
        }
    }
}

fn serve_control(s: &Shared, stream: TcpStream) {
    let _ = stream.set_nonblocking(false);
    let _ = stream.set_read_timeout(Some(Duration::from_millis(200)));
    let Ok(mut w) = stream.try_clone() else {
        return;
    };
    let mut r = BufReader::new(stream);
    let mut line = String::new();
    while !s.shutdown.load(Ordering::Relaxed) {
        match r.read_line(&mut line) {
            Ok(0) => return,
            Ok(_) => {}
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => continue,
            Err(_) => return,
        }
        let reply = control_command(s, line.trim());
        line.clear();
        if writeln!(w, "{reply}").is_err() {
            return;
        }
    }
}

fn control_command(s: &Shared, cmd: &str) -> String {
    let (verb, arg) = cmd.split_once(' ').unwrap_or((cmd, ""));
    match verb {
        "scene" => match LiveScene::load(Path::new(arg.trim())) {
            Ok(live) => {
                let since_ns = live.in_force_since_or(monotonic_now_ns());
                *lock(&s.pending_scene) = Some((live.scene, since_ns));
                "ok".into()
            }
            Err(e) => format!("error: {e}"),
        },
        "status" => serde_json::to_string(&summary(s)).unwrap_or_else(|e| format!("error: {e}")),
        "error" => match arg.trim().parse::<u8>() {
            Ok(code) if code != 0 => {
                lock(&s.controller).raise_error(ControllerError::from(code));
                "ok".into()
            }
            _ => format!("error: bad error code {:?} (1..=255)", arg.trim()),
        },
        "state" => match arg.trim().parse::<u8>() {
            Ok(state) => {
                lock(&s.controller).request_state(state);
                "ok".into()
            }
            _ => format!("error: bad state {:?} (0..=255)", arg.trim()),
        },
        "freeze" => match arg.trim() {
            "on" | "off" => {
                lock(&s.controller).set_frozen(arg.trim() == "on");
                "ok".into()
            }
            other => format!("error: freeze on|off, not {other:?}"),
        },
        "shutdown" => {
            s.shutdown_requested.store(true, Ordering::Relaxed);
            "ok".into()
        }
        other => format!(
            "error: unknown command {other:?} (scene <path> | status | error <code> | \
             state <s> | freeze on|off | shutdown)"
        ),
    }
}
