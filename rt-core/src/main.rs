//! The `rt-core` binary: a thin command-line edge over the rt-core library.
//!
//! Subcommands live one per file under `cli/`: `twin` (debugging the digital twin, JSON on
//! stdout), and, as they land, `run` (the real-time runtime), `bench-loop` (latency and
//! jitter harness) and `xarm` (driver tools such as `probe`).

#![forbid(unsafe_code)]

mod cli;

/// Counts allocations of threads that opt in (the cycle thread of `run` and `bench-loop`);
/// a plain pass-through to the system allocator otherwise.
#[global_allocator]
static ALLOC: rt_core::rt::alloc_count::CountingAlloc = rt_core::rt::alloc_count::CountingAlloc;

fn main() -> std::process::ExitCode {
    cli::main()
}
