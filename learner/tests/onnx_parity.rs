//! `learner export --onnx`'s graph, run in ONNX Runtime (the library `make setup` installs
//! for perception), matches the learner's tch network and rt-core's kernel within 1e-5 on
//! 1 000 observations, for each bundled policy (the joint-step one too); and each bundled
//! policy's export beside its blob is the one its blob gives today (the library keeps it
//! current).

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use learner::checkpoint::Checkpoint;
use learner::export::{blob_normalizer, export_blob, policy_id_for, read_blob};
use learner::net::ActorCritic;
use learner::onnx;
use ort::session::Session;
use ort::value::TensorRef;
use policy::{PolicyExpectation, PolicyLoader};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use shm_schemas::PolicyBlob;
use tch::{Device, Tensor};

const OBSERVATIONS: usize = 1000;
const TOLERANCE: f32 = 1e-5;

fn assets() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets")
}

/// The ONNX Runtime library: `ORT_DYLIB_PATH`, or the one `make setup` installed (baked in
/// by the Makefile's environment at build time).
fn ort_library() -> PathBuf {
    std::env::var_os("ORT_DYLIB_PATH")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| option_env!("FORESIGHT_ORT_DYLIB").filter(|s| !s.is_empty()).map(PathBuf::from))
        .expect("no ONNX Runtime library: run the tests through `make test` (make setup installs it) or set ORT_DYLIB_PATH")
}

fn session(model: &[u8]) -> Session {
    // One ONNX Runtime environment per process, shared by the tests (kept alive here).
    static ENV: std::sync::Mutex<Option<ort::environment::Environment>> =
        std::sync::Mutex::new(None);
    let mut env = ENV
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    if env.is_none() {
        *env = Some(
            ort::init_from(ort_library())
                .expect("loading ONNX Runtime")
                .with_name("onnx-parity")
                .with_telemetry(false)
                .build()
                .expect("an ONNX Runtime environment"),
        );
    }
    let mut builder = Session::builder(env.as_ref().unwrap())
        .unwrap()
        .with_intra_threads(1)
        .unwrap();
    builder
        .commit_from_memory(model)
        .expect("ONNX Runtime loads the exported graph")
}

/// Observations around the normaliser's mean, out to ±4 standard deviations (past the
/// clip of 5 σ for a few values in every batch: the clip is exercised too).
fn observations(blob: &PolicyBlob, seed: u64) -> Vec<f32> {
    let n = blob.obs_dim as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut obs = Vec::with_capacity(OBSERVATIONS * n);
    for k in 0..OBSERVATIONS {
        let spread = if k % 10 == 0 { 8.0 } else { 4.0 };
        for i in 0..n {
            let z: f32 = rng.random_range(-spread..spread);
            obs.push(blob.obs_mean[i] + z * blob.obs_std[i]);
        }
    }
    obs
}

fn run_onnx(model: &[u8], obs: &[f32], obs_dim: usize, act_dim: usize) -> Vec<f32> {
    let mut s = session(model);
    let input = TensorRef::from_array_view(([OBSERVATIONS, obs_dim], obs)).unwrap();
    let outputs = s.run(ort::inputs![onnx::INPUT => input]).unwrap();
    let (shape, values) = outputs[onnx::OUTPUT].try_extract_tensor::<f32>().unwrap();
    assert_eq!(shape.to_vec(), vec![OBSERVATIONS as i64, act_dim as i64]);
    values.to_vec()
}

/// The learner's own network (tch) on the same observations: normalised as in training,
/// the actor's mean, clipped to the blob's action clip.
fn run_tch(ck: &Checkpoint, blob: &PolicyBlob, obs: &[f32]) -> Vec<f32> {
    let n = blob.obs_dim as usize;
    let a = blob.act_dim as usize;
    let norm = blob_normalizer(blob);
    let mut x = vec![0.0f32; obs.len()];
    for (raw, out) in obs.chunks(n).zip(x.chunks_mut(n)) {
        norm.apply(raw, out);
    }
    let net = ActorCritic::from_flat(ck.meta.spec.clone(), &ck.theta, Device::Cpu).unwrap();
    let mean = net
        .actor_mean(&Tensor::from_slice(&x).view([OBSERVATIONS as i64, n as i64]))
        .clamp(-f64::from(blob.action_clip), f64::from(blob.action_clip))
        .contiguous();
    let mut out = vec![0.0f32; OBSERVATIONS * a];
    mean.copy_data(&mut out, OBSERVATIONS * a);
    out
}

fn worst(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// `folder`'s blob, exported to ONNX, against tch and rt-core's kernel; its action space
/// is `space` (`cartesian_step`, `joint_step`).
fn parity(folder: &str, seed: u64, space: &str) {
    let dir = assets().join(folder);
    let ck = Checkpoint::load(&dir.join("best.ckpt")).unwrap();
    let blob = read_blob(&dir.join("policy.blob")).unwrap();
    assert_eq!(
        blob.policy_id,
        export_blob(&ck, policy_id_for(&ck)).unwrap().policy_id,
        "{folder}: the bundled blob is its checkpoint's"
    );
    let model = onnx::policy_onnx(&blob).unwrap();
    let n = blob.obs_dim as usize;
    let a = blob.act_dim as usize;
    let obs = observations(&blob, seed);
    let from_onnx = run_onnx(&model, &obs, n, a);
    assert!(from_onnx.iter().all(|v| v.is_finite()));
    let from_tch = run_tch(&ck, &blob, &obs);
    let rt_core = PolicyLoader::new(PolicyExpectation {
        task_config_hash: blob.task_config_hash,
        obs_dim: n,
        act_dim: a,
    })
    .prepare(&blob)
    .unwrap();
    let mut from_kernel = vec![0.0f32; OBSERVATIONS * a];
    for (o, out) in obs.chunks(n).zip(from_kernel.chunks_mut(a)) {
        rt_core.evaluate(o, out).unwrap();
    }
    let (vs_tch, vs_kernel) = (
        worst(&from_onnx, &from_tch),
        worst(&from_onnx, &from_kernel),
    );
    println!("{folder}: ONNX vs tch {vs_tch:e}, ONNX vs rt-core's kernel {vs_kernel:e}");
    assert!(
        vs_tch <= TOLERANCE,
        "{folder}: ONNX vs tch differs by {vs_tch}"
    );
    assert!(
        vs_kernel <= TOLERANCE,
        "{folder}: ONNX vs rt-core differs by {vs_kernel}"
    );
    // The outputs move with the input (not a constant graph) and reach the clip.
    let spread = worst(&from_onnx[..a], &from_onnx[a..2 * a]);
    assert!(
        spread > 1e-3,
        "{folder}: different observations, different actions"
    );
    // The export beside the blob is the blob's, today.
    let kept = std::fs::read(dir.join(onnx::ONNX_FILE)).unwrap_or_else(|e| {
        panic!("{folder}/{} is kept beside the blob: {e}; make it with `learner export --blob {folder}/policy.blob --onnx {folder}`", onnx::ONNX_FILE)
    });
    assert!(
        kept == model,
        "{folder}/{} is stale: re-export it",
        onnx::ONNX_FILE
    );
    let schema: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join(onnx::SCHEMA_FILE)).unwrap())
            .unwrap();
    assert_eq!(schema["policy"]["policy_id"], blob.policy_id);
    assert_eq!(schema["observation"]["dim"], n);
    assert_eq!(schema["action"]["space"], space);
    assert_eq!(schema["action"]["dim"], a);
}

#[test]
fn the_generalists_onnx_export_matches_tch_and_rt_core_within_1e_5() {
    parity("policy", 1, "cartesian_step");
}

#[test]
fn the_distilled_policys_onnx_export_matches_tch_and_rt_core_within_1e_5() {
    parity("policy-distilled", 2, "cartesian_step");
}

#[test]
fn the_joint_step_policys_onnx_export_matches_tch_and_rt_core_within_1e_5() {
    parity("policy-joint-distilled", 3, "joint_step");
    let schema: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(
            assets()
                .join("policy-joint-distilled")
                .join(onnx::SCHEMA_FILE),
        )
        .unwrap(),
    )
    .unwrap();
    assert_eq!(schema["observation"]["kind"], "joint_v1");
    assert_eq!(
        schema["observation"]["layout_version"],
        shm_schemas::OBS_LAYOUT_JOINT_V1
    );
    assert_eq!(schema["action"]["names"][4], "dq5");
}
