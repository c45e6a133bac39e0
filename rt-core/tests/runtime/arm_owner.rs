//! Who may drive the arm, and whether the twin is the arm it drives (issue 14), on the real
//! protocol against `xarm-sim` through the rig's rewriting proxies: one owner per
//! controller (a second `open_xarm` is refused with the holder named, and never connects),
//! only an xArm5 is driven (a controller that says 6 axes is refused), and the twin's TCP
//! must match the one the controller reports (a 10 mm offset is refused at start, and
//! while running stops the arm under control and latches until acknowledged).

use std::sync::atomic::Ordering;
use std::time::Duration;

use crate::xarm_rig::{MOVE, Rewrite, XRig, max_step_rad, sim_behind_proxies, urdf};
use rt_core::cycle::xarm_link::{XArmOpenError, XArmOpenOptions, open_xarm};
use rt_core::cycle::{Mode, StopReason};
use twin::RobotModel;
use xarm::driver::XArmError;
use xarm::owner::ArmLockError;

fn opts(report_port: u16, dry_run: bool) -> XArmOpenOptions {
    XArmOpenOptions {
        report_port: Some(report_port),
        dry_run,
        clear_errors: false,
        max_resume_step_rad: 0.05,
        resume_after_reconnect: false,
        max_tcp_gap_m: rt_core::cycle::xarm_link::MAX_TCP_GAP_M,
        sim_rights: None,
    }
}

fn model() -> RobotModel {
    RobotModel::load(&urdf()).expect("urdf")
}

#[test]
fn a_second_owner_of_one_controller_is_refused_with_the_holder_named() {
    let (sim, cmd, rep) = sim_behind_proxies(Rewrite::None, Rewrite::None);
    let addr = format!("127.0.0.1:{}", cmd.port);
    let model = model();
    let first = open_xarm(&addr, &opts(rep.port, false), &model).expect("the first owner");
    let lock = first.owner().expect("a live run holds the lock");
    assert_eq!(lock.holder().pid, std::process::id());
    let e = open_xarm(&addr, &opts(rep.port, false), &model).expect_err("a second owner");
    let XArmOpenError::Owned(ArmLockError::Held { holder, path, .. }) = &e else {
        panic!("not refused as owned: {e}");
    };
    assert_eq!(path, lock.path());
    assert_eq!(holder.as_ref().map(|h| h.pid), Some(std::process::id()));
    let msg = e.to_string();
    assert!(
        msg.contains(&format!("already commanded by pid {}", std::process::id())),
        "{msg}"
    );
    // Refused before connecting: the controller saw one client.
    assert_eq!(sim.summary().connections, 1, "{:?}", sim.summary());
    // A dry run sends nothing: it may watch the arm another process drives.
    let watcher = open_xarm(&addr, &opts(rep.port, true), &model).expect("a dry run");
    assert!(watcher.owner().is_none());
    drop(watcher);
    // The lock goes with its owner.
    drop(first);
    let next = open_xarm(&addr, &opts(rep.port, false), &model).expect("the next owner");
    assert!(next.owner().is_some());
}

#[test]
fn a_controller_that_reports_6_axes_is_refused_before_anything_moves() {
    let (sim, cmd, rep) = sim_behind_proxies(
        Rewrite::Version("6,6,XI1202,AC1302,v1.12.10".into()),
        Rewrite::None,
    );
    let addr = format!("127.0.0.1:{}", cmd.port);
    let e = open_xarm(&addr, &opts(rep.port, false), &model()).expect_err("an xArm6");
    assert!(
        matches!(
            e,
            XArmOpenError::Driver(XArmError::NotXArm5 {
                axis: 6,
                robot_type: 6
            })
        ),
        "{e}"
    );
    assert!(e.to_string().contains("robot type 6 with 6 axes"), "{e}");
    let s = sim.summary();
    assert_ne!(s.mode, 1, "servo mode was entered: {s:?}");
    assert_eq!(
        s.counters.servo_accepted + s.counters.servo_rejected,
        0,
        "{s:?}"
    );
}

#[test]
fn a_reported_tcp_10_mm_off_the_twin_is_refused_at_start_naming_both_poses() {
    let (offset, _) = Rewrite::tcp_offset(10.0);
    let (sim, cmd, rep) = sim_behind_proxies(Rewrite::None, offset);
    let addr = format!("127.0.0.1:{}", cmd.port);
    let e = open_xarm(&addr, &opts(rep.port, false), &model()).expect_err("a 10 mm mismatch");
    let XArmOpenError::TcpMismatch(m) = &e else {
        panic!("not refused for the TCP: {e}");
    };
    // The simulated controller's own kinematics may differ from the twin's by < 1 mm.
    assert!((m.gap_mm - 10.0).abs() < 1.5, "{m:?}");
    let msg = e.to_string();
    let twin_x = format!("({:.1},", m.twin_tcp_mm[0]);
    let reported_x = format!("({:.1},", m.reported_tcp_pose[0]);
    assert!(
        msg.contains(&twin_x) && msg.contains(&reported_x) && msg.contains("mm apart"),
        "{msg}"
    );
    let s = sim.summary();
    assert_ne!(s.mode, 1, "servo mode was entered: {s:?}");
    assert_eq!(s.counters.servo_accepted, 0, "{s:?}");
}

#[test]
fn a_reported_tcp_10_mm_off_while_moving_stops_the_arm_under_control_and_latches() {
    let (offset, mm) = Rewrite::tcp_offset(0.0);
    let mut rig = XRig::start_rewriting(false, offset);
    rig.run_for(Duration::from_millis(100));
    rig.send_plan(MOVE, 2.5);
    rig.run_for(Duration::from_millis(700));
    assert_eq!(rig.cycle.mode(), Mode::Following);
    let sent_before = rig.sim_summary().counters.servo_accepted;
    mm.store(10.0_f64.to_bits(), Ordering::Release);
    // Until the arm is at rest and the stop latched (bounded: a hang guard, not a timing).
    for _ in 0..1000 {
        rig.cycle_once();
        if rig.cycle.report().awaiting_ack {
            break;
        }
    }
    rig.run_for(Duration::from_millis(200));
    let r = *rig.cycle.report();
    let s = rig.sim_summary();
    assert_eq!(r.stop_reason, StopReason::ModelMismatch, "{r:?}");
    assert_eq!(r.mode, Mode::Stopped, "{r:?}");
    assert!(r.awaiting_ack, "a mismatch latches: {r:?}");
    assert_eq!(r.cmd.dq_rad_s, [0.0; 5], "at rest: {r:?}");
    // A controlled stop: the arm was commanded down to rest (not left at its last target),
    // within the step limit and with no protective fault on the controller.
    assert!(
        s.counters.servo_accepted > sent_before + 10,
        "no stop commanded after the mismatch: {sent_before} → {s:?}"
    );
    assert!(s.max_joint_step_rad <= max_step_rad(&rig.cfg), "{s:?}");
    assert_eq!(s.protective_faults, 0, "{s:?}");
    // Latched: nothing is sent, no plan taken.
    let latched_at = rig.sim_summary().counters.servo_accepted;
    rig.send_plan([0.1, 0.0, 0.0, 0.0, 0.0], 1.0);
    rig.run_for(Duration::from_millis(300));
    assert_eq!(rig.cycle.report().mode, Mode::Stopped);
    assert_eq!(rig.sim_summary().counters.servo_accepted, latched_at);
    // The operator fixes the model (here: the offset goes) and acknowledges.
    mm.store(0.0_f64.to_bits(), Ordering::Release);
    rig.run_for(Duration::from_millis(100));
    rig.cycle.control().acknowledge_latched();
    rig.run_for(Duration::from_millis(300));
    let r = *rig.cycle.report();
    assert!(!r.awaiting_ack, "{r:?}");
    assert_eq!(r.stop_reason, StopReason::ModelMismatch, "{r:?}");
}
