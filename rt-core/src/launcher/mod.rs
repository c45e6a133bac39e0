//! The `foresight` launcher's library side: the run folder, the process supervisor, and the
//! run report (summary, plots, Markdown). The binary `foresight` (src/bin/foresight.rs)
//! wires them into the self-improving scenario. Nothing here is on the real-time path.

pub mod observer;
pub mod report;
pub mod run_dir;
pub mod scenario;
pub mod supervisor;
