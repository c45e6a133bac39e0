//! The joint-step action space (issue 40 item 3): the observation that carries the goal
//! posture, the step bound shared with the Cartesian space, and the joint-space baseline —
//! approved where the way is free, refused by the one verification where a box is in it.

use shm_schemas::ActionSpace;
use twin::approval::{ApprovalSettings, EpisodeApproval, PlanRejection, ShieldViolation};
use twin::{
    DOF, JOINT_OBS_DIM, Joints, MAX_EPISODE_STEPS, Scene, TaskConfig, choose_goal_posture,
    rollout_joint,
};

use super::common::{assets, env, scene};

fn empty(s: &Scene) -> Scene {
    let mut e = *s;
    e.obstacles.clear();
    e
}

#[test]
fn the_observation_carries_the_goal_posture_and_the_joint_error() {
    let mut e = env().with_action_space(ActionSpace::JointStep);
    let s = scene("tall_box.toml");
    let start = e.config().start.joints_rad;
    let chosen = choose_goal_posture(&e, &s, &start).unwrap().best().joints;
    let obs = e.reset(&s);
    assert_eq!(e.obs_dim(), JOINT_OBS_DIM);
    assert_eq!(e.goal_posture(), Some(chosen));
    let q = e.joints();
    for i in 0..DOF {
        assert_eq!(obs[1 + i], (chosen[i] - q[i]) as f32);
        assert_eq!(obs[6 + i], chosen[i] as f32);
    }
    let target = e.target_m();
    let tcp = e.tcp_m();
    for k in 0..3 {
        assert_eq!(obs[11 + k], tcp[k] as f32);
        assert_eq!(obs[14 + k], target[k] as f32);
    }
    // The tall box is the nearest (and only) box; 2nd and 3rd read 1 (none), the table
    // is farther than the box.
    assert_eq!(obs[17], s.obstacles[0].height_m() as f32);
    assert!(obs[25] > 0.0 && obs[25] < 1.0, "{}", obs[25]);
    assert_eq!((obs[26], obs[27]), (1.0, 1.0));
    assert!(obs[28] > obs[25], "{obs:?}");
    // The Cartesian space's observation of the same reset is the one it always was.
    let mut c = env();
    let cart = c.reset(&s);
    assert_eq!(c.obs_dim(), c.config().obs_dim());
    assert_eq!(c.goal_posture(), None);
    assert_eq!(cart[3], tcp[0] as f32);
}

#[test]
fn a_joint_step_moves_each_joint_by_at_most_its_scale_through_the_shared_bound() {
    let mut e = env().with_action_space(ActionSpace::JointStep);
    let scale = e.config().action.joint_scale_rad();
    e.reset(&empty(&scene("tall_box.toml")));
    let before = e.joints();
    let out = e.step_joint(&[1.0, -1.0, 5.0, f32::NAN, -0.5]);
    let dq: Joints = std::array::from_fn(|i| out.joints[i] - before[i]);
    let expected = [scale[0], -scale[1], scale[2], 0.0, -0.5 * scale[4]];
    for i in 0..DOF {
        assert!((dq[i] - expected[i]).abs() < 1e-12, "joint {i}: {dq:?}");
    }
    // r_a = −‖a‖ of the five clipped components: −√(1 + 1 + 1 + 0 + 0.25).
    assert!((out.terms.action + 3.25_f32.sqrt()).abs() < 1e-6, "{out:?}");
}

#[test]
fn the_joint_scale_is_bounded_and_absent_from_the_bundled_hash() {
    let task = TaskConfig::load(&assets().join("task.toml")).unwrap();
    assert_eq!(task.action.joint_scale_rad, None);
    assert!(!task.to_toml_string().contains("joint_scale_rad"));
    let mut set = task;
    set.action.joint_scale_rad = Some([0.05; DOF]);
    assert!(set.validate().is_ok());
    assert_ne!(set.hash(), task.hash());
    for bad in [0.0, -0.01, 0.2, f64::NAN] {
        let mut b = task;
        b.action.joint_scale_rad = Some([0.05, 0.05, bad, 0.05, 0.05]);
        assert!(b.validate().is_err(), "{bad}");
    }
}

/// The joint-space baseline goes straight in joint space to the chosen goal posture: in the
/// free scene it reaches the goal and rt-core's verification approves its plan; with the
/// demo's wide tall box standing on that straight joint-space path, the blind rollout still
/// gets to the goal but through the box's clearance, and the same verification refuses it
/// at the shield.
#[test]
fn the_joint_line_reaches_a_free_goal_and_is_refused_through_the_box() {
    let settings = ApprovalSettings::shipped().unwrap();
    let boxed = scene("wide_tall_box.toml");
    let free = empty(&boxed);
    let mut e = env();
    let p = e.joint_line_policy();
    let mut wps = heapless::Vec::<Joints, MAX_EPISODE_STEPS>::new();
    let run = rollout_joint(&mut e, &free, |o| p.act(o), Some(&mut wps), true);
    assert!(run.success && run.safe, "{run:?}");
    assert_eq!(e.action_space(), ActionSpace::JointStep);
    let goal = e.goal_posture().unwrap();
    let last = wps.last().copied().unwrap();
    assert!(
        twin::max_joint_gap_rad(&last, &goal) < 0.1,
        "{last:?} {goal:?}"
    );
    let mut approval = EpisodeApproval::new(&settings, &e);
    approval
        .approve(&e, &free, &wps)
        .expect("approved in the free scene");

    let blind = rollout_joint(&mut e, &boxed, |o| p.act(o), Some(&mut wps), false);
    assert!(blind.success && !blind.safe, "{blind:?}");
    match approval.approve(&e, &boxed, &wps) {
        Err(PlanRejection::Shield {
            violation: ShieldViolation::Clearance { distance_m },
            ..
        }) => assert!(distance_m < settings.shield.min_distance_m, "{distance_m}"),
        other => panic!("expected the shield's clearance refusal, got {other:?}"),
    }
}
