//! Simulation rights by identity, not address (issue 30 item 1), at the driver: with
//! `XArmConfig::sim_secret` set, a controller is driven only once it has proven it is
//! `xarm-sim` holding that secret. Anything else on 127.0.0.1 — `xarm-sim` without the
//! secret or with another, a controller that ignores the challenge, answers it with an error
//! or hangs up — is refused with `XArmError::NotSimulator` after `GET_VERSION` and the
//! challenge, and nothing else reaches it; the same holds at every reconnect.

use std::io::{Read, Write};
use std::net::TcpListener;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use xarm::codec::{self, STATUS_INVALID};
use xarm::driver::{XArmConfig, XArmDriver, XArmError};
use xarm::sim_identity::{self, SimIdentityError, SimSecret};
use xarm_sim::{SimOptions, SimServer};

use crate::support::{Clock, cfg, home, sim, urdf};

fn sim_with(secret: Option<SimSecret>, ports: xarm_sim::SimPorts) -> SimServer {
    SimServer::start(SimOptions {
        ports,
        urdf: urdf(),
        q0_rad: home(),
        sim_secret: secret,
        ..SimOptions::default()
    })
    .expect("sim starts")
}

fn secret() -> SimSecret {
    SimSecret::generate().expect("OS random source")
}

#[test]
fn xarm_sim_holding_the_secret_proves_it_at_connect_and_is_driven() {
    let s = secret();
    let a = sim_with(Some(s.clone()), xarm_sim::SimPorts::ephemeral());
    let mut c = cfg(&a);
    c.sim_secret = Some(s.clone());
    assert_eq!(sim_identity::ask(&c, &s), Ok(()), "the launcher's question");
    let mut d = XArmDriver::connect(c).expect("a proven xarm-sim connects");
    let q0 = d.start_servo_mode().expect("servo mode");
    let clock = Clock(Instant::now());
    d.send_servo(clock.ns(), &q0).expect("servo_j");
    d.flush().expect("flush");
    let summary = a.shutdown();
    assert_eq!(summary.counters.identity_challenges, 2);
    assert_eq!(summary.counters.identity_proofs, 2);
    assert_eq!(summary.counters.servo_accepted, 1);
}

#[test]
fn xarm_sim_without_the_secret_or_with_another_is_a_real_arm() {
    for (held, want) in [(None, "unsupported"), (Some(secret()), "wrong proof")] {
        let a = sim_with(held, xarm_sim::SimPorts::ephemeral());
        let mut c = cfg(&a);
        let s = secret();
        c.sim_secret = Some(s.clone());
        let asked = sim_identity::ask(&c, &s);
        let e = XArmDriver::connect(c).expect_err("refused");
        let reason = match e {
            XArmError::NotSimulator(r) => r,
            other => panic!("{want}: {other:?}"),
        };
        assert_eq!(asked, Err(reason), "{want}: the launcher hears the same");
        match want {
            "unsupported" => {
                assert!(
                    matches!(reason, SimIdentityError::Unsupported { status } if status & STATUS_INVALID != 0),
                    "{reason:?}"
                );
                assert!(e.to_string().contains("as a real xArm"), "{e}");
            }
            _ => assert_eq!(reason, SimIdentityError::WrongProof),
        }
        let summary = a.shutdown();
        // GET_VERSION and the challenge, twice (the launcher's question, rt-core's connect):
        // no GET_ERROR, no MOTION_EN, no servo_j.
        assert_eq!(summary.counters.frames, 4, "{want}: {summary:?}");
        assert_eq!(summary.counters.identity_challenges, 2, "{want}");
        assert_eq!(
            summary.counters.servo_accepted + summary.counters.servo_rejected,
            0
        );
    }
}

#[test]
fn without_a_secret_nothing_is_asked_and_the_arm_is_driven_as_a_real_arm() {
    let a = sim(Vec::new());
    let mut d = XArmDriver::connect(cfg(&a)).expect("connect");
    d.start_servo_mode().expect("servo mode");
    let summary = a.shutdown();
    assert_eq!(summary.counters.identity_challenges, 0);
}

/// How a stand-in for a real controller treats the unknown register 0xF0.
#[derive(Debug, Clone, Copy, PartialEq)]
enum OnChallenge {
    /// Answers nothing.
    Silent,
    /// Closes the connection.
    HangUp,
    /// Answers with the error and not-ready bits and no data.
    ErrorStatus,
}

/// A minimal controller on loopback speaking the real protocol: answers `GET_VERSION` as an
/// xArm5, every other register it knows with an empty OK, 0xF0 as `on`; records each
/// register it receives.
fn real_arm_stand_in(on: OnChallenge) -> (XArmConfig, Arc<Mutex<Vec<u8>>>) {
    let cmd = TcpListener::bind("127.0.0.1:0").expect("bind");
    let rep = TcpListener::bind("127.0.0.1:0").expect("bind");
    let mut c = XArmConfig::new("127.0.0.1");
    c.command_port = cmd.local_addr().expect("addr").port();
    c.report_port = rep.local_addr().expect("addr").port();
    c.reply_timeout = Duration::from_millis(300);
    let seen = Arc::new(Mutex::new(Vec::new()));
    let log = seen.clone();
    std::thread::spawn(move || {
        let _rep = rep; // accepts the report connection (backlog) and sends nothing
        while let Ok((s, _)) = cmd.accept() {
            let log = log.clone();
            std::thread::spawn(move || serve_stand_in(s, on, &log));
        }
    });
    (c, seen)
}

fn serve_stand_in(mut s: std::net::TcpStream, on: OnChallenge, log: &Mutex<Vec<u8>>) {
    let _ = s.set_read_timeout(Some(Duration::from_millis(1500)));
    let mut buf = [0u8; 256];
    let mut len = 0;
    while let Ok(n) = s.read(&mut buf[len..]) {
        if n == 0 {
            return;
        }
        len += n;
        while let Ok(Some(flen)) = codec::frame_len(&buf[..len], 1) {
            let (tid, proto, reg) = (
                u16::from_be_bytes([buf[0], buf[1]]),
                u16::from_be_bytes([buf[2], buf[3]]),
                buf[6],
            );
            log.lock().unwrap().push(reg);
            buf.copy_within(flen..len, 0);
            len -= flen;
            let mut out = [0u8; 64];
            let n = match (reg, on) {
                (0x01, _) => {
                    let mut v = [0u8; 40];
                    v[..24].copy_from_slice(b"5,5,XF1302,AC1302,v2.6.0");
                    codec::encode_response(tid, proto, reg, 0x10, &v, &mut out)
                }
                (0xF0, OnChallenge::Silent) => continue,
                (0xF0, OnChallenge::HangUp) => return,
                (0xF0, OnChallenge::ErrorStatus) => {
                    codec::encode_response(tid, proto, reg, 0x50, &[], &mut out)
                }
                _ => codec::encode_response(tid, proto, reg, 0, &[0, 0], &mut out),
            }
            .expect("encode");
            let _ = s.write_all(&out[..n]);
        }
    }
}

#[test]
fn a_controller_that_ignores_refuses_or_hangs_up_on_the_challenge_gets_nothing_more() {
    for (on, want) in [
        (OnChallenge::Silent, SimIdentityError::NoAnswer),
        (OnChallenge::HangUp, SimIdentityError::Closed),
        (
            OnChallenge::ErrorStatus,
            SimIdentityError::NoProof { len: 0 },
        ),
    ] {
        let (mut c, seen) = real_arm_stand_in(on);
        let s = secret();
        assert_eq!(sim_identity::ask(&c, &s), Err(want), "{on:?}: ask");
        c.sim_secret = Some(s);
        assert_eq!(
            XArmDriver::connect(c).expect_err("refused"),
            XArmError::NotSimulator(want),
            "{on:?}: connect"
        );
        std::thread::sleep(Duration::from_millis(50));
        assert_eq!(
            *seen.lock().unwrap(),
            [0x01, 0xF0, 0x01, 0xF0],
            "{on:?}: only GET_VERSION and the challenge reach it"
        );
    }
}

#[test]
fn a_closed_port_is_unreachable_to_ask() {
    let port = TcpListener::bind("127.0.0.1:0")
        .expect("bind")
        .local_addr()
        .expect("addr")
        .port();
    let mut c = XArmConfig::new("127.0.0.1");
    c.command_port = port;
    assert!(
        matches!(
            sim_identity::ask(&c, &secret()),
            Err(SimIdentityError::Unreachable(_))
        ),
        "nothing listens on {port}"
    );
}

/// With `--auto-resume` a lost link is re-opened without the operator: the controller
/// behind the address after a restart must prove it again, or the driver does not
/// reconnect to it (and sends it nothing but the handshake and the challenge).
#[test]
fn a_controller_behind_the_address_after_a_restart_must_prove_it_again() {
    let s = secret();
    let a = sim_with(Some(s.clone()), xarm_sim::SimPorts::ephemeral());
    let ports = a.ports();
    let mut c = cfg(&a);
    c.sim_secret = Some(s.clone());
    c.resume_after_reconnect = true;
    let clock = Clock(Instant::now());
    let mut d = XArmDriver::connect(c).expect("connect");
    d.start_servo_mode().expect("servo mode");
    a.shutdown();
    std::thread::sleep(Duration::from_millis(100));
    // A controller without the secret takes the ports: never reconnected to.
    let b = sim_with(None, ports);
    let deadline = Instant::now() + Duration::from_millis(800);
    while Instant::now() < deadline {
        assert!(
            d.read_state(clock.ns()).is_err(),
            "the driver reconnected to a controller that is not xarm-sim"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    let summary = b.shutdown();
    assert!(summary.counters.identity_challenges >= 1, "{summary:?}");
    assert_eq!(summary.counters.identity_proofs, 0);
    assert_eq!(
        summary.counters.frames,
        2 * summary.counters.identity_challenges,
        "only GET_VERSION and the challenge: {summary:?}"
    );
    // The run's xarm-sim again: reconnected.
    std::thread::sleep(Duration::from_millis(50));
    let a2 = sim_with(Some(s), ports);
    let st = crate::support::wait_for_state(&mut d, &clock);
    assert_eq!(st.reconnects, 1);
    a2.shutdown();
}
