//! What a detector reports for one object: class, confidence, image box and, with a
//! calibration, its position and size in the twin's frame. Printed as JSON by
//! `perception detect`, mapped to shm-schemas' `DetectedObject` at the publishing edge.

use serde::{Deserialize, Serialize};

/// What an object is, for the twin.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObjectKind {
    /// The goal cube.
    Goal,
    /// An obstacle box.
    Obstacle,
}

impl ObjectKind {
    /// The name used in JSON, labels files and annotations.
    pub fn name(self) -> &'static str {
        match self {
            Self::Goal => "goal",
            Self::Obstacle => "obstacle",
        }
    }

    /// Parses `goal` / `obstacle` (case-insensitive).
    pub fn parse(s: &str) -> Option<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "goal" => Some(Self::Goal),
            "obstacle" => Some(Self::Obstacle),
            _ => None,
        }
    }
}

/// One detected object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    /// Goal or obstacle.
    #[serde(rename = "class")]
    pub kind: ObjectKind,
    /// Detector confidence in [0, 1].
    pub confidence: f32,
    /// Image box `[x, y, w, h]` (px).
    pub bbox_px: [i32; 4],
    /// Box centre in the twin's frame (m); without depth, the table point under the box's
    /// bottom edge (z = table height).
    pub position_m: [f64; 3],
    /// Full extents along x, y, z (m); z is 0 when no depth was available.
    pub size_m: [f64; 3],
}

/// The JSON document `perception detect` prints.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DetectionReport {
    /// Every object found.
    pub objects: Vec<Detection>,
}
