//! The simulated controller fed arbitrary frames: answers or typed errors, never a panic,
//! never a motion outside the joint limits.
#![no_main]
use libfuzzer_sys::fuzz_target;
use xarm::codec::{MAX_FRAME_LEN, frame_len};
use xarm::limits::{LIMIT_SLACK_RAD, XARM5_JOINT_LIMITS_RAD};
use xarm_sim::Controller;

fuzz_target!(|data: &[u8]| {
    let mut c = Controller::default();
    let mut out = [0u8; MAX_FRAME_LEN];
    let mut rest = data;
    let mut t = 0.0;
    while let Ok(Some(n)) = frame_len(rest, 1) {
        let _ = c.handle(&rest[..n], &mut out);
        t += 0.004;
        c.step(t);
        rest = &rest[n..];
    }
    let _ = c.handle(rest, &mut out);
    c.step(t + 1.0);
    for (q, [lo, hi]) in c.q_rad().iter().zip(XARM5_JOINT_LIMITS_RAD) {
        assert!(
            q.is_finite() && *q >= lo - LIMIT_SLACK_RAD - 1e-6 && *q <= hi + LIMIT_SLACK_RAD + 1e-6
        );
    }
});
