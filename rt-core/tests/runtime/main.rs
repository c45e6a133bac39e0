//! Integration tests of the runtime: the cycle and the twin worker together on the toy rig
//! (`cycle`), its safety paths (`safety`), the shield on the real twin model (`shield_twin`) and the `rt-core twin` CLI
//! (`twin_cli`), who may drive the arm and whether the twin matches it (`arm_owner`), plans
//! only on settled scenes (`settled_scene`) and only when the smoothed path reaches the goal
//! (`goal_reach`), the policy library's fallback to the base policy (`policy_library`), and the
//! planner fallback (`planner_fallback`), the worker's phase along an excursion (`phase`), and
//! the re-verification of every live plan on the scene path (`plan_guard`), and verified
//! sampling before the planner (`sampling`), and the operator's acknowledgement channel
//! (`operator_ack`), and a controller starved of CPU while the arm moves
//! (`starved_controller`), and a plan unsafe far ahead joined by a safe one without
//! stopping (`join_before_stop`), and planning while a box moves and a horizon that covers
//! the stop (`moving_world`), and a
//! planner-made plan that joins the running one in time despite its search
//! (`planner_join`), and a goal a box has taken said at once (`goal_taken`), and an arm
//! stopped too close backing out along the path it came (`back_out`).

#![allow(missing_docs, clippy::unwrap_used, clippy::expect_used)]
// The tests drive the runtime from threads of their own and wait in wall time; the bans of
// rt-core/clippy.toml (Instant::now, thread::sleep, Mutex) are for the runtime's own code.
#![allow(clippy::disallowed_methods, clippy::disallowed_types)]

#[path = "../common/rig.rs"]
mod common;
#[path = "../common/twin.rs"]
mod twin_common;
#[path = "../common/xarm_rig.rs"]
mod xarm_rig;

mod arm_owner;
mod back_out;
mod cycle;
mod goal_cancel;
mod goal_reach;
mod goal_taken;
mod join_before_stop;
mod limits;
mod moving_world;
mod operator_ack;
mod phase;
mod plan_guard;
mod planner_fallback;
mod planner_join;
mod policy_library;
mod retraining_loop;
mod safety;
mod sampling;
mod settled_scene;
mod shield_twin;
mod stale_state;
mod starved_controller;
mod twin_cli;
mod xarm_paths;
