//! The one interface every playout policy implements: what it is told and
//! what it answers. The endpoint holds one policy and calls nothing else.

use core::fmt;

use crate::endpoint::Underflow;
use crate::predictor::{NetworkPredictor, Prediction};
use crate::sync::ClockSync;
use crate::time::{Duration, Instant};
use crate::wire::Role;

/// When a regulator releases each sample: the paper's FIFO, a target delay
/// released at the ticks, the adaptive playout's own schedule, or a policy
/// of the application's own.
///
/// The endpoint keeps the samples in its queue and tells the policy what
/// happens — arrivals, ticks, releases, losses, a new regime — with a
/// [`View`] of what it knows at that instant; the policy answers which
/// queued samples a release takes ([`Policy::due`]), when it releases apart
/// from the ticks ([`Policy::next_release`]), the delay it holds and what
/// it announces. It reads no clock: time is an argument.
///
/// A policy that only sets a target one-way delay implements
/// [`TargetDelay`](super::TargetDelay) (two methods) and runs as
/// [`OnTicks`](super::OnTicks); one that decides more implements this
/// trait. Either plugs in through a [`Factory`] under the `alloc` feature,
/// named by [`Playout::Custom`](super::Playout::Custom).
pub trait Policy: fmt::Debug + Send + PolicyClone {
    /// A new regime starts (the initialization pattern set the paper's
    /// nominal size `ns`). Returns the stock the queue keeps before its
    /// first release: the FIFO's `ns`, `0` for a policy that releases each
    /// sample at a slot of its own.
    fn start(&mut self, ns: usize) -> usize;

    /// The period changed: a pause resized the link.
    fn set_period(&mut self, period: Duration);

    /// The link ended: nothing more is released.
    fn stop(&mut self) {}

    /// A Data frame arrived, or a copy of a sample came in a later
    /// datagram (`Arrival::copy`). Says whether its delay was taken.
    fn arrival(&mut self, arrival: &Arrival, view: &View<'_>) -> Observed;

    /// The floor of the received frames' raw delays moved at a level shift
    /// of the path (a route change), from `from` to `to` seconds
    /// (`ClockSync::floor_at`).
    fn floor_moved(&mut self, from: f64, to: f64) {
        let _ = (from, to);
    }

    /// Whether a sample received while the link runs goes into the queue.
    fn admit(&self, sample: &Stamps, now: Instant, view: &View<'_>) -> Admit;

    /// A sample went into the queue.
    fn queued(&mut self, view: &View<'_>) {
        let _ = view;
    }

    /// A sample was lost: it came after its slot, or a release passed over
    /// it ([`Due::Release::passed`]).
    fn lost(&mut self) {}

    /// A tick of the sending grid, scheduled at `at` and run at `t`, the
    /// next one at `next_tick`: what it releases, `None` for a policy that
    /// releases on a schedule of its own ([`Policy::next_release`]).
    fn tick(
        &mut self,
        at: Instant,
        t: Instant,
        next_tick: Option<Instant>,
        view: &View<'_>,
    ) -> Option<Due>;

    /// A release of its own schedule ([`Policy::next_release`]) scheduled
    /// at `at` runs at `t`: what it takes. (The default, for a policy that
    /// releases at the ticks: nothing.)
    fn due(&mut self, at: Instant, t: Instant, view: &View<'_>) -> Due {
        let _ = (at, t, view);
        Due::NotYet
    }

    /// What a release gave (not called after [`Due::Later`]).
    fn released(&mut self, at: Instant, t: Instant, outcome: Outcome, view: &View<'_>) {
        let _ = (at, t, outcome, view);
    }

    /// The next release apart from the ticks, `None` for a policy that
    /// releases at the ticks.
    fn next_release(&self) -> Option<Instant> {
        None
    }

    /// The end-to-end delay it holds now (release time minus send time),
    /// `None` while it has none (the FIFO never has one: its delay is its
    /// queue's).
    fn delay(&self) -> Option<Duration>;

    /// What it has to announce, oldest first; drained after every call.
    fn poll_announcement(&mut self) -> Option<Announcement> {
        None
    }

    /// The tick after the one at `plain − T`: `plain`, unless the policy
    /// moves a remote's grid onto its releases (so that the state answering
    /// a command leaves as the command is released).
    fn following_tick(&self, plain: Instant) -> Instant {
        plain
    }

    /// Whether a tick at `at` is on the grid the releases keep: until one
    /// is, a remote's ticks send probes rather than states that would
    /// answer no command.
    fn grid_settled(&self, at: Instant) -> bool {
        let _ = at;
        true
    }
}

/// What a policy is made for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct Setup {
    /// This side's role.
    pub(crate) role: Role,
    /// The period `T` the link starts at.
    pub(crate) period: Duration,
    /// What a tick does when its sample is missing.
    pub(crate) underflow: Underflow,
    /// How long without a fresh sample is an outage, not a delay.
    pub(crate) watchdog: Option<Duration>,
}

impl Setup {
    /// A setup for `role` at `period`.
    #[must_use]
    pub(crate) const fn new(
        role: Role,
        period: Duration,
        underflow: Underflow,
        watchdog: Option<Duration>,
    ) -> Self {
        Setup {
            role,
            period,
            underflow,
            watchdog,
        }
    }
}

/// A sample's stamps: its sequence number, its send time (the peer's
/// clock) and its arrival (the local clock).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stamps {
    /// The sequence number: one per tick of the peer.
    pub(crate) seq: u64,
    /// When the peer's tick that sent it was scheduled, on its clock.
    pub(crate) sent_at: Instant,
    /// When it arrived, on the local clock.
    pub(crate) arrived_at: Instant,
}

/// The samples waiting in the queue, oldest first.
pub trait Queued {
    /// How many wait.
    fn len(&self) -> usize;
    /// Whether none waits.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The `i`-th oldest.
    fn get(&self, i: usize) -> Option<Stamps>;
    /// Whether the queue is still building its stock ([`Policy::start`]):
    /// no release has come since the regime started.
    fn prefilling(&self) -> bool;
}

/// What the endpoint knows when it tells a policy something.
#[derive(Clone, Copy)]
#[non_exhaustive]
pub struct View<'a> {
    /// The estimate of the peer's clock (offset, skew, the delays' floor).
    pub(crate) sync: &'a ClockSync,
    /// The queued samples.
    pub(crate) queue: &'a dyn Queued,
    /// The newest Data frame received: its send stamp and its arrival.
    pub(crate) newest: Option<(Instant, Instant)>,
    /// The newest sample released.
    pub(crate) released: Option<u64>,
    /// The network predictor, if the endpoint runs one.
    pub(crate) predictor: Option<&'a NetworkPredictor>,
}

impl<'a> View<'a> {
    /// A view (for the endpoint, and for tests of a policy).
    #[must_use]
    pub(crate) fn new(sync: &'a ClockSync, queue: &'a dyn Queued) -> Self {
        View {
            sync,
            queue,
            newest: None,
            released: None,
            predictor: None,
        }
    }

    /// This view with the newest frame, the newest release and the
    /// network predictor.
    #[must_use]
    pub(crate) fn with(
        mut self,
        newest: Option<(Instant, Instant)>,
        released: Option<u64>,
        predictor: &'a NetworkPredictor,
    ) -> Self {
        self.newest = newest;
        self.released = released;
        self.predictor = Some(predictor);
        self
    }

    /// The network predictor's latest forecast.
    #[must_use]
    pub(crate) fn forecast(&self) -> Option<Prediction> {
        self.predictor?.last()
    }
}

impl fmt::Debug for View<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("View")
            .field("queued", &self.queue.len())
            .field("newest", &self.newest)
            .field("released", &self.released)
            .finish_non_exhaustive()
    }
}

/// A sample's arrival, as a policy is told it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct Arrival {
    /// Its send stamp (the peer's clock).
    pub(crate) sent_at: Instant,
    /// Its arrival (the local clock).
    pub(crate) arrived: Instant,
    /// The Data frame received before it (send stamp, arrival); `None` for
    /// the first, and for a copy.
    pub(crate) prev: Option<(Instant, Instant)>,
    /// The driver handed it over a watchdog's time after a deadline it
    /// missed: its arrival time is the driver's stall, not the network's.
    pub(crate) stalled: bool,
    /// A copy from a later datagram's bundle: it came late by design, and
    /// its delay is the one the sample really had.
    pub(crate) copy: bool,
}

impl Arrival {
    /// A Data frame's own arrival.
    #[must_use]
    pub(crate) const fn frame(
        sent_at: Instant,
        arrived: Instant,
        prev: Option<(Instant, Instant)>,
        stalled: bool,
    ) -> Self {
        Arrival {
            sent_at,
            arrived,
            prev,
            stalled,
            copy: false,
        }
    }

    /// A copy of a sample recovered from a later datagram.
    #[must_use]
    pub(crate) const fn copy(sent_at: Instant, arrived: Instant) -> Self {
        Arrival {
            sent_at,
            arrived,
            prev: None,
            stalled: false,
            copy: true,
        }
    }
}

/// What a policy did with an arrival.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Observed {
    /// Its delay was taken.
    Delay,
    /// It ended an outage, or came in the backlog after one: not a delay
    /// (counted in [`Stats::outage_delays`](crate::endpoint::Stats::outage_delays)).
    Outage,
    /// Nothing was taken.
    Ignored,
}

/// Whether a received sample goes into the queue.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Admit {
    /// It waits for its release.
    Queue,
    /// Its slot has passed (under [`Underflow::DropLate`]): lost, counted
    /// late.
    Late,
    /// It came in an outage's backlog, past its slot: kept, it would
    /// stretch the delay to the outage's length (counted discarded).
    Stale,
}

/// What a release takes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Due {
    /// The release moves later, to this instant, and takes nothing now (a
    /// remote's tick moves with it).
    Later(Instant),
    /// Nothing is due and no slot is missed: not an underflow (the policy
    /// has no delay yet, or its first sample's slot has not come).
    NotYet,
    /// A release.
    Release {
        /// The oldest samples to pass over first, each lost.
        passed: usize,
        /// How each one passed over counts.
        lost_as: Lost,
        /// Whether the oldest sample left is released; if not, or if none
        /// is queued, the release is an underflow.
        release: bool,
    },
}

impl Due {
    /// Release the oldest queued sample, passing over none.
    pub(crate) const FRONT: Due = Due::Release {
        passed: 0,
        lost_as: Lost::Late,
        release: true,
    };
}

/// How a sample passed over by a release counts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Lost {
    /// Its slot had passed ([`Stats::late`](crate::endpoint::Stats::late)).
    Late,
    /// The delay fell and it shares a slot with a newer sample
    /// ([`Stats::skipped`](crate::endpoint::Stats::skipped)).
    Skipped,
}

/// What a release gave.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// A fresh sample.
    Released(Stamps),
    /// Nothing due: the last sample was held.
    Underflow,
    /// Nothing, and no underflow (pre-fill, or [`Due::NotYet`]).
    Nothing,
}

/// What a policy announces.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Announcement {
    /// It settled on a new end-to-end delay, `ticks` periods rounded up
    /// ([`Event::DelayChanged`](crate::endpoint::Event::DelayChanged)).
    DelayChanged {
        /// The delay.
        delay: Duration,
        /// The delay in periods, rounded up.
        ticks: u64,
    },
}

/// Where an endpoint keeps its policy, made from the
/// [`Playout`](super::Playout) its configuration names:
/// [`Builtin`](super::Builtin) (the built-in policies, no heap),
/// [`HeapRoom`](super::HeapRoom) (feature `alloc`: those, or a
/// [`Custom`](super::Custom) one, boxed), or `Box<dyn Policy>` (any policy,
/// each boxed).
pub trait Room: Policy + Clone + Sized {
    /// The policy `playout` names, for `setup`.
    ///
    /// # Errors
    ///
    /// [`NoRoom`] when this room cannot hold it.
    fn make(playout: super::Playout, setup: &Setup) -> Result<Self, NoRoom>;
}

/// A [`Room`] that cannot hold the policy asked for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum NoRoom {
    /// The adaptive playout on a [`Builtin<NoAdaptive>`](super::Builtin).
    Adaptive,
    /// A policy of the application's own in a room for the built-in ones.
    Custom,
}

impl fmt::Display for NoRoom {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            NoRoom::Adaptive => {
                "the adaptive playout needs room for its histogram: \
                 build the endpoint with the default `Adaptive` slot, not `NoAdaptive`"
            }
            NoRoom::Custom => {
                "a playout policy of the application's own is boxed: \
                 build the endpoint on Heap storage (feature `alloc`)"
            }
        })
    }
}

impl core::error::Error for NoRoom {}

#[cfg(feature = "alloc")]
pub use boxed::{Custom, Factory, HeapRoom, PolicyClone};

#[cfg(not(feature = "alloc"))]
pub use unboxed::PolicyClone;

#[cfg(not(feature = "alloc"))]
mod unboxed {
    /// Nothing to do without a heap: a policy is cloned where it lies.
    pub trait PolicyClone {}

    impl<T> PolicyClone for T {}
}

#[cfg(feature = "alloc")]
mod boxed {
    use alloc::boxed::Box;
    use core::fmt;
    use core::hash::{Hash, Hasher};

    use super::{
        Admit, Announcement, Arrival, Due, NoRoom, Observed, Outcome, Policy, Room, Setup, Stamps,
        View,
    };
    use crate::playout::{Adaptive, Builtin, Playout};
    use crate::time::{Duration, Instant};

    /// Makes one policy of the application's own for each endpoint (the
    /// part of a [`Custom`] playout the configuration carries).
    pub trait Factory: Sync {
        /// The name reports give it.
        fn name(&self) -> &str;
        /// A policy for one endpoint.
        fn build(&self, setup: &Setup) -> Box<dyn Policy>;
    }

    /// A playout policy of the application's own:
    /// [`Playout::Custom`](crate::playout::Playout::Custom). Two are equal
    /// when they are the same factory.
    ///
    /// The factory is `'static` so that a [`Config`](crate::Config) stays
    /// `Copy`: a `static`, or `Box::leak` for one made at run time.
    #[derive(Clone, Copy)]
    pub struct Custom(&'static dyn Factory);

    impl Custom {
        /// The playout made by `factory`.
        #[must_use]
        pub const fn new(factory: &'static dyn Factory) -> Self {
            Custom(factory)
        }

        fn addr(&self) -> *const () {
            core::ptr::from_ref(self.0).cast()
        }
    }

    impl PartialEq for Custom {
        fn eq(&self, other: &Self) -> bool {
            core::ptr::eq(self.addr(), other.addr())
        }
    }

    impl Eq for Custom {}

    impl Hash for Custom {
        fn hash<H: Hasher>(&self, state: &mut H) {
            self.addr().hash(state);
        }
    }

    impl fmt::Debug for Custom {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.debug_tuple("Custom").field(&self.0.name()).finish()
        }
    }

    impl fmt::Display for Custom {
        fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
            f.write_str(self.0.name())
        }
    }

    /// How a boxed policy is cloned: every `Clone` policy is.
    pub trait PolicyClone {
        /// A boxed copy.
        fn clone_box(&self) -> Box<dyn Policy>;
    }

    impl<T: Policy + Clone + 'static> PolicyClone for T {
        fn clone_box(&self) -> Box<dyn Policy> {
            Box::new(self.clone())
        }
    }

    impl Clone for Box<dyn Policy> {
        fn clone(&self) -> Self {
            (**self).clone_box()
        }
    }

    impl Room for Box<dyn Policy> {
        fn make(playout: Playout, setup: &Setup) -> Result<Self, NoRoom> {
            match playout {
                Playout::Custom(custom) => Ok(custom.0.build(setup)),
                builtin => Ok(Builtin::<crate::playout::Adaptive>::make(builtin, setup)?.boxed()),
            }
        }
    }

    /// Where a [`Heap`](crate::storage::Heap) endpoint keeps its policy:
    /// a built-in one in the registry's enum, its calls made without a
    /// vtable (the adaptive playout's histogram boxed, so that a link that
    /// does not run it does not carry it), or the application's own, boxed.
    #[derive(Clone, Debug)]
    #[allow(clippy::large_enum_variant)]
    pub enum HeapRoom {
        /// A built-in policy.
        Builtin(Builtin<Box<Adaptive>>),
        /// A policy of the application's own.
        Custom(Box<dyn Policy>),
    }

    impl Room for HeapRoom {
        fn make(playout: Playout, setup: &Setup) -> Result<Self, NoRoom> {
            match playout {
                Playout::Custom(custom) => Ok(HeapRoom::Custom(custom.0.build(setup))),
                builtin => Ok(HeapRoom::Builtin(Builtin::make(builtin, setup)?)),
            }
        }
    }

    macro_rules! either {
        ($self:ident, $p:ident => $call:expr) => {
            match $self {
                HeapRoom::Builtin($p) => $call,
                HeapRoom::Custom($p) => $call,
            }
        };
    }

    impl Policy for HeapRoom {
        #[inline]
        fn start(&mut self, ns: usize) -> usize {
            either!(self, p => p.start(ns))
        }
        #[inline]
        fn set_period(&mut self, period: Duration) {
            either!(self, p => p.set_period(period));
        }
        #[inline]
        fn stop(&mut self) {
            either!(self, p => p.stop());
        }
        #[inline]
        fn arrival(&mut self, arrival: &Arrival, view: &View<'_>) -> Observed {
            either!(self, p => p.arrival(arrival, view))
        }
        #[inline]
        fn floor_moved(&mut self, from: f64, to: f64) {
            either!(self, p => p.floor_moved(from, to));
        }
        #[inline]
        fn admit(&self, sample: &Stamps, now: Instant, view: &View<'_>) -> Admit {
            either!(self, p => p.admit(sample, now, view))
        }
        #[inline]
        fn queued(&mut self, view: &View<'_>) {
            either!(self, p => p.queued(view));
        }
        #[inline]
        fn lost(&mut self) {
            either!(self, p => p.lost());
        }
        #[inline]
        fn tick(
            &mut self,
            at: Instant,
            t: Instant,
            next_tick: Option<Instant>,
            view: &View<'_>,
        ) -> Option<Due> {
            either!(self, p => p.tick(at, t, next_tick, view))
        }
        #[inline]
        fn due(&mut self, at: Instant, t: Instant, view: &View<'_>) -> Due {
            either!(self, p => p.due(at, t, view))
        }
        #[inline]
        fn released(&mut self, at: Instant, t: Instant, outcome: Outcome, view: &View<'_>) {
            either!(self, p => p.released(at, t, outcome, view));
        }
        #[inline]
        fn next_release(&self) -> Option<Instant> {
            either!(self, p => p.next_release())
        }
        #[inline]
        fn delay(&self) -> Option<Duration> {
            either!(self, p => p.delay())
        }
        #[inline]
        fn poll_announcement(&mut self) -> Option<Announcement> {
            either!(self, p => p.poll_announcement())
        }
        #[inline]
        fn following_tick(&self, plain: Instant) -> Instant {
            either!(self, p => p.following_tick(plain))
        }
        #[inline]
        fn grid_settled(&self, at: Instant) -> bool {
            either!(self, p => p.grid_settled(at))
        }
    }

    impl Policy for Box<dyn Policy> {
        #[inline]
        fn start(&mut self, ns: usize) -> usize {
            (**self).start(ns)
        }
        #[inline]
        fn set_period(&mut self, period: Duration) {
            (**self).set_period(period);
        }
        #[inline]
        fn stop(&mut self) {
            (**self).stop();
        }
        #[inline]
        fn arrival(&mut self, arrival: &Arrival, view: &View<'_>) -> Observed {
            (**self).arrival(arrival, view)
        }
        #[inline]
        fn floor_moved(&mut self, from: f64, to: f64) {
            (**self).floor_moved(from, to);
        }
        #[inline]
        fn admit(&self, sample: &Stamps, now: Instant, view: &View<'_>) -> Admit {
            (**self).admit(sample, now, view)
        }
        #[inline]
        fn queued(&mut self, view: &View<'_>) {
            (**self).queued(view);
        }
        #[inline]
        fn lost(&mut self) {
            (**self).lost();
        }
        #[inline]
        fn tick(
            &mut self,
            at: Instant,
            t: Instant,
            next_tick: Option<Instant>,
            view: &View<'_>,
        ) -> Option<Due> {
            (**self).tick(at, t, next_tick, view)
        }
        #[inline]
        fn due(&mut self, at: Instant, t: Instant, view: &View<'_>) -> Due {
            (**self).due(at, t, view)
        }
        #[inline]
        fn released(&mut self, at: Instant, t: Instant, outcome: Outcome, view: &View<'_>) {
            (**self).released(at, t, outcome, view);
        }
        #[inline]
        fn next_release(&self) -> Option<Instant> {
            (**self).next_release()
        }
        #[inline]
        fn delay(&self) -> Option<Duration> {
            (**self).delay()
        }
        #[inline]
        fn poll_announcement(&mut self) -> Option<Announcement> {
            (**self).poll_announcement()
        }
        #[inline]
        fn following_tick(&self, plain: Instant) -> Instant {
            (**self).following_tick(plain)
        }
        #[inline]
        fn grid_settled(&self, at: Instant) -> bool {
            (**self).grid_settled(at)
        }
    }
}
