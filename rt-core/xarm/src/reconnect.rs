//! Reconnection off the cycle: a helper thread re-opens a lost xArm link (TCP connect,
//! `GET_VERSION` handshake, servo mode, joint read — all blocking, up to the connect and
//! reply timeouts) while the cycle keeps its period and only sees `Disconnected` until the
//! live connection is handed over.
//!
//! The hand-over is two single-slot, lock-free SPSC queues (`heapless::spsc`): the cycle
//! posts a `Job` carrying the dead connection (its sockets are closed and its memory freed
//! on the helper, not on the cycle) and the helper posts the `Reopened` connection back.
//! On this path the cycle never blocks, takes a lock, allocates or formats a log line; the
//! helper does the logging. It is the driver's only reconnect path: both the first connection
//! and every re-open go through [`Session::open`].

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::time::Duration;

use heapless::spsc::{Consumer, Producer, Queue};

use crate::codes::ControllerError;
use crate::config::XArmConfig;
use crate::error::XArmError;
use crate::session::Session;

/// How often an idle helper looks for a job.
const IDLE_POLL: Duration = Duration::from_millis(5);

/// A reconnection request from the cycle.
pub(super) struct Job {
    /// Why the link was lost (for the helper's log line).
    pub why: XArmError,
    /// Re-enter servo mode after the handshake.
    pub servo: bool,
    /// The lost connection, to be dropped off the cycle.
    pub dead: Option<Session>,
}

/// A live connection, ready to be installed by the cycle.
pub(super) struct Reopened {
    /// The session, with the controller's error and warning at reconnect: with an error,
    /// servo mode was not re-entered and the cycle reads the error instead of moving.
    pub session: Session,
    /// The joints re-read after the handshake: the next target must start from them.
    pub q_rad: [f64; 5],
}

/// The cycle's end of the helper.
pub(super) struct Reconnector {
    jobs: Producer<'static, Job>,
    done: Consumer<'static, Reopened>,
    /// A job was posted and its connection not yet taken.
    pending: bool,
    busy: Arc<AtomicBool>,
    attempts: Arc<AtomicU32>,
    stop: Arc<AtomicBool>,
}

impl Reconnector {
    /// Starts the helper thread for `cfg` (start-up: allocates the thread and the two
    /// queues, which live for the rest of the process).
    pub fn spawn(cfg: XArmConfig) -> std::io::Result<Self> {
        let jobs: &'static mut Queue<Job, 2> = Box::leak(Box::new(Queue::new()));
        let done: &'static mut Queue<Reopened, 2> = Box::leak(Box::new(Queue::new()));
        let (jobs_tx, jobs_rx) = jobs.split();
        let (done_tx, done_rx) = done.split();
        let busy = Arc::new(AtomicBool::new(false));
        let attempts = Arc::new(AtomicU32::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let helper = Helper {
            cfg,
            jobs: jobs_rx,
            done: done_tx,
            busy: busy.clone(),
            attempts: attempts.clone(),
            stop: stop.clone(),
        };
        std::thread::Builder::new()
            .name("xarm-reconnect".into())
            .spawn(move || helper.run())?;
        Ok(Self {
            jobs: jobs_tx,
            done: done_rx,
            pending: false,
            busy,
            attempts,
            stop,
        })
    }

    /// Asks for a reconnection unless one is under way; `dead` is dropped on the helper.
    /// Non-blocking, allocation-free.
    pub fn request(&mut self, why: XArmError, servo: bool, dead: Option<Session>) {
        if self.pending {
            return; // `dead` (None here: a pending job means the link was already down).
        }
        // The slot is free: the previous job was taken by the helper before it could post
        // the connection that cleared `pending`.
        if self.jobs.enqueue(Job { why, servo, dead }).is_ok() {
            self.pending = true;
        }
    }

    /// The reopened connection, once the helper has one. Non-blocking, allocation-free.
    pub fn take(&mut self) -> Option<Reopened> {
        let r = self.done.dequeue()?;
        self.pending = false;
        Some(r)
    }

    /// Whether the helper is inside a connection attempt right now.
    pub fn busy(&self) -> bool {
        self.busy.load(Ordering::Acquire)
    }

    /// Connection attempts so far.
    pub fn attempts(&self) -> u32 {
        self.attempts.load(Ordering::Relaxed)
    }
}

impl Drop for Reconnector {
    fn drop(&mut self) {
        // The helper notices within one poll or back-off step; it is not joined (an attempt
        // in progress may take up to the connect and reply timeouts).
        self.stop.store(true, Ordering::Release);
    }
}

/// The helper thread's state.
struct Helper {
    cfg: XArmConfig,
    jobs: Consumer<'static, Job>,
    done: Producer<'static, Reopened>,
    busy: Arc<AtomicBool>,
    attempts: Arc<AtomicU32>,
    stop: Arc<AtomicBool>,
}

impl Helper {
    fn stopped(&self) -> bool {
        self.stop.load(Ordering::Acquire)
    }

    fn run(mut self) {
        while !self.stopped() {
            let Some(job) = self.jobs.dequeue() else {
                std::thread::sleep(IDLE_POLL);
                continue;
            };
            drop(job.dead);
            tracing::warn!("xArm link lost ({}); reconnecting off the cycle", job.why);
            let Some(reopened) = self.reopen_with_backoff(job.servo) else {
                return;
            };
            if self.done.enqueue(reopened).is_err() {
                // Cannot happen: one job is answered once and the cycle posts no new job
                // before taking the answer. Dropping the connection is the safe outcome.
                tracing::error!("reconnected, but the hand-over slot was full");
            }
        }
    }

    /// Attempts until one succeeds (`Some`) or the driver is dropped (`None`), waiting
    /// `backoff_initial_ns` after the first failure, doubling up to `backoff_max_ns`.
    fn reopen_with_backoff(&self, servo: bool) -> Option<Reopened> {
        let mut backoff_ns = self.cfg.backoff_initial_ns;
        loop {
            if self.stopped() {
                return None;
            }
            self.busy.store(true, Ordering::Release);
            self.attempts.fetch_add(1, Ordering::Relaxed);
            let result = reopen(&self.cfg, servo);
            self.busy.store(false, Ordering::Release);
            match result {
                Ok(r) => {
                    tracing::info!(
                        error = %r.session.error,
                        attempts = self.attempts.load(Ordering::Relaxed),
                        "xArm link re-established"
                    );
                    return Some(r);
                }
                Err(e) => tracing::debug!("xArm reconnect attempt failed: {e}"),
            }
            let mut waited_ns = 0;
            while waited_ns < backoff_ns {
                if self.stopped() {
                    return None;
                }
                std::thread::sleep(IDLE_POLL);
                waited_ns += IDLE_POLL.as_nanos() as u64;
            }
            backoff_ns = backoff_ns.saturating_mul(2).min(self.cfg.backoff_max_ns);
        }
    }
}

/// One blocking attempt: handshake, servo mode (unless the controller has an error, which
/// is handed over instead), joint read.
fn reopen(cfg: &XArmConfig, servo: bool) -> Result<Reopened, XArmError> {
    let mut session = Session::open(cfg)?;
    let timeout = cfg.reply_timeout;
    if servo && session.error == ControllerError::None {
        match session.enter_servo_mode(timeout) {
            Ok(_) | Err(XArmError::Controller(_)) => {}
            Err(e) => return Err(e),
        }
    }
    let q_rad = session.get_joints(timeout)?;
    Ok(Reopened { session, q_rad })
}
