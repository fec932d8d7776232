//! What the endpoint tells its application.

use crate::time::{Duration, Instant};
use crate::wire::Hello;

use super::error::LinkError;

/// Whether a released sample is new or a repeat.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Status {
    /// The sample due at this tick.
    Fresh,
    /// The due sample had not arrived (an underflow): the last sample is repeated.
    Held,
}

impl Status {
    /// `"fresh"` or `"held"`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Status::Fresh => "fresh",
            Status::Held => "held",
        }
    }
}

/// One sample released by the regulator at a tick, its values in `V`
/// (the endpoint's [`Storage::Values`](crate::storage::Storage::Values)).
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Release<V> {
    /// The sample's sequence number (the peer's Data frame count).
    pub seq: u64,
    /// When the peer sent it, on the peer's clock.
    pub sent_at: Instant,
    /// When it arrived, on this side's clock.
    pub arrived_at: Instant,
    /// The tick that released it, on this side's clock.
    pub released_at: Instant,
    /// Fresh, or a repeat because the due sample was missing.
    pub status: Status,
    /// The control term its frame carried: on a remote, the term of the
    /// command (always the one its link holds: others are refused); on a
    /// base, the robot's term when the state was sent.
    pub term: u16,
    /// The round trip as the application sees it, measured at this release:
    /// from this side's sample that the peer had just released when it sent
    /// this one, to now. `None` if this release closes no new round trip.
    pub grtt: Option<Duration>,
    len: u16,
    values: V,
}

impl<V: AsRef<[f64]> + AsMut<[f64]> + Clone> Release<V> {
    pub(crate) fn fresh(
        head: Head,
        term: u16,
        values: V,
        len: u16,
        released_at: Instant,
        grtt: Option<Duration>,
    ) -> Self {
        Release {
            seq: head.seq,
            sent_at: head.sent_at,
            arrived_at: head.arrived_at,
            released_at,
            status: Status::Fresh,
            term,
            grtt,
            len,
            values,
        }
    }

    /// The sample's values, one per axis.
    #[must_use]
    pub fn values(&self) -> &[f64] {
        let all = self.values.as_ref();
        all.get(..usize::from(self.len)).unwrap_or(all)
    }

    /// Becomes a copy of `other`, in place when the values are as wide
    /// (no allocation for heap storage).
    pub(crate) fn copy_from(&mut self, other: &Self) {
        if self.values.as_ref().len() == other.values.as_ref().len() {
            self.values.as_mut().copy_from_slice(other.values.as_ref());
        } else {
            self.values = other.values.clone();
        }
        self.seq = other.seq;
        self.sent_at = other.sent_at;
        self.arrived_at = other.arrived_at;
        self.released_at = other.released_at;
        self.status = other.status;
        self.term = other.term;
        self.grtt = other.grtt;
        self.len = other.len;
    }

    /// Time spent in the regulator: release − arrival.
    #[must_use]
    pub fn added_delay(&self) -> Duration {
        self.released_at - self.arrived_at
    }
}

/// The timing part of a queued sample.
pub(crate) type Head = crate::playout::Stamps;

/// Something the application should know; drain with
/// [`Endpoint::poll_event`](super::Endpoint::poll_event).
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum Event<V> {
    /// The handshake succeeded; the initialization pattern starts.
    Connected {
        /// The peer's Hello.
        peer: Hello,
    },
    /// The initialization pattern is over: samples flow with these parameters.
    Started {
        /// The period.
        period: Duration,
        /// The regulators' nominal size.
        ns: usize,
    },
    /// A tick released a sample (or repeated the last one).
    Released(Release<V>),
    /// Dynamic mode: the peers pause to change the parameters; a new
    /// initialization pattern runs, then [`Event::Started`] follows.
    Paused {
        /// The period after the pause.
        period: Duration,
        /// The nominal size after the pause.
        ns: usize,
    },
    /// No fresh sample has been released for the configured watchdog time
    /// ([`Config::watchdog`](super::Config::watchdog)): hold the robot safely.
    /// Emitted once per outage.
    LinkLost {
        /// How long since the last fresh sample.
        silent_for: Duration,
    },
    /// Target-delay playout: the end-to-end delay of the released samples
    /// changed: by at least a tick for the fixed policies; by whole quanta
    /// for the adaptive one (periods up to 20 ms, `T/⌈T/20 ms⌉` beyond,
    /// 20 ms), without a pause: a repeated
    /// sample when it rises, releases brought forward when it falls.
    DelayChanged {
        /// The new delay (release on this side's clock − send on the peer's,
        /// offset-corrected for the adaptive policy).
        delay: Duration,
        /// The same in periods, rounded up (a sub-tick delay of the adaptive
        /// policy at a long period counts as one).
        ticks: u64,
    },
    /// The round trip of this side's own samples, in its ticks, changed:
    /// a fresh release's GRTT, rounded up to whole periods (the tick that
    /// takes it), differs from the last one measured; the first measured
    /// round trip is announced too. Emitted before that release. Under the
    /// adaptive playout it moves by a tick between [`Event::DelayChanged`]
    /// events as releases fall on either side of a tick (and as the peer's
    /// tick grid drifts across this side's); under the FIFO an underflow
    /// stretches it. A controller that compensates the round trip (a
    /// [`SmithPredictor`](crate::control::SmithPredictor)) follows these.
    RoundTripChanged {
        /// The GRTT of the release that showed the change.
        grtt: Duration,
        /// `⌈grtt / period⌉`
        /// ([`round_trip_ticks`](crate::control::round_trip_ticks)).
        ticks: u64,
    },
    /// Fresh samples flow again after a [`Event::LinkLost`]. A driver
    /// that reconnects raises it too when a new session's samples flow.
    LinkRestored {
        /// How long the outage lasted: from the last fresh sample before
        /// it (for a reconnect: from the loss of the old session) to now.
        outage: Duration,
    },
    /// This link holds control from now, in `term`: a base's commands
    /// apply from the first one of this term (on the remote, the link's
    /// base was granted it). Not raised on a link of an observer.
    ControlGranted {
        /// The control term.
        term: u16,
    },
    /// A base lost control (taken for another base, or yielded): it
    /// observes from now, its commands are no longer sent.
    ControlLost {
        /// The term it held.
        term: u16,
    },
    /// A base that holds control: another base waits for it
    /// ([`Endpoint::yield_control`](super::Endpoint::yield_control) gives
    /// it up).
    ControlRequested,
    /// A remote: the link's base gave control up; nothing of its term
    /// applies any longer.
    ControlYielded {
        /// The term it held.
        term: u16,
    },
    /// An observer: the robot applied this command (sent on the reliable
    /// path as soon as it was, not held by the playout: its times say when).
    Applied(super::AppliedCommand<V>),
    /// The link ended.
    Closed {
        /// Why; `None` after a local [`close`](super::Endpoint::close).
        error: Option<LinkError>,
    },
}

impl<V> Event<V> {
    /// The event's name, the same in every binding and report:
    /// `connected`, `started`, `released`, `paused`, `link_lost`,
    /// `delay_changed`, `round_trip_changed`, `link_restored`,
    /// `control_granted`, `control_lost`, `control_requested`,
    /// `control_yielded`, `applied`, `closed`.
    #[must_use]
    pub const fn kind(&self) -> &'static str {
        match self {
            Event::Connected { .. } => "connected",
            Event::Started { .. } => "started",
            Event::Released(_) => "released",
            Event::Paused { .. } => "paused",
            Event::LinkLost { .. } => "link_lost",
            Event::DelayChanged { .. } => "delay_changed",
            Event::RoundTripChanged { .. } => "round_trip_changed",
            Event::LinkRestored { .. } => "link_restored",
            Event::ControlGranted { .. } => "control_granted",
            Event::ControlLost { .. } => "control_lost",
            Event::ControlRequested => "control_requested",
            Event::ControlYielded { .. } => "control_yielded",
            Event::Applied(_) => "applied",
            Event::Closed { .. } => "closed",
        }
    }
}
