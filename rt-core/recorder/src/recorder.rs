//! The recording thread: subscribes to a run's iceoryx2 services like any other reader
//! (never touching the cycle), turns each sample into ROS 2 messages and writes them to an
//! [`McapFile`]. [`Recorder::start`] opens the file and the subscribers (and, with
//! [`RecorderConfig::bag_metadata`], writes the bag's first `metadata.yaml`, [`crate::bag`])
//! before it returns; [`Recorder::stop`] (or dropping the handle) drains what is left, closes
//! the file and rewrites `metadata.yaml` with the final counts.

use shm_schemas::error_chain::error_chain;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use shm_schemas::{
    DetectionFrame, RetrainProgress, RetrainRequest, RobotState, ShmMessage, TwinVerdict, services,
};
use twin::{DOF, RobotModel};

use crate::bag::{BagMetadataWriteError, OfferedQos, RecordingState, RecordingStats};
use crate::markers::{PlanPath, scene_markers};
use crate::mcap_file::{McapCreateError, McapFile, McapFileOptions, McapWriteError};
use crate::msgs::{
    DetectionsMsg, Header, JointState, MarkerArray, Quaternion, RefereeClearance,
    RefereeClearanceMsg, RetrainProgressMsg, RetrainRequestMsg, RobotStatusMsg, StringMsg,
    TfMessage, Time, TransformStamped, TwinVerdictMsg, Vec3,
};
use crate::ros_view::link_transforms;

/// Topics of a recording.
pub mod topics {
    /// Measured joints (`sensor_msgs/JointState`).
    pub const JOINT_STATES: &str = "/joint_states";
    /// Commanded joints (`sensor_msgs/JointState`).
    pub const JOINT_COMMANDS: &str = "/joint_commands";
    /// Link frames of the measured joints (`tf2_msgs/TFMessage`).
    pub const TF: &str = "/tf";
    /// The URDF, once (`std_msgs/String`).
    pub const ROBOT_DESCRIPTION: &str = "/robot_description";
    /// Goal, obstacles, commanded plan path, verdict text (`visualization_msgs/MarkerArray`).
    pub const SCENE_MARKERS: &str = "/foresight/scene_markers";
    /// Detection frames.
    pub const DETECTIONS: &str = "/foresight/detections";
    /// Lookahead verdicts.
    pub const VERDICTS: &str = "/foresight/verdicts";
    /// Retraining requests.
    pub const RETRAIN_REQUESTS: &str = "/foresight/retrain_requests";
    /// Retraining progress.
    pub const RETRAIN_PROGRESS: &str = "/foresight/retrain_progress";
    /// The cycle's status of the arm (stop reason, controller codes, cycle figures).
    pub const ROBOT_STATUS: &str = "/foresight/robot_status";
    /// The simulated arm's referee (contacts, smallest clearance so far).
    pub const REFEREE: &str = "/foresight/referee";
    /// Every topic.
    pub const ALL: [&str; 11] = [
        JOINT_STATES,
        JOINT_COMMANDS,
        TF,
        ROBOT_DESCRIPTION,
        SCENE_MARKERS,
        DETECTIONS,
        VERDICTS,
        RETRAIN_REQUESTS,
        RETRAIN_PROGRESS,
        ROBOT_STATUS,
        REFEREE,
    ];
}

/// Joint names as in `assets/xarm5.urdf`.
pub const JOINT_NAMES: [&str; DOF] = ["joint1", "joint2", "joint3", "joint4", "joint5"];

/// Settings of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct RecorderConfig {
    /// The MCAP file (its folder is created).
    pub path: PathBuf,
    /// Make the file's folder a rosbag2 bag: write its `metadata.yaml` beside the file at the
    /// start and at the end ([`crate::bag`]). For a folder that holds this recording alone
    /// (the launcher's run folder); off by default, so that a file recorded into a shared
    /// folder does not claim it. The channels carry their offered QoS either way.
    pub bag_metadata: bool,
    /// iceoryx2 service prefix of the run.
    pub prefix: String,
    /// URDF text (for `/robot_description` and the forward kinematics of `/tf`).
    pub urdf: String,
    /// Fixed frame of every pose.
    pub frame_id: String,
    /// Largest file (bytes). Default 256 MiB.
    pub max_bytes: u64,
    /// Chunk size (bytes). Default 128 KiB.
    pub chunk_bytes: u64,
    /// Most robot-state samples recorded per second (the cycle publishes at its rate, 250 Hz
    /// on the xArm). Default 100 Hz.
    pub state_rate_hz: f64,
    /// The chunk in progress is written at least this often (s): what a killed process
    /// can lose. Default 1 s.
    pub flush_interval_s: f64,
}

/// Default [`RecorderConfig::max_bytes`]: 256 MiB.
pub const DEFAULT_MAX_BYTES: u64 = 256 * 1024 * 1024;

impl RecorderConfig {
    /// Defaults for a run.
    pub fn new(path: PathBuf, prefix: &str, urdf: String) -> Self {
        Self {
            path,
            bag_metadata: false,
            prefix: prefix.to_owned(),
            urdf,
            frame_id: "world".to_owned(),
            max_bytes: DEFAULT_MAX_BYTES,
            chunk_bytes: 128 * 1024,
            state_rate_hz: 100.0,
            flush_interval_s: 1.0,
        }
    }

    /// Checks every setting against its bounds.
    ///
    /// # Errors
    /// [`RecorderConfigError`] naming the field.
    pub fn validate(&self) -> Result<(), RecorderConfigError> {
        let bad = |field: &'static str, allowed: &'static str| {
            Err(RecorderConfigError { field, allowed })
        };
        if !(1024 * 1024..=1 << 40).contains(&self.max_bytes) {
            return bad("max_bytes", "1 MiB ..= 1 TiB");
        }
        if !(4096..=self.max_bytes / 8).contains(&self.chunk_bytes) {
            return bad("chunk_bytes", "4 KiB ..= max_bytes / 8");
        }
        if !(self.state_rate_hz.is_finite() && (1.0..=1000.0).contains(&self.state_rate_hz)) {
            return bad("state_rate_hz", "1 ..= 1000 Hz");
        }
        if !(self.flush_interval_s.is_finite() && (0.05..=60.0).contains(&self.flush_interval_s)) {
            return bad("flush_interval_s", "0.05 ..= 60 s");
        }
        if self.frame_id.is_empty() {
            return bad("frame_id", "a non-empty frame name");
        }
        Ok(())
    }
}

/// A recorder setting is out of bounds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("recorder setting {field} out of bounds (allowed: {allowed})")]
pub struct RecorderConfigError {
    /// The field.
    pub field: &'static str,
    /// Its bounds.
    pub allowed: &'static str,
}

/// Why a recording could not start.
#[derive(Debug, thiserror::Error)]
pub enum RecorderStartError {
    /// A setting is out of bounds.
    #[error(transparent)]
    Config(#[from] RecorderConfigError),
    /// The URDF could not be read as a robot model.
    #[error("the recorder cannot read the URDF")]
    Urdf(#[source] twin::UrdfLoadError),
    /// The file could not be created.
    #[error(transparent)]
    Create(#[from] McapCreateError),
    /// A channel could not be added.
    #[error(transparent)]
    Write(#[from] McapWriteError),
    /// The bag's first `metadata.yaml` could not be written.
    #[error(transparent)]
    Metadata(#[from] BagMetadataWriteError),
    /// The iceoryx2 node could not be created.
    #[error("the recorder cannot subscribe to the run's services")]
    Node(#[source] shm_schemas::services::NodeCreateError),
    /// A subscriber could not be opened.
    #[error("the recorder cannot subscribe to the run's services")]
    Subscribe(#[source] shm_schemas::ShmOpenError),
    /// The thread could not be started.
    #[error("the recorder thread could not start")]
    Thread(#[source] std::io::Error),
    /// The thread ended before it was ready.
    #[error("the recorder thread could not start: ended before it was ready")]
    ThreadEnded,
}

/// Why a recording ended badly.
#[derive(Debug, thiserror::Error)]
pub enum RecorderStopError {
    /// Writing failed (the file is readable up to its last finished chunk).
    #[error(transparent)]
    Write(#[from] McapWriteError),
    /// The bag's final `metadata.yaml` could not be written (the MCAP file is complete; the
    /// folder keeps the first `metadata.yaml`).
    #[error(transparent)]
    Metadata(#[from] BagMetadataWriteError),
    /// The recording thread panicked.
    #[error("the recorder thread panicked")]
    Panicked,
}

/// Facts that do not travel on iceoryx2, handed to the recorder by its owner.
#[derive(Debug, Clone, PartialEq)]
enum Fact {
    Referee(RefereeClearance),
}

/// A running recording.
pub struct Recorder {
    stop: Arc<AtomicBool>,
    facts: mpsc::Sender<Fact>,
    thread: Option<JoinHandle<Result<RecordingStats, RecorderStopError>>>,
    path: PathBuf,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("path", &self.path)
            .finish_non_exhaustive()
    }
}

fn unix_now_ns() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
}

/// The bag folder of the MCAP file `path` (where `metadata.yaml` goes).
fn bag_dir(path: &Path) -> &Path {
    path.parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

impl Recorder {
    /// Opens the file, writes `/robot_description`, subscribes to the run's services, writes
    /// the bag's first `metadata.yaml` (with [`RecorderConfig::bag_metadata`]) and starts the
    /// recording thread (named `recorder`, a normal thread).
    ///
    /// # Errors
    /// [`RecorderStartError`]; nothing runs after an error.
    pub fn start(cfg: RecorderConfig) -> Result<Self, RecorderStartError> {
        cfg.validate()?;
        let model = RobotModel::from_urdf_str(&cfg.urdf).map_err(RecorderStartError::Urdf)?;
        let mut file = McapFile::create(
            &cfg.path,
            McapFileOptions {
                max_bytes: cfg.max_bytes,
                chunk_bytes: cfg.chunk_bytes,
            },
        )?;
        add_topics(&mut file)?;
        let now = unix_now_ns();
        file.write(
            topics::ROBOT_DESCRIPTION,
            now,
            &StringMsg {
                data: cfg.urdf.clone(),
            },
        )?;
        file.flush()?;
        let stop = Arc::new(AtomicBool::new(false));
        let (facts_tx, facts_rx) = mpsc::channel();
        let (ready_tx, ready_rx) = mpsc::sync_channel::<Result<(), RecorderStartError>>(1);
        let path = cfg.path.clone();
        let thread_stop = stop.clone();
        let thread = std::thread::Builder::new()
            .name("recorder".to_owned())
            .spawn(move || {
                let subs = match Subscriptions::open(&cfg.prefix) {
                    Ok(s) => s,
                    Err(e) => {
                        let _ = ready_tx.send(Err(e));
                        return Ok(file.finish()?);
                    }
                };
                // The folder is a bag from the start: a killed recording keeps this file.
                if cfg.bag_metadata
                    && let Err(e) = file
                        .bag_metadata(RecordingState::Recording)
                        .write(bag_dir(&cfg.path))
                {
                    let _ = ready_tx.send(Err(e.into()));
                    return Ok(file.finish()?);
                }
                let _ = ready_tx.send(Ok(()));
                let mut session = Session::new(cfg, model, file);
                session.run(&subs, &facts_rx, &thread_stop);
                session.finish()
            })
            .map_err(RecorderStartError::Thread)?;
        match ready_rx.recv() {
            Ok(Ok(())) => Ok(Self {
                stop,
                facts: facts_tx,
                thread: Some(thread),
                path,
            }),
            Ok(Err(e)) => {
                let _ = thread.join();
                Err(e)
            }
            Err(_) => {
                let _ = thread.join();
                Err(RecorderStartError::ThreadEnded)
            }
        }
    }

    /// The file being written.
    pub fn path(&self) -> &std::path::Path {
        &self.path
    }

    /// Records the simulated arm's referee figures (`/foresight/referee`).
    pub fn referee(&self, clearance: RefereeClearance) {
        let _ = self.facts.send(Fact::Referee(clearance));
    }

    /// Drains what is left, closes the file and returns what was written.
    ///
    /// # Errors
    /// [`RecorderStopError`].
    pub fn stop(mut self) -> Result<RecordingStats, RecorderStopError> {
        self.stop_and_join()
    }

    fn stop_and_join(&mut self) -> Result<RecordingStats, RecorderStopError> {
        self.stop.store(true, Ordering::Relaxed);
        let Some(thread) = self.thread.take() else {
            return Ok(RecordingStats::default());
        };
        match thread.join() {
            Ok(r) => r,
            Err(_) => Err(RecorderStopError::Panicked),
        }
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        if let Err(e) = self.stop_and_join() {
            tracing::warn!(path = %self.path.display(), "recording ended badly: {}", error_chain(&e));
        }
    }
}

/// Every topic, with the QoS [`OfferedQos::for_topic`] gives it (`/robot_description`
/// latched, the rest streaming).
fn add_topics(file: &mut McapFile) -> Result<(), McapWriteError> {
    fn add<M: crate::msgs::RosMessage>(
        file: &mut McapFile,
        topic: &str,
    ) -> Result<(), McapWriteError> {
        file.add_topic::<M>(topic, OfferedQos::for_topic(topic))
    }
    add::<JointState>(file, topics::JOINT_STATES)?;
    add::<JointState>(file, topics::JOINT_COMMANDS)?;
    add::<TfMessage>(file, topics::TF)?;
    add::<StringMsg>(file, topics::ROBOT_DESCRIPTION)?;
    add::<MarkerArray>(file, topics::SCENE_MARKERS)?;
    add::<DetectionsMsg>(file, topics::DETECTIONS)?;
    add::<TwinVerdictMsg>(file, topics::VERDICTS)?;
    add::<RetrainRequestMsg>(file, topics::RETRAIN_REQUESTS)?;
    add::<RetrainProgressMsg>(file, topics::RETRAIN_PROGRESS)?;
    add::<RobotStatusMsg>(file, topics::ROBOT_STATUS)?;
    add::<RefereeClearanceMsg>(file, topics::REFEREE)
}

struct Subscriptions {
    _node: Node<ipc::Service>,
    states: Subscriber<ipc::Service, RobotState, ()>,
    verdicts: Subscriber<ipc::Service, TwinVerdict, ()>,
    detections: Subscriber<ipc::Service, DetectionFrame, ()>,
    requests: Subscriber<ipc::Service, RetrainRequest, ()>,
    progress: Subscriber<ipc::Service, RetrainProgress, ()>,
}

impl Subscriptions {
    fn open(prefix: &str) -> Result<Self, RecorderStartError> {
        let (node, _cleanup) = services::create_node::<ipc::Service>("foresight-recorder")
            .map_err(RecorderStartError::Node)?;
        let open = RecorderStartError::Subscribe;
        Ok(Self {
            states: services::open_subscriber::<RobotState, _>(&node, prefix).map_err(open)?,
            verdicts: services::open_subscriber::<TwinVerdict, _>(&node, prefix).map_err(open)?,
            detections: services::open_subscriber::<DetectionFrame, _>(&node, prefix)
                .map_err(open)?,
            requests: services::open_subscriber::<RetrainRequest, _>(&node, prefix)
                .map_err(open)?,
            progress: services::open_subscriber::<RetrainProgress, _>(&node, prefix)
                .map_err(open)?,
            _node: node,
        })
    }
}

/// Takes every valid sample waiting on `sub` (invalid ones are counted).
fn drain<T: ShmMessage + Copy>(
    sub: &Subscriber<ipc::Service, T, ()>,
    rejected: &mut u64,
) -> Vec<T> {
    let mut out = Vec::new();
    while let Ok(Some(sample)) = sub.receive() {
        if sample.validate_message().is_ok() {
            out.push(*sample);
        } else {
            *rejected += 1;
        }
    }
    out
}

/// The recording's state on its thread.
struct Session {
    cfg: RecorderConfig,
    model: RobotModel,
    file: McapFile,
    error: Option<McapWriteError>,
    rejected: u64,
    next_state_ns: u64,
    last_detection: Option<DetectionFrame>,
    last_verdict: Option<TwinVerdict>,
    path: PlanPath,
    /// A plan was approved: the commanded TCP is its path.
    path_active: bool,
    markers_dirty: bool,
}

/// Scene markers are written at most this often, when something changed.
const MARKER_PERIOD: Duration = Duration::from_millis(500);
/// Pause between two polls of the subscribers.
const POLL_PERIOD: Duration = Duration::from_millis(5);

impl Session {
    fn new(cfg: RecorderConfig, model: RobotModel, file: McapFile) -> Self {
        Self {
            cfg,
            model,
            file,
            error: None,
            rejected: 0,
            next_state_ns: 0,
            last_detection: None,
            last_verdict: None,
            path: PlanPath::default(),
            path_active: false,
            markers_dirty: false,
        }
    }

    fn header(&self, stamp_ns: u64) -> Header {
        Header {
            stamp: Time::from_unix_ns(stamp_ns),
            frame_id: self.cfg.frame_id.clone(),
        }
    }

    /// Writes one message; the first write error is kept and ends the recording.
    fn put<M: crate::msgs::RosMessage>(&mut self, topic: &str, t_ns: u64, msg: &M) {
        if self.error.is_some() {
            return;
        }
        if let Err(e) = self.file.write(topic, t_ns, msg) {
            tracing::warn!("recording stopped: {}", error_chain(&e));
            self.error = Some(e);
        }
    }

    fn run(&mut self, subs: &Subscriptions, facts: &mpsc::Receiver<Fact>, stop: &AtomicBool) {
        let flush_every = Duration::from_secs_f64(self.cfg.flush_interval_s);
        let mut last_flush = Instant::now();
        let mut last_markers = Instant::now();
        loop {
            let stopping = stop.load(Ordering::Relaxed);
            self.poll(subs, facts);
            if self.markers_dirty && (stopping || last_markers.elapsed() >= MARKER_PERIOD) {
                self.write_markers();
                last_markers = Instant::now();
            }
            if stopping || self.error.is_some() {
                break;
            }
            if last_flush.elapsed() >= flush_every {
                if let Err(e) = self.file.flush() {
                    tracing::warn!("recording stopped: {}", error_chain(&e));
                    self.error = Some(e);
                }
                last_flush = Instant::now();
            }
            std::thread::sleep(POLL_PERIOD);
        }
        if self.rejected > 0 {
            tracing::warn!(
                rejected = self.rejected,
                "the recorder skipped invalid samples"
            );
        }
    }

    fn poll(&mut self, subs: &Subscriptions, facts: &mpsc::Receiver<Fact>) {
        let mut rejected = 0;
        let now = unix_now_ns();
        for state in drain(&subs.states, &mut rejected) {
            self.on_state(now, &state);
        }
        for v in drain(&subs.verdicts, &mut rejected) {
            self.on_verdict(now, v);
        }
        for f in drain(&subs.detections, &mut rejected) {
            self.on_detection(now, f);
        }
        for r in drain(&subs.requests, &mut rejected) {
            let msg = RetrainRequestMsg {
                header: self.header(now),
                request: r,
            };
            self.put(crate::topics::RETRAIN_REQUESTS, now, &msg);
        }
        for p in drain(&subs.progress, &mut rejected) {
            let msg = RetrainProgressMsg {
                header: self.header(now),
                progress: p,
            };
            self.put(crate::topics::RETRAIN_PROGRESS, now, &msg);
        }
        while let Ok(Fact::Referee(clearance)) = facts.try_recv() {
            let msg = RefereeClearanceMsg {
                header: self.header(now),
                clearance,
            };
            self.put(crate::topics::REFEREE, now, &msg);
        }
        self.rejected += rejected;
    }

    fn on_state(&mut self, now: u64, s: &RobotState) {
        // The commanded path follows every sample; the topics are thinned to the rate.
        let tcp = self.model.fk(&s.command_joints_rad).tcp_m();
        if self.path_active && self.path.push([tcp.x, tcp.y, tcp.z]) {
            self.markers_dirty = true;
        }
        if now < self.next_state_ns {
            return;
        }
        self.next_state_ns = now + (1e9 / self.cfg.state_rate_hz) as u64;
        let header = self.header(now);
        let names: Vec<String> = JOINT_NAMES.iter().map(|n| (*n).to_owned()).collect();
        let measured = JointState {
            header: header.clone(),
            name: names.clone(),
            position: s.joints_rad.to_vec(),
            velocity: s.joint_velocities_rad_s.to_vec(),
            effort: Vec::new(),
        };
        self.put(crate::topics::JOINT_STATES, now, &measured);
        let commanded = JointState {
            header: header.clone(),
            name: names,
            position: s.command_joints_rad.to_vec(),
            velocity: Vec::new(),
            effort: Vec::new(),
        };
        self.put(crate::topics::JOINT_COMMANDS, now, &commanded);
        let tf = self.tf(&header, &s.joints_rad);
        self.put(crate::topics::TF, now, &tf);
        let status = RobotStatusMsg { header, state: *s };
        self.put(crate::topics::ROBOT_STATUS, now, &status);
    }

    /// Every link frame of the twin's FK (and the TCP), parented to the fixed frame
    /// ([`crate::ros_view::link_transforms`], as `ros-bridge` publishes them).
    fn tf(&self, header: &Header, q: &[f64; DOF]) -> TfMessage {
        let poses = self.model.fk(q);
        let transforms = link_transforms(&self.model, &poses, &header.frame_id)
            .into_iter()
            .map(|t| TransformStamped {
                header: header.clone(),
                child_frame_id: t.child_frame_id.to_owned(),
                translation: Vec3::from_array(t.translation_m),
                rotation: Quaternion {
                    x: t.rotation_xyzw[0],
                    y: t.rotation_xyzw[1],
                    z: t.rotation_xyzw[2],
                    w: t.rotation_xyzw[3],
                },
            })
            .collect();
        TfMessage { transforms }
    }

    fn on_verdict(&mut self, now: u64, v: TwinVerdict) {
        if v.is_plan_approved() {
            self.path.restart(v.policy_id);
            self.path_active = true;
        }
        self.last_verdict = Some(v);
        self.markers_dirty = true;
        let msg = TwinVerdictMsg {
            header: self.header(now),
            verdict: v,
        };
        self.put(crate::topics::VERDICTS, now, &msg);
    }

    fn on_detection(&mut self, now: u64, f: DetectionFrame) {
        if self
            .last_detection
            .is_some_and(|d| d.sequence == f.sequence)
        {
            return;
        }
        let changed = self
            .last_detection
            .is_none_or(|d| d.objects() != f.objects() || d.settled() != f.settled());
        self.markers_dirty |= changed;
        self.last_detection = Some(f);
        let msg = DetectionsMsg {
            header: self.header(now),
            frame: f,
        };
        self.put(crate::topics::DETECTIONS, now, &msg);
    }

    fn write_markers(&mut self) {
        let now = unix_now_ns();
        let msg = scene_markers(
            &self.header(now),
            self.last_detection.as_ref(),
            &self.path,
            self.last_verdict.as_ref(),
        );
        self.put(crate::topics::SCENE_MARKERS, now, &msg);
        self.markers_dirty = false;
    }

    /// Closes the file, then (with [`RecorderConfig::bag_metadata`]) rewrites the bag's
    /// `metadata.yaml` with what it holds (also after a write error: the counts are those of
    /// the file's readable part).
    fn finish(self) -> Result<RecordingStats, RecorderStopError> {
        let mut metadata = self.file.bag_metadata(RecordingState::Finished);
        let finished = self.file.finish();
        let failed = self.error.is_some() || finished.is_err();
        if let Ok(stats) = &finished {
            metadata.stats = stats.clone();
        }
        metadata.state = if failed {
            RecordingState::Failed
        } else if metadata.stats.limit_reached {
            RecordingState::SizeLimit
        } else {
            RecordingState::Finished
        };
        let written = if self.cfg.bag_metadata {
            metadata.write(bag_dir(&self.cfg.path)).map(|_| ())
        } else {
            Ok(())
        };
        let stats = finished?;
        if let Some(e) = self.error {
            return Err(e.into());
        }
        written?;
        Ok(stats)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::{DetectedObject, ObjectClass};

    /// Without `bag_metadata` the folder gets the MCAP file alone (a file recorded into a
    /// shared folder does not claim it as a bag).
    #[test]
    fn a_plain_recording_writes_no_bag_metadata() {
        let urdf = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../assets/xarm5.urdf"
        ))
        .unwrap();
        let dir = std::env::temp_dir().join(format!("recorder-plain-{}", std::process::id()));
        let path = dir.join("plain.mcap");
        let cfg = RecorderConfig::new(path.clone(), "unused", urdf.clone());
        assert!(!cfg.bag_metadata);
        let model = RobotModel::from_urdf_str(&urdf).unwrap();
        let mut file = McapFile::create(
            &path,
            McapFileOptions {
                max_bytes: cfg.max_bytes,
                chunk_bytes: cfg.chunk_bytes,
            },
        )
        .unwrap();
        add_topics(&mut file).unwrap();
        let mut s = Session::new(cfg, model, file);
        s.put(topics::ROBOT_DESCRIPTION, 1, &StringMsg { data: urdf });
        assert_eq!(s.finish().unwrap().total(), 1);
        assert!(path.is_file());
        assert!(!dir.join(crate::bag::METADATA_FILE).exists());
        std::fs::remove_dir_all(&dir).ok();
    }

    /// One message of every topic, through the same code as a run (the system test
    /// `tests/tests/run_mcap.rs` reads a real run back with an independent reader).
    #[test]
    fn every_topic_gets_its_messages() {
        let urdf = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../assets/xarm5.urdf"
        ))
        .unwrap();
        let dir = std::env::temp_dir().join(format!("recorder-all-{}", std::process::id()));
        let path = dir.join("run.mcap");
        let mut cfg = RecorderConfig::new(path.clone(), "unused", urdf.clone());
        cfg.bag_metadata = true;
        let model = RobotModel::from_urdf_str(&urdf).unwrap();
        let mut file = McapFile::create(
            &path,
            McapFileOptions {
                max_bytes: cfg.max_bytes,
                chunk_bytes: cfg.chunk_bytes,
            },
        )
        .unwrap();
        add_topics(&mut file).unwrap();
        let mut s = Session::new(cfg, model, file);
        let mut frame = DetectionFrame {
            sequence: 1,
            ..DetectionFrame::default()
        };
        frame.push(DetectedObject::new(
            1,
            ObjectClass::Goal,
            0.9,
            [0.4, 0.1, 0.05],
            [0.05; 3],
        ));
        s.on_detection(1_000, frame);
        let mut v = TwinVerdict::default();
        v.set_flags(true, true, true);
        s.on_verdict(2_000, v);
        let mut state = RobotState::default();
        for i in 0..3u32 {
            state.command_joints_rad[1] = 0.1 * f64::from(i);
            s.on_state(3_000 + u64::from(i) * 20_000_000, &state);
        }
        s.write_markers();
        let now = unix_now_ns();
        s.put(topics::ROBOT_DESCRIPTION, now, &StringMsg { data: urdf });
        s.put(
            topics::RETRAIN_PROGRESS,
            now,
            &RetrainProgressMsg::default(),
        );
        s.put(topics::RETRAIN_REQUESTS, now, &RetrainRequestMsg::default());
        s.put(
            topics::REFEREE,
            now,
            &RefereeClearanceMsg {
                header: Header::default(),
                clearance: RefereeClearance {
                    contacts: 0,
                    steps: 10,
                    min_clearance_m: Some(0.02),
                    ..RefereeClearance::default()
                },
            },
        );
        let stats = s.finish().unwrap();
        for t in topics::ALL {
            assert!(stats.messages[t] >= 1, "{t}: {stats:?}");
        }
        // Three states 20 ms apart at 100 Hz: all three recorded; the path has two points
        // (the first two commanded TCPs are 2 mm apart or more).
        assert_eq!(stats.messages[topics::JOINT_STATES], 3);
        // The folder is a bag: metadata.yaml beside the file, with the file's counts.
        let yaml = std::fs::read_to_string(dir.join(crate::bag::METADATA_FILE)).unwrap();
        assert!(
            yaml.contains(&format!("  message_count: {}\n", stats.total())),
            "{yaml}"
        );
        assert!(yaml.contains("foresight_recording: finished"), "{yaml}");
        assert_eq!(yaml.matches("- topic_metadata:").count(), topics::ALL.len());
        assert_eq!(yaml.matches("durability: transient_local").count(), 1);
        std::fs::remove_dir_all(&dir).ok();
    }
}
