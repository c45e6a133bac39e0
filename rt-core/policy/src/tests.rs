//! Unit tests of the policy module: hand-computed outputs and every rejection reason.

use shm_schemas::{
    ActionSpace, Activation, JOINT_ACT_DIM, JOINT_OBS_DIM, PolicyBlob, PolicyBlobBuilder,
    SchemaError,
};

use super::*;
use shm_schemas::{ACT_DIM, OBS_DIM};

const TASK: u64 = 0x1234_5678_9abc_def0;

/// 2 → 2 → 1 with normalisation mean [1, -1], std [2, 0.5], clip 3; action scale 0.5.
fn tiny(activation: Activation, action_clip: f32) -> Box<PolicyBlob> {
    PolicyBlobBuilder::new(11, TASK)
        .activation(activation)
        .layer(2, 2, &[1.0, 2.0, -1.0, 0.5], &[0.5, 0.25])
        .layer(2, 1, &[2.0, -3.0], &[-1.0])
        .obs_normalization(&[1.0, -1.0], &[2.0, 0.5], 3.0)
        .action_scaling(&[0.5], action_clip)
        .build()
        .unwrap()
}

fn tiny_expectation() -> PolicyExpectation {
    PolicyExpectation {
        task_config_hash: TASK,
        obs_dim: 2,
        act_dim: 1,
    }
}

fn eval(p: &MlpPolicy, obs: [f32; 2]) -> f32 {
    let mut out = [0.0f32; 1];
    p.evaluate(&obs, &mut out).unwrap();
    out[0]
}

#[test]
fn relu_network_matches_hand_computation() {
    let loader = PolicyLoader::new(tiny_expectation());
    let p = loader.prepare(&tiny(Activation::Relu, 5.0)).unwrap();
    // x = [(5-1)/2, (-1.25+1)/0.5] = [2, -0.5]
    // h = relu([1*2 + 2*(-0.5) + 0.5, -1*2 + 0.5*(-0.5) + 0.25]) = relu([1.5, -2]) = [1.5, 0]
    // y = 2*1.5 - 3*0 - 1 = 2; a = clamp(2, ±5) * 0.5 = 1
    assert_eq!(eval(&p, [5.0, -1.25]), 1.0);
    // The same with the output clipped at ±1: a = 1 * 0.5.
    let clipped = loader.prepare(&tiny(Activation::Relu, 1.0)).unwrap();
    assert_eq!(eval(&clipped, [5.0, -1.25]), 0.5);
}

#[test]
fn tanh_network_matches_hand_computation() {
    let loader = PolicyLoader::new(tiny_expectation());
    let p = loader.prepare(&tiny(Activation::Tanh, 5.0)).unwrap();
    // h = tanh([1.5, -2]); y = 2 tanh(1.5) - 3 tanh(-2) - 1 = 3.702380...; a = y * 0.5
    let expected = 0.5 * (2.0 * 1.5f64.tanh() - 3.0 * (-2.0f64).tanh() - 1.0);
    assert!((f64::from(eval(&p, [5.0, -1.25])) - expected).abs() < 1e-6);
    assert!((expected - 1.851_190).abs() < 1e-5);
}

#[test]
fn normalised_observation_is_clipped() {
    let loader = PolicyLoader::new(tiny_expectation());
    let p = loader.prepare(&tiny(Activation::Relu, 100.0)).unwrap();
    // obs[0] = 1001 → (1001-1)/2 = 500, clipped to 3; obs[1] = -1 → 0.
    // h = relu([3 + 0 + 0.5, -3 + 0 + 0.25]) = [3.5, 0]; y = 7 - 1 = 6; a = 3
    assert_eq!(eval(&p, [1001.0, -1.0]), 3.0);
}

#[test]
fn act_on_twin_dimensions_is_deterministic_and_uses_the_layout() {
    // A linear 17 → 3 policy that copies the TCP position (obs 3..6).
    let mut w = vec![0.0f32; ACT_DIM * OBS_DIM];
    for j in 0..ACT_DIM {
        w[j * OBS_DIM + 3 + j] = 1.0;
    }
    let blob = PolicyBlobBuilder::new(5, TASK)
        .layer(OBS_DIM, ACT_DIM, &w, &[0.1, 0.2, 0.3])
        .build()
        .unwrap();
    let loader = PolicyLoader::new(PolicyExpectation::for_task(TASK));
    let p = loader.prepare(&blob).unwrap();
    let mut obs = [0.0f32; OBS_DIM];
    obs[3] = 0.25;
    obs[4] = -0.5;
    obs[5] = 2.0;
    // [0.25+0.1, -0.5+0.2, clamp(2.0+0.3, ±1)]
    let a = p.act(&obs);
    assert_eq!(a, [0.35, -0.3, 1.0]);
    let random = loader
        .prepare(
            &PolicyBlobBuilder::random(6, TASK, OBS_DIM, &[64, 64], ACT_DIM, 3)
                .build()
                .unwrap(),
        )
        .unwrap();
    let first = random.act(&obs);
    assert!(first.iter().all(|v| v.is_finite() && v.abs() <= 1.0));
    assert_eq!(first, random.act(&obs));
}

fn valid() -> Box<PolicyBlob> {
    PolicyBlobBuilder::random(7, TASK, OBS_DIM, &[32, 32], ACT_DIM, 9)
        .build()
        .unwrap()
}

/// A valid joint-step policy for the task (issue 40 item 3): the joint-space observation
/// and five joint steps.
fn joint_step_blob() -> Box<PolicyBlob> {
    PolicyBlobBuilder::random(9, TASK, JOINT_OBS_DIM, &[32], JOINT_ACT_DIM, 1)
        .action_space(ActionSpace::JointStep)
        .build()
        .unwrap()
}

/// Issue 40 item 3: a blob in a space this loader runs is run — the Cartesian step and the
/// joint step, each through its own entry point — and one in a space it does not know is
/// refused, the refusal naming the byte.
#[test]
fn a_policy_is_run_or_refused_by_its_action_space_named() {
    let loader = PolicyLoader::new(PolicyExpectation::for_task(TASK));
    let obs = [0.3f32; OBS_DIM];
    let cartesian = loader.prepare(&valid()).unwrap();
    assert_eq!(ActionSpaceRefusal::of(&valid()), None);
    assert_eq!(cartesian.action_space(), ActionSpace::CartesianStep);
    assert_ne!(cartesian.act(&obs), [0.0; ACT_DIM]);
    assert_eq!(cartesian.act_joint(&obs), [0.0; JOINT_ACT_DIM]);

    let blob = joint_step_blob();
    assert_eq!(ActionSpaceRefusal::of(&blob), None);
    let joint = loader.prepare(&blob).unwrap();
    assert_eq!(joint.action_space(), ActionSpace::JointStep);
    let mut expected = [0.0f32; JOINT_ACT_DIM];
    joint
        .evaluate(&obs[..JOINT_OBS_DIM], &mut expected)
        .unwrap();
    assert_eq!(joint.act_joint(&obs), expected);
    assert_ne!(expected, [0.0; JOINT_ACT_DIM]);
    assert_eq!(joint.act(&obs), [0.0; ACT_DIM]);

    let mut unknown = valid();
    unknown.action_space = 7;
    unknown.seal();
    assert_eq!(
        loader.prepare(&unknown).err(),
        Some(PolicyRejectReason::UnknownActionSpace)
    );
    let why = ActionSpaceRefusal::of(&unknown).unwrap();
    assert_eq!(why, ActionSpaceRefusal::Unknown(7));
    assert!(why.to_string().contains("byte 7"), "{why}");
    assert_eq!(loader.counters().accepted(), 2);
    assert_eq!(loader.counters().total_rejected(), 1);
}

#[test]
fn every_reject_reason_is_detected_counted_and_leaves_the_running_policy() {
    let loader = PolicyLoader::new(PolicyExpectation::for_task(TASK));
    let mut running = MlpPolicy::with_capacity();
    loader.prepare_into(&valid(), &mut running).unwrap();
    let obs = [0.3f32; OBS_DIM];
    let before = running.act(&obs);

    let mut cases: Vec<(Box<PolicyBlob>, PolicyRejectReason)> = Vec::new();
    let mut b = valid();
    b.weights[10] = f32::NAN;
    b.seal();
    cases.push((b, PolicyRejectReason::NonFinite));
    let mut b = valid();
    b.obs_mean[2] = f32::INFINITY;
    b.seal();
    cases.push((b, PolicyRejectReason::NonFinite));
    cases.push((
        PolicyBlobBuilder::random(8, TASK, OBS_DIM - 1, &[32], ACT_DIM, 1)
            .build()
            .unwrap(),
        PolicyRejectReason::DimensionMismatch,
    ));
    cases.push((
        PolicyBlobBuilder::random(8, TASK, OBS_DIM, &[32], ACT_DIM + 1, 1)
            .build()
            .unwrap(),
        PolicyRejectReason::DimensionMismatch,
    ));
    cases.push((
        PolicyBlobBuilder::random(8, TASK ^ 1, OBS_DIM, &[32], ACT_DIM, 1)
            .build()
            .unwrap(),
        PolicyRejectReason::TaskHashMismatch,
    ));
    let mut b = valid();
    b.weights[0] += 1.0;
    cases.push((b, PolicyRejectReason::BadChecksum));
    let mut b = valid();
    b.n_weights -= 1;
    b.seal();
    cases.push((b, PolicyRejectReason::LayoutInvalid));
    let mut b = valid();
    b.activation = 9;
    b.seal();
    cases.push((b, PolicyRejectReason::LayoutInvalid));
    let mut b = valid();
    b.hidden_sizes[0] = 300;
    b.seal();
    cases.push((b, PolicyRejectReason::LayoutInvalid));
    let mut b = valid();
    b.format_version = 2;
    b.seal();
    cases.push((b, PolicyRejectReason::VersionMismatch));
    let mut b = valid();
    b.obs_std[0] = 0.0;
    b.seal();
    cases.push((b, PolicyRejectReason::OutOfRange));
    let mut b = valid();
    b.action_space = 2;
    b.seal();
    cases.push((b, PolicyRejectReason::UnknownActionSpace));

    for (blob, want) in &cases {
        assert_eq!(
            loader.prepare_into(blob, &mut running),
            Err(*want),
            "{want:?}"
        );
        assert_eq!(loader.prepare(blob).err(), Some(*want));
        assert_eq!(running.policy_id(), 7);
        assert_eq!(running.act(&obs), before);
    }
    for reason in PolicyRejectReason::ALL {
        let expected = 2 * cases.iter().filter(|(_, r)| *r == reason).count() as u64;
        assert!(expected > 0, "{reason:?} has no case");
        assert_eq!(
            loader.counters().count(reason),
            expected,
            "{}",
            reason.as_str()
        );
    }
    assert_eq!(loader.counters().total_rejected(), 2 * cases.len() as u64);
    assert_eq!(loader.counters().accepted(), 1);
}

#[test]
fn swapping_into_a_spare_changes_the_action() {
    let loader = PolicyLoader::new(PolicyExpectation::for_task(TASK));
    let mut spare = MlpPolicy::with_capacity();
    let a = PolicyBlobBuilder::random(1, TASK, OBS_DIM, &[64, 64], ACT_DIM, 1)
        .build()
        .unwrap();
    let b = PolicyBlobBuilder::random(2, TASK, OBS_DIM, &[256, 256], ACT_DIM, 2)
        .build()
        .unwrap();
    let obs = [0.1f32; OBS_DIM];
    loader.prepare_into(&a, &mut spare).unwrap();
    let from_a = spare.act(&obs);
    loader.prepare_into(&b, &mut spare).unwrap();
    assert_eq!(spare.policy_id(), 2);
    assert_ne!(spare.act(&obs), from_a);
    loader.prepare_into(&a, &mut spare).unwrap();
    assert_eq!(spare.act(&obs), from_a);
}

/// A straightforward f64 evaluation of a blob, as the reference for the optimised kernels.
fn reference(blob: &PolicyBlob, obs: &[f32]) -> Vec<f64> {
    let d = blob.obs_dim as usize;
    let clip = f64::from(blob.obs_clip);
    let mut x: Vec<f64> = (0..d)
        .map(|i| {
            ((f64::from(obs[i]) - f64::from(blob.obs_mean[i])) / f64::from(blob.obs_std[i]))
                .clamp(-clip, clip)
        })
        .collect();
    for k in 0..blob.n_layers() {
        let l = blob.layer(k).unwrap();
        let last = k + 1 == blob.n_layers();
        x = (0..l.out_dim)
            .map(|o| {
                let z: f64 = (0..l.in_dim)
                    .map(|j| f64::from(l.weights[o * l.in_dim + j]) * x[j])
                    .sum::<f64>()
                    + f64::from(l.bias[o]);
                match (last, blob.activation) {
                    (true, _) => z,
                    (false, 1) => z.tanh(),
                    (false, _) => z.max(0.0),
                }
            })
            .collect();
    }
    let c = f64::from(blob.action_clip);
    x.iter()
        .enumerate()
        .map(|(j, v)| v.clamp(-c, c) * f64::from(blob.action_scale[j]))
        .collect()
}

#[test]
fn optimised_kernels_match_a_plain_f64_evaluation() {
    let loader = PolicyLoader::new(PolicyExpectation::for_task(TASK));
    for (hidden, activation) in [
        (vec![64usize, 64], Activation::Tanh),
        (vec![256, 256], Activation::Tanh),
        (vec![100, 17, 40], Activation::Relu),
        (vec![8], Activation::Relu),
    ] {
        let blob = PolicyBlobBuilder::random(9, TASK, OBS_DIM, &hidden, ACT_DIM, 4)
            .activation(activation)
            .obs_normalization(&[0.1; OBS_DIM], &[0.5; OBS_DIM], 5.0)
            .action_scaling(&[2.0, 1.0, 0.5], 1.0)
            .build()
            .unwrap();
        let p = loader.prepare(&blob).unwrap();
        for s in 0..20 {
            let obs: [f32; OBS_DIM] =
                core::array::from_fn(|i| ((i * 7 + s * 13) % 23) as f32 * 0.1 - 1.0);
            let got = p.act(&obs);
            let want = reference(&blob, &obs);
            for j in 0..ACT_DIM {
                assert!(
                    (f64::from(got[j]) - want[j]).abs() < 1e-4,
                    "{hidden:?} sample {s} action {j}: {} vs {}",
                    got[j],
                    want[j]
                );
            }
        }
    }
}

#[test]
fn loader_works_on_a_private_copy_so_later_writes_to_the_source_do_not_reach_the_policy() {
    // The loader's entry points take only a private copy (a `&PolicyBlob` from shared
    // memory does not fit; see also the `compile_fail` example on `PolicyLoader`).
    type Private<'a> = &'a Box<PolicyBlob>;
    let _: fn(&PolicyLoader, Private<'_>) -> Result<(), PolicyRejectReason> = PolicyLoader::check;
    let _: fn(&PolicyLoader, Private<'_>) -> Result<MlpPolicy, PolicyRejectReason> =
        PolicyLoader::prepare;
    let _: fn(&PolicyLoader, Private<'_>, &mut MlpPolicy) -> Result<(), PolicyRejectReason> =
        PolicyLoader::prepare_into;

    let loader = PolicyLoader::new(PolicyExpectation::for_task(TASK));
    let obs = [0.7f32; OBS_DIM];
    let want = loader.prepare(&valid()).unwrap().act(&obs);
    // `shared` stands for the iceoryx2 sample; the loader only accepts the private copy
    // (`&Box<PolicyBlob>`), taken before anything is checked, as `TwinNode::receive` does.
    let mut shared = valid();
    let private = shared.to_boxed();
    assert_eq!(loader.check(&private), Ok(()));
    // A writer racing on the sample after the copy: inverted and NaN clip bounds, other
    // weights, resealed so that only the values are wrong.
    shared.obs_clip = -1.0;
    shared.action_clip = f32::NAN;
    shared.weights[0] = 1e6;
    shared.seal();
    let mut spare = MlpPolicy::with_capacity();
    loader.prepare_into(&private, &mut spare).unwrap();
    assert_eq!(
        spare.act(&obs),
        want,
        "the loaded policy has the validated values"
    );
    assert_eq!(loader.prepare(&private).unwrap().act(&obs), want);
    assert_eq!(loader.check(&private), Ok(()), "the copy still validates");
    assert_eq!(
        loader.check(&shared.to_boxed()),
        Err(PolicyRejectReason::NonFinite),
        "the source is now invalid"
    );
}

#[test]
fn clip_bounds_with_min_above_max_or_nan_are_rejected_naming_the_field() {
    let loader = PolicyLoader::new(PolicyExpectation::for_task(TASK));
    type Field = fn(&mut PolicyBlob) -> &mut f32;
    let fields: [(&str, Field); 2] = [
        ("obs_clip", |b| &mut b.obs_clip),
        ("action_clip", |b| &mut b.action_clip),
    ];
    for (field, slot) in fields {
        for (bound, schema, reason) in [
            // clamp(-c, c) with c < 0: min > max.
            (
                -0.5,
                SchemaError::OutOfRange { field },
                PolicyRejectReason::OutOfRange,
            ),
            (
                f32::NAN,
                SchemaError::NonFinite { field },
                PolicyRejectReason::NonFinite,
            ),
            (
                f32::INFINITY,
                SchemaError::NonFinite { field },
                PolicyRejectReason::NonFinite,
            ),
        ] {
            let mut blob = valid();
            *slot(&mut blob) = bound;
            blob.seal();
            assert_eq!(blob.validate(), Err(schema), "{field} = {bound}");
            assert!(schema.to_string().contains(field), "{schema}");
            assert_eq!(loader.check(&blob), Err(reason), "{field} = {bound}");
            let mut running = MlpPolicy::with_capacity();
            assert_eq!(loader.prepare_into(&blob, &mut running), Err(reason));
            assert!(!running.is_loaded());
        }
    }
}
