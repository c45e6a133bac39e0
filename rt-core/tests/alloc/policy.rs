//! Zero-allocation test of policy inference: a counting global allocator watches
//! `MlpPolicy::act` over 100 000 evaluations, with 100 hot swaps through
//! `PolicyLoader::prepare_into` (accepted and rejected blobs) in between, and asserts that
//! nothing was allocated or freed.

use std::hint::black_box;

use policy::{MlpPolicy, PolicyExpectation, PolicyLoader, PolicyRejectReason};
use rt_core::rt::alloc_count;
use shm_schemas::PolicyBlobBuilder;
use twin::{ACT_DIM, OBS_DIM};

#[test]
fn act_and_prepare_into_allocate_nothing() {
    const TASK: u64 = 0x5eed;
    let loader = PolicyLoader::new(PolicyExpectation::for_task(TASK));
    let small = PolicyBlobBuilder::random(1, TASK, OBS_DIM, &[64, 64], ACT_DIM, 1)
        .build()
        .unwrap();
    let large = PolicyBlobBuilder::random(2, TASK, OBS_DIM, &[256, 256], ACT_DIM, 2)
        .build()
        .unwrap();
    let mut bad = PolicyBlobBuilder::random(3, TASK, OBS_DIM, &[64], ACT_DIM, 3)
        .build()
        .unwrap();
    bad.weights[7] = f32::NAN;
    bad.seal();
    let mut running = loader.prepare(&small).unwrap();
    let mut spare = MlpPolicy::with_capacity();
    let mut obs = [0.0f32; OBS_DIM];
    black_box(running.act(&obs));

    let _serial = crate::serial();
    // The counter works (allocation and free), so the zero below means something.
    alloc_count::count_this_thread(true);
    let before = alloc_count::counted();
    drop(black_box(vec![1u8; 64]));
    let after = alloc_count::counted();
    alloc_count::count_this_thread(false);
    assert!(after >= before + 2);

    alloc_count::count_this_thread(true);
    let start = alloc_count::counted();
    let mut checksum = 0.0f32;
    let mut swaps = 0u32;
    for i in 0..100_000u32 {
        obs[(i as usize) % OBS_DIM] = (i % 97) as f32 * 0.01 - 0.5;
        let a = running.act(black_box(&obs));
        checksum += a[0] + a[1] + a[2];
        if (i + 1).is_multiple_of(1_000) {
            let next = if swaps.is_multiple_of(2) {
                &large
            } else {
                &small
            };
            loader.prepare_into(next, &mut spare).unwrap();
            std::mem::swap(&mut running, &mut spare);
            swaps += 1;
            if swaps.is_multiple_of(10) {
                assert_eq!(
                    loader.prepare_into(&bad, &mut spare),
                    Err(PolicyRejectReason::NonFinite)
                );
            }
        }
    }
    let end = alloc_count::counted();
    alloc_count::count_this_thread(false);

    assert!(checksum.is_finite());
    assert_eq!(swaps, 100);
    assert_eq!(loader.counters().count(PolicyRejectReason::NonFinite), 10);
    assert_eq!(
        end - start,
        0,
        "allocations or frees during act/prepare_into"
    );
    println!("100 000 act() calls, {swaps} swaps, 10 rejections: 0 allocations");
}
