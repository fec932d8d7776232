//! The links a listener serves at once
//! ([`Listener::with_max_links`](super::Listener::with_max_links)): a link
//! takes a seat when its handshake completes and gives it back when it is
//! dropped; a link that has ended (its peer closed, went silent, …) no
//! longer counts, even while the application still holds it.

use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use ndr_core::endpoint::Phase;

use crate::hub::Shared;

/// The seats of one listener.
#[derive(Default)]
pub(crate) struct Seats {
    /// Most links alive at once; 0: no limit.
    max: AtomicUsize,
    /// The links holding a seat, by key, with what shows whether they ended.
    held: Mutex<Vec<(u64, Arc<Shared>)>>,
    next: AtomicU64,
}

impl Seats {
    /// Serves at most `max` links at once (0: no limit).
    pub(crate) fn set_max(&self, max: usize) {
        self.max.store(max, Ordering::Relaxed);
    }

    /// A seat for the link whose state is `shared`, unless as many links
    /// as allowed are alive.
    pub(crate) fn take(self: &Arc<Self>, shared: &Arc<Shared>) -> Option<Seat> {
        let mut held = self.held.lock().unwrap_or_else(PoisonError::into_inner);
        let max = self.max.load(Ordering::Relaxed);
        if max != 0 && held.iter().filter(|(_, s)| !ended(s)).count() >= max {
            return None;
        }
        let key = self.next.fetch_add(1, Ordering::Relaxed);
        held.push((key, Arc::clone(shared)));
        Some(Seat {
            seats: Arc::clone(self),
            key,
        })
    }
}

/// Whether the hub has closed the link: it publishes the link's last
/// stats, in the closed phase, before letting it go.
fn ended(shared: &Shared) -> bool {
    shared
        .stats
        .lock()
        .unwrap_or_else(PoisonError::into_inner)
        .is_some_and(|s| s.phase == Phase::Closed)
}

/// A link's place among those its listener serves; given back on drop.
pub(crate) struct Seat {
    seats: Arc<Seats>,
    key: u64,
}

impl Drop for Seat {
    fn drop(&mut self) {
        let mut held = self
            .seats
            .held
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if let Some(i) = held.iter().position(|(k, _)| *k == self.key) {
            held.swap_remove(i);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::sync::Notify;

    fn shared() -> Arc<Shared> {
        Arc::new(Shared {
            sample: Mutex::new((Vec::new(), false)),
            stats: Mutex::new(None),
            notify: Notify::new(),
            peer_chain: Mutex::new(None),
        })
    }

    #[test]
    fn seats_are_limited_and_given_back_on_drop() {
        let seats = Arc::new(Seats::default());
        let (a, b) = (shared(), shared());
        // No limit by default.
        let many: Vec<Seat> = (0..5).filter_map(|_| seats.take(&a)).collect();
        assert_eq!(many.len(), 5);
        drop(many);
        seats.set_max(1);
        let first = seats.take(&a).expect("a free seat");
        assert!(seats.take(&b).is_none());
        drop(first);
        let second = seats.take(&b).expect("the seat given back");
        assert!(seats.take(&a).is_none());
        // (A link that ended frees its seat while held: tests/link_availability.rs.)
        drop(second);
    }
}
