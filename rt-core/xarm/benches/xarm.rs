//! xArm driver benches: servo_j encode, encode + send on a loopback socket, and the
//! driver's per-call cost while streaming at 250 Hz against `xarm-sim` (printed as
//! percentiles, since criterion reports means).

// Benchmarks: a failed unwrap or expect is a failed run, with its message.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::hint::black_box;
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use xarm::codec::{JointTarget, SERVOJ_FRAME_LEN, encode_servo_j};
use xarm::driver::{XArmConfig, XArmDriver};
use xarm::report::ReportKind;
use xarm_sim::{SimOptions, SimPorts, SimServer};

/// A loopback socket pair whose far end discards everything. The far end polls every
/// 500 µs instead of blocking in `read`, so a send does not pay for waking a reader on this
/// machine (the controller is another machine).
fn sink() -> TcpStream {
    let l = TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = l.local_addr().expect("addr");
    std::thread::spawn(move || {
        if let Ok((mut s, _)) = l.accept() {
            s.set_nonblocking(true).expect("nonblocking");
            let mut buf = [0u8; 65536];
            loop {
                match s.read(&mut buf) {
                    Ok(0) => return,
                    Ok(_) => {}
                    Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                        std::thread::sleep(Duration::from_micros(500));
                    }
                    Err(_) => return,
                }
            }
        }
    });
    let s = TcpStream::connect(addr).expect("connect");
    s.set_nodelay(true).expect("nodelay");
    s
}

fn percentiles(name: &str, mut ns: Vec<u64>) {
    ns.sort_unstable();
    let p = |q: f64| ns[((ns.len() as f64 - 1.0) * q) as usize];
    println!(
        "{name}: n={} p50={} ns p90={} ns p99={} ns max={} ns",
        ns.len(),
        p(0.5),
        p(0.9),
        p(0.99),
        ns[ns.len() - 1]
    );
}

fn encode_send_percentiles() {
    let mut s = sink();
    let mut frame = [0u8; SERVOJ_FRAME_LEN];
    let mut samples = Vec::with_capacity(20_000);
    for i in 0..20_000u32 {
        let q = [0.001 * f64::from(i % 100), -0.2, -0.3, 0.0, 0.0];
        let t0 = Instant::now();
        encode_servo_j(i as u16, &JointTarget::xarm5(&q), &mut frame);
        s.write_all(&frame).expect("write");
        samples.push(t0.elapsed().as_nanos() as u64);
        if i % 64 == 0 {
            std::thread::sleep(Duration::from_micros(50));
        }
    }
    percentiles("encode+send servo_j (loopback sink)", samples);
}

fn driver_250hz_percentiles() {
    let opts = SimOptions {
        ports: SimPorts::ephemeral(),
        q0_rad: [0.0, -0.3, -0.5, 0.0, 0.0],
        ..SimOptions::default()
    };
    let sim = SimServer::start(opts).expect("sim");
    let ports = sim.ports();
    let mut cfg = XArmConfig::new("127.0.0.1");
    cfg.command_port = ports.command;
    cfg.report_port = ports.report_real;
    cfg.report_kind = ReportKind::Real;
    let mut d = XArmDriver::connect(cfg).expect("connect");
    let q0 = d.start_servo_mode().expect("servo mode");
    let origin = Instant::now();
    let period = Duration::from_millis(4);
    let mut next = Instant::now();
    let mut send = Vec::with_capacity(1000);
    let mut read = Vec::with_capacity(1000);
    for k in 0..1000 {
        next += period;
        let now = Instant::now();
        if next > now {
            std::thread::sleep(next - now);
        }
        let q = [
            q0[0] + 0.05 * (k as f64 * 0.004).sin(),
            q0[1],
            q0[2],
            q0[3],
            q0[4],
        ];
        let t0 = Instant::now();
        let _ = black_box(d.read_state(origin.elapsed().as_nanos() as u64));
        let t1 = Instant::now();
        d.send_servo(origin.elapsed().as_nanos() as u64, &q)
            .expect("send");
        let t2 = Instant::now();
        read.push((t1 - t0).as_nanos() as u64);
        send.push((t2 - t1).as_nanos() as u64);
    }
    d.flush().expect("flush");
    percentiles("driver send_servo at 250 Hz (encode+write+drain)", send);
    percentiles("driver read_state at 250 Hz (drain reports+replies)", read);
    let summary = sim.shutdown();
    println!(
        "sim: servo accepted {} rejected {} (driver sent {})",
        summary.counters.servo_accepted,
        summary.counters.servo_rejected,
        d.stats().servo_sent
    );
}

fn benches(c: &mut Criterion) {
    encode_send_percentiles();
    driver_250hz_percentiles();
    let q = [0.1, -0.2, -0.3, 0.4, 0.5];
    let mut frame = [0u8; SERVOJ_FRAME_LEN];
    c.bench_function("servo_j encode", |b| {
        b.iter(|| {
            encode_servo_j(7, &JointTarget::xarm5(black_box(&q)), &mut frame);
            black_box(&frame);
        })
    });
    let mut s = sink();
    let mut i = 0u16;
    c.bench_function("servo_j encode + send (loopback)", |b| {
        b.iter(|| {
            i = i.wrapping_add(1);
            encode_servo_j(i, &JointTarget::xarm5(black_box(&q)), &mut frame);
            s.write_all(&frame).expect("write");
        })
    });
}

criterion_group!(xarm, benches);
criterion_main!(xarm);
