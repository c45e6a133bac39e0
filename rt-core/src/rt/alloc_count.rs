//! A counting global allocator for the zero-allocation checks: it counts allocations made
//! by threads that have switched counting on ([`count_this_thread`]), so the cycle thread
//! can be watched while other threads allocate freely. Install it in a binary or a test:
//!
//! ```ignore
//! #[global_allocator]
//! static ALLOC: rt_core::rt::alloc_count::CountingAlloc = rt_core::rt::alloc_count::CountingAlloc;
//! ```

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};

static COUNTED: AtomicU64 = AtomicU64::new(0);

thread_local! {
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}

/// The system allocator, counting allocations of watched threads.
pub struct CountingAlloc;

#[inline]
fn note() {
    // `try_with` because the thread-local may be gone during thread teardown.
    let on = COUNTING.try_with(Cell::get).unwrap_or(false);
    if on {
        COUNTED.fetch_add(1, Ordering::Relaxed);
    }
}

// SAFETY: every method forwards to `System` with the caller's arguments unchanged, so the
// `GlobalAlloc` contract is upheld by `System`; counting touches only an atomic and a
// const-initialised thread-local `Cell` (no allocation, no re-entrancy).
unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note();
        // SAFETY: forwarded unchanged; the caller upholds `alloc`'s contract.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note();
        // SAFETY: forwarded unchanged; the caller upholds `alloc_zeroed`'s contract.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note();
        // SAFETY: forwarded unchanged; `ptr` came from this allocator (i.e. `System`).
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        note();
        // SAFETY: forwarded unchanged; `ptr` came from this allocator (i.e. `System`).
        unsafe { System.dealloc(ptr, layout) }
    }
}

/// Switches counting on or off for the calling thread.
pub fn count_this_thread(on: bool) {
    COUNTING.with(|c| c.set(on));
}

/// Allocations, reallocations and frees made by watched threads so far (only meaningful
/// where [`CountingAlloc`] is the global allocator).
pub fn counted() -> u64 {
    COUNTED.load(Ordering::Relaxed)
}
