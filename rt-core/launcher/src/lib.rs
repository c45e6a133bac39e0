//! The `foresight` launcher: runs the whole system on one machine and reports on it.
//! Nothing here is on the real-time path.
//!
//! - [`launch`]: the scenario end to end (start reading here), [`args`] its command line; [`processes`]: which
//!   processes a run starts and how; [`supervisor`]: starting, restarting and stopping them.
//! - [`scenario`]: the world director (scene changes, phases, goal and collision checks);
//!   [`observer`]: what the run publishes, as the director sees it; [`sim_link`]: the
//!   simulated arm's control port.
//! - [`report`]: summary, plots and Markdown; [`worlds`]: the unseen-worlds benchmark's
//!   table and plot over `--runs N --worlds random`; [`run_dir`]: the run folder, atomic writes;
//!   [`runtime_view`]: what the launcher reads of rt-core's configuration; [`recording`]:
//!   the run's MCAP recording (`runs/<run>/run.mcap`); [`reach`]: `foresight reach`, the ROS 2
//!   `Reach` action's client.

#![forbid(unsafe_code)]

pub mod acts;
pub mod args;
pub mod launch;
pub mod observer;
pub mod processes;
pub mod reach;
pub mod recording;
pub mod report;
pub mod run_dir;
pub mod runtime_view;
pub mod scenario;
pub mod separation;
pub mod sim_link;
pub mod supervisor;
pub mod worlds;
