//! A global allocator that counts the current thread's allocations while it measures.
//!
//! ```
//! #[global_allocator]
//! static GLOBAL: conductor_testkit::alloc::Counting = conductor_testkit::alloc::Counting;
//!
//! fn rt_tick(buf: &mut [f64; 4]) -> f64 {
//!     buf.iter_mut().for_each(|x| *x += 1.0);
//!     buf.iter().sum()
//! }
//!
//! fn main() {
//!     let mut buf = [0.0; 4];
//!     let (sum, allocations) = conductor_testkit::alloc::measure(|| rt_tick(&mut buf));
//!     assert_eq!((sum, allocations), (4.0, 0));
//!     // What allocates is seen.
//!     let (_, allocations) = conductor_testkit::alloc::measure(|| vec![0u8; 64]);
//!     assert_eq!(allocations, 1);
//! }
//! ```
//!
//! Only allocations made by the measuring thread, inside [`measure`], are counted, so the test
//! harness's own threads do not disturb the figure.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

// Both per thread: tests of one binary run on parallel threads, and a count shared between them
// would charge one test's allocations to another that measures at the same time.
thread_local! {
    static MEASURING: Cell<bool> = const { Cell::new(false) };
    static ALLOCS: Cell<u64> = const { Cell::new(0) };
}

/// The system allocator, counting `alloc` and `realloc` calls made inside [`measure`].
pub struct Counting;

fn count() {
    if MEASURING.with(Cell::get) {
        ALLOCS.with(|a| a.set(a.get() + 1));
    }
}

// SAFETY: every call is forwarded unchanged to the system allocator; counting touches only
// two const-initialised thread-locals, neither of which allocates.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        count();
        // SAFETY: the caller upholds GlobalAlloc::alloc's contract, which we pass on.
        unsafe { System.alloc(l) }
    }
    unsafe fn alloc_zeroed(&self, l: Layout) -> *mut u8 {
        count();
        // SAFETY: as for alloc.
        unsafe { System.alloc_zeroed(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        // SAFETY: `p` was allocated by System with `l` (we forward every allocation).
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        count();
        // SAFETY: as for dealloc; the caller upholds realloc's contract.
        unsafe { System.realloc(p, l, n) }
    }
}

/// Runs `f` and returns its result with the number of allocations this thread made meanwhile.
/// Meaningful only in a test binary whose `#[global_allocator]` is [`Counting`].
pub fn measure<R>(f: impl FnOnce() -> R) -> (R, u64) {
    let before = ALLOCS.with(Cell::get);
    MEASURING.with(|m| m.set(true));
    let r = f();
    MEASURING.with(|m| m.set(false));
    (r, ALLOCS.with(Cell::get) - before)
}
