//! What the join loop and a bridge's two threads share: [`Flags`], each behind its own
//! atomic or lock, and how often they look again while they wait.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::time::{Duration, Instant};

/// How often a waiting thread looks again.
pub(super) const POLL: Duration = Duration::from_millis(20);

/// Flags the join loop and the bridge's threads share.
#[derive(Default)]
pub(super) struct Flags {
    /// The actors have stopped: send what is left, then say done.
    pub(super) finishing: AtomicBool,
    /// The central host is gone for good: drain the actors' steps without sending them.
    pub(super) abandon: AtomicBool,
    /// The run ordered the actors to stop.
    pub(super) stop_ordered: AtomicBool,
    /// Since when the central host's presence has not been seen (None while it is).
    pub(super) central_gone_since: Mutex<Option<Instant>>,
    /// Times the central host's presence came back (or first came): parcels it may not
    /// have taken are sent again.
    pub(super) central_returns: AtomicU64,
    /// Stop the down thread.
    pub(super) closed: AtomicBool,
}

pub(super) fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|e| e.into_inner())
}
