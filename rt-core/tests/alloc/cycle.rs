//! The zero-allocation test: a counting global allocator watches the cycle thread over
//! 100 000 cycles, including hundreds of policy hot-swaps (each a lookahead, a Ruckig
//! plan and a hand-over that joins the running plan), stale-input stops and resumptions, and
//! asserts that `Cycle::process` allocated (or freed) nothing.

use crate::common::{Rig, TARGET_A, TARGET_B};
use rt_core::rt::alloc_count;
use rt_core::rt::clock::Clock;

#[test]
fn the_cycle_allocates_nothing_over_100k_cycles_with_policy_swaps() {
    let _serial = crate::serial();
    // The counter works (so a zero below is meaningful).
    alloc_count::count_this_thread(true);
    let before = alloc_count::counted();
    let v: Vec<u64> = std::hint::black_box(Vec::with_capacity(16));
    drop(v);
    assert!(alloc_count::counted() >= before + 2);
    alloc_count::count_this_thread(false);

    // What the official ruckig wrapper does per online update (reported, not asserted:
    // it is the reason plans are smoothed off the cycle).
    {
        use ruckig::{InputParameter, OutputParameter, Ruckig};
        let mut r = Ruckig::new_direct(5, 0.004);
        let mut i = InputParameter::new(5);
        let mut o = OutputParameter::new_direct(5);
        i.max_velocity = vec![1.0; 5];
        i.max_acceleration = vec![4.0; 5];
        i.max_jerk = vec![40.0; 5];
        i.target_position = vec![0.5; 5];
        r.update(&mut i, &mut o);
        alloc_count::count_this_thread(true);
        let b = alloc_count::counted();
        r.update(&mut i, &mut o);
        let per_update = alloc_count::counted() - b;
        alloc_count::count_this_thread(false);
        println!("ruckig 0.19.4 Ruckig::update allocations per call: {per_update}");
    }

    let mut rig = Rig::new();
    rig.policy(1, TARGET_A);
    rig.run(2_000); // warm-up: first plan adopted and finished
    let period = rig.cfg.period_ns();
    let mut counted_allocs = 0;
    let mut swaps = 0u64;
    let mut cycles = 0u64;
    let mut next_policy = 2;
    while cycles < 100_000 {
        // A new policy every 240 cycles (~1 s), alternating targets: each joins the
        // running plan or starts from rest.
        if cycles.is_multiple_of(240) {
            let target = if next_policy % 2 == 0 {
                TARGET_B
            } else {
                TARGET_A
            };
            rig.policy(next_policy, target);
            next_policy += 1;
        }
        // Detections pause now and then: stale stops and fresh plans afterwards.
        rig.detections_on = cycles % 20_000 <= 19_800;
        let now = rig.clock.now_ns();
        if rig.detections_on && cycles.is_multiple_of(8) {
            rig.detect(rig.scene, now, true, true);
        }
        rig.twin.step(&mut rig.events);
        let taken_before = rig.cycle.report().plans_taken;
        alloc_count::count_this_thread(true);
        let b = alloc_count::counted();
        rig.cycle.process(now);
        counted_allocs += alloc_count::counted() - b;
        alloc_count::count_this_thread(false);
        swaps += rig.cycle.report().plans_taken - taken_before;
        rig.clock.advance_ns(period);
        cycles += 1;
        if rig.events.len() > 10_000 {
            rig.events.clear();
        }
        rig.log.drain(|_| {});
    }
    println!(
        "cycles {cycles}, policy swaps reaching the arm {swaps}, stops {}, allocations in the cycle {counted_allocs}",
        rig.cycle.report().stops
    );
    assert!(swaps >= 100, "only {swaps} swaps reached the cycle");
    assert!(
        rig.cycle.report().stops >= 4,
        "the stale pauses should have stopped the arm"
    );
    assert_eq!(counted_allocs, 0, "the cycle allocated");
}

/// Speed and separation monitoring on the cycle allocates nothing either: a box above the
/// arm, inside the protective separation distance, scales the playback (the scale moves
/// between 0 and 1 as the arm's shape changes) over 20 000 cycles with policy swaps.
#[test]
fn the_speed_scaled_cycle_allocates_nothing() {
    let _serial = crate::serial();
    let mut cfg = rt_core::config::RuntimeConfig::xarm5_default();
    cfg.return_home = false;
    cfg.separation.enabled = true;
    let mut rig = Rig::with_config(cfg);
    rig.scene
        .push_obstacle([0.0, 0.0, 1.45], [0.02, 0.02, 0.02]);
    rig.policy(1, TARGET_A);
    rig.run(500);
    let period = rig.cfg.period_ns();
    let mut counted_allocs = 0;
    let (mut lowest, mut highest) = (1.0f64, 0.0f64);
    let mut next_policy = 2;
    for cycles in 0..20_000u64 {
        if cycles.is_multiple_of(1_000) {
            let target = if next_policy % 2 == 0 {
                TARGET_B
            } else {
                TARGET_A
            };
            rig.policy(next_policy, target);
            next_policy += 1;
        }
        let now = rig.clock.now_ns();
        if cycles.is_multiple_of(8) {
            // The box counts as moving: it is what the monitor watches.
            rig.detect_moving(rig.scene, now, true, rt_core::cycle::Intruders::ALL_UNKNOWN);
        }
        rig.twin.step(&mut rig.events);
        alloc_count::count_this_thread(true);
        let b = alloc_count::counted();
        rig.cycle.process(now);
        counted_allocs += alloc_count::counted() - b;
        alloc_count::count_this_thread(false);
        let r = rig.cycle.report();
        if r.mode == rt_core::cycle::Mode::Following {
            lowest = lowest.min(r.speed_scale);
            highest = highest.max(r.speed_scale);
        }
        rig.clock.advance_ns(period);
        if rig.events.len() > 10_000 {
            rig.events.clear();
        }
        rig.log.drain(|_| {});
    }
    println!(
        "speed scale while following {lowest:.3}..{highest:.3}, plans taken {}, allocations in the cycle {counted_allocs}",
        rig.cycle.report().plans_taken
    );
    assert!(lowest < highest && highest > 0.0, "{lowest}..{highest}");
    assert!(lowest < 1.0, "the playback was never scaled");
    assert_eq!(counted_allocs, 0, "the cycle allocated");
}
