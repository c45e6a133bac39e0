//! A report byte stream cut into chunks (first byte picks the chunk size) through the framer.
#![no_main]
use libfuzzer_sys::fuzz_target;
use xarm::report::{ReportFramer, ReportKind, decode};

fuzz_target!(|data: &[u8]| {
    let Some((&chunk, rest)) = data.split_first() else {
        return;
    };
    let chunk = usize::from(chunk).max(1);
    let mut f = ReportFramer::new();
    for piece in rest.chunks(chunk) {
        let spare = f.spare();
        let n = piece.len().min(spare.len());
        spare[..n].copy_from_slice(&piece[..n]);
        f.commit(n);
        loop {
            match f.next_packet() {
                Ok(Some(p)) => {
                    let _ = decode(ReportKind::Real, p);
                }
                Ok(None) => break,
                Err(_) => {
                    f.reset();
                    break;
                }
            }
        }
    }
});
