//! [`DetectionFrame`]: what perception saw in one camera frame (perception → rt-core).
//!
//! Each [`DetectedObject`] carries its box and, since `DetectionFrame.v4`, the estimated
//! velocity of the box centre with a 1-sigma uncertainty
//! ([`DetectedObject::velocity_m_s`], [`DetectedObject::velocity_sigma_m_s`]): zero with
//! [`UNKNOWN_VELOCITY_SIGMA_M_S`] for an object just seen, zero with 0 for a fixed object of a
//! producer that is not a camera ([`DetectedObject::new`]). Speeds and sigmas are bounded by
//! [`MAX_OBJECT_SPEED_M_S`].

use iceoryx2::prelude::ZeroCopySend;

use crate::error::{SchemaError, count_within, finite_f32};
use crate::scene_file::MAX_SCENE_EXTENT_M;

/// Most objects one frame can carry. The twin's scene holds as many obstacles
/// ([`crate::scene_file::MAX_OBSTACLES`]), so every object a valid frame carries reaches the
/// twin: one capacity from the camera to the shield.
pub const MAX_DETECTIONS: usize = 16;

const _: () = assert!(MAX_DETECTIONS == crate::scene_file::MAX_OBSTACLES);

/// Largest speed of an object's centre, and largest velocity sigma, a valid
/// [`DetectedObject`] carries (m/s). Nothing on the table moves faster: a fast hand moves at
/// about 2 m/s (ISO 13855's approach speed), a thrown object at a few m/s. A larger estimate
/// is a measurement error (a track matched to another object, stamps too close together) and
/// [`DetectedObject::validate`] refuses it; perception publishes such an estimate at this
/// speed with [`UNKNOWN_VELOCITY_SIGMA_M_S`] instead.
pub const MAX_OBJECT_SPEED_M_S: f32 = 5.0;

/// Velocity sigma of an object whose velocity is not known yet (just seen, too few
/// measurements), published with a zero velocity (m/s): the assumed maximum intruder speed,
/// ISO 13855's approach speed of a hand or arm (2.0 m/s). A consumer that grows an object by
/// its uncertainty grows a new object as if it could move at that speed.
pub const UNKNOWN_VELOCITY_SIGMA_M_S: f32 = 2.0;

const _: () = assert!(UNKNOWN_VELOCITY_SIGMA_M_S <= MAX_OBJECT_SPEED_M_S);

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
/// metres, z up), with the estimated velocity of its centre.
///
/// Layout (52 bytes, no padding: every field 4-byte aligned): `object_id` 0, `class` 4,
/// `reserved` 5, `confidence` 8, `center_m` 12, `size_m` 24, `velocity_m_s` 36,
/// `velocity_sigma_m_s` 48.
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::DetectedObject.v2")]
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
    /// Estimated velocity of the box centre in the base frame (m/s); finite, speed at most
    /// [`MAX_OBJECT_SPEED_M_S`]. Zero for an untracked object, a newly seen one (then with
    /// `velocity_sigma_m_s` = [`UNKNOWN_VELOCITY_SIGMA_M_S`]) and a fixed one (sigma 0).
    pub velocity_m_s: [f32; 3],
    /// 1-sigma uncertainty of `velocity_m_s`, the same along each axis (m/s); finite, in
    /// 0 ..= [`MAX_OBJECT_SPEED_M_S`]. [`UNKNOWN_VELOCITY_SIGMA_M_S`] when the velocity is not
    /// known yet (a newly seen object); 0 only for an object known to be still (a fixed scene,
    /// a test rig: [`DetectedObject::new`]).
    pub velocity_sigma_m_s: f32,
}

const _: () = assert!(size_of::<DetectedObject>() == 52);
const _: () = assert!(align_of::<DetectedObject>() == 4);
const _: () = assert!(core::mem::offset_of!(DetectedObject, velocity_m_s) == 36);
const _: () = assert!(core::mem::offset_of!(DetectedObject, velocity_sigma_m_s) == 48);

impl DetectedObject {
    /// A new still object of the given class: velocity zero with sigma 0, meaning "known to
    /// be still" — for producers that are not cameras (a fixed scene, a test rig). A camera
    /// gives its estimate with [`DetectedObject::with_velocity`].
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
            velocity_m_s: [0.0; 3],
            velocity_sigma_m_s: 0.0,
        }
    }

    /// The same object with the estimated velocity of its centre (m/s) and that estimate's
    /// 1-sigma uncertainty (m/s); an object whose velocity is not known yet takes
    /// `([0.0; 3], UNKNOWN_VELOCITY_SIGMA_M_S)`. Nothing is checked here:
    /// [`DetectedObject::validate`] does.
    #[must_use]
    pub fn with_velocity(mut self, velocity_m_s: [f32; 3], velocity_sigma_m_s: f32) -> Self {
        self.velocity_m_s = velocity_m_s;
        self.velocity_sigma_m_s = velocity_sigma_m_s;
        self
    }

    /// Speed of the centre, |`velocity_m_s`| (m/s), computed in `f64`.
    pub fn speed_m_s(&self) -> f64 {
        self.velocity_m_s
            .iter()
            .map(|v| f64::from(*v).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    /// The class, checked.
    ///
    /// # Errors
    /// [`SchemaError::BadEnum`] for an unknown class byte.
    pub fn class(&self) -> Result<ObjectClass, SchemaError> {
        ObjectClass::try_from(self.class)
    }

    /// Checks one object: valid class, finite numbers, confidence in [0, 1], positive
    /// sizes, centre within [`MAX_SCENE_EXTENT_M`], speed and velocity sigma within
    /// [`MAX_OBJECT_SPEED_M_S`], sigma not negative.
    ///
    /// # Errors
    /// The first [`SchemaError`] found.
    pub fn validate(&self) -> Result<(), SchemaError> {
        self.class()?;
        finite_f32("confidence", &[self.confidence])?;
        finite_f32("center_m", &self.center_m)?;
        finite_f32("size_m", &self.size_m)?;
        finite_f32("velocity_m_s", &self.velocity_m_s)?;
        finite_f32("velocity_sigma_m_s", &[self.velocity_sigma_m_s])?;
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
        if self.speed_m_s() > f64::from(MAX_OBJECT_SPEED_M_S) {
            return Err(SchemaError::OutOfRange {
                field: "velocity_m_s",
            });
        }
        if !(0.0..=MAX_OBJECT_SPEED_M_S).contains(&self.velocity_sigma_m_s) {
            return Err(SchemaError::OutOfRange {
                field: "velocity_sigma_m_s",
            });
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
/// tracker: every object confirmed, nothing appeared, disappeared or moved for a while, and no
/// object's estimated speed is beyond its noise: a moving object never settles). rt-core
/// re-verifies the running plan against every frame, settled or not, and approves a new plan
/// on a settled one — or, from rest, on one that shows an obstacle moving, with each moving
/// box as the volume it may sweep (`plan_in_moving_world`). Unknown bits are refused by [`DetectionFrame::validate`].
#[derive(Debug, Clone, Copy, PartialEq, Default, ZeroCopySend)]
#[repr(C)]
#[type_name("foresight::DetectionFrame.v4")]
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

// 32 header bytes, then the objects at offset 32 (a multiple of their alignment); the total,
// 864, is a multiple of the frame's 8-byte alignment: no padding anywhere.
const _: () = assert!(size_of::<DetectionFrame>() == 32 + 52 * MAX_DETECTIONS);
const _: () = assert!(core::mem::offset_of!(DetectionFrame, objects) == 32);
const _: () = assert!(size_of::<DetectionFrame>().is_multiple_of(align_of::<DetectionFrame>()));

impl DetectionFrame {
    /// Schema version carried as a service attribute (3: `flags` replaced `reserved`; 4: each
    /// object carries `velocity_m_s` and `velocity_sigma_m_s`).
    pub const SCHEMA_VERSION: u32 = 4;

    /// Bit of `flags`: the object set is complete and stable — the publisher saw every object
    /// confirmed and nothing appear, disappear or move for a while (perception's tracker
    /// settings say how long), and sees no object moving now (no speed estimate beyond its
    /// noise). A frame without it is an intermediate view of a changing
    /// world: rt-core re-verifies against it (and may stop) and approves no plan on it, but
    /// from rest when it shows an obstacle moving (`plan_in_moving_world`).
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::services::{self, ShmOpenError};
    use iceoryx2::prelude::{ServiceName, ZeroCopySend, ipc};

    fn goal() -> DetectedObject {
        DetectedObject::new(1, ObjectClass::Goal, 0.9, [0.4, 0.2, 0.025], [0.05; 3])
    }

    fn with_object(o: DetectedObject) -> DetectionFrame {
        let mut f = DetectionFrame {
            sequence: 1,
            capture_time_ns: 5,
            ..Default::default()
        };
        assert!(f.push(o));
        f
    }

    #[test]
    fn new_objects_are_still_and_the_builder_sets_the_velocity() {
        let o = goal();
        assert_eq!((o.velocity_m_s, o.velocity_sigma_m_s), ([0.0; 3], 0.0));
        assert_eq!(o.validate(), Ok(()));
        let moving = goal().with_velocity([0.3, -0.4, 0.0], 0.05);
        assert_eq!(moving.velocity_m_s, [0.3, -0.4, 0.0]);
        assert_eq!(moving.velocity_sigma_m_s, 0.05);
        assert!((moving.speed_m_s() - 0.5).abs() < 1e-6);
        assert_eq!(with_object(moving).validate(), Ok(()));
        // A newly seen object: zero velocity, the large sigma; valid.
        let unknown = goal().with_velocity([0.0; 3], UNKNOWN_VELOCITY_SIGMA_M_S);
        assert_eq!(unknown.validate(), Ok(()));
        // The bounds themselves are valid.
        let at_bound = goal().with_velocity([0.0, MAX_OBJECT_SPEED_M_S, 0.0], MAX_OBJECT_SPEED_M_S);
        assert_eq!(at_bound.validate(), Ok(()));
    }

    #[test]
    fn a_non_finite_velocity_is_refused_naming_the_field() {
        for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let f = with_object(goal().with_velocity([0.0, bad, 0.0], 0.1));
            assert_eq!(
                f.validate(),
                Err(SchemaError::NonFinite {
                    field: "velocity_m_s"
                })
            );
        }
    }

    #[test]
    fn a_negative_or_non_finite_sigma_is_refused_naming_the_field() {
        for bad in [f32::NAN, f32::INFINITY] {
            let e = with_object(goal().with_velocity([0.1, 0.0, 0.0], bad)).validate();
            assert_eq!(
                e,
                Err(SchemaError::NonFinite {
                    field: "velocity_sigma_m_s"
                })
            );
        }
        for bad in [-0.001, -1.0, MAX_OBJECT_SPEED_M_S * 1.01] {
            let e = with_object(goal().with_velocity([0.1, 0.0, 0.0], bad))
                .validate()
                .unwrap_err();
            assert_eq!(
                e,
                SchemaError::OutOfRange {
                    field: "velocity_sigma_m_s"
                },
                "{bad}"
            );
            assert!(e.to_string().contains("velocity_sigma_m_s"), "{e}");
        }
    }

    #[test]
    fn a_speed_above_the_physical_bound_is_refused_even_when_no_axis_is() {
        // 4 m/s along x and y: each axis within the bound, the speed (5.66 m/s) not.
        let f = with_object(goal().with_velocity([4.0, 4.0, 0.0], 0.1));
        assert_eq!(
            f.validate(),
            Err(SchemaError::OutOfRange {
                field: "velocity_m_s"
            })
        );
        let f = with_object(goal().with_velocity([0.0, 0.0, -5.01], 0.1));
        assert!(
            f.validate()
                .unwrap_err()
                .to_string()
                .contains("velocity_m_s")
        );
        let f = with_object(goal().with_velocity([3.0, -4.0, 0.0], 0.1));
        assert_eq!(f.validate(), Ok(()));
    }

    /// `DetectedObject.v1` and `DetectionFrame.v3` as they were: what a stale publisher sends.
    #[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
    #[repr(C)]
    #[type_name("foresight::DetectedObject.v1")]
    struct ObjectV1 {
        object_id: u32,
        class: u8,
        reserved: [u8; 3],
        confidence: f32,
        center_m: [f32; 3],
        size_m: [f32; 3],
    }

    #[derive(Debug, Clone, Copy, Default, ZeroCopySend)]
    #[repr(C)]
    #[type_name("foresight::DetectionFrame.v3")]
    struct FrameV3 {
        sequence: u64,
        capture_time_ns: u64,
        camera_id: u32,
        count: u32,
        dropped_count: u32,
        flags: u32,
        objects: [ObjectV1; MAX_DETECTIONS],
    }

    fn unique_prefix(test: &str) -> String {
        use std::sync::atomic::{AtomicU32, Ordering};
        static N: AtomicU32 = AtomicU32::new(0);
        format!(
            "test/detection/{test}/{}-{}",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        )
    }

    /// A v3 publisher (schema attribute 3, the v3 payload) and a v4 subscriber never meet,
    /// whichever created the service.
    #[test]
    fn a_v3_publisher_and_a_v4_subscriber_cannot_connect() {
        let (node, _cleanup) = services::create_node::<ipc::Service>("detection-v3").unwrap();
        let verifier_v3 = services::schema_verifier(services::DETECTIONS, 3).unwrap();

        // The stale (v3) process came first.
        let prefix = unique_prefix("v3first");
        let name =
            ServiceName::new(&services::service_name(&prefix, services::DETECTIONS)).unwrap();
        let v3 = node
            .service_builder(&name)
            .publish_subscribe::<FrameV3>()
            .open_or_create_with_attributes(&verifier_v3)
            .unwrap();
        let _stale_publisher = v3.publisher_builder().create().unwrap();
        assert_eq!(
            services::open_subscriber::<DetectionFrame, _>(&node, &prefix).err(),
            Some(ShmOpenError::SchemaMismatch(services::DETECTIONS))
        );

        // The v4 subscriber came first: the stale publisher cannot open the service.
        let prefix = unique_prefix("v4first");
        let _subscriber = services::open_subscriber::<DetectionFrame, _>(&node, &prefix).unwrap();
        let name =
            ServiceName::new(&services::service_name(&prefix, services::DETECTIONS)).unwrap();
        assert!(
            node.service_builder(&name)
                .publish_subscribe::<FrameV3>()
                .open_or_create_with_attributes(&verifier_v3)
                .is_err(),
            "a v3 publisher opened a v4 service"
        );
        // Nor can one that claims version 4 but still has the v3 payload (type name, size).
        let verifier_v4 =
            services::schema_verifier(services::DETECTIONS, DetectionFrame::SCHEMA_VERSION)
                .unwrap();
        assert!(
            node.service_builder(&name)
                .publish_subscribe::<FrameV3>()
                .open_or_create_with_attributes(&verifier_v4)
                .is_err()
        );
        assert_eq!(DetectionFrame::SCHEMA_VERSION, 4);
        assert_ne!(size_of::<FrameV3>(), size_of::<DetectionFrame>());
    }
}
