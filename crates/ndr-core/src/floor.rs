//! The floor: which of a remote's links holds control, in which term, and
//! who waits for it.
//!
//! A remote serves one controlling base and up to
//! [`observers`](Floor::new) observers, each on a link of its own — an
//! [`Endpoint`](crate::endpoint::Endpoint) driven by the one drive contract,
//! as any other. The floor sits beside them, sans-IO like them: the driver
//! tells it what the links' events say (a base connected, passed its
//! initialization pattern, yielded, left) and carries out what it decides
//! ([`poll_action`](Floor::poll_action)) on the links. Each control term has
//! a number; the endpoints stamp it in the frames and a remote applies only
//! commands of the term its link holds now (fencing, counted in
//! [`Stats::commands_refused_stale_term`](crate::endpoint::Stats)).
//!
//! Control changes hands when its holder closes, yields, or is dropped by
//! the liveness rule: the first base waiting for it ([`Seat::WaitForControl`])
//! whose link has passed its initialization pattern gets the next term.
//! Between terms nothing is applied: the robot holds (its watchdog's safe
//! state), from [`vacant_since`](Floor::vacant_since).
//!
//! ```
//! use ndr_core::floor::{Action, Admission, Floor};
//! use ndr_core::time::Instant;
//! use ndr_core::wire::Seat;
//!
//! let mut floor = Floor::new(4)?;
//! let t = Instant::from_millis;
//! // Base 1 asks for control and gets it (its link's Hello said so).
//! assert_eq!(floor.offer(), (Seat::Control, 1));
//! assert_eq!(floor.admit(1, Seat::Control, Seat::Control, true)?, Admission::Control { term: 1 });
//! floor.started(1);
//! assert_eq!(floor.poll_action(), Some(Action::Grant { link: 1, term: 1 }));
//! assert_eq!(floor.poll_action(), Some(Action::Term { term: 1 }));
//! // Base 2 waits for control: it observes, and base 1 is told.
//! assert_eq!(floor.offer(), (Seat::Observe, 1));
//! assert_eq!(floor.admit(2, Seat::WaitForControl, Seat::Observe, true)?, Admission::Observe { waiting: true });
//! floor.started(2);
//! assert_eq!(floor.poll_action(), Some(Action::Request { link: 1 }));
//! // Base 1 leaves: base 2 gets term 2.
//! floor.left(1, t(6000));
//! assert_eq!(floor.poll_action(), Some(Action::Grant { link: 2, term: 2 }));
//! assert_eq!(floor.poll_action(), Some(Action::Term { term: 2 }));
//! assert_eq!(floor.stats().handovers, 1);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use heapless::{Deque, Vec};

use crate::endpoint::LinkError;
use crate::time::Instant;
use crate::wire::Seat;

/// How the driver names a link to the floor (a connection number).
pub type LinkId = u64;

/// Most observers a floor serves.
pub const MAX_OBSERVERS: usize = 64;

/// The floor's default number of observers.
pub const DEFAULT_OBSERVERS: usize = 4;

/// Actions that may wait for the driver: one hand-over's worth, many times.
const ACTION_QUEUE: usize = 16;

/// What a base was admitted as.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Admission {
    /// It holds control in `term` once its link passes the initialization
    /// pattern (the floor's [`Action::Grant`] then).
    Control {
        /// The term.
        term: u16,
    },
    /// It observes; `waiting`: it waits for control.
    Observe {
        /// It asked to wait for control.
        waiting: bool,
    },
}

/// What the floor asks the driver to do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Action {
    /// Grant `link` control in `term`
    /// ([`Endpoint::grant`](crate::endpoint::Endpoint::grant)).
    Grant {
        /// The link.
        link: LinkId,
        /// The term.
        term: u16,
    },
    /// Tell `link`, which holds control, that a base waits for it
    /// ([`Endpoint::request_control`](crate::endpoint::Endpoint::request_control)).
    Request {
        /// The controller's link.
        link: LinkId,
    },
    /// The robot's term is `term` now: every link announces it
    /// ([`Endpoint::set_term`](crate::endpoint::Endpoint::set_term)).
    Term {
        /// The term.
        term: u16,
    },
}

/// The floor's counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct FloorStats {
    /// Terms granted after the first: control changing hands.
    pub handovers: u64,
    /// The most observers served at once.
    pub observers_max: u64,
    /// Bases refused control because another held it.
    pub refused_busy: u64,
    /// Bases refused control because their identity may only observe.
    pub refused_observer_only: u64,
    /// Bases refused because every observer's seat was taken.
    pub refused_full: u64,
    /// Actions the driver did not take in time, given up (the oldest).
    pub actions_dropped: u64,
}

/// An error of [`Floor::new`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum FloorError {
    /// More observers than [`MAX_OBSERVERS`].
    TooManyObservers(usize),
}

impl core::fmt::Display for FloorError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            FloorError::TooManyObservers(n) => write!(
                f,
                "{n} observers asked for; a remote serves at most {MAX_OBSERVERS}"
            ),
        }
    }
}

impl core::error::Error for FloorError {}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Holding {
    /// Admitted as controller; its link runs its initialization pattern.
    Pending { term: u16 },
    /// Holds control in this term.
    Term(u16),
}

#[derive(Clone, Copy, Debug)]
struct Controller {
    link: LinkId,
    holding: Holding,
}

#[derive(Clone, Copy, Debug)]
struct Observer {
    link: LinkId,
    waiting: bool,
    /// Its link passed the initialization pattern.
    ready: bool,
}

/// One remote's seats: a controller, up to N observers, the term.
#[derive(Clone, Debug)]
pub struct Floor {
    limit: usize,
    /// The newest term granted (0 before the first).
    term: u16,
    controller: Option<Controller>,
    /// In the order they came: the first ready waiter is promoted first.
    observers: Vec<Observer, MAX_OBSERVERS>,
    /// Since when no base holds control.
    vacant_since: Option<Instant>,
    actions: Deque<Action, ACTION_QUEUE>,
    stats: FloorStats,
}

impl Floor {
    /// A floor that serves up to `observers` observers (a base waiting for
    /// control is one).
    ///
    /// # Errors
    /// [`FloorError::TooManyObservers`] above [`MAX_OBSERVERS`].
    pub fn new(observers: usize) -> Result<Self, FloorError> {
        if observers > MAX_OBSERVERS {
            return Err(FloorError::TooManyObservers(observers));
        }
        Ok(Floor {
            limit: observers,
            term: 0,
            controller: None,
            observers: Vec::new(),
            vacant_since: None,
            actions: Deque::new(),
            stats: FloorStats::default(),
        })
    }

    /// What a new link's endpoint offers a base that asks for control
    /// ([`Endpoint::offer`](crate::endpoint::Endpoint::offer)): control
    /// while it is free and nobody waits for it, with the term it would
    /// get; else observation, with the robot's term now (0 before the
    /// first), which its frames announce.
    #[must_use]
    pub fn offer(&self) -> (Seat, u16) {
        let free = self.controller.is_none() && !self.observers.iter().any(|o| o.waiting);
        if free {
            (Seat::Control, self.next_term())
        } else {
            (Seat::Observe, self.term)
        }
    }

    /// A link's handshake is done: its base asked for `asked` and its
    /// endpoint gave it `given` (the offer made before); `may_control`:
    /// its identity may hold control.
    ///
    /// # Errors
    /// The error to end the link with
    /// ([`Endpoint::abort`](crate::endpoint::Endpoint::abort)):
    /// [`LinkError::ObserverOnly`] for a base that asked for control with
    /// an observer's identity, [`LinkError::Busy`] for control given when
    /// another base took it meanwhile, [`LinkError::ObserversFull`] when
    /// every observer's seat is taken.
    pub fn admit(
        &mut self,
        link: LinkId,
        asked: Seat,
        given: Seat,
        may_control: bool,
    ) -> Result<Admission, LinkError> {
        if asked != Seat::Observe && !may_control {
            self.stats.refused_observer_only += 1;
            return Err(LinkError::ObserverOnly);
        }
        if given == Seat::Control {
            if self.controller.is_some() {
                self.stats.refused_busy += 1;
                return Err(LinkError::Busy);
            }
            let term = self.next_term();
            self.controller = Some(Controller {
                link,
                holding: Holding::Pending { term },
            });
            return Ok(Admission::Control { term });
        }
        let waiting = asked == Seat::WaitForControl;
        if self.observers.len() >= self.limit
            || self
                .observers
                .push(Observer {
                    link,
                    waiting,
                    ready: false,
                })
                .is_err()
        {
            self.stats.refused_full += 1;
            return Err(LinkError::ObserversFull);
        }
        self.stats.observers_max = self.stats.observers_max.max(self.observers.len() as u64);
        if waiting && let Some(c) = self.controller {
            self.act(Action::Request { link: c.link });
        }
        Ok(Admission::Observe { waiting })
    }

    /// `link` passed its initialization pattern (its endpoint's
    /// [`Event::Started`](crate::endpoint::Event::Started)): a controller's
    /// term starts ([`Action::Grant`]), a waiter may be promoted.
    pub fn started(&mut self, link: LinkId) {
        match &mut self.controller {
            Some(c) if c.link == link => {
                if let Holding::Pending { term } = c.holding {
                    c.holding = Holding::Term(term);
                    self.act(Action::Grant { link, term });
                    self.begin_term(term);
                }
            }
            _ => {
                if let Some(o) = self.observers.iter_mut().find(|o| o.link == link) {
                    o.ready = true;
                }
                self.promote();
            }
        }
    }

    /// The controller of `link` gave control up (its endpoint's
    /// [`Event::ControlYielded`](crate::endpoint::Event::ControlYielded));
    /// it observes from now, and the first ready waiter gets the next term.
    pub fn yielded(&mut self, link: LinkId, now: Instant) {
        if self.controller.is_some_and(|c| c.link == link) {
            self.controller = None;
            // It was admitted: it keeps a seat, over the limit if need be
            // (the list holds MAX_OBSERVERS; past that it is dropped).
            let _ = self.observers.push(Observer {
                link,
                waiting: false,
                ready: true,
            });
            self.vacate(now);
        }
    }

    /// `link` ended (closed, dropped by the liveness rule, failed): its
    /// seat frees; if it held control, the first ready waiter gets the next
    /// term.
    pub fn left(&mut self, link: LinkId, now: Instant) {
        if self.controller.is_some_and(|c| c.link == link) {
            self.controller = None;
            self.vacate(now);
        } else if let Some(i) = self.observers.iter().position(|o| o.link == link) {
            let _ = self.observers.remove(i);
        }
    }

    /// The next thing for the driver to do on the links.
    #[must_use]
    pub fn poll_action(&mut self) -> Option<Action> {
        self.actions.pop_front()
    }

    /// The link that holds control now, and its term.
    #[must_use]
    pub(crate) fn controller(&self) -> Option<(LinkId, u16)> {
        match self.controller? {
            Controller {
                link,
                holding: Holding::Term(term),
            } => Some((link, term)),
            _ => None,
        }
    }

    /// Whether `link` holds control in `term` now: the driver applies a
    /// command only then (the endpoint has fenced it already).
    #[must_use]
    pub fn may_apply(&self, link: LinkId, term: u16) -> bool {
        self.controller() == Some((link, term))
    }

    /// The newest term granted (0 before the first).
    #[must_use]
    pub fn term(&self) -> u16 {
        self.term
    }

    /// Since when no base holds control (the robot holds), after a first
    /// term ended; `None` while one holds it or before the first.
    #[must_use]
    pub fn vacant_since(&self) -> Option<Instant> {
        self.vacant_since
    }

    /// Observers served now, waiting bases included.
    #[must_use]
    pub fn observers(&self) -> usize {
        self.observers.len()
    }

    /// Bases waiting for control now.
    #[must_use]
    pub fn waiting(&self) -> usize {
        self.observers.iter().filter(|o| o.waiting).count()
    }

    /// The counters.
    #[must_use]
    pub fn stats(&self) -> FloorStats {
        self.stats
    }

    fn next_term(&self) -> u16 {
        // Terms are compared for equality only: after 65 535 comes 1 (0
        // means none).
        match self.term.wrapping_add(1) {
            0 => 1,
            t => t,
        }
    }

    fn begin_term(&mut self, term: u16) {
        if self.term != 0 {
            self.stats.handovers += 1;
        }
        self.term = term;
        self.vacant_since = None;
        self.act(Action::Term { term });
        if self.observers.iter().any(|o| o.waiting)
            && let Some(c) = self.controller
        {
            self.act(Action::Request { link: c.link });
        }
    }

    fn vacate(&mut self, now: Instant) {
        self.vacant_since = Some(now);
        self.promote();
    }

    /// Control is free: the first waiter whose link is ready takes the
    /// next term.
    fn promote(&mut self) {
        if self.controller.is_some() {
            return;
        }
        let Some(i) = self.observers.iter().position(|o| o.waiting && o.ready) else {
            return;
        };
        let link = self.observers.remove(i).link;
        let term = self.next_term();
        self.controller = Some(Controller {
            link,
            holding: Holding::Term(term),
        });
        self.act(Action::Grant { link, term });
        self.begin_term(term);
    }

    fn act(&mut self, action: Action) {
        if self.actions.push_back(action).is_err() {
            let _ = self.actions.pop_front();
            self.stats.actions_dropped += 1;
            let _ = self.actions.push_back(action);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_observer_only_identity_is_refused_control_and_may_observe() {
        let mut floor = Floor::new(1).unwrap();
        for asked in [Seat::Control, Seat::WaitForControl] {
            let given = asked.given(Seat::Control).unwrap();
            assert_eq!(
                floor.admit(1, asked, given, false),
                Err(LinkError::ObserverOnly)
            );
        }
        assert_eq!(
            floor.admit(1, Seat::Observe, Seat::Observe, false),
            Ok(Admission::Observe { waiting: false })
        );
        assert_eq!(floor.stats().refused_observer_only, 2);
        // The one observer's seat is taken.
        assert_eq!(
            floor.admit(2, Seat::Observe, Seat::Observe, true),
            Err(LinkError::ObserversFull)
        );
        assert_eq!(floor.stats().refused_full, 1);
        assert_eq!(floor.controller(), None);
    }

    #[test]
    fn control_given_twice_in_a_race_goes_to_the_first_and_a_waiter_needs_a_ready_link() {
        let mut floor = Floor::new(2).unwrap();
        // Both were offered control before either was admitted.
        assert_eq!(floor.offer(), (Seat::Control, 1));
        assert!(floor.admit(1, Seat::Control, Seat::Control, true).is_ok());
        assert_eq!(
            floor.admit(2, Seat::WaitForControl, Seat::Control, true),
            Err(LinkError::Busy)
        );
        floor.started(1);
        assert_eq!(floor.controller(), Some((1, 1)));
        assert!(floor.may_apply(1, 1) && !floor.may_apply(1, 2) && !floor.may_apply(3, 1));
        // A waiter whose link has not passed its pattern is not promoted
        // when control frees; it is once it has.
        assert!(
            floor
                .admit(3, Seat::WaitForControl, Seat::Observe, true)
                .is_ok()
        );
        floor.left(1, Instant::from_millis(10));
        assert_eq!(floor.controller(), None);
        assert_eq!(floor.vacant_since(), Some(Instant::from_millis(10)));
        while floor.poll_action().is_some() {}
        floor.started(3);
        assert_eq!(
            floor.poll_action(),
            Some(Action::Grant { link: 3, term: 2 })
        );
        assert_eq!(floor.controller(), Some((3, 2)));
        assert_eq!(floor.vacant_since(), None);
        assert_eq!((floor.observers(), floor.waiting()), (0, 0));
    }
}
