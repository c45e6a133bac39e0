//! The xArm driver on the cycle path allocates nothing: `read_state` + `send_servo` while
//! streaming to `xarm-sim`, and `read_state` while a reconnect hangs off the cycle.

#[path = "../../xarm/tests/driver/support.rs"]
mod support;

use std::net::TcpListener;
use std::time::{Duration, Instant};

use support::{Clock, cfg, driver, sim, sleep_until, urdf, wait_for_state};
use xarm::driver::{XArmDriver, XArmError};
use xarm_sim::{SimOptions, SimServer};

#[test]
fn the_cycle_path_does_not_allocate() {
    let s = sim(Vec::new());
    let clock = Clock(Instant::now());
    let mut d = XArmDriver::connect(cfg(&s)).expect("connect");
    let q0 = d.start_servo_mode().expect("servo mode");
    let mut next = Instant::now();
    let mut k = 0_u32;
    let mut run = |d: &mut XArmDriver, cycles: u32| {
        for _ in 0..cycles {
            next += Duration::from_millis(4);
            sleep_until(next);
            k += 1;
            let mut q = q0;
            q[0] += 0.001 * f64::from(k);
            let _ = d.read_state(clock.ns());
            // A loaded machine may leave the pipeline full for a cycle (the sim answers
            // late): that is the driver refusing to queue more, not a failure here.
            match d.send_servo(clock.ns(), &q) {
                Ok(()) | Err(XArmError::Backlog) => {}
                Err(e) => panic!("send: {e:?}"),
            }
        }
    };
    run(&mut d, 50);
    let ((), allocations) = crate::count_allocations(|| run(&mut d, 250));
    assert_eq!(allocations, 0, "read_state + send_servo allocated");
    s.shutdown();
}

/// A controller that accepts the connection and never answers holds a reconnect attempt for
/// the whole reply timeout. Off the cycle, `read_state` keeps answering `Disconnected` at once
/// meanwhile, without allocating; once a real controller is back, the link resumes.
#[test]
fn a_hanging_reconnect_never_blocks_read_state() {
    let a = sim(Vec::new());
    let ports = a.ports();
    let clock = Clock(Instant::now());
    let mut c = cfg(&a);
    c.reply_timeout = Duration::from_secs(3);
    // A simulated controller: the helper re-enters servo mode after the reconnect (a real
    // arm would wait for the operator's acknowledgement).
    c.resume_after_reconnect = true;
    let mut d = driver(c);
    let q0 = d.start_servo_mode().expect("servo mode");
    d.send_servo(clock.ns(), &q0).expect("send");
    d.flush().expect("flush");
    a.shutdown();
    // Silent listeners on the controller's ports: the kernel completes the TCP handshake,
    // nobody ever replies.
    let silent = [ports.command, ports.report_real]
        .map(|p| TcpListener::bind(("127.0.0.1", p)).expect("bind the silent controller"));
    let deadline = Instant::now() + Duration::from_secs(5);
    while !d.reconnect_progress().is_some_and(|(busy, _)| busy) {
        let _ = d.read_state(clock.ns());
        assert!(
            Instant::now() < deadline,
            "the helper never started an attempt: {:?}",
            d.reconnect_progress()
        );
        std::thread::sleep(Duration::from_millis(2));
    }
    let mut answers = Vec::with_capacity(100);
    let ((), allocations) = crate::count_allocations(|| {
        for _ in 0..100 {
            answers.push(d.read_state(clock.ns()).err());
            std::thread::sleep(Duration::from_millis(1));
        }
    });
    let (busy_after, _) = d.reconnect_progress().expect("helper");
    assert!(
        busy_after,
        "the attempt (3 s reply timeout) must still be running after 100 calls of ~1 ms"
    );
    assert!(
        answers.iter().all(|a| *a == Some(XArmError::Disconnected)),
        "{answers:?}"
    );
    assert_eq!(
        allocations, 0,
        "read_state allocated while the link was down"
    );
    drop(silent);
    let b = SimServer::start(SimOptions {
        ports,
        urdf: urdf(),
        q0_rad: q0,
        ..SimOptions::default()
    })
    .expect("restart on the same ports");
    let st = wait_for_state(&mut d, &clock);
    assert_eq!(st.reconnects, 1);
    d.send_servo(clock.ns(), &q0)
        .expect("resume from the actual joints");
    d.flush().expect("flush");
    assert_eq!(b.shutdown().counters.servo_accepted, 1);
}
