//! Latency across the host-to-host link: iceoryx2 publish on one "host" → relay → Zenoh
//! over a veth pair between two network namespaces → relay → iceoryx2 receive on the other.
//!
//! - a policy blob (the full `PolicyBlob`, ≈ 328 KB) from the learner side to the controller;
//! - a retrain request (≈ 0.7 KB) from the controller side to the learner.
//!
//! Prints p50, p90, p99 and max over `BENCH_SAMPLES` (default 200) of each. Needs root
//! (`ip netns`) and the built `zenoh-relay`; says so and exits 0 without root.
//! `make bench-link`.
#![allow(clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

use foresight_tests::bin_path;
use foresight_tests::veth::TwoHosts;
use iceoryx2::prelude::*;
use shm_schemas::services::{self, loan_zeroed};
use shm_schemas::{EpisodeEnd, PolicyBlob, PolicyBlobBuilder, RetrainRequest, TwinVerdict};
use zenoh_relay::status::RelayStatus;

struct Proc(Child);
impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn percentiles(name: &str, mut v: Vec<f64>) {
    v.sort_by(f64::total_cmp);
    let at = |q: f64| v[((v.len() - 1) as f64 * q).round() as usize];
    println!(
        "{name:<40} n={:<4} p50 {:>7.3} ms  p90 {:>7.3} ms  p99 {:>7.3} ms  max {:>7.3} ms",
        v.len(),
        at(0.5),
        at(0.9),
        at(0.99),
        v[v.len() - 1]
    );
}

fn main() {
    // `cargo bench` passes `--bench`; a filter that is not ours means "not this bench".
    if std::env::args()
        .skip(1)
        .any(|a| !a.starts_with('-') && !"link_latency".contains(&a))
    {
        return;
    }
    let samples: usize = std::env::var("BENCH_SAMPLES")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(200);
    let hosts = match TwoHosts::make("b") {
        Ok(h) => h,
        Err(e) => {
            println!("link_latency: SKIPPED, cannot make network namespaces ({e}); needs root");
            return;
        }
    };
    let id = std::process::id();
    let dir = std::env::temp_dir().join(format!("fs-link-bench-{id}"));
    std::fs::create_dir_all(&dir).unwrap();
    let (pc, pl) = (format!("fsbc{id}"), format!("fsbl{id}"));
    let endpoint = format!("tcp/{}:7447", hosts.learner_addr);
    // The link's keys (issue 25): both relays authenticate and sign, as in production.
    let keys = dir.join("keys");
    let _ = std::fs::remove_dir_all(&keys);
    let keygen = std::process::Command::new(bin_path("zenoh-relay"))
        .arg("keygen")
        .arg("--out")
        .arg(&keys)
        .output()
        .unwrap();
    assert!(keygen.status.success(), "zenoh-relay keygen: {keygen:?}");
    let relay = |ns: &str, side: &str, prefix: &str, link: [&str; 2], status: &str| {
        let folder = if side == "controller" {
            "robot-pc"
        } else {
            "learner-host"
        };
        Proc(
            hosts
                .exec(ns, &bin_path("zenoh-relay"))
                .arg(side)
                .args(["--prefix", prefix, "--link-name", "bench"])
                .args(link)
                .arg("--link-keys")
                .arg(keys.join(folder))
                .arg("--status")
                .arg(dir.join(status))
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .unwrap(),
        )
    };
    let _ctl = relay(
        &hosts.robot_ns,
        "controller",
        &pc,
        ["--peer", &endpoint],
        "c.json",
    );
    let _lrn = relay(
        &hosts.learner_ns,
        "learner",
        &pl,
        ["--listen", &endpoint],
        "l.json",
    );

    let (node, _) = services::create_node::<ipc::Service>("link-bench").unwrap();
    let pol_pub = services::open_publisher::<PolicyBlob, _>(&node, &pl).unwrap();
    let pol_sub = services::open_subscriber::<PolicyBlob, _>(&node, &pc).unwrap();
    let req_pub = services::open_publisher::<RetrainRequest, _>(&node, &pc).unwrap();
    let req_sub = services::open_subscriber::<RetrainRequest, _>(&node, &pl).unwrap();
    let deadline = Instant::now() + Duration::from_secs(30);
    while !RelayStatus::read(&dir.join("c.json"))
        .ok()
        .and_then(|s| s.peer)
        .is_some_and(|p| p.connected)
    {
        assert!(Instant::now() < deadline, "the relays did not connect");
        std::thread::sleep(Duration::from_millis(20));
    }
    // Let the learner relay's iceoryx2 subscribers see the bench's publishers.
    std::thread::sleep(Duration::from_millis(500));

    let mut blob = PolicyBlob::new_boxed();
    let mut policy_ms = Vec::new();
    for i in 0..samples + 5 {
        PolicyBlobBuilder::random(1000 + i as u64, 0x55, 17, &[256, 256], 3, i as u64)
            .write_into(&mut blob)
            .unwrap();
        let mut s = loan_zeroed(&pol_pub).unwrap();
        s.payload_mut().copy_from(&blob);
        let t0 = Instant::now();
        s.send().unwrap();
        let want = blob.policy_id;
        loop {
            if let Some(r) = pol_sub.receive().unwrap()
                && r.payload().policy_id == want
            {
                break;
            }
            assert!(t0.elapsed() < Duration::from_secs(10), "policy {i} lost");
            // Not a spin: on two cores a spinning bench would take a core from the relays.
            std::thread::sleep(Duration::from_micros(50));
        }
        if i >= 5 {
            policy_ms.push(t0.elapsed().as_secs_f64() * 1e3);
        }
        std::thread::sleep(Duration::from_millis(10));
    }

    let mut request_ms = Vec::new();
    for i in 0..samples + 5 {
        let r = RetrainRequest {
            request_id: 1 + i as u64,
            request_time_ns: 1 + i as u64,
            goal_center_m: [0.3, 0.1, 0.02],
            goal_size_m: 0.04,
            verdict: TwinVerdict {
                episode_end: EpisodeEnd::Collision as u8,
                ..TwinVerdict::default()
            },
            ..RetrainRequest::default()
        };
        let t0 = Instant::now();
        req_pub.send_copy(r).unwrap();
        loop {
            if let Some(got) = req_sub.receive().unwrap()
                && got.payload().request_id == r.request_id
            {
                break;
            }
            assert!(t0.elapsed() < Duration::from_secs(10), "request {i} lost");
            // Not a spin: on two cores a spinning bench would take a core from the relays.
            std::thread::sleep(Duration::from_micros(50));
        }
        if i >= 5 {
            request_ms.push(t0.elapsed().as_secs_f64() * 1e3);
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    println!(
        "link_latency over a veth pair between two network namespaces (iceoryx2 → relay → Zenoh/TCP → relay → iceoryx2):"
    );
    percentiles(
        &format!(
            "policy blob ({} KB), learner → controller",
            size_of::<PolicyBlob>() / 1024
        ),
        policy_ms,
    );
    percentiles(
        &format!(
            "retrain request ({} B), controller → learner",
            size_of::<RetrainRequest>()
        ),
        request_ms,
    );
    std::fs::remove_dir_all(&dir).ok();
}
