//! The UFactory xArm5 on the wire: the controller's command/report protocol (allocation-free
//! codec), controller error codes, the SDK's client-side joint limits, our driver and a
//! simulated controller (`xarm-sim`) that speaks the same protocol.
//!
//! ```
//! use rt_core::xarm::codec::{JointTarget, SERVOJ_FRAME_LEN, encode_servo_j};
//! let mut frame = [0u8; SERVOJ_FRAME_LEN];
//! encode_servo_j(1, &JointTarget::xarm5(&[0.0, -0.2, -0.3, 0.0, 0.0]), &mut frame);
//! assert_eq!(frame[6], 0x1d); // MOVE_SERVOJ
//! ```

pub mod codec;
pub mod codes;
pub mod driver;
pub mod limits;
pub mod link;
pub mod reconnect;
pub mod report;
pub mod sim;
