//! Property tests of the xArm codec: every decoder of controller (or client) bytes returns
//! a value or a typed error on any input, never panics; encode → decode round-trips.

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use proptest::prelude::*;
use xarm::codec::{
    self, JointTarget, MAX_FRAME_LEN, Request, Response, SERVOJ_FRAME_LEN, VersionInfo,
    encode_servo_j,
};
use xarm::report::{self, ArmReport, ReportFramer, ReportKind};
use xarm_sim::Controller;

fn kinds() -> impl Strategy<Value = ReportKind> {
    prop_oneof![
        Just(ReportKind::RealTime),
        Just(ReportKind::Normal),
        Just(ReportKind::Rich),
        Just(ReportKind::Real),
    ]
}

fn finite() -> impl Strategy<Value = f32> {
    -1.0e4f32..1.0e4f32
}

fn joint_target() -> impl Strategy<Value = JointTarget> {
    (
        proptest::array::uniform7(finite()),
        finite(),
        finite(),
        finite(),
    )
        .prop_map(
            |(joints_rad, speed_rad_s, acc_rad_s2, mvtime_s)| JointTarget {
                joints_rad,
                speed_rad_s,
                acc_rad_s2,
                mvtime_s,
            },
        )
}

fn request() -> impl Strategy<Value = Request> {
    prop_oneof![
        Just(Request::GetVersion),
        Just(Request::GetRobotSn),
        (any::<u8>(), any::<bool>())
            .prop_map(|(servo_id, enable)| Request::MotionEnable { servo_id, enable }),
        any::<u8>().prop_map(Request::SetState),
        Just(Request::GetState),
        Just(Request::GetCmdNum),
        Just(Request::GetError),
        Just(Request::CleanError),
        Just(Request::CleanWarn),
        (any::<u8>(), proptest::option::of(any::<u8>()))
            .prop_map(|(mode, detection)| Request::SetMode { mode, detection }),
        joint_target().prop_map(Request::MoveJoint),
        joint_target().prop_map(Request::ServoJ),
        (
            proptest::array::uniform6(finite()),
            finite(),
            finite(),
            any::<bool>()
        )
            .prop_map(
                |(pose, speed_mm_s, acc_mm_s2, tool_frame)| Request::ServoCart {
                    pose,
                    speed_mm_s,
                    acc_mm_s2,
                    tool_frame
                }
            ),
        finite().prop_map(Request::SetTcpJerk),
        finite().prop_map(Request::SetTcpMaxAcc),
        finite().prop_map(Request::SetJointJerk),
        finite().prop_map(Request::SetJointMaxAcc),
        Just(Request::GetTcpPose),
        proptest::option::of(any::<u8>()).prop_map(Request::GetJointPos),
        Just(Request::GetTcpPoseAa),
        any::<u8>().prop_map(Request::SetFeedbackType),
        Just(Request::FeedbackCheck),
        any::<[u8; 16]>().prop_map(Request::SimIdentity),
    ]
}

fn arm_report(kind: ReportKind) -> impl Strategy<Value = ArmReport> {
    (
        0u8..=9,
        0u8..=11,
        any::<u16>(),
        proptest::array::uniform7(finite()),
        proptest::array::uniform6(finite()),
        proptest::array::uniform7(finite()),
        any::<u64>(),
    )
        .prop_map(move |(state, mode, cmdnum, joints, pose, other, ts)| {
            let mut r = ArmReport::empty(kind);
            r.state = state;
            r.mode = mode;
            r.cmdnum = cmdnum;
            r.joints_rad = joints;
            r.tcp_pose = pose;
            match kind {
                ReportKind::RealTime => {
                    r.target_joints_rad = other;
                    r.timestamp_us = ts;
                }
                _ => r.torques = other,
            }
            if matches!(kind, ReportKind::Normal | ReportKind::Rich) {
                r.error_code = Some((ts & 0xff) as u8);
                r.warn_code = Some((ts >> 8 & 0xff) as u8);
                r.enable_bits = Some(0x1f);
                r.brake_bits = Some(0x1f);
            }
            r
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn response_decoding_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
        let _ = codec::frame_len(&bytes, 2);
        if let Ok(r) = Response::parse(&bytes) {
            let _ = r.check(1, 3, 0x1d);
            let _ = r.state();
            let _ = r.err_warn();
            let _ = r.cmdnum();
            let _ = r.joints();
            let _ = r.tcp_pose();
            let _ = r.version();
            prop_assert!(r.data.len() + 8 <= bytes.len());
        }
        let _ = VersionInfo::parse(&bytes);
    }

    #[test]
    fn request_decoding_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
        let _ = codec::frame_len(&bytes, 1);
        let _ = Request::decode(&bytes);
    }

    #[test]
    fn the_simulator_answers_any_bytes_without_panicking(
        bytes in proptest::collection::vec(any::<u8>(), 0..200)
    ) {
        let mut c = Controller::default();
        let mut out = [0u8; MAX_FRAME_LEN];
        if let Ok(Some(n)) = codec::frame_len(&bytes, 1) {
            let _ = c.handle(&bytes[..n], &mut out);
        }
        let _ = c.handle(&bytes, &mut out);
        c.step(0.01);
    }

    #[test]
    fn requests_round_trip(req in request(), tid in any::<u16>(), protocol in 0u16..4) {
        let mut buf = [0u8; 128];
        let n = req.encode(tid, protocol, &mut buf).unwrap();
        prop_assert_eq!(codec::frame_len(&buf[..n], 1).unwrap(), Some(n));
        let (h, back) = Request::decode(&buf[..n]).unwrap();
        prop_assert_eq!((h.tid, h.protocol), (tid, protocol));
        prop_assert_eq!(back, req);
    }

    #[test]
    fn servo_j_fast_path_equals_the_generic_encoder(t in joint_target(), tid in any::<u16>()) {
        let mut fast = [0u8; SERVOJ_FRAME_LEN];
        encode_servo_j(tid, &t, &mut fast);
        let mut generic = [0u8; 64];
        let n = Request::ServoJ(t).encode(tid, codec::PROTOCOL_PRIVATE, &mut generic).unwrap();
        prop_assert_eq!(&generic[..n], &fast[..]);
    }

    #[test]
    fn responses_round_trip(
        tid in any::<u16>(),
        register in any::<u8>(),
        status in any::<u8>(),
        data in proptest::collection::vec(any::<u8>(), 0..100),
    ) {
        let mut buf = [0u8; MAX_FRAME_LEN];
        let n = codec::encode_response(tid, 3, register, status, &data, &mut buf).unwrap();
        let r = Response::parse(&buf[..n]).unwrap();
        prop_assert_eq!((r.header.tid, r.register, r.status, r.data), (tid, register, status, &data[..]));
    }

    #[test]
    fn report_decoding_never_panics(
        kind in kinds(),
        bytes in proptest::collection::vec(any::<u8>(), 0..900),
        size_hint in prop_oneof![Just(87u32), Just(135), Just(145), Just(245), Just(587), Just(804), any::<u32>()],
    ) {
        let _ = report::decode(kind, &bytes);
        // Also with a plausible size field, so decoding reaches the body checks.
        let mut b = bytes.clone();
        if b.len() >= 4 {
            b[..4].copy_from_slice(&size_hint.to_be_bytes());
        }
        let _ = report::decode(kind, &b);
    }

    #[test]
    fn real_and_rt_reports_round_trip(r in arm_report(ReportKind::Real), rt in arm_report(ReportKind::RealTime)) {
        let mut buf = [0u8; report::REAL_LEN];
        report::encode_real(&r, &mut buf);
        prop_assert_eq!(report::decode(ReportKind::Real, &buf).unwrap(), r);
        let mut buf = [0u8; report::RT_LEN];
        report::encode_rt(&rt, &mut buf);
        prop_assert_eq!(report::decode(ReportKind::RealTime, &buf).unwrap(), rt);
    }

    #[test]
    fn rich_and_normal_reports_round_trip(r in arm_report(ReportKind::Rich), n in arm_report(ReportKind::Normal)) {
        let x = report::RichExtras::default();
        let mut buf = [0u8; report::RICH_LEN];
        report::encode_rich(&r, &x, &mut buf);
        prop_assert_eq!(report::decode(ReportKind::Rich, &buf).unwrap(), r);
        let mut buf = [0u8; report::NORMAL_LEN];
        report::encode_normal(&n, &x, &mut buf);
        prop_assert_eq!(report::decode(ReportKind::Normal, &buf).unwrap(), n);
    }

    #[test]
    fn the_framer_never_panics_and_keeps_valid_streams_whole(
        junk in proptest::collection::vec(any::<u8>(), 0..3000),
        chunks in proptest::collection::vec(1usize..400, 1..20),
        r in arm_report(ReportKind::Real),
    ) {
        let mut f = ReportFramer::new();
        let mut at = 0;
        for c in chunks.iter().cycle().take(40) {
            let end = (at + c).min(junk.len());
            let spare = f.spare();
            let n = (end - at).min(spare.len());
            spare[..n].copy_from_slice(&junk[at..at + n]);
            f.commit(n);
            at += n;
            while let Ok(Some(_)) = f.next_packet() {}
            if at >= junk.len() {
                break;
            }
        }
        // A valid stream, cut at arbitrary points, yields exactly its packets.
        let mut pkt = [0u8; report::REAL_LEN];
        report::encode_real(&r, &mut pkt);
        let stream: Vec<u8> = pkt.iter().copied().cycle().take(5 * report::REAL_LEN).collect();
        let mut f = ReportFramer::new();
        let mut got = 0;
        let mut at = 0;
        for c in chunks.iter().cycle() {
            if at >= stream.len() {
                break;
            }
            let end = (at + c).min(stream.len());
            f.spare()[..end - at].copy_from_slice(&stream[at..end]);
            f.commit(end - at);
            at = end;
            while let Some(p) = f.next_packet().unwrap() {
                prop_assert_eq!(p, &pkt[..]);
                got += 1;
            }
        }
        prop_assert_eq!(got, 5);
    }
}
