//! What the launcher sees of a run: it subscribes (iceoryx2) to everything the processes
//! publish — robot state, verdicts, detections, retrain requests and progress — and turns
//! it into timestamped facts the scenario director and the report use. Read-only: the
//! observer never publishes.

use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use shm_schemas::{
    DetectionFrame, ObjectClass, RetrainProgress, RetrainRequest, RobotState, ShmOpenError,
    TwinVerdict, services,
};

/// A verdict with the launcher time it arrived.
#[derive(Debug, Clone, Copy)]
pub struct SeenVerdict {
    /// Launcher time (s).
    pub t_s: f64,
    /// The verdict.
    pub verdict: TwinVerdict,
}

/// The obstacle and goal the camera currently reports.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct SeenScene {
    /// Goal centre (m), if a goal is seen.
    pub goal_m: Option<[f32; 3]>,
    /// Tallest obstacle height (m), 0 if none.
    pub tallest_obstacle_m: f32,
    /// Number of obstacles.
    pub obstacles: usize,
    /// Frame sequence.
    pub sequence: u64,
    /// Perception marked the frame settled (the twin approves new plans only on such).
    pub settled: bool,
}

impl SeenScene {
    fn from_frame(frame: &DetectionFrame) -> Self {
        let mut s = Self {
            sequence: frame.sequence,
            settled: frame.settled(),
            ..Self::default()
        };
        for o in frame.objects() {
            match o.class() {
                Ok(ObjectClass::Goal) => s.goal_m = Some(o.center_m),
                Ok(ObjectClass::Obstacle) => {
                    s.obstacles += 1;
                    s.tallest_obstacle_m = s.tallest_obstacle_m.max(o.size_m[2]);
                }
                Err(_) => {}
            }
        }
        s
    }
}

/// One poll's news.
#[derive(Debug, Default)]
pub struct Observations {
    /// Robot states received (oldest first).
    pub states: Vec<RobotState>,
    /// Verdicts received.
    pub verdicts: Vec<TwinVerdict>,
    /// Retrain requests received.
    pub retrain_requests: Vec<RetrainRequest>,
    /// Retrain progress messages received.
    pub progress: Vec<RetrainProgress>,
    /// The newest detection frame's content, if any arrived.
    pub scene: Option<SeenScene>,
    /// Samples rejected by `validate()`.
    pub rejected: u64,
}

/// Subscribers to every topic of one run.
pub struct Observer {
    _node: Node<ipc::Service>,
    states: Subscriber<ipc::Service, RobotState, ()>,
    verdicts: Subscriber<ipc::Service, TwinVerdict, ()>,
    detections: Subscriber<ipc::Service, DetectionFrame, ()>,
    requests: Subscriber<ipc::Service, RetrainRequest, ()>,
    progress: Subscriber<ipc::Service, RetrainProgress, ()>,
}

impl std::fmt::Debug for Observer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Observer")
    }
}

/// Why the observer could not start.
#[derive(Debug, thiserror::Error)]
pub enum ObserverError {
    /// The iceoryx2 node could not be created.
    #[error("cannot create the launcher's iceoryx2 node")]
    Node(#[source] services::NodeCreateError),
    /// A subscriber could not be opened.
    #[error(transparent)]
    Open(#[from] ShmOpenError),
}

macro_rules! drain {
    ($sub:expr, $out:expr, $rejected:expr) => {
        while let Ok(Some(sample)) = $sub.receive() {
            if sample.validate().is_ok() {
                $out.push(*sample);
            } else {
                $rejected += 1;
            }
        }
    };
}

impl Observer {
    /// Opens subscribers on every service of the run `prefix`.
    ///
    /// # Errors
    /// [`ObserverError`].
    pub fn open(prefix: &str) -> Result<Self, ObserverError> {
        let (node, _cleanup) = services::create_node::<ipc::Service>("foresight-launcher")
            .map_err(ObserverError::Node)?;
        Ok(Self {
            states: services::open_subscriber::<RobotState, _>(&node, prefix)?,
            verdicts: services::open_subscriber::<TwinVerdict, _>(&node, prefix)?,
            detections: services::open_subscriber::<DetectionFrame, _>(&node, prefix)?,
            requests: services::open_subscriber::<RetrainRequest, _>(&node, prefix)?,
            progress: services::open_subscriber::<RetrainProgress, _>(&node, prefix)?,
            _node: node,
        })
    }

    /// Takes everything that arrived since the last poll.
    pub fn poll(&self) -> Observations {
        let mut o = Observations::default();
        drain!(self.states, o.states, o.rejected);
        drain!(self.verdicts, o.verdicts, o.rejected);
        drain!(self.requests, o.retrain_requests, o.rejected);
        drain!(self.progress, o.progress, o.rejected);
        let mut frames: Vec<DetectionFrame> = Vec::new();
        drain!(self.detections, frames, o.rejected);
        o.scene = frames.last().map(SeenScene::from_frame);
        o
    }
}
