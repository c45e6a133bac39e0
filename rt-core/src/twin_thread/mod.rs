//! The twin thread's side of the runtime (not real-time; it may allocate):
//!
//! - [`worker`]: [`TwinWorker`] and its state ([`worker::Phase`]), one concept per file:
//!   the scene and its gates, the policy library, plan approval, the executed path and the
//!   way home;
//! - [`lookahead`]: the whole next episode in the twin with the current policy;
//! - [`path_planner`]: the planner fallback on the twin (`twin::feasibility`'s path);
//! - [`smoother`]: Ruckig smoothing of approved waypoints into a plan the cycle streams;
//! - [`intake`]: detection frames → the twin's scene;
//! - [`node`]: the thread's iceoryx2 ends (detections and policies in; robot state,
//!   verdicts and retrain requests out);
//! - [`command_log`]: the CSV of computed commands (dry runs);
//! - [`serve`]: `rt-core run` as a library function — the cycle thread started, and the twin
//!   thread's loop.

pub mod command_log;
pub mod intake;
pub mod lookahead;
pub mod node;
pub mod path_planner;
pub mod serve;
pub mod smoother;
pub mod worker;

pub use worker::{GoalApproach, Lookahead, TwinEvent, TwinWorker, Verdict, VerdictSource};
