//! Controller → driver replies on port 502: framing, SDK-order checks, typed accessors.
#![no_main]
use libfuzzer_sys::fuzz_target;
use xarm::codec::{Response, VersionInfo, frame_len};

fuzz_target!(|data: &[u8]| {
    if let Ok(Some(n)) = frame_len(data, 2) {
        assert!(n <= data.len());
    }
    if let Ok(r) = Response::parse(data) {
        let _ = r.check(1, 3, 0x1d);
        let _ = r.state();
        let _ = r.err_warn();
        let _ = r.cmdnum();
        let _ = r.joints();
        let _ = r.tcp_pose();
        let _ = r.version();
    }
    let _ = VersionInfo::parse(data);
});
