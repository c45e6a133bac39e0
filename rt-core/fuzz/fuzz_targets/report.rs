//! Report packets of every stream kind.
#![no_main]
use libfuzzer_sys::fuzz_target;
use xarm::report::{ReportKind, decode};

fuzz_target!(|data: &[u8]| {
    for kind in [
        ReportKind::RealTime,
        ReportKind::Normal,
        ReportKind::Rich,
        ReportKind::Real,
    ] {
        if let Ok(r) = decode(kind, data) {
            assert!(r.joints_rad.iter().all(|v| v.is_finite()));
            assert!(r.state <= 9 && r.mode <= 11);
        }
    }
});
