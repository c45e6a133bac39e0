//! No allocation in any per-step query: FK, IK, distance, contact, step, rollout.

use nalgebra::Vector3;
use twin::{IkConfig, IkSolver, Joints, MAX_EPISODE_STEPS, RobotGeometry, rollout};

use crate::count_allocations;
use crate::twin_fixtures::{env, model, scene};

#[test]
fn per_step_work_does_not_allocate() {
    let m = model();
    let g = RobotGeometry::new(&m);
    let ik = IkSolver::new(&m, IkConfig::default());
    let small = scene("small_box.toml");
    let tall = scene("tall_box.toml");
    let mut e = env();
    let mut waypoints: heapless::Vec<Joints, MAX_EPISODE_STEPS> = heapless::Vec::new();
    let policy = e.straight_line_policy();
    // Warm up (lazy statics, thread locals).
    e.reset(&small);
    e.step(&[0.1, 0.2, 0.3]);
    let (checksum, allocations) = count_allocations(|| {
        let mut acc = 0.0;
        for i in 0..1000 {
            let q = [0.001 * f64::from(i), 0.2, -0.6, 0.5, 0.0];
            let p = m.fk(&q);
            acc += p.tcp_m().x;
            let r = ik.solve(&m, &Vector3::new(0.3, 0.1, 0.2 + 1e-5 * f64::from(i)), &q);
            acc += r.error_m;
            acc += g.distance(&p, &small).distance_m;
            acc += f64::from(u8::from(g.in_contact(&p, &tall, 0.02)));
        }
        for (k, s) in [&small, &tall].into_iter().cycle().take(20).enumerate() {
            e.reset(s);
            for j in 0..30 {
                let a = [((k + j) % 3) as f32 - 1.0, 0.5, -0.5];
                let out = e.step(&a);
                acc += f64::from(out.reward);
                if out.terminated {
                    break;
                }
            }
            let sum = rollout(&mut e, s, |o| policy.act(o), Some(&mut waypoints));
            acc += sum.return_ + waypoints.len() as f64;
        }
        acc
    });
    assert!(checksum.is_finite());
    assert_eq!(
        allocations, 0,
        "per-step twin work allocated {allocations} times"
    );
}

#[test]
fn the_counter_does_count() {
    // Guard against a counter that cannot fail.
    let (v, n) = count_allocations(|| vec![1u8; 64]);
    assert_eq!(v.len(), 64);
    assert!(n >= 1);
}
