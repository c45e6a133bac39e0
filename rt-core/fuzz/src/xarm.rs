//! The decoders under test, included from rt-core's sources (no copy).

#[path = "../../src/xarm/codec.rs"]
pub mod codec;
#[path = "../../src/xarm/codes.rs"]
pub mod codes;
#[path = "../../src/xarm/limits.rs"]
pub mod limits;
#[path = "../../src/xarm/report.rs"]
pub mod report;

#[path = "sim.rs"]
pub mod sim;
