//! Controller error and warning codes (the bytes of `GET_ERROR` and of the normal/rich
//! reports), mapped totally from `u8`: every code the public docs name has a variant, any
//! other byte lands in `Unknown(code)`. Never `transmute`.

use thiserror::Error;

/// A controller error code (0 = none).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Error)]
pub enum ControllerError {
    /// 0: no error.
    #[error("no error")]
    None,
    /// 1: emergency stop button pressed.
    #[error("emergency stop button pressed (1)")]
    EmergencyStopButton,
    /// 2: emergency IO triggered.
    #[error("emergency IO triggered (2)")]
    EmergencyIo,
    /// 3: emergency stop of the three-state switch.
    #[error("three-state switch emergency stop (3)")]
    ThreeStateSwitch,
    /// 10: servo motor error (unspecified joint).
    #[error("servo motor error (10)")]
    ServoMotor,
    /// 11..=17: servo motor error on joint n (1..=7).
    #[error("servo motor error on joint {0}")]
    JointServo(u8),
    /// 18: force/torque sensor communication error.
    #[error("force/torque sensor communication error (18)")]
    ForceTorqueComm,
    /// 19: end-module communication error.
    #[error("end module communication error (19)")]
    EndModuleComm,
    /// 21: kinematic error.
    #[error("kinematic error (21)")]
    Kinematic,
    /// 22: self-collision.
    #[error("self-collision (22)")]
    SelfCollision,
    /// 23: joint angle exceeds its limit.
    #[error("joint angle exceeds limit (23)")]
    JointLimit,
    /// 24: speed exceeds limit.
    #[error("speed exceeds limit (24)")]
    SpeedLimit,
    /// 25: planning error.
    #[error("planning error (25)")]
    Planning,
    /// 26: Linux real-time error.
    #[error("linux RT error (26)")]
    LinuxRt,
    /// 27: command reply error.
    #[error("command reply error (27)")]
    CommandReply,
    /// 28: end-module communication error.
    #[error("end module communication error (28)")]
    EndModuleComm2,
    /// 29: other error.
    #[error("other error (29)")]
    Other,
    /// 30: feedback speed exceeds limit.
    #[error("feedback speed exceeds limit (30)")]
    FeedbackSpeed,
    /// 31: collision caused abnormal current (the collision error).
    #[error("collision caused abnormal current (31)")]
    Collision,
    /// 32: circle calculation error.
    #[error("three-point circle calculation error (32)")]
    CircleCalculation,
    /// 33: abnormal arm current.
    #[error("abnormal arm current (33)")]
    AbnormalCurrent,
    /// 35: safety boundary limit.
    #[error("safety boundary limit (35)")]
    SafetyBoundary,
    /// 36: too many instructions queued.
    #[error("instruction count exceeds limit (36)")]
    InstructionOverflow,
    /// 38: abnormal joint angle.
    #[error("abnormal joint angle (38)")]
    AbnormalJointAngle,
    /// 39: abnormal reduced mode.
    #[error("abnormal reduced mode (39)")]
    ReducedMode,
    /// 60: linear speed exceeds limit.
    #[error("linear speed exceeds limit (60)")]
    LinearSpeed,
    /// 110: arm base board communication error.
    #[error("arm base board communication error (110)")]
    BaseBoardComm,
    /// Any other code.
    #[error("controller error code {0}")]
    Unknown(u8),
}

impl From<u8> for ControllerError {
    fn from(code: u8) -> Self {
        match code {
            0 => Self::None,
            1 => Self::EmergencyStopButton,
            2 => Self::EmergencyIo,
            3 => Self::ThreeStateSwitch,
            10 => Self::ServoMotor,
            11..=17 => Self::JointServo(code - 10),
            18 => Self::ForceTorqueComm,
            19 => Self::EndModuleComm,
            21 => Self::Kinematic,
            22 => Self::SelfCollision,
            23 => Self::JointLimit,
            24 => Self::SpeedLimit,
            25 => Self::Planning,
            26 => Self::LinuxRt,
            27 => Self::CommandReply,
            28 => Self::EndModuleComm2,
            29 => Self::Other,
            30 => Self::FeedbackSpeed,
            31 => Self::Collision,
            32 => Self::CircleCalculation,
            33 => Self::AbnormalCurrent,
            35 => Self::SafetyBoundary,
            36 => Self::InstructionOverflow,
            38 => Self::AbnormalJointAngle,
            39 => Self::ReducedMode,
            60 => Self::LinearSpeed,
            110 => Self::BaseBoardComm,
            other => Self::Unknown(other),
        }
    }
}

impl From<ControllerError> for u8 {
    fn from(e: ControllerError) -> u8 {
        use ControllerError as E;
        match e {
            E::None => 0,
            E::EmergencyStopButton => 1,
            E::EmergencyIo => 2,
            E::ThreeStateSwitch => 3,
            E::ServoMotor => 10,
            E::JointServo(n) => 10u8.wrapping_add(n),
            E::ForceTorqueComm => 18,
            E::EndModuleComm => 19,
            E::Kinematic => 21,
            E::SelfCollision => 22,
            E::JointLimit => 23,
            E::SpeedLimit => 24,
            E::Planning => 25,
            E::LinuxRt => 26,
            E::CommandReply => 27,
            E::EndModuleComm2 => 28,
            E::Other => 29,
            E::FeedbackSpeed => 30,
            E::Collision => 31,
            E::CircleCalculation => 32,
            E::AbnormalCurrent => 33,
            E::SafetyBoundary => 35,
            E::InstructionOverflow => 36,
            E::AbnormalJointAngle => 38,
            E::ReducedMode => 39,
            E::LinearSpeed => 60,
            E::BaseBoardComm => 110,
            E::Unknown(c) => c,
        }
    }
}

impl ControllerError {
    /// Whether this is the collision error (31) or self-collision (22).
    pub fn is_collision(&self) -> bool {
        matches!(self, Self::Collision | Self::SelfCollision)
    }
}

/// A controller warning code (0 = none).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Error)]
pub enum ControllerWarning {
    /// 0: no warning.
    #[error("no warning")]
    None,
    /// 11: command buffer overflow.
    #[error("command buffer overflow (11)")]
    BufferOverflow,
    /// 12: command parameter abnormal.
    #[error("command parameter abnormal (12)")]
    BadParameter,
    /// 13: unknown command.
    #[error("unknown command (13)")]
    UnknownCommand,
    /// 14: command has no solution.
    #[error("command has no solution (14)")]
    NoSolution,
    /// 15: modbus count error.
    #[error("modbus count error (15)")]
    ModbusCount,
    /// Any other code.
    #[error("controller warning code {0}")]
    Unknown(u8),
}

impl From<u8> for ControllerWarning {
    fn from(code: u8) -> Self {
        match code {
            0 => Self::None,
            11 => Self::BufferOverflow,
            12 => Self::BadParameter,
            13 => Self::UnknownCommand,
            14 => Self::NoSolution,
            15 => Self::ModbusCount,
            other => Self::Unknown(other),
        }
    }
}

impl From<ControllerWarning> for u8 {
    fn from(w: ControllerWarning) -> u8 {
        match w {
            ControllerWarning::None => 0,
            ControllerWarning::BufferOverflow => 11,
            ControllerWarning::BadParameter => 12,
            ControllerWarning::UnknownCommand => 13,
            ControllerWarning::NoSolution => 14,
            ControllerWarning::ModbusCount => 15,
            ControllerWarning::Unknown(c) => c,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mappings_are_total_and_invertible() {
        for c in 0..=255u8 {
            assert_eq!(u8::from(ControllerError::from(c)), c);
            assert_eq!(u8::from(ControllerWarning::from(c)), c);
        }
        assert_eq!(ControllerError::from(31), ControllerError::Collision);
        assert_eq!(ControllerError::from(13), ControllerError::JointServo(3));
        assert_eq!(ControllerError::from(200), ControllerError::Unknown(200));
        assert!(ControllerError::from(31).is_collision());
        assert!(!ControllerError::from(24).is_collision());
    }
}
