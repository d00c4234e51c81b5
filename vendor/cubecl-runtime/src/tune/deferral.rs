//! When a key missing from the tune cache is not tuned, and its caller runs the first
//! candidate that serves instead (as for a key another thread is tuning).
//!
//! - Inside a measurement. A candidate being compiled or measured can reach a key of its
//!   own (a convolution through im2col reaches the matmul's tuner). Tuning that key there
//!   starts a second batch on the device thread, blocked inside the first one's exclusive
//!   access; it is left to be tuned when it is reached outside any measurement.
//! - While tuning is deferred, process-wide ([`defer_tuning`]): for a device where a tune
//!   costs more than the work it speeds up, such as a software rasterizer. Results already in
//!   the persistent cache still answer.

use core::sync::atomic::{AtomicBool, Ordering};

static DEFERRED: AtomicBool = AtomicBool::new(false);

/// Whether a cache miss tunes (`false`, the default) or runs the first candidate that serves
/// the problem (`true`), from now on in this process. Results already cached, in memory or
/// in the persistent cache, are used either way.
pub fn defer_tuning(defer: bool) {
    DEFERRED.store(defer, Ordering::Relaxed);
}

/// Whether a miss on this thread is left untuned now.
pub(crate) fn tuning_deferred() -> bool {
    DEFERRED.load(Ordering::Relaxed) || measuring::active()
}

/// Marks the current thread as compiling or measuring candidates while `run` runs.
pub(crate) fn measuring<R>(run: impl FnOnce() -> R) -> R {
    let _mark = measuring::Mark::new();
    run()
}

#[cfg(multi_threading)]
mod measuring {
    use core::cell::Cell;

    std::thread_local! {
        static DEPTH: Cell<u32> = const { Cell::new(0) };
    }

    pub(super) fn active() -> bool {
        DEPTH.with(|depth| depth.get() > 0)
    }

    /// Counts the current thread in a measurement until dropped (a panic included).
    pub(super) struct Mark;

    impl Mark {
        pub(super) fn new() -> Self {
            DEPTH.with(|depth| depth.set(depth.get() + 1));
            Mark
        }
    }

    impl Drop for Mark {
        fn drop(&mut self) {
            DEPTH.with(|depth| depth.set(depth.get() - 1));
        }
    }
}

// Without threads nothing nests on a device thread.
#[cfg(not(multi_threading))]
mod measuring {
    pub(super) fn active() -> bool {
        false
    }

    pub(super) struct Mark;

    impl Mark {
        pub(super) fn new() -> Self {
            Mark
        }
    }
}
