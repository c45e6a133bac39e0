//! Publishing: tracked objects → `DetectionFrame` (sequence number, capture time, stable
//! ids) over iceoryx2 on `<prefix>/foresight/detections`, written in place into the loaned
//! sample.
//!
//! The objects go in the order [`crate::selection::select`] gives (the goal, then obstacles
//! nearest the robot base first). When more are seen than a frame holds
//! ([`MAX_DETECTIONS`](shm_schemas::MAX_DETECTIONS)), the frame is still published, with the nearest ones and
//! `dropped_count` = how many were left out: [`DetectionFrame::validate`] refuses such a
//! frame, so rt-core stops rather than act on a scene with a hidden obstacle. Every other
//! check of `validate` holds before a frame is sent, and a frame without a capture time
//! (`capture_time_ns` = 0) is never sent. `DetectionFrame::FRAME_SETTLED` is set when the
//! tracker says the reported set is settled ([`crate::tracker`]): rt-core approves plans
//! only on such frames.

use iceoryx2::node::Node;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::ipc;
use shm_schemas::{DetectedObject, DetectionFrame, ObjectClass, services};

use crate::detection::ObjectKind;
use crate::selection::select;
use crate::tracker::TrackedObject;

/// Why publishing failed.
#[derive(Debug, thiserror::Error)]
pub enum PublishError {
    /// The node could not be created.
    #[error("cannot create the iceoryx2 node")]
    Node(#[from] services::NodeCreateError),
    /// The service or port could not be opened.
    #[error(transparent)]
    Open(#[from] services::ShmOpenError),
    /// Loaning or sending a sample failed.
    #[error("cannot send a DetectionFrame")]
    Send(#[source] iceoryx2::port::SendError),
    /// The frame failed its own validation (a bug or a wild measurement).
    #[error("DetectionFrame failed validation")]
    Invalid(#[from] shm_schemas::SchemaError),
    /// The frame has no capture time (`capture_time_ns` = 0): consumers could not tell its
    /// age, so it is not sent.
    #[error("capture_time_ns is 0 (no CLOCK_MONOTONIC capture stamp): frame not sent")]
    NoCaptureTime,
}

fn class_of(kind: ObjectKind) -> ObjectClass {
    match kind {
        ObjectKind::Goal => ObjectClass::Goal,
        ObjectKind::Obstacle => ObjectClass::Obstacle,
    }
}

/// A built frame and what the goal choice did (see [`crate::selection`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BuiltFrame {
    /// The frame; `dropped_count` > 0 when objects did not fit.
    pub frame: DetectionFrame,
    /// Goal tracks left out as the same cube as the chosen goal.
    pub goals_merged: u32,
    /// Goal tracks apart from the chosen goal, published as obstacles.
    pub goals_as_obstacles: u32,
}

/// Builds the frame: at most one goal, then obstacles nearest the robot base first, the
/// first [`MAX_DETECTIONS`](shm_schemas::MAX_DETECTIONS) of them kept and the rest counted in `dropped_count`; sizes
/// clamped to at least 1 mm so a flat blob stays a valid box; `FRAME_SETTLED` as `settled`
/// says ([`crate::tracker::Tracker::settled`]).
pub fn to_frame(
    sequence: u64,
    capture_time_ns: u64,
    camera_id: u32,
    objects: &[TrackedObject],
    settled: bool,
) -> BuiltFrame {
    let mut f = DetectionFrame {
        sequence,
        capture_time_ns,
        camera_id,
        ..Default::default()
    };
    f.set_settled(settled);
    let selection = select(objects);
    for o in &selection.objects {
        f.push(
            DetectedObject::new(
                o.id,
                class_of(o.kind),
                if o.confidence.is_finite() {
                    o.confidence.clamp(0.0, 1.0)
                } else {
                    0.0
                },
                o.position_m.map(|v| v as f32),
                o.size_m.map(|v| (v as f32).max(0.001)),
            )
            .with_velocity(
                o.velocity_m_s.map(|v| v as f32),
                o.velocity_sigma_m_s as f32,
            ),
        );
    }
    BuiltFrame {
        frame: f,
        goals_merged: selection.goals_merged,
        goals_as_obstacles: selection.goals_as_obstacles,
    }
}

/// Checks a frame before it is sent: a capture time, and every check of
/// [`DetectionFrame::validate`] except `dropped_count` (a frame that says it left objects out
/// is sent on purpose, for rt-core to refuse).
///
/// # Errors
/// [`PublishError::NoCaptureTime`] or [`PublishError::Invalid`].
pub fn check_before_sending(frame: &DetectionFrame) -> Result<(), PublishError> {
    if frame.capture_time_ns == 0 {
        return Err(PublishError::NoCaptureTime);
    }
    let mut rest = *frame;
    rest.dropped_count = 0;
    rest.validate()?;
    Ok(())
}

/// The DetectionFrame publisher.
pub struct DetectionPublisher {
    _node: Node<ipc::Service>,
    publisher: Publisher<ipc::Service, DetectionFrame, ()>,
    sequence: u64,
    camera_id: u32,
}

impl DetectionPublisher {
    /// Opens the publisher under `prefix` (empty for the default service name).
    ///
    /// # Errors
    /// [`PublishError`].
    pub fn open(prefix: &str, camera_id: u32) -> Result<Self, PublishError> {
        let (node, _cleanup) = services::create_node::<ipc::Service>("perception")?;
        let publisher = services::open_publisher::<DetectionFrame, _>(&node, prefix)?;
        Ok(Self {
            _node: node,
            publisher,
            sequence: 0,
            camera_id,
        })
    }

    /// Publishes one frame (built by [`to_frame`], checked by [`check_before_sending`]);
    /// returns what was sent. The sequence number advances only for a frame that passed the
    /// checks.
    ///
    /// # Errors
    /// [`PublishError`].
    pub fn publish(
        &mut self,
        capture_time_ns: u64,
        objects: &[TrackedObject],
        settled: bool,
    ) -> Result<BuiltFrame, PublishError> {
        let built = to_frame(
            self.sequence + 1,
            capture_time_ns,
            self.camera_id,
            objects,
            settled,
        );
        let frame = built.frame;
        check_before_sending(&frame)?;
        self.sequence += 1;
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| PublishError::Send(e.into()))?;
        let sample = sample.write_payload(frame);
        sample.send().map_err(PublishError::Send)?;
        Ok(built)
    }

    /// Sequence number of the last published frame (0 before the first).
    pub fn sequence(&self) -> u64 {
        self.sequence
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shm_schemas::MAX_DETECTIONS;

    fn obstacle(id: u32, x_m: f64) -> TrackedObject {
        TrackedObject {
            id,
            kind: ObjectKind::Obstacle,
            confidence: 0.8,
            position_m: [x_m, 0.0, 0.05],
            size_m: [0.06, 0.06, 0.1],
            velocity_m_s: [0.0; 3],
            velocity_sigma_m_s: 0.0,
        }
    }

    #[test]
    fn frames_carry_ids_classes_and_valid_boxes() {
        let objs = [
            TrackedObject {
                id: 7,
                kind: ObjectKind::Goal,
                confidence: 1.2,
                position_m: [0.4, 0.2, 0.025],
                size_m: [0.05, 0.05, 0.0],
                velocity_m_s: [0.0; 3],
                velocity_sigma_m_s: 0.0,
            },
            obstacle(9, 0.35),
        ];
        let b = to_frame(3, 1234, 0, &objs, true);
        let f = b.frame;
        assert_eq!(f.sequence, 3);
        assert_eq!(f.capture_time_ns, 1234);
        assert_eq!(f.count, 2);
        assert_eq!(f.dropped_count, 0);
        assert_eq!(f.objects()[0].class().unwrap(), ObjectClass::Goal);
        assert_eq!(f.objects()[0].confidence, 1.0);
        assert_eq!(f.objects()[1].object_id, 9);
        assert!(f.settled());
        f.validate().unwrap();
        check_before_sending(&f).unwrap();
        let unsettled = to_frame(3, 1234, 0, &objs, false).frame;
        assert_eq!((unsettled.flags, unsettled.objects()), (0, f.objects()));
        check_before_sending(&unsettled).unwrap();
    }

    /// 40 obstacles in tracker (id) order, the farthest first: the frame keeps the goal and
    /// the 15 nearest, says 25 were left out, and still passes every other check.
    #[test]
    fn too_many_objects_keep_the_goal_and_the_nearest_and_count_the_rest() {
        let mut objs: Vec<TrackedObject> = (0..40)
            .map(|i| obstacle(i + 1, 0.8 - 0.015 * f64::from(i)))
            .collect();
        objs.push(TrackedObject {
            id: 100,
            kind: ObjectKind::Goal,
            confidence: 0.9,
            position_m: [0.6, 0.3, 0.025],
            size_m: [0.05; 3],
            velocity_m_s: [0.0; 3],
            velocity_sigma_m_s: 0.0,
        });
        let f = to_frame(1, 5, 0, &objs, false).frame;
        assert_eq!(f.count as usize, MAX_DETECTIONS);
        assert_eq!(f.dropped_count as usize, 41 - MAX_DETECTIONS);
        assert_eq!(f.objects()[0].object_id, 100, "the goal comes first");
        let ids: Vec<u32> = f.objects()[1..].iter().map(|o| o.object_id).collect();
        let nearest: Vec<u32> = (26..=40).rev().collect();
        assert_eq!(ids, nearest, "the 15 obstacles nearest the base");
        assert!(matches!(
            f.validate(),
            Err(shm_schemas::SchemaError::CountOverCapacity {
                field: "dropped_count",
                ..
            })
        ));
        check_before_sending(&f).unwrap();
        // Exactly full: nothing dropped.
        let f = to_frame(1, 5, 0, &objs[..MAX_DETECTIONS], false).frame;
        assert_eq!((f.count as usize, f.dropped_count), (MAX_DETECTIONS, 0));
        f.validate().unwrap();
    }

    #[test]
    fn a_frame_has_at_most_one_goal_and_never_a_zero_stamp() {
        let goal = |id, x_m, confidence| TrackedObject {
            id,
            kind: ObjectKind::Goal,
            confidence,
            position_m: [x_m, 0.2, 0.025],
            size_m: [0.05; 3],
            velocity_m_s: [0.0; 3],
            velocity_sigma_m_s: 0.0,
        };
        let b = to_frame(
            1,
            5,
            0,
            &[goal(1, 0.3, 0.6), goal(2, 0.5, 0.9), goal(3, 0.51, 0.7)],
            false,
        );
        b.frame.validate().unwrap();
        assert_eq!(b.frame.goal().unwrap().object_id, 2);
        assert_eq!((b.goals_merged, b.goals_as_obstacles), (1, 1));
        assert_eq!(b.frame.count, 2);
        let unstamped = to_frame(1, 0, 0, &[goal(1, 0.3, 0.6)], true).frame;
        assert!(matches!(
            check_before_sending(&unstamped),
            Err(PublishError::NoCaptureTime)
        ));
        let wild = to_frame(1, 5, 0, &[obstacle(1, 50.0)], true).frame;
        assert!(matches!(
            check_before_sending(&wild),
            Err(PublishError::Invalid(_))
        ));
    }

    #[test]
    fn the_publisher_refuses_a_zero_stamp_and_sends_a_truncated_frame() {
        let prefix = format!("percpubtest{}", std::process::id());
        let (node, _) = services::create_node::<ipc::Service>("perception-pub-test").unwrap();
        let sub = services::open_subscriber::<DetectionFrame, _>(&node, &prefix).unwrap();
        let mut p = DetectionPublisher::open(&prefix, 3).unwrap();
        let objs: Vec<TrackedObject> = (0..20)
            .map(|i| obstacle(i + 1, 0.3 + 0.01 * f64::from(i)))
            .collect();
        assert!(matches!(
            p.publish(0, &objs, true),
            Err(PublishError::NoCaptureTime)
        ));
        assert_eq!(p.sequence(), 0);
        assert!(sub.receive().unwrap().is_none(), "nothing was sent");
        let sent = p.publish(42, &objs, false).unwrap().frame;
        assert_eq!((sent.sequence, sent.dropped_count), (1, 4));
        let got = *sub
            .receive()
            .unwrap()
            .expect("the truncated frame is sent")
            .payload();
        assert_eq!(got, sent);
        assert_eq!(got.camera_id, 3);
        assert!(!got.settled());
    }
}
