//! Whether a key missing from the tune cache is tuned, or its caller runs the first candidate
//! that serves instead (as for a key another thread is tuning): for a device where a tune
//! costs more than the work it speeds up, such as a software rasterizer. Results already in
//! the tune cache, in memory or on disk, still answer.

use core::sync::atomic::{AtomicBool, Ordering};

static DEFERRED: AtomicBool = AtomicBool::new(false);

/// Whether a cache miss tunes (`false`, the default) or runs the first candidate that serves
/// the problem (`true`), from now on in this process.
pub fn defer_tuning(defer: bool) {
    DEFERRED.store(defer, Ordering::Relaxed);
}

/// Whether a miss is left untuned now.
pub(crate) fn tuning_deferred() -> bool {
    DEFERRED.load(Ordering::Relaxed)
}
