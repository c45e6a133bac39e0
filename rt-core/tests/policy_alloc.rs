//! Zero-allocation test of policy inference: a counting global allocator watches
//! `MlpPolicy::act` over 100 000 evaluations, with 100 hot swaps through
//! `PolicyLoader::prepare_into` (accepted and rejected blobs) in between, and asserts that
//! nothing was allocated or freed.

use std::alloc::{GlobalAlloc, Layout, System};
use std::hint::black_box;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use rt_core::policy::{MlpPolicy, PolicyExpectation, PolicyLoader, PolicyRejectReason};
use rt_core::twin::{ACT_DIM, OBS_DIM};
use shm_schemas::PolicyBlobBuilder;

struct Counting;

static ENABLED: AtomicBool = AtomicBool::new(false);
static ALLOCS: AtomicU64 = AtomicU64::new(0);
static FREES: AtomicU64 = AtomicU64::new(0);

// SAFETY: delegates every call to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if ENABLED.load(Ordering::Relaxed) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if ENABLED.load(Ordering::Relaxed) {
            FREES.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if ENABLED.load(Ordering::Relaxed) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn counted() -> (u64, u64) {
    (
        ALLOCS.load(Ordering::Relaxed),
        FREES.load(Ordering::Relaxed),
    )
}

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

    // The counter works, so the zero below means something.
    ENABLED.store(true, Ordering::SeqCst);
    let before = counted();
    drop(black_box(vec![1u8; 64]));
    let after = counted();
    ENABLED.store(false, Ordering::SeqCst);
    assert!(after.0 > before.0 && after.1 > before.1);

    ENABLED.store(true, Ordering::SeqCst);
    let start = counted();
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
    let end = counted();
    ENABLED.store(false, Ordering::SeqCst);

    assert!(checksum.is_finite());
    assert_eq!(swaps, 100);
    assert_eq!(loader.counters().count(PolicyRejectReason::NonFinite), 10);
    assert_eq!(end.0 - start.0, 0, "allocations during act/prepare_into");
    assert_eq!(end.1 - start.1, 0, "deallocations during act/prepare_into");
    println!("100 000 act() calls, {swaps} swaps, 10 rejections: 0 allocations");
}
