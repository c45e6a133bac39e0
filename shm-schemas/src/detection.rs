//! [`DetectionFrame`]: what perception saw in one camera frame (perception → rt-core).

use iceoryx2::prelude::ZeroCopySend;

use crate::error::{SchemaError, count_within, finite_f32};
use crate::scene_file::MAX_SCENE_EXTENT_M;

/// Most objects one frame can carry. The twin's scene holds as many obstacles
/// ([`crate::scene_file::MAX_OBSTACLES`]), so every object a valid frame carries reaches the
/// twin: one capacity from the camera to the shield.
pub const MAX_DETECTIONS: usize = 16;

const _: () = assert!(MAX_DETECTIONS == crate::scene_file::MAX_OBSTACLES);

/// What a detected object is. Stored as a `u8` in [`DetectedObject::class`]; convert with
/// `ObjectClass::try_from(byte)` (never transmute).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum ObjectClass {
    /// The goal cube the arm should reach.
    Goal = 1,
    /// An obstacle box the arm must avoid.
    Obstacle = 2,
}

impl TryFrom<u8> for ObjectClass {
    type Error = SchemaError;
    fn try_from(value: u8) -> Result<Self, SchemaError> {
        match value {
            1 => Ok(Self::Goal),
            2 => Ok(Self::Obstacle),
            _ => Err(SchemaError::BadEnum {
                field: "class",
                value: u32::from(value),
            }),
        }
    }
}

/// One detected object, as an axis-aligned box in the twin's frame (the robot base frame,
/// metres, z up).
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::DetectedObject.v1")]
pub struct DetectedObject {
    /// Identifier that stays the same for the same physical object across frames
    /// (assigned by perception's tracker; 0 = untracked).
    pub object_id: u32,
    /// [`ObjectClass`] as a byte.
    pub class: u8,
    /// Reserved, zero.
    pub reserved: [u8; 3],
    /// Detector confidence in [0, 1].
    pub confidence: f32,
    /// Box centre in the base frame (m).
    pub center_m: [f32; 3],
    /// Full box extents along x, y, z (m), each > 0.
    pub size_m: [f32; 3],
}

const _: () = assert!(size_of::<DetectedObject>() == 36);

impl DetectedObject {
    /// A new object of the given class.
    pub fn new(
        object_id: u32,
        class: ObjectClass,
        confidence: f32,
        center_m: [f32; 3],
        size_m: [f32; 3],
    ) -> Self {
        Self {
            object_id,
            class: class as u8,
            reserved: [0; 3],
            confidence,
            center_m,
            size_m,
        }
    }

    /// The class, checked.
    ///
    /// # Errors
    /// [`SchemaError::BadEnum`] for an unknown class byte.
    pub fn class(&self) -> Result<ObjectClass, SchemaError> {
        ObjectClass::try_from(self.class)
    }

    /// Checks one object: valid class, finite numbers, confidence in [0, 1], positive
    /// sizes, centre within [`MAX_SCENE_EXTENT_M`].
    ///
    /// # Errors
    /// The first [`SchemaError`] found.
    pub fn validate(&self) -> Result<(), SchemaError> {
        self.class()?;
        finite_f32("confidence", &[self.confidence])?;
        finite_f32("center_m", &self.center_m)?;
        finite_f32("size_m", &self.size_m)?;
        if !(0.0..=1.0).contains(&self.confidence) {
            return Err(SchemaError::OutOfRange {
                field: "confidence",
            });
        }
        if self
            .size_m
            .iter()
            .any(|s| *s <= 0.0 || f64::from(*s) > MAX_SCENE_EXTENT_M)
        {
            return Err(SchemaError::OutOfRange { field: "size_m" });
        }
        if self
            .center_m
            .iter()
            .any(|c| f64::from(c.abs()) > MAX_SCENE_EXTENT_M)
        {
            return Err(SchemaError::OutOfRange { field: "center_m" });
        }
        Ok(())
    }
}

/// The objects perception found in one camera frame.
///
/// `capture_time_ns` is `CLOCK_MONOTONIC` of the machine all Foresight processes run on
/// (shared by every process), taken when the frame was captured, so consumers can compute
/// detection age and end-to-end latency directly. 0 means "no stamp" and is refused as stale
/// by rt-core, as is a stamp in the future.
///
/// A frame that does not fit (perception saw more objects than [`MAX_DETECTIONS`]) is still
/// published, with the nearest objects kept and `dropped_count` saying how many were left
/// out: [`DetectionFrame::validate`] refuses it, so a hidden obstacle stops the arm instead of
/// being silently ignored.
///
/// `flags` says what the publisher knows about the frame as a whole; the one bit defined is
/// [`DetectionFrame::FRAME_SETTLED`]: the object set is complete and stable (perception's
/// tracker: every object confirmed, nothing appeared, disappeared or moved for a while). rt-core
/// re-verifies the running plan against every frame, settled or not, but approves a new plan
/// only on a settled one. Unknown bits are refused by [`DetectionFrame::validate`].
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::DetectionFrame.v3")]
pub struct DetectionFrame {
    /// Increases by one per published frame of one camera.
    pub sequence: u64,
    /// Capture time, `CLOCK_MONOTONIC` (ns).
    pub capture_time_ns: u64,
    /// Which camera produced the frame.
    pub camera_id: u32,
    /// Number of valid entries at the front of `objects` (≤ [`MAX_DETECTIONS`]).
    pub count: u32,
    /// Objects seen in the camera frame but left out because the frame was full (0 in a
    /// frame rt-core accepts).
    pub dropped_count: u32,
    /// Bits of [`DetectionFrame::FRAME_FLAGS`] ([`DetectionFrame::FRAME_SETTLED`]); every
    /// other bit zero.
    pub flags: u32,
    /// The objects; entries at and beyond `count` are ignored.
    pub objects: [DetectedObject; MAX_DETECTIONS],
}

const _: () = assert!(size_of::<DetectionFrame>() == 32 + 36 * MAX_DETECTIONS);

impl DetectionFrame {
    /// Schema version carried as a service attribute (3: `flags` replaced `reserved`).
    pub const SCHEMA_VERSION: u32 = 3;

    /// Bit of `flags`: the object set is complete and stable — the publisher saw every object
    /// confirmed and nothing appear, disappear or move for a while (perception's tracker
    /// settings say how long). A frame without it is an intermediate view of a changing
    /// world: rt-core re-verifies against it (and may stop) but approves no plan on it.
    /// Producers that are not a camera (a fixed scene, a test rig) set it.
    pub const FRAME_SETTLED: u32 = 1 << 0;

    /// Every bit of `flags` this schema defines.
    pub const FRAME_FLAGS: u32 = Self::FRAME_SETTLED;

    /// Whether [`DetectionFrame::FRAME_SETTLED`] is set.
    pub fn settled(&self) -> bool {
        self.flags & Self::FRAME_SETTLED != 0
    }

    /// Sets or clears [`DetectionFrame::FRAME_SETTLED`].
    pub fn set_settled(&mut self, settled: bool) {
        if settled {
            self.flags |= Self::FRAME_SETTLED;
        } else {
            self.flags &= !Self::FRAME_SETTLED;
        }
    }

    /// The valid objects (the first `count`, clamped to the capacity).
    pub fn objects(&self) -> &[DetectedObject] {
        let n = (self.count as usize).min(MAX_DETECTIONS);
        &self.objects[..n]
    }

    /// Appends an object; returns `false` and counts it in `dropped_count` when the frame is
    /// full (a frame that then no longer validates).
    pub fn push(&mut self, object: DetectedObject) -> bool {
        let n = self.count as usize;
        if n >= MAX_DETECTIONS {
            self.dropped_count = self.dropped_count.saturating_add(1);
            return false;
        }
        self.objects[n] = object;
        self.count += 1;
        true
    }

    /// Checks the count, that nothing was dropped (`dropped_count` = 0: every object seen
    /// fits), that `flags` holds only defined bits, at most one goal, and every valid object.
    ///
    /// # Errors
    /// The first [`SchemaError`] found.
    pub fn validate(&self) -> Result<(), SchemaError> {
        count_within("count", self.count, MAX_DETECTIONS)?;
        if self.dropped_count != 0 {
            return Err(SchemaError::CountOverCapacity {
                field: "dropped_count",
                count: self.count.saturating_add(self.dropped_count),
                capacity: MAX_DETECTIONS as u32,
            });
        }
        let unknown = self.flags & !Self::FRAME_FLAGS;
        if unknown != 0 {
            return Err(SchemaError::BadEnum {
                field: "flags",
                value: unknown,
            });
        }
        self.objects()
            .iter()
            .try_for_each(DetectedObject::validate)?;
        let goals = self
            .objects()
            .iter()
            .filter(|o| o.class == ObjectClass::Goal as u8)
            .count();
        if goals > 1 {
            return Err(SchemaError::OutOfRange { field: "class" });
        }
        Ok(())
    }

    /// The goal object, if the frame has one.
    pub fn goal(&self) -> Option<&DetectedObject> {
        self.objects()
            .iter()
            .find(|o| o.class == ObjectClass::Goal as u8)
    }
}
