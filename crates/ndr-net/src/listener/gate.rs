//! The listener's accept loop and the handshakes it runs: what a
//! connection gets before it has authenticated.
//!
//! A connection takes one of a fixed number of slots until its handshakes
//! are done, within one budget of time. A newcomer takes another's slot
//! when it must, chosen so that a peer that completes its handshake
//! promptly keeps its own.
//!
//! - A source (an IPv4 address, an IPv6 /64) may hold only a few slots.
//!   A newcomer from a source that holds all it may takes the slot of one
//!   of that source's handshakes: one that has not yet sent its whole first
//!   message before one that has, before one past TLS; among equals, one
//!   that has not got any further for a while ([`GRACE`]) before a fresher
//!   one, then the one stuck longest. It takes it only if that one has said
//!   less than the newcomer, or as much and is stale: never the slot of one
//!   that has said more. Else a newcomer that has sent its
//!   whole first message is turned away (told why, on a plain link), and
//!   one that has not waits on probation ([`super::probation`]) for it: a
//!   real peer's first message may be a moment behind its connection. So
//!   every handshake of a source has a grace in which newcomers that say no
//!   more than it cannot take its slot, and a real peer, which sends its
//!   first message whole at once, keeps its slot against silent or
//!   trickling connections from its own address (the same NAT, or clients
//!   of the same relay), however fast they come back; its whole message
//!   takes one of theirs at once.
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

use super::first::{self, Heard, Said};
use super::handshake::{Progress, handshake, stage};
use super::probation::{self, Ended, Probation};
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

/// Newcomers that may wait on probation at once, per handshake slot.
const PROBATION_PER_SLOT: usize = 4;

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

/// What a newcomer gets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Room {
    /// A free slot.
    Free,
    /// Another's slot.
    Take(Evict),
    /// None: its source holds `held` slots, each of a handshake that has
    /// said as much as it and moved lately.
    Refused { held: usize },
}

/// How far a handshake at `stage` has said its first message, for the cap
/// per source: part of one is no more than none (a trickle is not a peer
/// about to speak).
fn said(stage: u8) -> u8 {
    match stage {
        stage::SILENT | stage::SPEAKING => 0,
        stage::SPOKEN => 1,
        _ => 2,
    }
}

/// What a newcomer from `source` that has said `stage` of its first
/// message gets at `now`: a free slot; else, if its source holds
/// `per_source` slots, the slot of [`source_victim`] if that one has said
/// less than the newcomer, or as much and not moved for [`GRACE`], or
/// none; else, if
/// all `slots` are taken, the slot of [`victim`]. At most one slot is
/// taken: one taken for the source's cap is also one more free.
fn make_room<T>(
    pending: &[Pending<T>],
    source: Source,
    stage: u8,
    slots: usize,
    per_source: usize,
    now: StdInstant,
) -> Room {
    let held = pending.iter().filter(|p| p.source == source).count();
    if held >= per_source {
        let Some(index) = source_victim(pending, source, now) else {
            return Room::Refused { held };
        };
        let p = pending.get(index).map(|p| &p.progress);
        let gives_way = p.is_some_and(|p| {
            let (theirs, ours) = (said(p.stage()), said(stage));
            theirs < ours || (theirs == ours && p.stuck_for(now) >= GRACE)
        });
        return if gives_way {
            Room::Take(Evict {
                index,
                per_source: true,
            })
        } else {
            Room::Refused { held }
        };
    }
    if pending.len() >= slots
        && let Some(index) = victim(pending, now)
    {
        return Room::Take(Evict {
            index,
            per_source: false,
        });
    }
    Room::Free
}

/// Which of `source`'s handshakes gives way to a newcomer of the same
/// source: the one that has said least, then a stale one before a fresh
/// one, then the one stuck longest.
fn source_victim<T>(pending: &[Pending<T>], source: Source, now: StdInstant) -> Option<usize> {
    pending
        .iter()
        .enumerate()
        .filter(|(_, p)| p.source == source)
        .min_by_key(|(_, p)| {
            let stuck = p.progress.stuck_for(now);
            (
                said(p.progress.stage()),
                stuck < GRACE,
                std::cmp::Reverse(stuck),
                p.seq,
            )
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
    /// Newcomers that wait for their first message without a slot.
    probation: Probation,
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
            // As many as the slots, a few times over: each costs a socket
            // and a small task, for a tenth of a second.
            probation: Probation::new(PROBATION_PER_SLOT * slots.max(1), common.tls.is_some()),
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
                Some(ended) = self.probation.next(), if !self.probation.is_empty() => {
                    let Some(common) = self.common.upgrade() else {
                        return;
                    };
                    self.probation_ended(&common, ended);
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

    /// Looks at what a new connection has said, then [`place`](Self::place)s it.
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
        self.place(common, stream, peer, heard);
    }

    /// Gives a connection whose peer has said `heard` a slot, taking
    /// another's if it must; or puts it on probation, or turns it away.
    fn place(&mut self, common: &Arc<Common>, stream: TcpStream, peer: SocketAddr, heard: Heard) {
        let source = Source::of(peer.ip());
        let now = StdInstant::now();
        let stage = stage::of(heard);
        match make_room(
            &self.pending,
            source,
            stage,
            self.slots,
            self.per_source,
            now,
        ) {
            Room::Free => {}
            Room::Take(evict) => self.evict(common, evict),
            Room::Refused { .. } if said(stage) == 0 => {
                if let Some(gone) = self.probation.admit(stream, peer) {
                    common.refuse(
                        Refusal::PerSource,
                        gone,
                        &"its source held all the handshake slots it may \
                          (LinkConfig::admission.max_pending_per_source), and it gave its place \
                          on probation to a newer connection before its first message was whole",
                    );
                }
                return;
            }
            Room::Refused { held } => {
                probation::refuse(stream, common.tls.is_none());
                common.refuse(
                    Refusal::PerSource,
                    peer,
                    &format_args!(
                        "{held} handshakes from its source are already pending, the most one \
                         source may have (LinkConfig::admission.max_pending_per_source), each \
                         having said as much as it and moved within {GRACE:?}"
                    ),
                );
                return;
            }
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

    /// A newcomer's probation ended: a slot if it spoke, else counted.
    fn probation_ended(&mut self, common: &Arc<Common>, ended: Ended) {
        match ended {
            Ended::Spoke(stream, peer) => self.place(common, stream, peer, Heard::Whole),
            Ended::Silent(peer) => common.refuse(
                Refusal::PerSource,
                peer,
                &format_args!(
                    "its source held all the handshake slots it may \
                     (LinkConfig::admission.max_pending_per_source), and its first message was \
                     not whole within {:?} on probation",
                    probation::PROBATION
                ),
            ),
            Ended::Left(peer) => {
                common.refuse(Refusal::Other, peer, &"it closed before its first message");
            }
        }
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

    fn source(ip: &str) -> Source {
        Source::of(ip.parse().expect("an address"))
    }

    /// The pending handshakes of a test, as the gate keeps them, with a
    /// clock of their own.
    struct Table {
        epoch: StdInstant,
        pending: Vec<Pending<()>>,
        next: u64,
        slots: usize,
        per_source: usize,
    }

    /// What a newcomer got: the number of the handshake whose slot it took
    /// and whether for its source's cap, or a refusal.
    #[derive(Debug, PartialEq, Eq)]
    enum Got {
        Free,
        Took(u64, bool),
        Refused,
    }

    impl Table {
        fn new(slots: usize, per_source: usize) -> Table {
            Table {
                epoch: StdInstant::now(),
                pending: Vec::new(),
                next: 0,
                slots,
                per_source,
            }
        }

        fn at(&self, ms: u64) -> StdInstant {
            self.epoch + StdDuration::from_millis(ms)
        }

        /// A connection from `ip` given a slot at `ms`, having sent
        /// `heard`; its number.
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

        fn has(&self, seq: u64) -> bool {
            self.pending.iter().any(|p| p.seq == seq)
        }

        /// A newcomer from `ip` at `ms` having sent `heard`, as the gate
        /// admits it: what it got, and its number if it got a slot.
        fn come(&mut self, ip: &str, heard: Heard, ms: u64) -> (Got, Option<u64>) {
            let room = make_room(
                &self.pending,
                source(ip),
                stage::of(heard),
                self.slots,
                self.per_source,
                self.at(ms),
            );
            let got = match room {
                Room::Free => Got::Free,
                Room::Refused { .. } => return (Got::Refused, None),
                Room::Take(evict) => {
                    let gone = self.pending.swap_remove(evict.index);
                    Got::Took(gone.seq, evict.per_source)
                }
            };
            (got, Some(self.accept(ip, heard, ms)))
        }
    }

    #[test]
    fn below_both_caps_a_newcomer_gets_a_free_slot() {
        let mut t = Table::new(8, 4);
        for k in 0..3 {
            t.accept("192.0.2.1", Heard::Nothing, k);
        }
        assert_eq!(t.come("192.0.2.1", Heard::Nothing, 10).0, Got::Free);
        let mut t = Table::new(4, 8);
        for k in 0..3 {
            t.accept("192.0.2.1", Heard::Nothing, k);
        }
        assert_eq!(t.come("192.0.2.2", Heard::Nothing, 10).0, Got::Free);
    }

    #[test]
    fn at_its_cap_a_source_gives_up_its_own_stalest_slot_and_no_other() {
        let mut t = Table::new(64, 2);
        let other = t.accept("192.0.2.9", Heard::Nothing, 0);
        let first = t.accept("192.0.2.1", Heard::Nothing, 10);
        let second = t.accept("192.0.2.1", Heard::Nothing, 20);
        // The other source's handshake is older and silent, but not the
        // newcomer's source's: it stays.
        assert_eq!(
            t.come("192.0.2.1", Heard::Nothing, 500).0,
            Got::Took(first, true)
        );
        assert_eq!(
            t.come("192.0.2.1", Heard::Nothing, 600).0,
            Got::Took(second, true)
        );
        assert!(t.has(other));
    }

    #[test]
    fn a_silent_newcomer_takes_only_a_stale_slot_of_its_source_and_is_refused_otherwise() {
        let mut t = Table::new(64, 2);
        let a = t.accept("192.0.2.1", Heard::Nothing, 0);
        let b = t.accept("192.0.2.1", Heard::Nothing, 50);
        // Both moved within the grace: no slot for another silent one.
        assert_eq!(t.come("192.0.2.1", Heard::Nothing, 90).0, Got::Refused);
        // Once the first is stale, it gives way.
        assert_eq!(
            t.come("192.0.2.1", Heard::Nothing, 100).0,
            Got::Took(a, true)
        );
        assert_eq!(t.come("192.0.2.1", Heard::Nothing, 120).0, Got::Refused);
        assert_eq!(
            t.come("192.0.2.1", Heard::Nothing, 150).0,
            Got::Took(b, true)
        );
        // Never the slot of one that has said more, however long it has
        // waited (a TLS handshake over a slow path).
        let mut t = Table::new(64, 2);
        t.accept("192.0.2.1", Heard::Whole, 0);
        t.accept("192.0.2.1", Heard::Whole, 0);
        assert_eq!(t.come("192.0.2.1", Heard::Nothing, 5000).0, Got::Refused);
    }

    #[test]
    fn a_newcomer_whose_first_message_is_whole_takes_a_silent_slot_at_once() {
        let mut t = Table::new(64, 2);
        let a = t.accept("192.0.2.1", Heard::Nothing, 0);
        t.accept("192.0.2.1", Heard::Nothing, 5);
        assert_eq!(t.come("192.0.2.1", Heard::Whole, 10).0, Got::Took(a, true));
    }

    #[test]
    fn a_base_outlasts_any_number_of_silent_newcomers_from_its_address() {
        // An attacker at the base's address reopens each dropped connection
        // at once, one every 100 µs: its connections come and go, the
        // base's stays.
        let per_source = 8;
        for base_heard in [Heard::Whole, Heard::Nothing] {
            let mut t = Table::new(64, per_source);
            for _ in 0..per_source {
                t.come("192.0.2.1", Heard::Nothing, 0);
            }
            // The base comes when the attacker's are stale: it gets a slot.
            let (got, base) = t.come("192.0.2.1", base_heard, 500);
            assert!(matches!(got, Got::Took(_, true)), "{got:?}");
            let base = base.expect("a slot");
            let mut took = 0;
            for k in 0..20_000u64 {
                let ms = 500 + k / 10;
                // A base whose Hello was not there at its accept has it
                // read within a few milliseconds, then goes on the hub.
                if k == 30 {
                    t.advance(base, stage::SPOKEN, ms);
                    t.advance(base, stage::ON_HUB, ms);
                }
                let (got, _) = t.come("192.0.2.1", Heard::Nothing, ms);
                if let Got::Took(seq, _) = got {
                    assert_ne!(seq, base, "{base_heard:?}: the base evicted at {ms} ms");
                    took += 1;
                }
                assert!(t.has(base));
            }
            // The attacker's slots turned over, a few every grace period.
            assert!(took >= 2000 / 100 * 7, "{took}");
        }
    }

    #[test]
    fn within_a_source_stale_silence_goes_before_a_fresh_newcomer_and_a_trickle_counts_as_silence()
    {
        let mut t = Table::new(64, 2);
        let trickle = t.accept("192.0.2.1", Heard::Part(None), 0);
        t.accept("192.0.2.1", Heard::Nothing, 950);
        // At 1 s the trickle has been stuck for 1 s, the newcomer 50 ms.
        assert_eq!(
            t.come("192.0.2.1", Heard::Nothing, 1000).0,
            Got::Took(trickle, true)
        );
        // One that has spoken goes after silent ones, stale or not.
        let mut t = Table::new(64, 2);
        let spoke = t.accept("192.0.2.1", Heard::Whole, 0);
        let silent = t.accept("192.0.2.1", Heard::Nothing, 990);
        assert_eq!(
            t.come("192.0.2.1", Heard::Whole, 1000).0,
            Got::Took(silent, true)
        );
        assert!(t.has(spoke));
    }

    #[test]
    fn at_the_global_cap_the_stalest_of_the_busiest_source_goes() {
        let mut t = Table::new(3, 8);
        let lone = t.accept("192.0.2.1", Heard::Nothing, 0);
        let a = t.accept("192.0.2.2", Heard::Nothing, 10);
        let _b = t.accept("192.0.2.2", Heard::Nothing, 20);
        // All stale and silent: the source holding two loses its oldest.
        assert_eq!(
            t.come("192.0.2.3", Heard::Nothing, 500).0,
            Got::Took(a, false)
        );
        // Stale ones before fresh ones, whatever their source: the lone
        // stale one goes before the fresh newcomer.
        assert_eq!(
            t.come("192.0.2.4", Heard::Nothing, 550).0,
            Got::Took(lone, false)
        );
    }

    #[test]
    fn a_newcomer_at_its_source_cap_when_all_slots_are_taken_evicts_only_once() {
        let mut t = Table::new(3, 1);
        t.accept("192.0.2.1", Heard::Nothing, 0);
        t.accept("192.0.2.2", Heard::Nothing, 0);
        let mine = t.accept("192.0.2.3", Heard::Nothing, 0);
        // Three slots, one per source: a newcomer from 192.0.2.3 takes its
        // own source's, and that frees the slot it needs.
        assert_eq!(
            t.come("192.0.2.3", Heard::Nothing, 500).0,
            Got::Took(mine, true)
        );
        assert_eq!(t.pending.len(), 3);
    }
}
