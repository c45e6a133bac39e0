//! Publishing: tracked objects → `DetectionFrame` (sequence number, capture time, stable
//! ids) over iceoryx2 on `<prefix>/foresight/detections`, written in place into the loaned
//! sample.

use iceoryx2::node::Node;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::ipc;
use shm_schemas::{DetectedObject, DetectionFrame, MAX_DETECTIONS, ObjectClass, services};

use crate::detection::ObjectKind;
use crate::tracker::TrackedObject;

/// Why publishing failed.
#[derive(Debug, thiserror::Error)]
pub enum PublishError {
    /// The node could not be created.
    #[error("cannot create the iceoryx2 node: {0}")]
    Node(#[from] services::NodeCreateError),
    /// The service or port could not be opened.
    #[error(transparent)]
    Open(#[from] services::ShmOpenError),
    /// Loaning or sending a sample failed.
    #[error("cannot send a DetectionFrame: {0}")]
    Send(String),
    /// The frame failed its own validation (a bug or a wild measurement).
    #[error("DetectionFrame failed validation: {0}")]
    Invalid(#[from] shm_schemas::SchemaError),
}

fn class_of(kind: ObjectKind) -> ObjectClass {
    match kind {
        ObjectKind::Goal => ObjectClass::Goal,
        ObjectKind::Obstacle => ObjectClass::Obstacle,
    }
}

/// Builds the frame: the first [`MAX_DETECTIONS`] objects (goal first), sizes clamped to
/// at least 1 mm so a flat blob stays a valid box.
pub fn to_frame(
    sequence: u64,
    capture_time_ns: u64,
    camera_id: u32,
    objects: &[TrackedObject],
) -> DetectionFrame {
    let mut f = DetectionFrame {
        sequence,
        capture_time_ns,
        camera_id,
        ..Default::default()
    };
    for o in objects.iter().take(MAX_DETECTIONS) {
        f.push(DetectedObject::new(
            o.id,
            class_of(o.kind),
            o.confidence.clamp(0.0, 1.0),
            o.position_m.map(|v| v as f32),
            o.size_m.map(|v| (v as f32).max(0.001)),
        ));
    }
    f
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

    /// Publishes one frame; returns what was sent.
    ///
    /// # Errors
    /// [`PublishError`].
    pub fn publish(
        &mut self,
        capture_time_ns: u64,
        objects: &[TrackedObject],
    ) -> Result<DetectionFrame, PublishError> {
        self.sequence += 1;
        let frame = to_frame(self.sequence, capture_time_ns, self.camera_id, objects);
        frame.validate()?;
        let sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| PublishError::Send(format!("{e:?}")))?;
        let sample = sample.write_payload(frame);
        sample
            .send()
            .map_err(|e| PublishError::Send(format!("{e:?}")))?;
        Ok(frame)
    }

    /// Sequence number of the last published frame (0 before the first).
    pub fn sequence(&self) -> u64 {
        self.sequence
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_carry_ids_classes_and_valid_boxes() {
        let objs = [
            TrackedObject {
                id: 7,
                kind: ObjectKind::Goal,
                confidence: 1.2,
                position_m: [0.4, 0.2, 0.025],
                size_m: [0.05, 0.05, 0.0],
            },
            TrackedObject {
                id: 9,
                kind: ObjectKind::Obstacle,
                confidence: 0.8,
                position_m: [0.35, 0.0, 0.05],
                size_m: [0.06, 0.06, 0.1],
            },
        ];
        let f = to_frame(3, 1234, 0, &objs);
        assert_eq!(f.sequence, 3);
        assert_eq!(f.capture_time_ns, 1234);
        assert_eq!(f.count, 2);
        assert_eq!(f.objects()[0].class().unwrap(), ObjectClass::Goal);
        assert_eq!(f.objects()[1].object_id, 9);
        f.validate().unwrap();
        let many: Vec<TrackedObject> = (0..40)
            .map(|i| TrackedObject {
                id: i + 1,
                ..objs[1]
            })
            .collect();
        assert_eq!(to_frame(1, 0, 0, &many).count as usize, MAX_DETECTIONS);
    }
}
