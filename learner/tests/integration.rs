//! Integration tests of the learner library: checkpoints (round trip, atomicity, exact
//! resume) and a training run on the toy task through the run driver.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;

use learner::checkpoint::{self, Checkpoint};
use learner::env::{PointReach, PointScene};
use learner::ppo::{PpoConfig, Trainer};
use learner::run::{RunOptions, train};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use tch::Device;

fn tmp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("learner-it-{tag}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn cfg() -> PpoConfig {
    PpoConfig {
        n_envs: 8,
        n_steps: 32,
        batch_size: 64,
        workers: 2,
        ..Default::default()
    }
}

fn trainer(seed: u64) -> Trainer<PointReach> {
    Trainer::new(cfg(), PointReach::default(), seed, Device::Cpu).unwrap()
}

#[test]
fn checkpoint_round_trip_restores_the_whole_training_state() {
    let dir = tmp_dir("rt");
    let mut a = trainer(3);
    for _ in 0..2 {
        a.iterate(&PointScene::random);
    }
    let ck = Checkpoint::capture(&a, 3, 0xfeed);
    ck.save(&dir.join("x.ckpt")).unwrap();
    let back = Checkpoint::load(&dir.join("x.ckpt")).unwrap();
    assert_eq!(back, ck);
    assert_eq!(back.meta.task_hash, 0xfeed);
    assert_eq!(back.meta.steps, 2 * 8 * 32);

    // Resuming from the checkpoint continues exactly like a trainer restored from the same
    // state (both restart episodes), and differs from a fresh trainer.
    let mut b = trainer(99);
    back.restore(&mut b).unwrap();
    assert_eq!(b.net.flat(), a.net.flat());
    assert_eq!(b.obs_rms, a.obs_rms);
    let mut c = trainer(7);
    ck.restore(&mut c).unwrap();
    b.iterate(&PointScene::random);
    c.iterate(&PointScene::random);
    assert_eq!(b.net.flat(), c.net.flat());
    assert_eq!(b.adam.t, c.adam.t);
    assert_ne!(b.net.flat(), ck.theta);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_crash_mid_write_leaves_the_old_checkpoint() {
    let dir = tmp_dir("crash");
    let path = dir.join(checkpoint::LAST);
    let mut t = trainer(1);
    let old = Checkpoint::capture(&t, 1, 1);
    old.save(&path).unwrap();
    t.iterate(&PointScene::random);
    let new = Checkpoint::capture(&t, 1, 1);
    let bytes = new.to_bytes().unwrap();
    for cut in [0, 10, bytes.len() / 2, bytes.len() - 1] {
        assert!(checkpoint::write_atomic_inner(&path, &bytes, Some(cut)).is_err());
        assert_eq!(Checkpoint::load(&path).unwrap(), old, "cut at {cut}");
    }
    // A torn file is rejected, never half-loaded.
    assert!(Checkpoint::from_bytes(&bytes[..bytes.len() / 2]).is_err());
    new.save(&path).unwrap();
    assert_eq!(Checkpoint::load(&path).unwrap(), new);
    // A directory resolves to best.ckpt when present, else last.ckpt.
    assert_eq!(Checkpoint::load(&dir).unwrap(), new);
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn run_driver_trains_checkpoints_and_writes_metrics() {
    let dir = tmp_dir("run");
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    let scenes: Vec<PointScene> = (0..32).map(|_| PointScene::random(&mut rng)).collect();
    let mut t = trainer(2);
    let before = t.evaluate(&scenes);
    let opts = RunOptions {
        out_dir: dir.clone(),
        total_steps: 20 * 8 * 32,
        eval_every_steps: 5 * 8 * 32,
        seed: 2,
        task_hash: 42,
        time_budget: None,
        success_rule: None,
        title: "test".into(),
        progress: false,
        lr_schedule: None,
    };
    let mut iters = 0;
    let sum = train(&mut t, &PointScene::random, &scenes, &opts, |_, _| {
        iters += 1;
        true
    })
    .unwrap();
    assert_eq!(iters, 20);
    assert_eq!(sum.total_steps, 20 * 8 * 32);
    let best = Checkpoint::load(&dir.join(checkpoint::BEST)).unwrap();
    let last = Checkpoint::load(&dir.join(checkpoint::LAST)).unwrap();
    assert_eq!(last.meta.steps, 20 * 8 * 32);
    assert_eq!(best.meta.task_hash, 42);
    let b = best.meta.eval.unwrap();
    assert!(
        b.mean_return > before.mean_return,
        "best {b:?} vs untrained {before:?}"
    );
    let csv = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
    assert_eq!(csv.lines().count(), 21);
    assert!(std::fs::metadata(dir.join("reward.svg")).unwrap().len() > 1000);
    std::fs::remove_dir_all(&dir).ok();
}

mod export_equivalence {
    use learner::checkpoint::Checkpoint;
    use learner::env::{Env, StepInfo};
    use learner::export;
    use learner::net::ActorCritic;
    use learner::normalize::ObsNormalizer;
    use learner::ppo::{PpoConfig, Trainer};
    use learner::random::randn;
    use policy::{PolicyExpectation, PolicyLoader};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use tch::{Device, Tensor};

    /// An environment with the twin's dimensions; only its shape matters here.
    #[derive(Clone)]
    struct Shape;
    impl Env for Shape {
        type Scene = ();
        fn obs_dim(&self) -> usize {
            twin::OBS_DIM
        }
        fn act_dim(&self) -> usize {
            twin::ACT_DIM
        }
        fn reset(&mut self, _: &(), obs: &mut [f32]) {
            obs.fill(0.0);
        }
        fn step(&mut self, _: &[f32], obs: &mut [f32]) -> StepInfo {
            obs.fill(0.0);
            StepInfo::default()
        }
    }

    #[test]
    fn exported_blob_acts_like_the_tch_policy_in_rt_core() {
        let mut t = Trainer::new(PpoConfig::default(), Shape, 5, Device::Cpu).unwrap();
        // Weights of a trained size (not the near-zero initial output layer) and
        // non-trivial normalisation statistics.
        let mut rng = ChaCha8Rng::seed_from_u64(17);
        let flat: Vec<f32> = (0..t.net.layout.len)
            .map(|_| 0.4 * randn(&mut rng))
            .collect();
        t.net = ActorCritic::from_flat(t.net.spec.clone(), &flat, Device::Cpu).unwrap();
        for (m, v) in t.obs_rms.mean.iter_mut().zip(t.obs_rms.var.iter_mut()) {
            *m = rng.random_range(-0.5..0.5);
            *v = rng.random_range(0.001..2.0);
        }
        let hash = 0x5eed_u64;
        let ck = Checkpoint::capture(&t, 5, hash);
        let blob = export::export_blob(&ck, 42).unwrap();
        blob.validate().unwrap();
        let loader = PolicyLoader::new(PolicyExpectation::for_task(hash));
        let policy = loader.prepare(&blob).unwrap();
        assert_eq!(policy.policy_id(), 42);

        let norm = ObsNormalizer::from_stats(&t.obs_rms, t.cfg.clip_obs);
        let n = 2000;
        let d = twin::OBS_DIM;
        // Wide observations so that the normalisation clip and the action clip both bite.
        let raw: Vec<f32> = (0..n * d).map(|_| rng.random_range(-3.0..3.0)).collect();
        let mut x = vec![0.0f32; n * d];
        for (r, o) in raw.chunks(d).zip(x.chunks_mut(d)) {
            norm.apply(r, o);
        }
        let mean = tch::no_grad(|| {
            t.net
                .actor_mean(&Tensor::from_slice(&x).view([n as i64, d as i64]))
                .clamp(-1.0, 1.0)
        });
        let a = twin::ACT_DIM;
        let mut tch_out = vec![0.0f32; n * a];
        mean.copy_data(&mut tch_out, n * a);
        let (mut max_diff, mut clipped) = (0.0f32, 0usize);
        let mut out = [0.0f32; twin::ACT_DIM];
        for (i, obs) in raw.chunks(d).enumerate() {
            policy.evaluate(obs, &mut out).unwrap();
            for k in 0..a {
                max_diff = max_diff.max((out[k] - tch_out[i * a + k]).abs());
                clipped += usize::from(out[k].abs() == 1.0);
            }
        }
        assert!(max_diff <= 1e-5, "max |rt-core - tch| = {max_diff}");
        assert!(
            clipped > 0 && clipped < n * a,
            "the test should exercise the action clip ({clipped})"
        );
    }

    #[test]
    fn blob_file_round_trips_and_rejects_corruption() {
        let t = Trainer::new(PpoConfig::default(), Shape, 1, Device::Cpu).unwrap();
        let ck = Checkpoint::capture(&t, 1, 7);
        let blob = export::export_blob(&ck, 9).unwrap();
        let dir = super::tmp_dir("blob");
        let path = dir.join("p.blob");
        export::write_blob(&path, &blob).unwrap();
        let back = export::read_blob(&path).unwrap();
        assert_eq!(*back, *blob);
        let mut bytes = std::fs::read(&path).unwrap();
        bytes[400] ^= 0x40;
        assert!(export::blob_from_bytes(&bytes).is_err());
        assert!(export::blob_from_bytes(&bytes[..100]).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}

/// The joint-step space (issue 40 item 3): `learner distil --action-space joint_step`'s
/// teachers and what it keeps.
mod joint_step_distillation {
    use std::path::PathBuf;

    use learner::checkpoint::{self, Checkpoint};
    use learner::distil::joint::{JointPathExpert, joint_step_toward};
    use learner::distil::{DistilConfig, DistilJob};
    use learner::normalize::ObsNormalizer;
    use learner::ppo::bc::BcConfig;
    use learner::twin_env::TwinTask;
    use policy::{PolicyExpectation, PolicyLoader};
    use shm_schemas::scene_file::SceneFile;
    use shm_schemas::{ActionSpace, JOINT_ACT_DIM, JOINT_OBS_DIM, OBS_LAYOUT_JOINT_V1};
    use twin::{DOF, Scene};

    fn assets() -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets")
    }

    #[test]
    fn the_step_toward_a_target_keeps_its_direction_and_its_largest_joint_at_one() {
        let scale = [0.03; DOF];
        let q = [0.0; DOF];
        let a = joint_step_toward(&q, &[0.3, -0.15, 0.0, 0.0, 0.03], &scale);
        assert_eq!(a, [1.0, -0.5, 0.0, 0.0, 0.1]);
        // Within one step: exactly the difference.
        let b = joint_step_toward(&q, &[0.015, 0.0, 0.0, 0.0, -0.03], &scale);
        assert!(
            (b[0] - 0.5).abs() < 1e-6 && (b[4] + 1.0).abs() < 1e-6,
            "{b:?}"
        );
    }

    #[test]
    fn the_path_expert_follows_its_path_to_the_end_and_restarts() {
        let scale = [0.03; DOF];
        let path = [
            [0.0; DOF],
            [0.5, 0.0, 0.0, 0.0, 0.0],
            [0.5, 0.5, 0.0, 0.0, 0.0],
        ];
        let mut e = JointPathExpert::new(&path, scale);
        let first = e.action(&[0.0; DOF]);
        let mut q = [0.0; DOF];
        for _ in 0..200 {
            let a = e.action(&q);
            for ((q, a), s) in q.iter_mut().zip(a).zip(scale) {
                *q += f64::from(a) * s;
            }
            // Never far from the L-shaped path (the corner cut by less than the lookahead).
            assert!(q[1] <= 0.01 || q[0] >= 0.45, "{q:?}");
        }
        assert!(
            (q[0] - 0.5).abs() < 1e-6 && (q[1] - 0.5).abs() < 1e-6,
            "{q:?}"
        );
        // At the end it stays; after a restart it starts along the path again.
        let rest = e.action(&q);
        assert!(rest.iter().all(|a| a.abs() < 1e-4), "{rest:?}");
        e.restart();
        assert_eq!(e.action(&[0.0; DOF]), first);
    }

    #[test]
    fn a_joint_step_distillation_keeps_a_blob_that_rt_core_loads_and_the_twin_rolls_out() {
        tch::set_num_threads(1);
        let out = std::env::temp_dir().join(format!("learner-distil-joint-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&out);
        let job = DistilJob {
            checkpoint: assets().join("policy"),
            task: assets().join("task.toml"),
            worlds: 6,
            harder_share: 0.5,
            hidden: None,
            config: DistilConfig {
                iterations: 2,
                bc: BcConfig {
                    steps: 60,
                    ..DistilConfig::default().bc
                },
                ..DistilConfig::default()
            },
            margin_m: 0.02,
            eval_episodes: 4,
            seed: 3,
            threads: 2,
            out: out.clone(),
            action_space: ActionSpace::JointStep,
        };
        let summary = job
            .run(tch::Device::Cpu, |_| {})
            .expect("joint distillation");
        let w = summary.worlds;
        assert!(w.line + w.planner >= 1, "no joint-step teacher: {w:?}");
        assert_eq!(w.via, 0, "a via-point route is a Cartesian teacher: {w:?}");
        assert_eq!(summary.action_space, "joint_step");

        // The checkpoint records its space; its network is the joint layout's.
        let ck = Checkpoint::load(&out.join(checkpoint::BEST)).expect("best.ckpt");
        assert_eq!(ck.meta.action_space(), ActionSpace::JointStep);
        assert_eq!(ck.meta.spec.obs_dim, JOINT_OBS_DIM);
        assert_eq!(ck.meta.spec.act_dim, JOINT_ACT_DIM);

        // Its blob names the space and the layout, and rt-core's loader takes it.
        let blob = learner::export::export_blob(&ck, 7).expect("blob");
        assert!(matches!(
            ActionSpace::try_from(blob.action_space),
            Ok(ActionSpace::JointStep)
        ));
        assert_eq!(blob.obs_layout, OBS_LAYOUT_JOINT_V1);
        let mlp = PolicyLoader::new(PolicyExpectation::for_task(ck.meta.task_hash))
            .prepare(&blob)
            .expect("rt-core's loader refused the joint-step blob");

        // It rolls out in the twin's joint-step space and moves the arm there, with the
        // actions the learner's network gives.
        let task = TwinTask::load(&assets().join("task.toml"), None).expect("task");
        let file =
            SceneFile::load(&assets().join("scenes").join("tall_box.toml")).expect("scene file");
        let scene = Scene::from_file(&file).expect("scene");
        let mut tw = task.env.clone();
        let mut first: Option<([f32; twin::OBS_DIM], [f32; JOINT_ACT_DIM])> = None;
        let ep = twin::rollout_joint(
            &mut tw,
            &scene,
            |o| {
                let a = mlp.act_joint(o);
                first.get_or_insert((*o, a));
                a
            },
            None,
            true,
        );
        assert!(ep.steps >= 1);
        let start = task.env.config().start.joints_rad;
        assert_ne!(
            tw.joints(),
            start,
            "the joint-step policy did not move the arm"
        );
        let (obs, act) = first.expect("one step");
        let net = ck.network(tch::Device::Cpu).expect("network");
        let norm = ObsNormalizer::from_stats(&ck.meta.obs_rms.to_rms(), ck.meta.ppo.clip_obs);
        let mut row = vec![0.0f32; JOINT_OBS_DIM];
        norm.apply(&obs[..JOINT_OBS_DIM], &mut row);
        let mean = net.actor_mean(&tch::Tensor::from_slice(&row).view([1, -1]));
        let mut want = [0.0f32; JOINT_ACT_DIM];
        mean.view([-1]).copy_data(&mut want, JOINT_ACT_DIM);
        for (a, b) in act.iter().zip(want) {
            assert!((a - b.clamp(-1.0, 1.0)).abs() < 1e-4, "{act:?} vs {want:?}");
        }

        // A Cartesian checkpoint's metadata has no action-space field (its bytes are what
        // they were before the joint step existed).
        let cartesian =
            Checkpoint::load(&assets().join("policy-distilled/best.ckpt")).expect("bundled policy");
        assert_eq!(cartesian.meta.action_space(), ActionSpace::CartesianStep);
        let meta = serde_json::to_string(&cartesian.meta).expect("meta");
        assert!(!meta.contains("action_space"), "{meta}");
        let _ = std::fs::remove_dir_all(&out);
    }
}
