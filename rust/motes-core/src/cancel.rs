//! Cooperative cancellation of long computations (optics tables, ensemble integrals).
//!
//! A table build can take minutes (a Mie ensemble at x ~ 10⁴, thousands of size bins). A caller that
//! can be interrupted — the Python binding, which polls for Ctrl-C while the work runs on another
//! thread — calls [`request`]; the long loops poll [`requested`] once per item (a particle, a node, a
//! refinement pass) and return early. **Values computed after a request are unspecified**: whoever
//! requested must discard them, and every interruptible computation runs inside a [`Run`] so that it
//! can tell whether a request came while it ran.
//!
//! The flag is process-wide (one Ctrl-C stops every build in flight); it is cleared when the last
//! [`Run`] ends, so a request never leaks into a later computation.
//!
//! Infrastructure: implements no equation of the paper.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);
static RUNS: AtomicUsize = AtomicUsize::new(0);

/// Ask every computation in flight to stop early.
pub fn request() {
    REQUESTED.store(true, Ordering::Relaxed);
}

/// Whether a stop was requested (one relaxed load: cheap enough to poll per item).
#[inline]
pub fn requested() -> bool {
    REQUESTED.load(Ordering::Relaxed)
}

/// An interruptible computation in flight. Dropping the last one clears the request.
pub struct Run(());

impl Run {
    pub fn begin() -> Run {
        RUNS.fetch_add(1, Ordering::SeqCst);
        Run(())
    }

    /// Whether this run was asked to stop (its results must then be discarded).
    pub fn cancelled(&self) -> bool {
        requested()
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        if RUNS.fetch_sub(1, Ordering::SeqCst) == 1 {
            REQUESTED.store(false, Ordering::SeqCst);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn request_lasts_until_the_last_run_ends() {
        let a = Run::begin();
        let b = Run::begin();
        request();
        assert!(a.cancelled() && b.cancelled());
        drop(a);
        assert!(b.cancelled(), "a request holds while any run is in flight");
        drop(b);
        assert!(!requested(), "cleared when the last run ends");
    }
}
