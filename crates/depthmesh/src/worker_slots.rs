//! Scratch space per rayon worker thread, each behind a lock that only its
//! own thread takes: parallel loops reuse their buffers across frames
//! without allocating and without contention.

use std::sync::{Mutex, MutexGuard, PoisonError};

/// The calling worker thread's slot of `slots` (slots are shared out by
/// thread index, so with one per thread each lock is only ever taken
/// uncontended), locked. A lock poisoned by a panic elsewhere is taken
/// anyway: slots are scratch, written before they are read.
pub(crate) fn lock_own<T>(slots: &[Mutex<T>]) -> MutexGuard<'_, T> {
    let slot = rayon::current_thread_index().unwrap_or(0) % slots.len();
    slots[slot].lock().unwrap_or_else(PoisonError::into_inner)
}
