//! The UFactory xArm5 on the wire: the controller's command/report protocol (allocation-free
//! codec, reports, error codes, the SDK's client-side joint limits) and our driver with its
//! off-cycle reconnect helper. A leaf crate: no Foresight dependency, so it is fuzzed and
//! reused as it is. The simulated controller that speaks the same protocol is `xarm-sim`;
//! it proves it is the run's simulator by [`sim_identity`], never by its address.
//!
//! ```
//! use xarm::codec::{JointTarget, SERVOJ_FRAME_LEN, encode_servo_j};
//! let mut frame = [0u8; SERVOJ_FRAME_LEN];
//! encode_servo_j(1, &JointTarget::xarm5(&[0.0, -0.2, -0.3, 0.0, 0.0]), &mut frame);
//! assert_eq!(frame[6], 0x1d); // MOVE_SERVOJ
//! ```

pub mod codec;
pub mod codes;
pub mod config;
pub mod driver;
pub mod error;
pub mod limits;
pub mod owner;
pub mod reconnect;
pub mod report;
pub mod session;
pub mod sim_identity;
