//! `validate()` rejects NaN, counts beyond capacity and bad enum bytes.

use shm_schemas::scene_file::MAX_OBSTACLES;
use shm_schemas::*;

use crate::roundtrip::{detection_frame, retrain_progress, retrain_request, robot_state, verdict};

#[test]
fn samples_are_valid() {
    detection_frame().validate().unwrap();
    verdict().validate().unwrap();
    retrain_request().validate().unwrap();
    robot_state().validate().unwrap();
    retrain_progress().validate().unwrap();
}

#[test]
fn detection_frame_rejects_bad_input() {
    let mut f = detection_frame();
    f.objects[0].center_m[1] = f32::NAN;
    assert_eq!(
        f.validate(),
        Err(SchemaError::NonFinite { field: "center_m" })
    );

    let mut f = detection_frame();
    f.count = 17;
    assert_eq!(
        f.validate(),
        Err(SchemaError::CountOverCapacity {
            field: "count",
            count: 17,
            capacity: 16
        })
    );

    let mut f = detection_frame();
    f.objects[1].class = 3;
    assert_eq!(
        f.validate(),
        Err(SchemaError::BadEnum {
            field: "class",
            value: 3
        })
    );

    // `flags`: the settled bit is known (either way valid); any other bit is refused, the
    // field and the unknown bits named.
    let mut f = detection_frame();
    assert!(f.settled());
    f.set_settled(false);
    assert_eq!((f.flags, f.validate()), (0, Ok(())));
    f.flags = DetectionFrame::FRAME_SETTLED | 0b110;
    assert_eq!(
        f.validate(),
        Err(SchemaError::BadEnum {
            field: "flags",
            value: 0b110
        })
    );
    assert!(f.validate().unwrap_err().to_string().contains("flags"));

    let mut f = detection_frame();
    f.objects[1].size_m[2] = -0.1;
    assert_eq!(
        f.validate(),
        Err(SchemaError::OutOfRange { field: "size_m" })
    );

    let mut f = detection_frame();
    f.objects[0].confidence = 1.5;
    assert_eq!(
        f.validate(),
        Err(SchemaError::OutOfRange {
            field: "confidence"
        })
    );

    // Garbage beyond `count` is ignored.
    let mut f = detection_frame();
    f.objects[5].center_m[0] = f32::INFINITY;
    f.objects[5].class = 200;
    assert_eq!(f.validate(), Ok(()));

    // A full frame (one goal, obstacles) validates; another object does not fit: it is
    // counted in `dropped_count` and the frame is refused (a hidden obstacle must stop the
    // arm, not vanish).
    let mut f = DetectionFrame::default();
    assert!(f.push(detection_frame().objects[0]));
    for _ in 1..MAX_DETECTIONS {
        assert!(f.push(detection_frame().objects[1]));
    }
    assert_eq!(f.validate(), Ok(()));
    assert!(!f.push(detection_frame().objects[1]));
    assert_eq!(f.dropped_count, 1);
    assert_eq!(
        f.validate(),
        Err(SchemaError::CountOverCapacity {
            field: "dropped_count",
            count: MAX_DETECTIONS as u32 + 1,
            capacity: MAX_DETECTIONS as u32
        })
    );

    // At most one goal.
    let mut f = detection_frame();
    assert!(f.push(detection_frame().objects[0]));
    assert_eq!(
        f.validate(),
        Err(SchemaError::OutOfRange { field: "class" })
    );
}

#[test]
fn verdict_rejects_bad_input() {
    let mut v = verdict();
    v.min_distance_m = f64::NAN;
    assert_eq!(
        v.validate(),
        Err(SchemaError::NonFinite {
            field: "min_distance_m"
        })
    );
    let mut v = verdict();
    v.safe = 2;
    assert_eq!(
        v.validate(),
        Err(SchemaError::BadEnum {
            field: "safe",
            value: 2
        })
    );
    let mut v = verdict();
    v.episode_end = 0;
    assert_eq!(
        v.validate(),
        Err(SchemaError::BadEnum {
            field: "episode_end",
            value: 0
        })
    );
    // Schema 4: episode_end 7 (not learned) and phase 6 (verification) are known; schema 5:
    // episode_end 8 (goal taken) and phase 7 (backing out) are; the next values are not.
    for (episode_end, phase) in [(7, 6), (8, 7)] {
        let mut v = verdict();
        v.episode_end = episode_end;
        v.phase = phase;
        assert_eq!(v.validate(), Ok(()), "{episode_end} {phase}");
    }
    let mut v = verdict();
    v.episode_end = 9;
    assert_eq!(
        v.validate(),
        Err(SchemaError::BadEnum {
            field: "episode_end",
            value: 9
        })
    );
    let mut v = verdict();
    v.phase = 8;
    assert_eq!(
        v.validate(),
        Err(SchemaError::BadEnum {
            field: "phase",
            value: 8
        })
    );
    let mut v = verdict();
    v.executor = 3;
    assert_eq!(
        v.validate(),
        Err(SchemaError::BadEnum {
            field: "executor",
            value: 3
        })
    );
    let mut v = verdict();
    v.plan_approved = 1; // approved although the task failed
    assert_eq!(
        v.validate(),
        Err(SchemaError::OutOfRange {
            field: "plan_approved"
        })
    );
}

#[test]
fn retrain_request_rejects_bad_input() {
    let mut r = retrain_request();
    r.obstacle_count = MAX_OBSTACLES as u32 + 1;
    assert_eq!(
        r.validate(),
        Err(SchemaError::CountOverCapacity {
            field: "obstacle_count",
            count: MAX_OBSTACLES as u32 + 1,
            capacity: MAX_OBSTACLES as u32
        })
    );
    let mut r = retrain_request();
    r.obstacles[0].size_m[0] = f64::INFINITY;
    assert_eq!(
        r.validate(),
        Err(SchemaError::NonFinite {
            field: "obstacles.size_m"
        })
    );
    let mut r = retrain_request();
    r.goal_size_m = 0.0;
    assert_eq!(
        r.validate(),
        Err(SchemaError::OutOfRange {
            field: "goal_size_m"
        })
    );
    let mut r = retrain_request();
    r.verdict.task_ok = 7;
    assert_eq!(
        r.validate(),
        Err(SchemaError::BadEnum {
            field: "task_ok",
            value: 7
        })
    );
}

#[test]
fn robot_state_rejects_bad_input() {
    let mut s = robot_state();
    s.joints_rad[4] = f64::NEG_INFINITY;
    assert_eq!(
        s.validate(),
        Err(SchemaError::NonFinite {
            field: "joints_rad"
        })
    );
    let mut s = robot_state();
    s.stop_reason = 99;
    assert_eq!(
        s.validate(),
        Err(SchemaError::BadEnum {
            field: "stop_reason",
            value: 99
        })
    );
    let mut s = robot_state();
    s.controlled_stop = 255;
    assert_eq!(
        s.validate(),
        Err(SchemaError::BadEnum {
            field: "controlled_stop",
            value: 255
        })
    );
}

#[test]
fn retrain_progress_rejects_bad_input() {
    let mut p = retrain_progress();
    p.phase = 0;
    assert_eq!(
        p.validate(),
        Err(SchemaError::BadEnum {
            field: "phase",
            value: 0
        })
    );
    let mut p = retrain_progress();
    p.mean_return = f64::NAN;
    assert_eq!(
        p.validate(),
        Err(SchemaError::NonFinite {
            field: "mean_return"
        })
    );
    let mut p = retrain_progress();
    p.success_rate = 1.01;
    assert_eq!(
        p.validate(),
        Err(SchemaError::OutOfRange {
            field: "success_rate"
        })
    );
}

#[test]
fn every_retrain_phase_byte_round_trips_and_an_infeasible_answer_validates() {
    // Issue 15: `Infeasible` (5) was missing from the byte conversion, so the learner's
    // "no safe way found" answer was rejected as malformed by every subscriber.
    for phase in [
        RetrainPhase::Training,
        RetrainPhase::Evaluating,
        RetrainPhase::Published,
        RetrainPhase::BudgetExhausted,
        RetrainPhase::Infeasible,
    ] {
        assert_eq!(RetrainPhase::try_from(phase as u8), Ok(phase));
    }
    let mut p = retrain_progress();
    p.phase = RetrainPhase::Infeasible as u8;
    p.infeasible_kind = InfeasibleKind::NoGoalPosture as u8;
    p.infeasible_blocker = 0;
    p.infeasible_link = 3;
    p.infeasible_by_m = 0.065;
    p.validate().unwrap();
    assert!(p.phase().unwrap().is_final());
    // An infeasible phase without a reason, or a reason on another phase, is refused.
    p.infeasible_kind = InfeasibleKind::None as u8;
    assert_eq!(
        p.validate(),
        Err(SchemaError::OutOfRange {
            field: "infeasible_kind"
        })
    );
}

fn policy() -> Box<PolicyBlob> {
    PolicyBlobBuilder::random(1, 2, 17, &[64, 64], 3, 3)
        .build()
        .unwrap()
}

#[test]
fn a_joint_step_blob_records_its_space_and_observation_layout() {
    use shm_schemas::{JOINT_ACT_DIM, JOINT_OBS_DIM, OBS_LAYOUT_CARTESIAN, OBS_LAYOUT_JOINT_V1};
    let joint = PolicyBlobBuilder::random(1, 2, JOINT_OBS_DIM, &[32], JOINT_ACT_DIM, 3)
        .action_space(ActionSpace::JointStep)
        .build()
        .unwrap();
    assert_eq!(
        ActionSpace::try_from(joint.action_space),
        Ok(ActionSpace::JointStep)
    );
    assert_eq!(joint.obs_layout, OBS_LAYOUT_JOINT_V1);
    assert_eq!(ActionSpace::JointStep.name(), "joint_step");
    // A Cartesian blob, as every blob before the field, carries layout 0.
    assert_eq!(policy().obs_layout, OBS_LAYOUT_CARTESIAN);
    // A layout that is not its space's is refused by name, either way round.
    let mut b = PolicyBlob::new_boxed();
    b.copy_from(&joint);
    b.obs_layout = OBS_LAYOUT_CARTESIAN;
    b.seal();
    assert_eq!(
        b.validate(),
        Err(SchemaError::BadEnum {
            field: "obs_layout",
            value: 0
        })
    );
    let mut c = policy();
    c.obs_layout = OBS_LAYOUT_JOINT_V1;
    c.seal();
    assert_eq!(
        c.validate(),
        Err(SchemaError::BadEnum {
            field: "obs_layout",
            value: 1
        })
    );
    // A joint-step blob of another length is refused.
    let short = PolicyBlobBuilder::random(1, 2, 17, &[32], 3, 3)
        .action_space(ActionSpace::JointStep)
        .build();
    assert!(short.is_err(), "{short:?}");
}

#[test]
fn policy_blob_rejects_bad_input() {
    // An action space this build does not know (a space from a newer learner, say) is
    // refused by name, never run as a Cartesian step (issue 40 item 3). Before, the byte was
    // reserved and never checked. (Byte 1 was the unknown one until the joint-step space
    // took it: the next byte now.)
    let mut b = policy();
    b.action_space = 2;
    b.seal();
    let e = b.validate().unwrap_err();
    assert_eq!(
        e,
        SchemaError::BadEnum {
            field: "action_space",
            value: 2
        }
    );
    assert!(e.to_string().contains("action_space"), "{e}");
    assert_eq!(
        ActionSpace::try_from(policy().action_space),
        Ok(ActionSpace::CartesianStep)
    );

    let mut b = policy();
    b.weights[100] = f32::NAN;
    b.seal();
    assert_eq!(
        b.validate(),
        Err(SchemaError::NonFinite { field: "weights" })
    );

    let mut b = policy();
    b.weights[100] = 0.5;
    assert!(matches!(
        b.validate(),
        Err(SchemaError::ChecksumMismatch { .. })
    ));

    let mut b = policy();
    b.n_weights = (MAX_WEIGHTS + 1) as u32;
    b.seal();
    assert!(matches!(
        b.validate(),
        Err(SchemaError::CountOverCapacity {
            field: "n_weights",
            ..
        })
    ));

    let mut b = policy();
    b.obs_dim = 40;
    b.seal();
    assert!(matches!(
        b.validate(),
        Err(SchemaError::CountOverCapacity {
            field: "obs_dim",
            ..
        })
    ));

    let mut b = policy();
    b.n_hidden = 5;
    b.seal();
    assert!(matches!(
        b.validate(),
        Err(SchemaError::CountOverCapacity {
            field: "n_hidden",
            ..
        })
    ));

    let mut b = policy();
    b.hidden_sizes[3] = 8; // set beyond n_hidden
    b.seal();
    assert_eq!(
        b.validate(),
        Err(SchemaError::LayoutInvalid {
            field: "hidden_sizes"
        })
    );

    let mut b = policy();
    b.output_activation = 3;
    b.seal();
    assert_eq!(
        b.validate(),
        Err(SchemaError::BadEnum {
            field: "output_activation",
            value: 3
        })
    );

    let mut b = policy();
    b.activation = Activation::Identity as u8;
    b.seal();
    assert_eq!(
        b.validate(),
        Err(SchemaError::OutOfRange {
            field: "activation"
        })
    );

    let mut b = policy();
    b.obs_std[16] = -1.0;
    b.seal();
    assert_eq!(
        b.validate(),
        Err(SchemaError::OutOfRange { field: "obs_std" })
    );

    // Values in unused slots are covered by the checksum but not by the range checks.
    let mut b = policy();
    b.obs_std[20] = -1.0;
    b.seal();
    assert_eq!(b.validate(), Ok(()));
}

#[test]
fn blob_copy_and_checksum_are_stable() {
    let a = policy();
    let b = a.to_boxed();
    assert_eq!(*a, *b);
    assert_eq!(a.compute_checksum(), b.compute_checksum());
    assert_eq!(a.checksum, a.compute_checksum());
}
