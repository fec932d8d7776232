//! A QUIC listener's handshake slots, taken on the hub's thread as it
//! accepts each connection and given back by the handshake's task.
//!
//! The rules are the TCP accept loop's ([`super::gate`]) as far as the
//! listener can see: a source may hold only a few slots, and when every
//! slot is taken a newcomer takes the slot of a pending handshake. The hub
//! runs QUIC's handshake, so how far one got is not seen here; the time
//! since it started stands for how long it has been stuck. The victim is
//! one past [`GRACE`] before a fresher one, then one of the source holding
//! the most slots, then the oldest. Its task is told (it ends its link as
//! busy); the slot is the newcomer's at once.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Instant as StdInstant;

use tokio::sync::Notify;

use super::gate::GRACE;
use super::source::Source;

/// The slots of one listener.
pub(super) struct Slots {
    held: Mutex<Held>,
    slots: usize,
    per_source: usize,
}

#[derive(Default)]
struct Held {
    pending: Vec<Pending>,
    /// The next handshake's number (unique: it names its slot).
    next: u64,
}

/// A handshake holding a slot.
struct Pending {
    seq: u64,
    source: Source,
    peer: SocketAddr,
    since: StdInstant,
    /// Told when its slot goes to a newcomer.
    cut: Arc<Notify>,
}

/// Why a connection got no slot.
pub(super) struct Full {
    /// Handshakes its source has pending.
    pub held: usize,
}

/// A slot given to a connection, and the peer whose slot it took if all
/// were taken.
pub(super) struct Admitted {
    pub slot: Slot,
    pub evicted: Option<SocketAddr>,
}

impl Slots {
    /// `slots` in all (at least one), `per_source` for each source (at
    /// least one).
    pub(super) fn new(slots: usize, per_source: usize) -> Arc<Slots> {
        Arc::new(Slots {
            held: Mutex::new(Held::default()),
            slots: slots.max(1),
            per_source: per_source.max(1),
        })
    }

    /// How many slots it has.
    pub(super) fn capacity(&self) -> usize {
        self.slots
    }

    /// Whether half the slots or more are taken: new connections must
    /// then prove their address before they get one.
    pub(super) fn crowded(&self) -> bool {
        2 * self.held().pending.len() >= self.slots
    }

    fn held(&self) -> std::sync::MutexGuard<'_, Held> {
        self.held.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// A slot for a connection from `peer`, evicting a pending handshake
    /// if all are taken; refused if its source has all it may have.
    /// Never waits: it runs on the hub's thread.
    pub(super) fn admit(
        self: &Arc<Self>,
        peer: SocketAddr,
        now: StdInstant,
    ) -> Result<Admitted, Full> {
        let source = Source::of(peer.ip());
        let mut held = self.held();
        let from_source = held.pending.iter().filter(|p| p.source == source).count();
        if from_source >= self.per_source {
            return Err(Full { held: from_source });
        }
        let evicted = if held.pending.len() >= self.slots {
            victim(&held.pending, now).map(|i| {
                let gone = held.pending.swap_remove(i);
                // Stored if its task is not waiting yet: it sees it first.
                gone.cut.notify_one();
                gone.peer
            })
        } else {
            None
        };
        let seq = held.next;
        held.next += 1;
        let cut = Arc::new(Notify::new());
        held.pending.push(Pending {
            seq,
            source,
            peer,
            since: now,
            cut: Arc::clone(&cut),
        });
        Ok(Admitted {
            slot: Slot {
                slots: Arc::clone(self),
                seq,
                cut,
            },
            evicted,
        })
    }
}

/// Which pending handshake loses its slot (see the module's notes).
fn victim(pending: &[Pending], now: StdInstant) -> Option<usize> {
    // A few dozen slots: counting by scanning beats hashing.
    let held_by = |source: Source| pending.iter().filter(|p| p.source == source).count();
    pending
        .iter()
        .enumerate()
        .min_by_key(|(_, p)| {
            let age = now.saturating_duration_since(p.since);
            (
                age < GRACE,
                std::cmp::Reverse(held_by(p.source)),
                std::cmp::Reverse(age),
                p.seq,
            )
        })
        .map(|(i, _)| i)
}

/// One handshake's slot: given back when released or dropped, whichever
/// comes first, unless a newcomer took it before.
pub(super) struct Slot {
    slots: Arc<Slots>,
    seq: u64,
    cut: Arc<Notify>,
}

impl Slot {
    /// Resolves once a newcomer has taken this slot.
    pub(super) async fn cut(&self) {
        self.cut.notified().await;
    }

    /// Gives the slot back: `false` if a newcomer had taken it already.
    pub(super) fn release(self) -> bool {
        self.give_back()
    }

    fn give_back(&self) -> bool {
        let mut held = self.slots.held();
        match held.pending.iter().position(|p| p.seq == self.seq) {
            Some(i) => {
                held.pending.swap_remove(i);
                true
            }
            None => false,
        }
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        // A second time finds nothing: the slot is given back once.
        self.give_back();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration as StdDuration;

    fn peer(ip: &str) -> SocketAddr {
        format!("{ip}:4433").parse().expect("an address")
    }

    #[test]
    fn a_source_gets_at_most_its_share_and_slots_come_back_once() {
        let slots = Slots::new(8, 2);
        let t = StdInstant::now();
        let a = slots.admit(peer("192.0.2.1"), t).ok().expect("a slot");
        let b = slots.admit(peer("192.0.2.1"), t).ok().expect("a slot");
        let refused = slots.admit(peer("192.0.2.1"), t).err().expect("refused");
        assert_eq!(refused.held, 2);
        // Another source is not held back by this one.
        let other = slots.admit(peer("192.0.2.2"), t).ok().expect("a slot");
        assert!(a.slot.release());
        drop(b);
        drop(other);
        assert!(slots.held().pending.is_empty());
        let again = slots.admit(peer("192.0.2.1"), t).ok().expect("a slot");
        assert!(again.evicted.is_none());
    }

    #[test]
    fn half_the_slots_taken_is_crowded() {
        let slots = Slots::new(4, 8);
        let t = StdInstant::now();
        let a = slots.admit(peer("192.0.2.1"), t).ok().expect("a slot");
        assert!(!slots.crowded());
        let b = slots.admit(peer("192.0.2.2"), t).ok().expect("a slot");
        assert!(slots.crowded());
        drop(a);
        assert!(!slots.crowded());
        drop(b);
    }

    #[test]
    fn a_newcomer_takes_the_slot_of_the_oldest_of_the_busiest_source() {
        let slots = Slots::new(3, 8);
        let t0 = StdInstant::now();
        let later = |ms| t0 + StdDuration::from_millis(ms);
        let lone = slots.admit(peer("192.0.2.1"), t0).ok().expect("a slot");
        let first = slots
            .admit(peer("192.0.2.2"), later(10))
            .ok()
            .expect("a slot");
        let second = slots
            .admit(peer("192.0.2.2"), later(20))
            .ok()
            .expect("a slot");
        let came = slots
            .admit(peer("192.0.2.3"), later(500))
            .ok()
            .expect("a slot");
        // The oldest of the source with two slots, not the oldest of all.
        assert_eq!(came.evicted, Some(peer("192.0.2.2")));
        assert!(!first.slot.release(), "its slot went to the newcomer");
        assert!(second.slot.release());
        drop(lone);
        drop(came);
        assert!(slots.held().pending.is_empty());
    }

    #[test]
    fn a_fresh_handshake_goes_after_older_ones() {
        let slots = Slots::new(2, 8);
        let t0 = StdInstant::now();
        let old = slots.admit(peer("192.0.2.1"), t0).ok().expect("a slot");
        let at = t0 + StdDuration::from_secs(1);
        let fresh = slots
            .admit(peer("192.0.2.2"), at - GRACE / 2)
            .ok()
            .expect("a slot");
        let came = slots.admit(peer("192.0.2.3"), at).ok().expect("a slot");
        assert_eq!(came.evicted, Some(peer("192.0.2.1")));
        assert!(!old.slot.release());
        assert!(fresh.slot.release());
    }

    #[tokio::test]
    async fn an_evicted_slot_hears_it_even_before_it_waits() {
        let slots = Slots::new(1, 8);
        let t0 = StdInstant::now();
        let old = slots.admit(peer("192.0.2.1"), t0).ok().expect("a slot");
        let _came = slots
            .admit(peer("192.0.2.2"), t0 + StdDuration::from_secs(1))
            .ok()
            .expect("a slot");
        tokio::time::timeout(StdDuration::from_secs(1), old.slot.cut())
            .await
            .expect("told");
    }
}
