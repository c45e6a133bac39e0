//! `learner serve` end to end: a short real pre-training gives a base checkpoint, the real
//! `learner serve` binary is started with a unique service prefix, a `RetrainRequest`
//! (the tall-box scene) is published over iceoryx2, and a `PolicyBlob` that validates and
//! carries the task's hash must come back, with `RetrainProgress` along the way.
//!
//! Budgets are tiny (a few thousand steps, seconds): this checks the hand-over, not the
//! quality of the retrained policy (that is measured by `learner retrain`, see the README).

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::{Command, Stdio};
use std::time::Duration;

use foresight_tests::{ChildGuard, asset, bin_path, unique_prefix, wait_for};
use iceoryx2::prelude::*;
use policy::{PolicyExpectation, PolicyLoader};
use shm_schemas::scene_file::SceneFile;
use shm_schemas::{
    EpisodeEnd, PolicyBlob, RetrainPhase, RetrainProgress, RetrainRequest, services,
};
use twin::TaskConfig;

#[test]
fn serve_answers_a_retrain_request_with_a_valid_policy_blob() {
    let learner = bin_path("learner");
    let task = asset("task.toml");
    let hash = TaskConfig::load(&task).expect("task config").hash();
    let dir = std::env::temp_dir().join(unique_prefix("learner_serve_ckpt"));
    let status = Command::new(&learner)
        .args([
            "pretrain",
            "--steps",
            "4096",
            "--seed",
            "3",
            "--eval-every",
            "4096",
            "--eval-episodes",
            "4",
        ])
        .args(["--envs", "16", "--workers", "1"])
        .arg("--task")
        .arg(&task)
        .arg("--out")
        .arg(&dir)
        .stdout(Stdio::null())
        .status()
        .expect("run learner pretrain");
    assert!(status.success(), "learner pretrain failed");
    assert!(dir.join("best.ckpt").is_file());

    let prefix = unique_prefix("learner_serve");
    let (node, _) = services::create_node::<ipc::Service>("learner_serve_test").expect("node");
    let blobs =
        services::open_subscriber::<PolicyBlob, _>(&node, &prefix).expect("blob subscriber");
    let progress = services::open_subscriber::<RetrainProgress, _>(&node, &prefix)
        .expect("progress subscriber");
    let requests =
        services::open_publisher::<RetrainRequest, _>(&node, &prefix).expect("request publisher");

    let mut serve = ChildGuard::spawn(
        "learner serve",
        Command::new(&learner)
            .args([
                "serve",
                "--prefix",
                &prefix,
                "--max-steps",
                "4096",
                "--time-budget-s",
                "20",
            ])
            .args([
                "--eval-every",
                "2048",
                "--eval-episodes",
                "4",
                "--max-requests",
                "1",
                "--workers",
                "1",
            ])
            .arg("--checkpoint")
            .arg(&dir)
            .arg("--task")
            .arg(&task)
            .arg("--out")
            .arg(dir.join("retrain"))
            .stdout(Stdio::null()),
    );

    let scene = SceneFile::load(&asset("scenes/tall_box.toml")).expect("tall box scene");
    let mut req = RetrainRequest {
        request_id: 7,
        task_config_hash: hash,
        ..Default::default()
    };
    req.set_scene(&scene);
    req.verdict.set_flags(false, false, false);
    req.verdict.episode_end = EpisodeEnd::Collision as u8;
    req.validate().expect("request validates");
    // Sent, then resent every 0.5 s while no progress shows up (a repeat of the request in
    // training is not a new request): the server may not have subscribed yet.
    requests.send_copy(req).expect("send request");
    let mut phases = Vec::new();
    let started = std::time::Instant::now();
    let mut resent = 0;
    let blob = wait_for(Duration::from_secs(90), || {
        if phases.is_empty() && started.elapsed() > Duration::from_millis(500 * (resent + 1)) {
            let _ = requests.send_copy(req);
            resent += 1;
        }
        while let Ok(Some(p)) = progress.receive() {
            assert_eq!(p.request_id, 7);
            p.validate().expect("progress validates");
            phases.push(p.phase().expect("phase"));
        }
        let got = blobs.receive().ok().flatten().map(|s| {
            let b: &PolicyBlob = s.payload();
            (
                b.validate(),
                b.task_config_hash,
                b.policy_id,
                PolicyLoader::new(PolicyExpectation::for_task(hash)).check(&b.to_boxed()),
            )
        });
        if got.is_none() {
            std::thread::sleep(Duration::from_millis(200));
        }
        got
    })
    .expect("no PolicyBlob within 90 s");
    let (valid, blob_hash, policy_id, accepted) = blob;
    assert_eq!(valid, Ok(()));
    assert_eq!(blob_hash, hash);
    assert_ne!(policy_id, 0);
    assert_eq!(accepted, Ok(()), "rt-core's loader must accept the blob");
    // The final progress message follows the blob.
    let _ = wait_for(Duration::from_secs(5), || {
        while let Ok(Some(p)) = progress.receive() {
            phases.push(p.phase().expect("phase"));
        }
        phases
            .iter()
            .any(|p| matches!(p, RetrainPhase::Published | RetrainPhase::BudgetExhausted))
            .then_some(())
    });
    assert!(
        phases
            .iter()
            .any(|p| matches!(p, RetrainPhase::Training | RetrainPhase::Evaluating)),
        "progress while training: {phases:?}"
    );
    assert!(
        phases
            .iter()
            .any(|p| matches!(p, RetrainPhase::Published | RetrainPhase::BudgetExhausted)),
        "final progress: {phases:?}"
    );
    let status = serve.interrupt_and_wait(Duration::from_secs(10));
    assert!(
        status.is_some_and(|s| s.success()),
        "learner serve should exit cleanly after --max-requests 1"
    );
    assert!(dir.join("retrain/request-7/metrics.csv").is_file());
    std::fs::remove_dir_all(&dir).ok();
}
