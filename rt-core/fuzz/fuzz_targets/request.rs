//! Client → controller requests (what xarm-sim parses), and re-encoding what parsed.
#![no_main]
use libfuzzer_sys::fuzz_target;
use xarm::codec::Request;

fuzz_target!(|data: &[u8]| {
    if let Ok((h, req)) = Request::decode(data) {
        let mut out = [0u8; 128];
        let n = req.encode(h.tid, h.protocol, &mut out).expect("fits");
        let (_, again) = Request::decode(&out[..n]).expect("re-decodes");
        // NaN payloads compare unequal; compare the bytes instead.
        let mut out2 = [0u8; 128];
        let m = again.encode(h.tid, h.protocol, &mut out2).expect("fits");
        assert_eq!(&out[..n], &out2[..m]);
    }
});
