//! The twin thread's side of the runtime (not real-time; it may allocate):
//!
//! - [`worker`]: [`TwinWorker`] and its state ([`worker::Phase`]), one concept per file:
//!   the scene and its gates, the policy library, plan approval, the executed path and the
//!   way home;
//! - [`lookahead`]: the whole next episode in the twin with the current policy;
//! - [`path_planner`]: the planner fallback on the twin (`twin::feasibility`'s path);
//! - [`smoother`]: Ruckig smoothing of approved waypoints into a plan the cycle streams;
//! - [`intake`]: detection frames → the twin's scene;
//! - [`scene_path`]: an accepted scene to the cycle's shield and to the [`plan_guard`],
//!   which re-verifies every plan the cycle holds against it (on the intake thread,
//!   [`intake_thread`], in `rt-core run`);
//! - [`node`]: the thread's iceoryx2 ends (detections and policies in; robot state,
//!   verdicts and retrain requests out);
//! - [`command_log`]: the CSV of computed commands (dry runs);
//! - [`reaction`]: the reaction time, from the causing frame to the changed command;
//! - [`serve`]: `rt-core run` as a library function — the cycle thread started, and the twin
//!   thread's loop.

pub mod command_log;
pub mod intake;
pub mod intake_thread;
pub mod lookahead;
pub mod node;
pub mod path_planner;
pub mod plan_guard;
pub mod reaction;
pub mod scene_path;
pub mod serve;
pub mod smoother;
pub mod worker;

pub use worker::{GoalApproach, Lookahead, TwinEvent, TwinWorker, Verdict, VerdictSource};
