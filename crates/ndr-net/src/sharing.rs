//! A listener's links to one robot, shared: one controller and up to N
//! observers, control changing hands by the core's
//! [`Floor`](ndr_core::floor::Floor).
//!
//! The hubs and the floor talk through two narrow channels. A hub tells the
//! floor what its links' endpoints said that matters to it (a link passed
//! its initialization pattern, its base yielded, it ended, the robot was
//! handed a command) as [`Note`]s, with `try_send` into a bounded queue: a
//! hub never waits on the floor, and what does not fit is dropped and
//! counted. The floor's thread decides and sends each link's hub a
//! [`SeatOp`] (grant, request, the term, an applied command for an
//! observer), which the hub carries out on the endpoint. An observer that
//! is slow, hung or flooding costs its own link's bounded queues, never the
//! controller's hub a wait.

use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex, PoisonError};

use ndr_core::endpoint::{Endpoint, Event, LinkError};
use ndr_core::floor::{Action, Admission, Floor, FloorStats, LinkId};
use ndr_core::storage::Heap;
use ndr_core::time::Instant;
use ndr_core::wire::Seat;

use crate::hub::{Hub, Msg};

/// Notes a floor's queue holds: a burst of every link's releases.
const NOTE_QUEUE: usize = 1024;

/// What a hub tells the floor about one of its links.
pub(crate) enum Note {
    /// The link passed its initialization pattern.
    Started(LinkId),
    /// Its base gave control up.
    Yielded(LinkId),
    /// It ended.
    Closed(LinkId),
    /// The robot was handed this command of the link's term.
    Applied {
        link: LinkId,
        term: u16,
        seq: u64,
        /// Its send time, on the robot's (the hubs') clock.
        sent_at: Instant,
        applied_at: Instant,
        values: Box<[f64]>,
    },
}

/// What the floor asks a link's hub to do with its endpoint.
pub(crate) enum SeatOp {
    Grant(u16),
    Request,
    Term(u16),
    Yield,
    Applied {
        term: u16,
        seq: u64,
        sent_at: Instant,
        applied_at: Instant,
        values: Box<[f64]>,
    },
}

impl SeatOp {
    /// Carries the operation out on `endpoint`; a refusal (a link that is
    /// no longer what the floor thought, a race with its end) is logged.
    pub(crate) fn apply(self, endpoint: &mut Endpoint<Heap>) {
        let done = match self {
            SeatOp::Grant(term) => endpoint.grant(term),
            SeatOp::Request => endpoint.request_control(),
            SeatOp::Term(term) => {
                endpoint.set_term(term);
                Ok(())
            }
            SeatOp::Yield => endpoint.yield_control(),
            SeatOp::Applied {
                term,
                seq,
                sent_at,
                applied_at,
                values,
            } => endpoint.send_applied((term, seq), sent_at, applied_at, &values),
        };
        if let Err(e) = done
            && e != LinkError::Closed
        {
            tracing::debug!("a seat operation was refused: {e}");
        }
    }
}

/// A hub's end: the link's key and the floor's queue.
pub(crate) struct Notes {
    link: LinkId,
    tx: SyncSender<Note>,
    dropped: Arc<AtomicU64>,
}

impl Notes {
    /// The link's key.
    pub(crate) fn link(&self) -> LinkId {
        self.link
    }

    /// What `event` of the link's `endpoint` tells the floor, if anything.
    pub(crate) fn note(&self, event: &Event<Box<[f64]>>, endpoint: &Endpoint<Heap>) {
        let note = match event {
            Event::Started { .. } => Note::Started(self.link),
            Event::ControlYielded { .. } => Note::Yielded(self.link),
            Event::Closed { .. } => Note::Closed(self.link),
            Event::Released(r)
                if r.status == ndr_core::endpoint::Status::Fresh
                    && endpoint.term() == Some(r.term) =>
            {
                Note::Applied {
                    link: self.link,
                    term: r.term,
                    seq: r.seq,
                    sent_at: endpoint.peer_to_local(r.sent_at, r.released_at),
                    applied_at: r.released_at,
                    values: r.values().into(),
                }
            }
            _ => return,
        };
        self.send(note);
    }

    fn send(&self, note: Note) {
        match self.tx.try_send(note) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
            // The listener and its floor are gone.
            Err(TrySendError::Disconnected(_)) => {}
        }
    }
}

/// Where a link is driven now: its hub and its id there (a QUIC link moves
/// from its listener's hub once its handshakes are done).
pub(crate) type Address = Arc<Mutex<(Hub, u64)>>;

/// What the sharing counted, besides the floor's own.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct SharingStats {
    /// The floor's counters: hand-overs, the most observers at once,
    /// refusals.
    pub floor: FloorStats,
    /// Notes from the hubs the floor's queue had no room for (applied
    /// commands not told to the observers, mostly).
    pub notes_dropped: u64,
    /// Applied commands told to observers.
    pub applied_forwarded: u64,
}

struct Seated {
    address: Address,
    observer: bool,
}

struct State {
    floor: Floor,
    links: HashMap<LinkId, Seated>,
    /// Links that passed their initialization pattern before they were
    /// admitted (their note came first).
    started: Vec<LinkId>,
    applied_forwarded: u64,
}

/// One listener's floor, its links and its thread.
pub(crate) struct Sharing {
    state: Mutex<State>,
    /// The next link's key (links on several hubs: their ids may meet).
    next: AtomicU64,
    tx: SyncSender<Note>,
    dropped: Arc<AtomicU64>,
}

impl Sharing {
    /// A floor for up to `observers` observers, and the thread that serves
    /// it until the listener and every link are gone.
    pub(crate) fn start(observers: usize) -> Result<Arc<Sharing>, crate::NetError> {
        let floor = Floor::new(observers)
            .map_err(|e| crate::NetError::Io(std::io::Error::other(e.to_string())))?;
        let (tx, rx) = mpsc::sync_channel(NOTE_QUEUE);
        let sharing = Arc::new(Sharing {
            state: Mutex::new(State {
                floor,
                links: HashMap::new(),
                started: Vec::new(),
                applied_forwarded: 0,
            }),
            tx,
            next: AtomicU64::new(1),
            dropped: Arc::default(),
        });
        let weak = Arc::downgrade(&sharing);
        std::thread::Builder::new()
            .name("ndr-floor".into())
            .spawn(move || serve(&weak, &rx))?;
        Ok(sharing)
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// A new link's key, and the hub's end for it.
    pub(crate) fn notes(&self) -> Notes {
        Notes {
            link: self.next.fetch_add(1, Ordering::Relaxed),
            tx: self.tx.clone(),
            dropped: Arc::clone(&self.dropped),
        }
    }

    /// What a new link's endpoint offers (see
    /// [`Floor::offer`](ndr_core::floor::Floor::offer)).
    pub(crate) fn offer(&self) -> (Seat, u16) {
        self.lock().floor.offer()
    }

    /// A link whose handshake is done: its base asked for `asked`, its
    /// endpoint offered `offered`; `may_control`: its identity may hold
    /// control. Whether it observes, or the error to end it with.
    pub(crate) fn admit(
        &self,
        link: LinkId,
        address: Address,
        (asked, offered): (Seat, Seat),
        may_control: bool,
    ) -> Result<bool, LinkError> {
        let given = asked.given(offered).ok_or(LinkError::Busy)?;
        let mut state = self.lock();
        let admission = state.floor.admit(link, asked, given, may_control)?;
        let observer = matches!(admission, Admission::Observe { .. });
        // Its offer named the term of its connection's start, which may
        // have passed since.
        if observer {
            send(&address, SeatOp::Term(state.floor.term()));
        }
        state.links.insert(link, Seated { address, observer });
        if let Some(i) = state.started.iter().position(|&l| l == link) {
            state.started.swap_remove(i);
            state.floor.started(link);
        }
        act(&mut state);
        Ok(observer)
    }

    pub(crate) fn stats(&self) -> SharingStats {
        let state = self.lock();
        SharingStats {
            floor: state.floor.stats(),
            notes_dropped: self.dropped.load(Ordering::Relaxed),
            applied_forwarded: state.applied_forwarded,
        }
    }
}

/// The floor's thread: each note, then what the floor decided.
fn serve(sharing: &std::sync::Weak<Sharing>, rx: &Receiver<Note>) {
    while let Ok(note) = rx.recv() {
        let Some(sharing) = sharing.upgrade() else {
            return;
        };
        let mut state = sharing.lock();
        match note {
            Note::Started(link) => {
                if state.links.contains_key(&link) {
                    state.floor.started(link);
                } else if state.started.len() < 4 * ndr_core::floor::MAX_OBSERVERS {
                    state.started.push(link);
                }
            }
            Note::Yielded(link) => {
                state.floor.yielded(link, Instant::ZERO);
                if let Some(s) = state.links.get_mut(&link) {
                    s.observer = true;
                }
            }
            Note::Closed(link) => {
                state.floor.left(link, Instant::ZERO);
                state.links.remove(&link);
                state.started.retain(|&l| l != link);
            }
            Note::Applied {
                link,
                term,
                seq,
                sent_at,
                applied_at,
                values,
            } => {
                if state.floor.may_apply(link, term) {
                    let mut told = 0;
                    for s in state.links.values().filter(|s| s.observer) {
                        let op = SeatOp::Applied {
                            term,
                            seq,
                            sent_at,
                            applied_at,
                            values: values.clone(),
                        };
                        if send(&s.address, op) {
                            told += 1;
                        }
                    }
                    state.applied_forwarded += told;
                }
            }
        }
        act(&mut state);
    }
}

/// Carries out the floor's decisions on the links' hubs.
fn act(state: &mut State) {
    while let Some(action) = state.floor.poll_action() {
        match action {
            Action::Grant { link, term } => {
                if let Some(s) = state.links.get_mut(&link) {
                    s.observer = false;
                    send(&s.address, SeatOp::Grant(term));
                }
            }
            Action::Request { link } => {
                if let Some(s) = state.links.get(&link) {
                    send(&s.address, SeatOp::Request);
                }
            }
            Action::Term { term } => {
                for s in state.links.values() {
                    send(&s.address, SeatOp::Term(term));
                }
            }
            _ => {}
        }
    }
}

fn send(address: &Address, op: SeatOp) -> bool {
    let (hub, id) = &*address.lock().unwrap_or_else(PoisonError::into_inner);
    hub.send(Msg::Seat(*id, Box::new(op)))
}
