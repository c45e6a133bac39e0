//! Criterion benches of policy inference: `MlpPolicy::act` for 17→64→64→3 and
//! 17→256→256→3 (tanh), and the off-cycle cost of accepting a blob
//! (`PolicyLoader::prepare_into`: validation, checksum, copy).
//!
//! `scripts/cargo.sh bench --release -p rt-core --bench policy`

// Benchmarks: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use policy::{MlpPolicy, PolicyExpectation, PolicyLoader};
use shm_schemas::{Activation, PolicyBlobBuilder};
use twin::{ACT_DIM, OBS_DIM};

const TASK: u64 = 0xbe7c;

fn bench_act(c: &mut Criterion) {
    let loader = PolicyLoader::new(PolicyExpectation::for_task(TASK));
    let mut obs = [0.0f32; OBS_DIM];
    for (i, o) in obs.iter_mut().enumerate() {
        *o = (i as f32 * 0.37).sin();
    }
    for (hidden, activation, name) in [
        (64, Activation::Tanh, "act 17-64-64-3 tanh"),
        (256, Activation::Tanh, "act 17-256-256-3 tanh"),
        (256, Activation::Relu, "act 17-256-256-3 relu"),
    ] {
        let blob = PolicyBlobBuilder::random(1, TASK, OBS_DIM, &[hidden, hidden], ACT_DIM, 7)
            .activation(activation)
            .build()
            .unwrap();
        let policy = loader.prepare(&blob).unwrap();
        c.bench_function(name, |b| b.iter(|| policy.act(black_box(&obs))));
    }
    let blob = PolicyBlobBuilder::random(2, TASK, OBS_DIM, &[256, 256], ACT_DIM, 8)
        .build()
        .unwrap();
    let mut spare = MlpPolicy::with_capacity();
    c.bench_function("prepare_into 17-256-256-3", |b| {
        b.iter(|| loader.prepare_into(black_box(&blob), &mut spare))
    });
}

criterion_group!(benches, bench_act);
criterion_main!(benches);
