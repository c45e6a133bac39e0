//! perception's ROS 2 source: a ros2-client node publishes a synthetic camera's colour
//! (`bgra8`, as the ZED wrapper does), depth (`32FC1`) and camera info on the ZED wrapper's
//! default topic names; the real `perception run --source ros2` process turns them into
//! `DetectionFrame`s on iceoryx2 with the right objects.
//!
//! Stamps: the images carry the system clock at capture (as a ROS 2 driver stamps them);
//! the frames carry that time on CLOCK_MONOTONIC, and unstamped images are refused, counted
//! and logged naming `header.stamp`.
//!
//! A stalled depth topic (issue 25 item 3): colour images without a depth image of the same
//! stamp are refused and counted (`unpaired_depth`), and no settled frame ever shows a new
//! tall box as a flat one.
//!
//! A calibration belongs to one camera (issue 30 item 2): the calibrations name the test
//! camera's frame id (`[camera] frame_id`); images of another camera (another
//! `header.frame_id`) are refused, counted (`wrong_camera`) and logged naming both ids, and
//! never published.
//!
//! DDS stays on loopback: both sides restrict rustdds to 127.0.0.1 (`with_only_networks`,
//! perception's default) and use perception's own default domain (42, not ROS 2's 0), and the test runs inside a private network namespace
//! (`unshare -n`, `lo` up with MULTICAST on, which rustdds' discovery needs) made by
//! `run_in_private_netns`. Needs `cargo build --release -p perception` first.

// Integration tests: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use foresight_tests::{
    ChildGuard, NetnsOutcome, bin_path, run_in_private_netns, unique_prefix, wait_for,
};
use iceoryx2::prelude::*;
use perception::calibration::{Calibration, CalibrationFile};
use perception::camera_id::{CalibratedAt, CalibrationCamera};
use perception::ros2_source::{
    CameraInfo, Header, Image, Ros2Topics, Time, camera_info_publisher, context, image_publisher,
    node,
};
use perception::synthetic::SyntheticCamera;
use shm_schemas::clock::monotonic_now_ns;
use shm_schemas::scene_file::SceneFile;
use shm_schemas::{DetectionFrame, ObjectClass, services};

const SCENE: &str = "[goal]\ncenter_m = [0.45, 0.20, 0.025]\nsize_m = 0.05\n[[obstacle]]\ncenter_m = [0.30, -0.10, 0.075]\nsize_m = [0.08, 0.06, 0.15]\n";

/// The `header.frame_id` the test camera stamps its images with.
const ZED_FRAME_ID: &str = "zed_left_camera_optical_frame";

/// The test camera, as its calibrations name it.
fn zed_camera() -> CalibrationCamera {
    CalibrationCamera {
        frame_id: ZED_FRAME_ID.into(),
        serial: Some("12345678".into()),
        calibrated_at: CalibratedAt::now(),
    }
}

/// The synthetic camera at a quarter of its resolution, the test scene, and a calibration of
/// it (named for the ZED test camera) saved as `dir/calibration.toml`.
fn quarter_camera_calibrated(dir: &std::path::Path) -> (SyntheticCamera, SceneFile) {
    let mut cam =
        SyntheticCamera::load(&foresight_tests::asset("perception/synthetic_camera.toml"))
            .unwrap()
            .config;
    cam.intrinsics.fx_px /= 4.0;
    cam.intrinsics.fy_px /= 4.0;
    cam.intrinsics.cx_px /= 4.0;
    cam.intrinsics.cy_px /= 4.0;
    cam.intrinsics.width_px /= 4;
    cam.intrinsics.height_px /= 4;
    let cam = SyntheticCamera::new(cam).unwrap();
    let scene = SceneFile::from_toml_str(SCENE, std::path::Path::new("<test>")).unwrap();
    Calibration::new(CalibrationFile {
        camera: zed_camera(),
        intrinsics: cam.config.intrinsics,
        workspace: cam.workspace_for(&scene),
        corners_px: cam.workspace_corners_px(&scene).unwrap(),
        rectified_px_per_m: 1000.0,
    })
    .unwrap()
    .save(&dir.join("calibration.toml"))
    .unwrap();
    (cam, scene)
}

#[test]
fn ros2_camera_topics_become_detection_frames() {
    if run_in_private_netns("ros2_camera_topics_become_detection_frames")
        == NetnsOutcome::RanInChild
    {
        return;
    }
    let dir = std::env::temp_dir().join(format!("foresight-perc-ros2-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    // A 640x360 camera (keeps each image message under 1 MB).
    let mut cam =
        SyntheticCamera::load(&foresight_tests::asset("perception/synthetic_camera.toml"))
            .unwrap()
            .config;
    cam.intrinsics.fx_px /= 2.0;
    cam.intrinsics.fy_px /= 2.0;
    cam.intrinsics.cx_px /= 2.0;
    cam.intrinsics.cy_px /= 2.0;
    cam.intrinsics.width_px /= 2;
    cam.intrinsics.height_px /= 2;
    let cam = SyntheticCamera::new(cam).unwrap();
    let scene = SceneFile::from_toml_str(SCENE, std::path::Path::new("<test>")).unwrap();
    let r = cam.render(&scene);
    Calibration::new(CalibrationFile {
        camera: zed_camera(),
        intrinsics: cam.config.intrinsics,
        workspace: cam.workspace_for(&scene),
        corners_px: cam.workspace_corners_px(&scene).unwrap(),
        rectified_px_per_m: 1000.0,
    })
    .unwrap()
    .save(&dir.join("calibration.toml"))
    .unwrap();
    let topics = Ros2Topics {
        networks: vec!["127.0.0.1".parse().unwrap()],
        timeout_s: 5.0,
        ..Ros2Topics::default()
    };
    std::fs::write(dir.join("topics.toml"), toml_of(&topics)).unwrap();

    let prefix = unique_prefix("percros");
    let (ice, _) = services::create_node::<ipc::Service>("perception-ros2-test").unwrap();
    let sub = services::open_subscriber::<DetectionFrame, _>(&ice, &prefix).unwrap();
    let mut p = ChildGuard::spawn(
        "perception run --source ros2",
        Command::new(bin_path("perception"))
            .args([
                "run",
                "--source",
                "ros2",
                "--prefix",
                &prefix,
                "--rate",
                "10",
                "--frames",
                "40",
                "--persist-frames",
                "1",
            ])
            .arg("--ros2-topics")
            .arg(dir.join("topics.toml"))
            .arg("--calibration")
            .arg(dir.join("calibration.toml"))
            .stdout(Stdio::null()),
    );

    // The camera: publish at 10 Hz until told to stop.
    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let (w, h) = (r.width_px as u32, r.height_px as u32);
    let bgra: Vec<u8> = r
        .bgr
        .chunks_exact(3)
        .flat_map(|p| [p[0], p[1], p[2], 255])
        .collect();
    let depth: Vec<u8> = r.depth_m.iter().flat_map(|d| d.to_le_bytes()).collect();
    let k = cam.config.intrinsics;
    let camera = std::thread::spawn(move || {
        let ctx = context(topics.domain_id, &topics.networks).unwrap();
        let mut n = node(&ctx, "fake_zed").unwrap();
        let colour_pub = image_publisher(&mut n, &topics.colour).unwrap();
        let depth_pub = image_publisher(&mut n, &topics.depth).unwrap();
        let info_pub = camera_info_publisher(&mut n, &topics.camera_info).unwrap();
        while !stop2.load(Ordering::Relaxed) {
            // Stamped as a ROS 2 driver does: the system clock at capture.
            let header = Header {
                stamp: ros_time(0),
                frame_id: ZED_FRAME_ID.into(),
            };
            let info = CameraInfo {
                header: header.clone(),
                height: h,
                width: w,
                distortion_model: "plumb_bob".into(),
                d: vec![0.0; 5],
                k: [k.fx_px, 0.0, k.cx_px, 0.0, k.fy_px, k.cy_px, 0.0, 0.0, 1.0],
                ..CameraInfo::default()
            };
            let _ = info_pub.publish(info);
            let _ = depth_pub.publish(Image {
                header: header.clone(),
                height: h,
                width: w,
                encoding: "32FC1".into(),
                is_bigendian: 0,
                step: w * 4,
                data: depth.clone(),
            });
            let _ = colour_pub.publish(Image {
                header,
                height: h,
                width: w,
                encoding: "bgra8".into(),
                is_bigendian: 0,
                step: w * 4,
                data: bgra.clone(),
            });
            std::thread::sleep(Duration::from_millis(100));
        }
    });

    let got = wait_for(Duration::from_secs(40), || {
        while let Ok(Some(s)) = sub.receive() {
            let f = *s.payload();
            if f.count == 2 {
                return Some(f);
            }
        }
        assert!(
            p.child.try_wait().unwrap().is_none(),
            "perception exited early"
        );
        None
    });
    stop.store(true, Ordering::Relaxed);
    camera.join().unwrap();
    let f = got.expect("no DetectionFrame with both objects arrived from the ROS 2 source");
    f.validate().unwrap();
    let goal = f.objects()[0];
    let obs = f.objects()[1];
    assert_eq!(goal.class().unwrap(), ObjectClass::Goal);
    assert_eq!(obs.class().unwrap(), ObjectClass::Obstacle);
    let close =
        |a: [f32; 3], b: [f32; 3], tol: f32| a.iter().zip(b).all(|(x, y)| (x - y).abs() < tol);
    assert!(close(goal.center_m, [0.45, 0.20, 0.025], 0.015), "{goal:?}");
    assert!(close(obs.center_m, [0.30, -0.10, 0.075], 0.015), "{obs:?}");
    assert!((obs.size_m[2] - 0.15).abs() < 0.015, "{obs:?}");
    assert!(f.capture_time_ns > 0);
    std::fs::remove_dir_all(&dir).ok();
}

/// `builtin_interfaces/Time` of the system clock `before_ns` ago.
fn ros_time(before_ns: u64) -> Time {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap();
    let t = now - Duration::from_nanos(before_ns);
    Time {
        sec: t.as_secs() as i32,
        nanosec: t.subsec_nanos(),
    }
}

fn toml_of(t: &Ros2Topics) -> String {
    format!(
        "domain_id = {}\nnetworks = [\"127.0.0.1\"]\ncolour = {:?}\ndepth = {:?}\ncamera_info = {:?}\ntimeout_s = {}\n",
        t.domain_id, t.colour, t.depth, t.camera_info, t.timeout_s
    )
}

/// Images stamped 400 ms before they are sent (a slow camera pipeline) give frames whose
/// `capture_time_ns` is that capture time on CLOCK_MONOTONIC, not the receipt time; images
/// with a zero stamp, sent first, are refused, counted in `bad_stamps` and logged naming
/// `header.stamp`. No frame ever carries 0.
#[test]
fn ros2_frames_carry_the_camera_stamp_on_the_monotonic_clock_and_unstamped_images_are_refused() {
    const BEFORE_NS: u64 = 400_000_000;
    let name = "ros2_frames_carry_the_camera_stamp_on_the_monotonic_clock_and_unstamped_images_are_refused";
    if run_in_private_netns(name) == NetnsOutcome::RanInChild {
        return;
    }
    let dir = std::env::temp_dir().join(format!("foresight-perc-stamp-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (cam, scene) = quarter_camera_calibrated(&dir);
    let r = cam.render(&scene);
    // The default networks (loopback only); a wider age bound for the 400 ms old stamps.
    let topics = Ros2Topics {
        timeout_s: 5.0,
        ..Ros2Topics::default()
    };
    std::fs::write(
        dir.join("topics.toml"),
        format!(
            "colour = {:?}\ndepth = {:?}\ncamera_info = {:?}\ntimeout_s = 5.0\n[stamp]\nmax_age_s = 1.0\n",
            topics.colour, topics.depth, topics.camera_info
        ),
    )
    .unwrap();

    let prefix = unique_prefix("percstamp");
    let (ice, _) = services::create_node::<ipc::Service>("perception-stamp-test").unwrap();
    let sub = services::open_subscriber::<DetectionFrame, _>(&ice, &prefix).unwrap();
    let mut p = ChildGuard::spawn(
        "perception run --source ros2",
        Command::new(bin_path("perception"))
            .args(["run", "--source", "ros2", "--prefix", &prefix])
            .args(["--rate", "10", "--frames", "60", "--persist-frames", "1"])
            .arg("--ros2-topics")
            .arg(dir.join("topics.toml"))
            .arg("--calibration")
            .arg(dir.join("calibration.toml"))
            .stdout(Stdio::piped())
            .stderr(Stdio::piped()),
    );
    // perception's log, line by line: the camera stamps its images only once perception
    // has refused an unstamped one.
    let refused = Arc::new(AtomicBool::new(false));
    let stderr = p.child.stderr.take().unwrap();
    let refused2 = refused.clone();
    let log = std::thread::spawn(move || {
        use std::io::BufRead;
        let mut all = String::new();
        for line in std::io::BufReader::new(stderr).lines() {
            let Ok(line) = line else { break };
            if line.contains("header.stamp is zero") {
                refused2.store(true, Ordering::Relaxed);
            }
            all += &line;
            all.push('\n');
        }
        all
    });

    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let (w, h) = (r.width_px as u32, r.height_px as u32);
    let bgra: Vec<u8> = r
        .bgr
        .chunks_exact(3)
        .flat_map(|p| [p[0], p[1], p[2], 255])
        .collect();
    let depth: Vec<u8> = r.depth_m.iter().flat_map(|d| d.to_le_bytes()).collect();
    // CLOCK_MONOTONIC when the first stamped image was sent.
    let first_stamped_mono_ns = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let first2 = first_stamped_mono_ns.clone();
    let camera = std::thread::spawn(move || {
        let ctx = context(topics.domain_id, &topics.networks).unwrap();
        let mut n = node(&ctx, "fake_zed").unwrap();
        let colour_pub = image_publisher(&mut n, &topics.colour).unwrap();
        let depth_pub = image_publisher(&mut n, &topics.depth).unwrap();
        while !stop2.load(Ordering::Relaxed) {
            let stamped = refused.load(Ordering::Relaxed);
            if stamped && first2.load(Ordering::Relaxed) == 0 {
                first2.store(monotonic_now_ns(), Ordering::Relaxed);
            }
            let header = Header {
                stamp: if stamped {
                    ros_time(BEFORE_NS)
                } else {
                    Time::default()
                },
                frame_id: ZED_FRAME_ID.into(),
            };
            let _ = depth_pub.publish(Image {
                header: header.clone(),
                height: h,
                width: w,
                encoding: "32FC1".into(),
                is_bigendian: 0,
                step: w * 4,
                data: depth.clone(),
            });
            let _ = colour_pub.publish(Image {
                header,
                height: h,
                width: w,
                encoding: "bgra8".into(),
                is_bigendian: 0,
                step: w * 4,
                data: bgra.clone(),
            });
            std::thread::sleep(Duration::from_millis(100));
        }
    });

    let mut frames = Vec::new();
    let done = wait_for(Duration::from_secs(90), || {
        while let Ok(Some(s)) = sub.receive() {
            frames.push((*s.payload(), monotonic_now_ns()));
        }
        p.child.try_wait().unwrap()
    });
    while let Ok(Some(s)) = sub.receive() {
        frames.push((*s.payload(), monotonic_now_ns()));
    }
    stop.store(true, Ordering::Relaxed);
    camera.join().unwrap();
    let log = log.join().unwrap();
    assert!(
        done.is_some_and(|s| s.success()),
        "perception run failed:\n{log}"
    );
    let mut stdout = String::new();
    use std::io::Read;
    p.child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut stdout)
        .unwrap();
    let stats: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert!(
        stats["bad_stamps"].as_u64().is_some_and(|n| n >= 1),
        "{stdout}\n{log}"
    );
    assert!(log.contains("header.stamp is zero"), "{log}");
    assert!(
        !frames.is_empty(),
        "no DetectionFrame arrived:\n{stdout}\n{log}"
    );
    let first_stamped = first_stamped_mono_ns.load(Ordering::Relaxed);
    assert!(first_stamped > 0);
    for (f, received_ns) in &frames {
        assert!(f.capture_time_ns > 0, "{f:?}");
        // Captured 400 ms before the image was sent, which is before the frame arrived
        // here: a receipt-time stamp would be later than this bound.
        assert!(
            f.capture_time_ns + BEFORE_NS <= *received_ns,
            "capture_time_ns {} is not 400 ms before the frame arrived ({received_ns})",
            f.capture_time_ns
        );
        // And not earlier than the first stamped image's capture.
        assert!(
            f.capture_time_ns + BEFORE_NS + 5_000_000 >= first_stamped,
            "capture_time_ns {} is before the first stamped image's capture",
            f.capture_time_ns
        );
    }
    std::fs::remove_dir_all(&dir).ok();
}

/// The scene of [`SCENE`] with a tall box added (0.30 m high).
const SCENE_TALL: &str = "[goal]\ncenter_m = [0.45, 0.20, 0.025]\nsize_m = 0.05\n[[obstacle]]\ncenter_m = [0.30, -0.10, 0.075]\nsize_m = [0.08, 0.06, 0.15]\n[[obstacle]]\ncenter_m = [0.46, -0.18, 0.15]\nsize_m = [0.07, 0.07, 0.30]\n";

/// Issue 25 item 3. The camera publishes colour and depth (scene A) until perception has
/// published a settled frame; then the depth publisher stops and a tall box appears in the
/// colour images only (scene B) for 3 s; then depth comes back (scene B). While depth is
/// stalled every frame is refused and counted (`unpaired_depth`); no settled frame ever
/// holds the tall box lower than it is (before the fix: the old table depth measured it as
/// a ~1 mm footprint, settled); once depth is fresh the box is published at its height.
#[test]
fn a_stalled_depth_topic_refuses_frames_and_never_settles_a_tall_box_as_flat() {
    let name = "a_stalled_depth_topic_refuses_frames_and_never_settles_a_tall_box_as_flat";
    if run_in_private_netns(name) == NetnsOutcome::RanInChild {
        return;
    }
    let dir = std::env::temp_dir().join(format!("foresight-perc-stall-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut cam =
        SyntheticCamera::load(&foresight_tests::asset("perception/synthetic_camera.toml"))
            .unwrap()
            .config;
    cam.intrinsics.fx_px /= 2.0;
    cam.intrinsics.fy_px /= 2.0;
    cam.intrinsics.cx_px /= 2.0;
    cam.intrinsics.cy_px /= 2.0;
    cam.intrinsics.width_px /= 2;
    cam.intrinsics.height_px /= 2;
    let cam = SyntheticCamera::new(cam).unwrap();
    let scene_a = SceneFile::from_toml_str(SCENE, std::path::Path::new("<a>")).unwrap();
    let scene_b = SceneFile::from_toml_str(SCENE_TALL, std::path::Path::new("<b>")).unwrap();
    Calibration::new(CalibrationFile {
        camera: zed_camera(),
        intrinsics: cam.config.intrinsics,
        workspace: cam.workspace_for(&scene_a),
        corners_px: cam.workspace_corners_px(&scene_a).unwrap(),
        rectified_px_per_m: 1000.0,
    })
    .unwrap()
    .save(&dir.join("calibration.toml"))
    .unwrap();
    let topics = Ros2Topics {
        timeout_s: 5.0,
        ..Ros2Topics::default()
    };
    std::fs::write(dir.join("topics.toml"), toml_of(&topics)).unwrap();

    let prefix = unique_prefix("percstall");
    let (ice, _) = services::create_node::<ipc::Service>("perception-stall-test").unwrap();
    let sub = services::open_subscriber::<DetectionFrame, _>(&ice, &prefix).unwrap();
    let mut p = ChildGuard::spawn(
        "perception run --source ros2",
        Command::new(bin_path("perception"))
            .args(["run", "--source", "ros2", "--prefix", &prefix])
            .args(["--rate", "10", "--frames", "200", "--persist-frames", "1"])
            .arg("--ros2-topics")
            .arg(dir.join("topics.toml"))
            .arg("--calibration")
            .arg(dir.join("calibration.toml"))
            .stdout(Stdio::piped())
            .stderr(Stdio::piped()),
    );
    let stderr = p.child.stderr.take().unwrap();
    let log = std::thread::spawn(move || {
        let mut all = String::new();
        use std::io::Read;
        let _ = std::io::BufReader::new(stderr).read_to_string(&mut all);
        all
    });

    // 0: scene A with depth; 1: scene B colour only (depth stalled); 2: scene B with depth.
    let phase = Arc::new(std::sync::atomic::AtomicU8::new(0));
    let stop = Arc::new(AtomicBool::new(false));
    let (phase2, stop2) = (phase.clone(), stop.clone());
    let image = |r: &perception::synthetic::RenderedFrame| {
        let bgra: Vec<u8> = r
            .bgr
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect();
        let depth: Vec<u8> = r.depth_m.iter().flat_map(|d| d.to_le_bytes()).collect();
        (r.width_px as u32, r.height_px as u32, bgra, depth)
    };
    let (a, b) = (image(&cam.render(&scene_a)), image(&cam.render(&scene_b)));
    let camera = std::thread::spawn(move || {
        let ctx = context(topics.domain_id, &topics.networks).unwrap();
        let mut n = node(&ctx, "fake_zed").unwrap();
        let colour_pub = image_publisher(&mut n, &topics.colour).unwrap();
        let depth_pub = image_publisher(&mut n, &topics.depth).unwrap();
        while !stop2.load(Ordering::Relaxed) {
            let ph = phase2.load(Ordering::Relaxed);
            let (w, h, bgra, depth) = if ph == 0 { &a } else { &b };
            let header = Header {
                stamp: ros_time(0),
                frame_id: ZED_FRAME_ID.into(),
            };
            if ph != 1 {
                let _ = depth_pub.publish(Image {
                    header: header.clone(),
                    height: *h,
                    width: *w,
                    encoding: "32FC1".into(),
                    is_bigendian: 0,
                    step: w * 4,
                    data: depth.clone(),
                });
            }
            let _ = colour_pub.publish(Image {
                header,
                height: *h,
                width: *w,
                encoding: "bgra8".into(),
                is_bigendian: 0,
                step: w * 4,
                data: bgra.clone(),
            });
            std::thread::sleep(Duration::from_millis(100));
        }
    });

    let mut frames: Vec<DetectionFrame> = Vec::new();
    let mut stalled_at = None;
    let done = wait_for(Duration::from_secs(60), || {
        while let Ok(Some(s)) = sub.receive() {
            frames.push(*s.payload());
        }
        match phase.load(Ordering::Relaxed) {
            0 if frames.iter().any(|f| f.settled() && f.count == 2) => {
                phase.store(1, Ordering::Relaxed);
                stalled_at = Some(std::time::Instant::now());
            }
            1 if stalled_at.is_some_and(|t| t.elapsed() > Duration::from_secs(3)) => {
                phase.store(2, Ordering::Relaxed);
            }
            _ => {}
        }
        p.child.try_wait().unwrap()
    });
    while let Ok(Some(s)) = sub.receive() {
        frames.push(*s.payload());
    }
    stop.store(true, Ordering::Relaxed);
    camera.join().unwrap();
    let log = log.join().unwrap();
    assert!(
        done.is_some_and(|s| s.success()),
        "perception run failed or did not end:\n{log}"
    );
    assert_eq!(
        phase.load(Ordering::Relaxed),
        2,
        "the depth stall was never reached (no settled frame of scene A):\n{log}"
    );
    let mut stdout = String::new();
    use std::io::Read;
    p.child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut stdout)
        .unwrap();
    let stats: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert!(
        stats["unpaired_depth"].as_u64().is_some_and(|n| n >= 10),
        "the stalled depth was not refused and counted: {stdout}\n{log}"
    );
    // The tall box, wherever it is reported: never lower than 0.25 m in a settled frame.
    let near_tall = |o: &shm_schemas::DetectedObject| {
        (o.center_m[0] - 0.46).abs() < 0.05 && (o.center_m[1] + 0.18).abs() < 0.05
    };
    for f in frames.iter().filter(|f| f.settled()) {
        for o in f.objects().iter().filter(|o| near_tall(o)) {
            assert!(
                o.size_m[2] > 0.25,
                "a settled frame holds the tall box as {:.3} m high: {f:?}",
                o.size_m[2]
            );
        }
    }
    // Once depth is fresh again, the box is published at its height, settled.
    assert!(
        frames.iter().any(|f| f.settled()
            && f.objects()
                .iter()
                .any(|o| near_tall(o) && (o.size_m[2] - 0.30).abs() < 0.03)),
        "no settled frame with the tall box at its height after depth returned:\n{log}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// Issue 30 item 2: a live camera is driven only with a calibration made for it. The
/// calibration names camera `zed_left_camera_optical_frame`; the camera first publishes
/// images of another camera (`header.frame_id` = `other_camera_optical_frame`, colour and
/// depth): every one is refused, counted in `wrong_camera` and logged naming both ids, and
/// nothing is published (before: they were measured with this calibration and published).
/// Then the calibrated camera's images arrive and are published: a refusal is per image, not
/// the end of the run.
#[test]
fn images_of_another_camera_are_refused_and_never_published() {
    const OTHER: &str = "other_camera_optical_frame";
    let name = "images_of_another_camera_are_refused_and_never_published";
    if run_in_private_netns(name) == NetnsOutcome::RanInChild {
        return;
    }
    let dir = std::env::temp_dir().join(format!("foresight-perc-camid-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (cam, scene) = quarter_camera_calibrated(&dir);
    let r = cam.render(&scene);
    let topics = Ros2Topics {
        timeout_s: 5.0,
        ..Ros2Topics::default()
    };
    std::fs::write(dir.join("topics.toml"), toml_of(&topics)).unwrap();

    let prefix = unique_prefix("perccamid");
    let (ice, _) = services::create_node::<ipc::Service>("perception-camid-test").unwrap();
    let sub = services::open_subscriber::<DetectionFrame, _>(&ice, &prefix).unwrap();
    let mut p = ChildGuard::spawn(
        "perception run --source ros2",
        Command::new(bin_path("perception"))
            .args(["run", "--source", "ros2", "--prefix", &prefix])
            .args(["--rate", "10", "--frames", "60", "--persist-frames", "1"])
            .arg("--ros2-topics")
            .arg(dir.join("topics.toml"))
            .arg("--calibration")
            .arg(dir.join("calibration.toml"))
            .stdout(Stdio::piped())
            .stderr(Stdio::piped()),
    );
    // perception's log, line by line: the calibrated camera starts publishing only once
    // perception has refused the other camera's images (never, before the fix).
    let refused = Arc::new(AtomicBool::new(false));
    let stderr = p.child.stderr.take().unwrap();
    let refused2 = refused.clone();
    let log = std::thread::spawn(move || {
        use std::io::BufRead;
        let mut all = String::new();
        for line in std::io::BufReader::new(stderr).lines() {
            let Ok(line) = line else { break };
            if line.contains("header.frame_id") && line.contains(OTHER) {
                refused2.store(true, Ordering::Relaxed);
            }
            all += &line;
            all.push('\n');
        }
        all
    });

    let stop = Arc::new(AtomicBool::new(false));
    let stop2 = stop.clone();
    let (w, h) = (r.width_px as u32, r.height_px as u32);
    let bgra: Vec<u8> = r
        .bgr
        .chunks_exact(3)
        .flat_map(|p| [p[0], p[1], p[2], 255])
        .collect();
    let depth: Vec<u8> = r.depth_m.iter().flat_map(|d| d.to_le_bytes()).collect();
    // CLOCK_MONOTONIC just before the first image of the calibrated camera was stamped.
    let switched_mono_ns = Arc::new(std::sync::atomic::AtomicU64::new(0));
    let switched2 = switched_mono_ns.clone();
    let camera = std::thread::spawn(move || {
        let ctx = context(topics.domain_id, &topics.networks).unwrap();
        let mut n = node(&ctx, "fake_zed").unwrap();
        let colour_pub = image_publisher(&mut n, &topics.colour).unwrap();
        let depth_pub = image_publisher(&mut n, &topics.depth).unwrap();
        while !stop2.load(Ordering::Relaxed) {
            let ours = refused.load(Ordering::Relaxed);
            if ours && switched2.load(Ordering::Relaxed) == 0 {
                switched2.store(monotonic_now_ns(), Ordering::Relaxed);
            }
            let header = Header {
                stamp: ros_time(0),
                frame_id: if ours { ZED_FRAME_ID } else { OTHER }.into(),
            };
            let _ = depth_pub.publish(Image {
                header: header.clone(),
                height: h,
                width: w,
                encoding: "32FC1".into(),
                is_bigendian: 0,
                step: w * 4,
                data: depth.clone(),
            });
            let _ = colour_pub.publish(Image {
                header,
                height: h,
                width: w,
                encoding: "bgra8".into(),
                is_bigendian: 0,
                step: w * 4,
                data: bgra.clone(),
            });
            std::thread::sleep(Duration::from_millis(100));
        }
    });

    let mut frames = Vec::new();
    let done = wait_for(Duration::from_secs(90), || {
        while let Ok(Some(s)) = sub.receive() {
            frames.push(*s.payload());
        }
        p.child.try_wait().unwrap()
    });
    while let Ok(Some(s)) = sub.receive() {
        frames.push(*s.payload());
    }
    stop.store(true, Ordering::Relaxed);
    camera.join().unwrap();
    let log = log.join().unwrap();
    let switched = switched_mono_ns.load(Ordering::Relaxed);
    // Nothing the other camera showed was published.
    for f in &frames {
        assert!(
            switched > 0 && f.capture_time_ns >= switched,
            "a frame of camera {OTHER:?} was published with the calibration of {ZED_FRAME_ID:?} \
             (captured at {} ns, the calibrated camera started at {switched} ns): {f:?}\n{log}",
            f.capture_time_ns
        );
    }
    assert!(
        done.is_some_and(|s| s.success()),
        "perception run failed:\n{log}"
    );
    let mut stdout = String::new();
    use std::io::Read;
    p.child
        .stdout
        .take()
        .unwrap()
        .read_to_string(&mut stdout)
        .unwrap();
    let stats: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert!(
        stats["wrong_camera"].as_u64().is_some_and(|n| n >= 1),
        "{stdout}\n{log}"
    );
    assert!(
        log.contains(&format!("header.frame_id {OTHER:?}"))
            && log.contains(&format!("camera frame_id {ZED_FRAME_ID:?}")),
        "the refusal does not name both frame ids:\n{log}"
    );
    // The calibrated camera's images are published, with both objects.
    assert!(
        frames.iter().any(|f| f.count == 2),
        "no DetectionFrame from the calibrated camera:\n{stdout}\n{log}"
    );
    std::fs::remove_dir_all(&dir).ok();
}
