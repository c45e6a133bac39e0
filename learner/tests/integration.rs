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
