//! The listener's accept loop and the handshakes it runs: what a
//! connection gets before it has authenticated.
//!
//! A connection takes one of a fixed number of slots until its handshakes
//! are done, within one budget of time. A source (an IPv4 address, an IPv6
//! /64) may hold only a few slots. When every slot is taken, the newcomer
//! takes the slot of a handshake that has not got any further for a while
//! ([`GRACE`]) if there is one: of those, the one that has got least far
//! (silent, part of its first message, all of it, past TLS), then one of
//! the source holding the most slots, then the one stuck longest. If all
//! have moved lately, one of the source holding the most slots goes, the
//! one stuck longest. A real peer sends its first message whole at once,
//! moves on at each round trip and comes alone from its address: silent or
//! trickling connections, or a flood from a few sources, evict each other
//! before it. Until its first message is whole, a connection reaches
//! neither TLS nor the hub.

use std::net::SocketAddr;
use std::sync::{Arc, PoisonError, Weak};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;
use tokio::task::{AbortHandle, Id, JoinError, JoinSet};

use super::first::{self, Said};
use super::handshake::{Progress, handshake};
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

/// A handshake under way.
struct Pending {
    task: Id,
    abort: AbortHandle,
    peer: SocketAddr,
    source: Source,
    /// Order of arrival: lower is older.
    seq: u64,
    progress: Arc<Progress>,
}

/// The accept loop's state, owned by its task.
pub(super) struct Gate {
    listener: TcpListener,
    /// Weak: a listener dropped while its runtime does not run (a
    /// current-thread runtime) must still let its hub go.
    common: Weak<Common>,
    ready: mpsc::Sender<Link>,
    handshakes: JoinSet<()>,
    pending: Vec<Pending>,
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
        let peer = self.pending.iter().find(|p| p.task == id).map(|p| p.peer);
        self.pending.retain(|p| p.task != id);
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

    /// Gives a new connection a slot, or turns it away.
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
        let held = self.pending.iter().filter(|p| p.source == source).count();
        if held >= self.per_source {
            reset(&stream);
            drop(stream);
            common.refuse(
                Refusal::PerSource,
                peer,
                &format_args!(
                    "{held} handshakes from its source are already pending, the most one \
                     source may have (LinkConfig::admission.max_pending_per_source)"
                ),
            );
            return;
        }
        if self.pending.len() >= self.slots {
            self.evict(common);
        }
        // What it sent before it was accepted counts at once: its task may
        // not run before the next eviction is decided.
        let progress = Arc::new(Progress::new(self.epoch, heard));
        let task = self.handshakes.spawn(handshake(
            Arc::clone(common),
            stream,
            peer,
            Arc::clone(&progress),
            self.ready.clone(),
        ));
        self.pending.push(Pending {
            task: task.id(),
            abort: task,
            peer,
            source,
            seq: self.next_seq,
            progress,
        });
        self.next_seq += 1;
    }

    /// Frees a slot (see the module's notes for which).
    fn evict(&mut self, common: &Common) {
        // A few dozen slots: counting by scanning beats hashing.
        let held_by = |source: Source| self.pending.iter().filter(|p| p.source == source).count();
        let now = StdInstant::now();
        let victim = self
            .pending
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
            .map(|(i, _)| i);
        let Some(i) = victim else {
            return;
        };
        let gone = self.pending.swap_remove(i);
        // Its task ends the link, if one was started, as busy.
        gone.abort.abort();
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

/// Closes with a reset rather than a normal close: a refused peer needs
/// no orderly goodbye, and this side keeps no TIME_WAIT for it.
fn reset(stream: &TcpStream) {
    let _ = stream.set_zero_linger();
}
