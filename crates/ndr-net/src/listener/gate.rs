//! The listener's accept loop and the handshakes it runs: what a
//! connection gets before it has authenticated.
//!
//! A connection takes one of a fixed number of slots until its handshakes
//! are done, within one budget of time. No connection is turned away for
//! want of a slot: a newcomer always gets one, and the one it takes is
//! chosen so that a peer that completes its handshake promptly keeps its
//! own.
//!
//! - A source (an IPv4 address, an IPv6 /64) may hold only a few slots.
//!   A newcomer from a source that holds all it may takes the slot of one
//!   of that source's handshakes: one that has not yet sent its whole first
//!   message before one that has, before one past TLS; among equals, one
//!   that has not got any further for a while ([`GRACE`]) before a fresher
//!   one, then the one stuck longest. A real peer sends its first message
//!   whole at once, so silent or trickling connections from its own
//!   address (the same NAT, or clients of the same relay), however fast
//!   they come back, are evicted before it.
//! - When every slot is taken, the newcomer takes the slot of a handshake
//!   that has not got any further for a while if there is one: of those,
//!   the one that has got least far (silent, part of its first message,
//!   all of it, past TLS), then one of the source holding the most slots,
//!   then the one stuck longest. If all have moved lately, one of the
//!   source holding the most slots goes, the one stuck longest. Silent or
//!   trickling connections, or a flood from a few sources, evict each other
//!   before a real peer.
//!
//! The peer whose slot is taken is told why (a Close with reason
//! `EVICTED_SOURCE` or `EVICTED`) where it can be: on a plain link at any
//! stage, under TLS once its TLS handshake is done. Until its first message
//! is whole, a connection reaches neither TLS nor the hub.

use std::net::SocketAddr;
use std::sync::{Arc, PoisonError, Weak};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;
use tokio::task::{AbortHandle, Id, JoinError, JoinSet};

use super::first::{self, Said};
use super::handshake::{Progress, handshake, stage};
use super::source::Source;
use super::{Common, Refusal};
use crate::link::Link;

/// How long the loop waits after the kernel could not hand over a
/// connection (out of descriptors or memory) before it tries again: the
/// condition lasts, and retrying at once would spin.
const ACCEPT_BACKOFF: StdDuration = StdDuration::from_millis(20);
/// A handshake that has not got any further for this long is the first
/// to lose its slot: a real peer moves on within a round trip or two.
pub(super) const GRACE: StdDuration = StdDuration::from_millis(100);

/// A handshake under way; `T` is its task's handle.
struct Pending<T> {
    task: T,
    peer: SocketAddr,
    source: Source,
    /// Order of arrival: lower is older.
    seq: u64,
    progress: Arc<Progress>,
}

/// A handshake task: its id, and how to cancel it.
type Task = (Id, AbortHandle);

/// Whose slot a newcomer takes, and why.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Evict {
    /// Its index among the pending handshakes.
    index: usize,
    /// For the newcomer's source's cap (else every slot was taken).
    per_source: bool,
}

/// The slot a newcomer from `source` takes at `now`, if it must take one:
/// its source holds `per_source` slots already, or all `slots` are taken.
/// At most one: a slot taken for the source's cap is also one more free.
fn make_room<T>(
    pending: &[Pending<T>],
    source: Source,
    slots: usize,
    per_source: usize,
    now: StdInstant,
) -> Option<Evict> {
    let held = pending.iter().filter(|p| p.source == source).count();
    if held >= per_source {
        return source_victim(pending, source, now).map(|index| Evict {
            index,
            per_source: true,
        });
    }
    if pending.len() >= slots {
        return victim(pending, now).map(|index| Evict {
            index,
            per_source: false,
        });
    }
    None
}

/// Which of `source`'s handshakes loses its slot (see the module's notes).
fn source_victim<T>(pending: &[Pending<T>], source: Source, now: StdInstant) -> Option<usize> {
    pending
        .iter()
        .enumerate()
        .filter(|(_, p)| p.source == source)
        .min_by_key(|(_, p)| {
            let stuck = p.progress.stuck_for(now);
            // Part of a first message is no more than none: a trickle is
            // not a peer about to speak.
            let said = match p.progress.stage() {
                stage::SILENT | stage::SPEAKING => 0,
                stage::SPOKEN => 1,
                _ => 2,
            };
            (said, stuck < GRACE, std::cmp::Reverse(stuck), p.seq)
        })
        .map(|(i, _)| i)
}

/// Which handshake loses its slot when every slot is taken (see the
/// module's notes).
fn victim<T>(pending: &[Pending<T>], now: StdInstant) -> Option<usize> {
    // A few dozen slots: counting by scanning beats hashing.
    let held_by = |source: Source| pending.iter().filter(|p| p.source == source).count();
    pending
        .iter()
        .enumerate()
        .min_by_key(|(_, p)| {
            let held = held_by(p.source);
            let stuck = p.progress.stuck_for(now);
            let fresh = stuck < GRACE;
            // Among fresh ones how far they got says little (a newcomer
            // has not had the time to speak).
            let stage = if fresh { 0 } else { p.progress.stage() };
            (
                fresh,
                stage,
                std::cmp::Reverse(held),
                std::cmp::Reverse(stuck),
                p.seq,
            )
        })
        .map(|(i, _)| i)
}

/// The accept loop's state, owned by its task.
pub(super) struct Gate {
    listener: TcpListener,
    /// Weak: a listener dropped while its runtime does not run (a
    /// current-thread runtime) must still let its hub go.
    common: Weak<Common>,
    ready: mpsc::Sender<Link>,
    handshakes: JoinSet<()>,
    pending: Vec<Pending<Task>>,
    next_seq: u64,
    slots: usize,
    per_source: usize,
    /// Where its handshakes count time from.
    epoch: StdInstant,
}

impl Gate {
    pub(super) fn new(
        listener: TcpListener,
        common: &Arc<Common>,
        ready: mpsc::Sender<Link>,
        slots: usize,
    ) -> Gate {
        Gate {
            listener,
            common: Arc::downgrade(common),
            ready,
            handshakes: JoinSet::new(),
            pending: Vec::new(),
            next_seq: 0,
            // At least one, or no connection could ever be served.
            slots: slots.max(1),
            per_source: common.config.admission.max_pending_per_source.max(1),
            epoch: StdInstant::now(),
        }
    }

    /// Accepts until the listener is dropped or its socket fails.
    pub(super) async fn run(mut self) {
        loop {
            tokio::select! {
                // Finished handshakes first: they free slots.
                biased;
                Some(done) = self.handshakes.join_next_with_id(), if !self.handshakes.is_empty() => {
                    self.finished(done);
                }
                accepted = self.listener.accept() => {
                    let Some(common) = self.common.upgrade() else {
                        return;
                    };
                    match accepted {
                        Ok((stream, peer)) => self.admit(&common, stream, peer),
                        Err(e) => match e.kind() {
                            // The socket no longer listens (the listener was
                            // dropped, or shut down by someone else).
                            std::io::ErrorKind::InvalidInput => {
                                *common.stopped.lock().unwrap_or_else(PoisonError::into_inner) =
                                    Some(e.to_string());
                                return;
                            }
                            // That one peer left before it was accepted.
                            std::io::ErrorKind::ConnectionAborted
                            | std::io::ErrorKind::ConnectionReset
                            | std::io::ErrorKind::Interrupted
                            | std::io::ErrorKind::WouldBlock => {}
                            _ => {
                                common.refuse(
                                    Refusal::AcceptError,
                                    None,
                                    &format_args!(
                                        "cannot accept a connection: {e} (raise the process's \
                                         open-file limit if it ran out of descriptors)"
                                    ),
                                );
                                drop(common);
                                tokio::time::sleep(ACCEPT_BACKOFF).await;
                            }
                        },
                    }
                }
            }
        }
    }

    /// A handshake task ended (or was aborted): its slot is free.
    fn finished(&mut self, done: Result<(Id, ()), JoinError>) {
        let id = match &done {
            Ok((id, ())) => *id,
            Err(e) => e.id(),
        };
        let peer = self.pending.iter().find(|p| p.task.0 == id).map(|p| p.peer);
        self.pending.retain(|p| p.task.0 != id);
        if let Err(e) = done
            && e.is_panic()
            && let Some(common) = self.common.upgrade()
        {
            common.refuse(
                Refusal::Other,
                peer,
                &format_args!("its handshake task failed: {e}"),
            );
        }
    }

    /// Gives a new connection a slot, taking another's if it must.
    fn admit(&mut self, common: &Arc<Common>, stream: TcpStream, peer: SocketAddr) {
        // Handshakes that ended since the last look give their slots back
        // before anyone is evicted for want of one.
        while let Some(done) = self.handshakes.try_join_next_with_id() {
            self.finished(done);
        }
        let heard = match first::said(&stream, common.tls.is_some()) {
            Said::Heard(heard) => heard,
            Said::Closed => {
                // Gone already (a scan, a reset): no slot for it.
                drop(stream);
                common.refuse(Refusal::Other, peer, &"it closed before saying anything");
                return;
            }
        };
        let source = Source::of(peer.ip());
        let now = StdInstant::now();
        if let Some(evict) = make_room(&self.pending, source, self.slots, self.per_source, now) {
            self.evict(common, evict);
        }
        // What it sent before it was accepted counts at once: its task may
        // not run before the next eviction is decided.
        let progress = Arc::new(Progress::at(self.epoch, heard, now));
        let task = self.handshakes.spawn(handshake(
            Arc::clone(common),
            stream,
            peer,
            Arc::clone(&progress),
            self.ready.clone(),
        ));
        self.pending.push(Pending {
            task: (task.id(), task),
            peer,
            source,
            seq: self.next_seq,
            progress,
        });
        self.next_seq += 1;
    }

    /// Frees the slot `evict` names: its task ends, telling its peer why.
    fn evict(&mut self, common: &Common, evict: Evict) {
        if evict.index >= self.pending.len() {
            return;
        }
        let gone = self.pending.swap_remove(evict.index);
        gone.progress.cut(evict.per_source);
        gone.task.1.abort();
        if evict.per_source {
            common.refuse(
                Refusal::PerSource,
                gone.peer,
                &format_args!(
                    "its handshake was cut short to make room for a newer connection from its \
                     source, which had {} handshakes pending, the most one source may have \
                     (LinkConfig::admission.max_pending_per_source), and it had said least \
                     for longest",
                    self.per_source
                ),
            );
        } else {
            common.refuse(
                Refusal::Evicted,
                gone.peer,
                &format_args!(
                    "its handshake was cut short to make room: all {} handshake slots were \
                     taken (TlsConfig::max_pending_handshakes), and it had got least far for \
                     longest",
                    self.slots
                ),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::listener::first::Heard;

    fn source(ip: &str) -> Source {
        Source::of(ip.parse().expect("an address"))
    }

    /// The pending handshakes of a test, as the gate keeps them, with a
    /// clock of their own.
    struct Table {
        epoch: StdInstant,
        pending: Vec<Pending<()>>,
        next: u64,
    }

    impl Table {
        fn new() -> Table {
            Table {
                epoch: StdInstant::now(),
                pending: Vec::new(),
                next: 0,
            }
        }

        fn at(&self, ms: u64) -> StdInstant {
            self.epoch + StdDuration::from_millis(ms)
        }

        /// A connection from `ip` accepted at `ms`, having sent `heard`;
        /// its number.
        fn accept(&mut self, ip: &str, heard: Heard, ms: u64) -> u64 {
            let seq = self.next;
            self.next += 1;
            self.pending.push(Pending {
                task: (),
                peer: format!("{ip}:{}", 1000 + seq).parse().expect("an address"),
                source: source(ip),
                seq,
                progress: Arc::new(Progress::at(self.epoch, heard, self.at(ms))),
            });
            seq
        }

        fn advance(&self, seq: u64, to: u8, ms: u64) {
            let p = self.pending.iter().find(|p| p.seq == seq).expect("pending");
            p.progress.advance_at(to, 0, self.at(ms));
        }

        /// What a newcomer from `ip` at `ms` does: the number of the
        /// handshake whose slot it takes, and whether for its source's
        /// cap. The newcomer itself is not added.
        fn room(
            &mut self,
            ip: &str,
            slots: usize,
            per_source: usize,
            ms: u64,
        ) -> Option<(u64, bool)> {
            let evict = make_room(&self.pending, source(ip), slots, per_source, self.at(ms))?;
            let gone = self.pending.swap_remove(evict.index);
            Some((gone.seq, evict.per_source))
        }

        /// `room`, then the newcomer takes the slot (silent, at `ms`).
        fn admit(
            &mut self,
            ip: &str,
            slots: usize,
            per_source: usize,
            ms: u64,
        ) -> (Option<(u64, bool)>, u64) {
            let gone = self.room(ip, slots, per_source, ms);
            (gone, self.accept(ip, Heard::Nothing, ms))
        }
    }

    #[test]
    fn below_both_caps_no_one_is_evicted() {
        let mut t = Table::new();
        for k in 0..3 {
            t.accept("192.0.2.1", Heard::Nothing, k);
        }
        assert_eq!(t.room("192.0.2.1", 8, 4, 10), None);
        assert_eq!(t.room("192.0.2.2", 4, 8, 10), None);
    }

    #[test]
    fn at_its_cap_a_source_gives_up_its_own_stalest_slot_and_no_other() {
        let mut t = Table::new();
        let other = t.accept("192.0.2.9", Heard::Nothing, 0);
        let first = t.accept("192.0.2.1", Heard::Nothing, 10);
        let second = t.accept("192.0.2.1", Heard::Nothing, 20);
        // The other source's handshake is older and silent, but not the
        // newcomer's source's: it stays.
        assert_eq!(t.room("192.0.2.1", 64, 2, 500), Some((first, true)));
        t.accept("192.0.2.1", Heard::Nothing, 500);
        assert_eq!(t.room("192.0.2.1", 64, 2, 600), Some((second, true)));
        assert!(t.pending.iter().any(|p| p.seq == other));
    }

    #[test]
    fn a_base_that_spoke_outlasts_any_number_of_silent_newcomers_from_its_address() {
        // An attacker at the base's address reopens each dropped
        // connection at once: all of its connections are fresh.
        let mut t = Table::new();
        let per_source = 8;
        let mut ms = 0;
        for _ in 0..per_source {
            t.admit("192.0.2.1", 64, per_source, ms);
        }
        // The base's Hello is whole when it is accepted; it goes on the
        // hub a moment later.
        ms += 1;
        assert!(t.room("192.0.2.1", 64, per_source, ms).is_some());
        let base = t.accept("192.0.2.1", Heard::Whole, ms);
        t.advance(base, stage::ON_HUB, ms + 1);
        // Thousands of newcomers, one every 10 µs, then slow ones: each
        // takes a silent one's slot, never the base's.
        for k in 0..5000u64 {
            let at = ms + 1 + k / 100;
            let (gone, _) = t.admit("192.0.2.1", 64, per_source, at);
            let (seq, per_source_cap) = gone.expect("at the cap");
            assert!(per_source_cap);
            assert_ne!(seq, base, "evicted at {at} ms");
        }
        assert!(t.pending.iter().any(|p| p.seq == base));
        // The same with the base still waiting for its Hello to be read
        // whole (only the gate's peek saw it) and stale: silent ones go
        // first all the same.
        let mut t = Table::new();
        for _ in 0..per_source - 1 {
            t.admit("192.0.2.1", 64, per_source, 0);
        }
        let base = t.accept("192.0.2.1", Heard::Whole, 0);
        for k in 0..1000 {
            let (gone, _) = t.admit("192.0.2.1", 64, per_source, 1000 + k);
            assert_ne!(gone.map(|g| g.0), Some(base));
        }
    }

    #[test]
    fn within_a_source_stale_silence_goes_before_a_fresh_newcomer_and_a_trickle_counts_as_silence()
    {
        let mut t = Table::new();
        let trickle = t.accept("192.0.2.1", Heard::Part(None), 0);
        let fresh = t.accept("192.0.2.1", Heard::Nothing, 950);
        // At 1 s the trickle has been stuck for 1 s, the newcomer 50 ms.
        assert_eq!(t.room("192.0.2.1", 64, 2, 1000), Some((trickle, true)));
        t.accept("192.0.2.1", Heard::Nothing, 1000);
        // Two fresh silent ones: the one stuck longest goes.
        assert_eq!(t.room("192.0.2.1", 64, 2, 1010), Some((fresh, true)));
    }

    #[test]
    fn at_the_global_cap_the_stalest_of_the_busiest_source_goes() {
        let mut t = Table::new();
        let lone = t.accept("192.0.2.1", Heard::Nothing, 0);
        let a = t.accept("192.0.2.2", Heard::Nothing, 10);
        let _b = t.accept("192.0.2.2", Heard::Nothing, 20);
        // All stale and silent: the source holding two loses its oldest.
        assert_eq!(t.room("192.0.2.3", 3, 8, 500), Some((a, false)));
        t.accept("192.0.2.3", Heard::Nothing, 500);
        // Stale ones before fresh ones, whatever their source: the lone
        // stale one goes before the fresh newcomer.
        assert_eq!(t.room("192.0.2.4", 3, 8, 550), Some((lone, false)));
    }

    #[test]
    fn a_newcomer_at_its_source_cap_when_all_slots_are_taken_evicts_only_once() {
        let mut t = Table::new();
        t.accept("192.0.2.1", Heard::Nothing, 0);
        t.accept("192.0.2.2", Heard::Nothing, 0);
        let mine = t.accept("192.0.2.3", Heard::Nothing, 0);
        // Three slots, one per source: a newcomer from 192.0.2.3 takes its
        // own source's, and that frees the slot it needs.
        assert_eq!(t.room("192.0.2.3", 3, 1, 500), Some((mine, true)));
        t.accept("192.0.2.3", Heard::Nothing, 500);
        assert_eq!(t.pending.len(), 3);
    }
}
