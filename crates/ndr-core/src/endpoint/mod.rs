//! The link endpoint: a sans-IO state machine for one side of the link.
//!
//! An [`Endpoint`] never reads a clock and never touches a socket: its
//! driver passes time in and moves bytes, following the drive contract of
//! the [crate docs](crate#the-drive-contract): a frame carries the sample
//! set last when it is transmitted, tagged with the newest peer sample
//! released when it was set.
//!
//! # Protocol
//!
//! 1. **Handshake.** The base sends Hello (role, mode, widths, layout, period); the
//!    remote checks it against its own configuration and answers with its
//!    Hello. Any mismatch ends the link with a specific [`LinkError`] and a
//!    Close frame carrying its reason.
//! 2. **Initialization pattern.** Both sides send a probe (a Data frame
//!    without channels) every tick and echo the newest frame they received.
//!    Once the base has measured
//!    [`INIT_EXCHANGES`](crate::sizing::INIT_EXCHANGES) round trips it sets
//!    `ns = 2 + floor(η·mt/T)` and sends Control RESUME(ns, T).
//! 3. **Running.** One sample each way per tick; each side's regulator keeps
//!    `ns` samples of stock and releases one per tick. Every frame echoes the
//!    newest peer frame (NRTT) and names the newest peer sample released
//!    (GRTT, measured when the base releases the state that carries it back).
//! 4. **Dynamic mode** ([`Mode::PaperDynamic`]): the base's network predictor
//!    runs on; when its forecast period or queue size leaves a band around
//!    the current ones, or its forecast `mt` would empty the queue
//!    ([`Adaptation`]), the base sends PAUSE_REQUEST(ns', T'), the remote answers PAUSE_ACK,
//!    both run a new initialization pattern at `T'`, and the base resumes
//!    with `ns'`. Samples queued when the pause starts are discarded (counted).
//!
//! Sequence numbers count Data frames (probes included), one per tick, so a
//! sample's release slot follows from its sequence number.

mod applied;
mod config;
mod datagram;
mod error;
mod event;
mod probes;
mod receive;
mod regime;
mod release;
mod rx_check;
mod seat;
mod stats;

use heapless::Deque;

pub use applied::AppliedCommand;
pub use config::{
    Adaptation, Config, ConfigError, DEFAULT_LIVENESS, MIN_PERIOD, Mode, REPEAT_HOLD, Transport,
    Underflow, UnknownName,
};
pub use datagram::{DatagramError, Origin, RenewError, Taken};
pub use error::LinkError;
pub use event::{Event, Release, Status};
pub use probes::ProbeArrival;
pub use stats::{Running, Stats};

use crate::playout::{Policy, Room, Setup};
use crate::predictor::{NetworkPredictor, Prediction};
use crate::regulator::{Occupancy, RegulatorIn};
use crate::storage::Storage;
use crate::sync::ClockSync;
use crate::time::{Duration, Instant};
use crate::wire::{self, Frame, Header, Hello, Role, Seat};
use event::Head;
use receive::Heard;
use regime::Regime;
use release::Released;

/// A pause or a re-run initialization pattern may take this many times
/// what it needs (its probes at the period, plus the slowest round trip
/// seen) before it times out, if that is longer than the handshake timeout.
pub(crate) const PATTERN_SLACK: u64 = 3;

/// Where the endpoint is in the protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize),
    serde(rename_all = "lowercase")
)]
pub enum Phase {
    /// Waiting for the peer's Hello.
    Handshake,
    /// Running the initialization pattern (probes only).
    Init,
    /// Samples flow and the regulator releases them.
    Running,
    /// The base asked to pause and waits for the remote's acknowledgement.
    Pausing,
    /// The link is over.
    Closed,
}

impl Phase {
    /// A short name for messages and reports.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Phase::Handshake => "the handshake",
            Phase::Init => "the initialization pattern",
            Phase::Running => "running",
            Phase::Pausing => "a pause",
            Phase::Closed => "closed",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Slot<V> {
    head: Head,
    /// The control term its frame carried.
    term: u16,
    peer_released: Option<u64>,
    len: u16,
    values: V,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Tx {
    Hello,
    Probe {
        seq: u64,
    },
    Sample {
        seq: u64,
    },
    Control {
        op: wire::ControlOp,
        ns: u16,
        period: Duration,
    },
    Close {
        reason: wire::CloseReason,
    },
    Token {
        session: u64,
    },
}

/// The regulator of an endpoint of storage `S`.
type SlotRegulator<S> =
    RegulatorIn<Slot<<S as Storage>::Values>, <S as Storage>::Queue<Slot<<S as Storage>::Values>>>;

/// An adaptive remote sends samples after this many running ticks even if
/// its grid has not yet moved to its releases.
const GRID_SETTLE_TICKS: u64 = 50;

/// Transmissions that may wait for the driver: a few ticks' worth.
const TX_QUEUE: usize = 8;
/// Events that may wait for the application.
const EVENT_QUEUE: usize = 32;
/// Events one tick or release raises at most (the release, its round trip,
/// the watchdog's, the policy's announcements, a regime's change, the
/// end): a catch-up stops with fewer free.
const STEP_EVENTS: usize = 8;

/// One side of a regulated link, its buffers in the storage `S`:
/// [`Inline<C, N>`](crate::storage::Inline) (no heap: samples of up to `C`
/// channels, `N` queued) or [`Heap`](crate::storage::Heap) (sized when the
/// endpoint is made, from the link's width and the capacity asked).
#[derive(Clone, Debug)]
pub struct Endpoint<S: Storage> {
    config: Config,
    phase: Phase,
    period: Duration,
    ns: usize,
    regulator: SlotRegulator<S>,
    /// When the regulator releases each sample.
    policy: S::Policy,
    /// The peer's clock offset and skew.
    sync: ClockSync,
    predictor: NetworkPredictor,
    next_tick: Option<Instant>,
    deadline: Option<Instant>,
    /// Where the protocol's regimes stand.
    regime: Regime,
    /// What goes to the peer.
    out: Outbox<S>,
    /// What came from the peer, and when.
    heard: Heard,
    /// What was released to the application.
    rel: Released<S::Values>,
    peer: Option<Hello>,
    /// Who on this link may command the robot, in which term.
    seating: seat::Seating,
    /// Applied commands waiting to go to an observer.
    applied: applied::AppliedOut<S::Values>,
    /// The datagram transport's state (`None` on a stream).
    dgram: Option<datagram::Datagrams<S::Values>>,
    events: Deque<Event<S::Values>, EVENT_QUEUE>,
    events_dropped: u64,
    /// Probe arrivals kept for the driver, if it asked.
    probes: probes::ProbeLog,
    stats: Stats,
}

/// What goes to the peer: the frames waiting for the driver, the sample
/// they carry, and when each recent tick was scheduled.
#[derive(Clone, Debug)]
struct Outbox<S: Storage> {
    tx: Deque<Tx, TX_QUEUE>,
    next_seq: u64,
    sample: S::Values,
    sample_fresh: bool,
    /// The newest peer sample released when `sample` was set: what it
    /// answers.
    answers: Option<u64>,
    /// Scheduled time of each tick that sent a sample or probe, by `seq`
    /// modulo the capacity: its frame's send stamp, and the start of its GRTT.
    sent_ticks: S::Ticks,
}

impl<S: Storage> Endpoint<S> {
    /// An endpoint that starts at `now`, with the storage's default
    /// capacity ([`Storage::DEFAULT_CAPACITY`]). A base queues its Hello at once.
    pub fn new(config: Config, now: Instant) -> Result<Self, ConfigError> {
        Self::with_capacity(config, now, S::DEFAULT_CAPACITY)
    }

    /// An endpoint that starts at `now` whose regulator holds `capacity`
    /// samples (its nominal size stays below that). An
    /// [`Inline<C, N>`](crate::storage::Inline) storage holds exactly `N`.
    pub fn with_capacity(
        config: Config,
        now: Instant,
        capacity: usize,
    ) -> Result<Self, ConfigError> {
        config.validate()?;
        let widest = config.command_width.max(config.state_width);
        let too_wide = ConfigError::Channels {
            width: widest,
            capacity: S::values(0).map_or(0, |v| v.as_ref().len()),
        };
        // What is received is made when it comes: check now that it fits.
        S::values(usize::from(widest)).ok_or(too_wide)?;
        let sample = S::values(usize::from(config.sent_width())).ok_or(too_wide)?;
        let dgram = match config.transport {
            Transport::Stream => None,
            transport => Some(
                datagram::Datagrams::new(transport, config.session, || {
                    S::values(usize::from(config.sent_width()))
                })
                .ok_or(too_wide)?,
            ),
        };
        let no_room = ConfigError::Capacity { asked: capacity };
        let queue = S::queue(capacity).ok_or(no_room)?;
        let sent_ticks = S::ticks(capacity, (u64::MAX, Instant::ZERO)).ok_or(no_room)?;
        let regulator = RegulatorIn::with_queue(queue, 0).map_err(|_| no_room)?;
        let predictor =
            NetworkPredictor::new(config.predictor_config()).map_err(ConfigError::Predictor)?;
        let setup = Setup::new(
            config.role,
            config.period,
            config.underflow,
            config.watchdog,
        );
        let policy = S::Policy::make(config.playout, &setup).map_err(ConfigError::NoRoom)?;
        let mut ep = Endpoint {
            phase: Phase::Handshake,
            period: config.period,
            ns: 0,
            regulator,
            policy,
            sync: ClockSync::new(),
            predictor,
            next_tick: None,
            deadline: Some(now + config.handshake_timeout),
            regime: Regime::new(now),
            out: Outbox {
                tx: Deque::new(),
                next_seq: 0,
                sample,
                sample_fresh: false,
                answers: None,
                sent_ticks,
            },
            heard: Heard::new(config.period),
            rel: Released::new(now),
            peer: None,
            seating: seat::Seating::new(config.role, config.seat),
            applied: applied::AppliedOut::new(),
            dgram,
            events: Deque::new(),
            events_dropped: 0,
            probes: probes::ProbeLog::default(),
            stats: Stats::default(),
            config,
        };
        if config.role == Role::Base {
            ep.queue_tx(Tx::Hello);
        }
        Ok(ep)
    }

    // ----- driver interface -------------------------------------------------

    /// A frame arrived at `now`. An error ends the link (see
    /// [`LinkError::is_fatal`]); a Close frame for the peer is then queued.
    pub fn handle_frame(&mut self, now: Instant, bytes: &[u8]) -> Result<(), LinkError> {
        if self.phase == Phase::Closed {
            return Err(LinkError::Closed);
        }
        let frame = match Frame::new_checked(bytes) {
            Ok(f) => f,
            Err(e) => return Err(self.fail(LinkError::from_wire(e))),
        };
        self.stats.frames_received += 1;
        match self.receive(now, &frame) {
            Ok(()) => Ok(()),
            Err(e) => Err(self.fail(e)),
        }
    }

    /// A deadline from [`poll_timeout`](Self::poll_timeout) passed: runs every
    /// tick due by `now`, in order, and checks the handshake timeout. Releases
    /// and sends are stamped `now`, the time they really happen.
    ///
    /// A driver held for many periods has many ticks to run at once. When
    /// the event queue it found with room fills up, the catch-up stops
    /// there rather than drop releases: [`catching_up`](Self::catching_up)
    /// then says so, and the driver takes the events and calls again at
    /// once. Called with its queue already full, it runs every tick due,
    /// and the events past the queue are dropped and counted in
    /// [`events_dropped`](Self::events_dropped).
    pub fn handle_timeout(&mut self, now: Instant) {
        if self.phase == Phase::Closed {
            return;
        }
        let room = self.events.len() + STEP_EVENTS <= EVENT_QUEUE;
        loop {
            if room && self.events.len() + STEP_EVENTS > EVENT_QUEUE {
                return;
            }
            let tick = self.next_tick.filter(|&t| t <= now);
            // A sample is stamped with its tick's scheduled time, and which
            // sample is due is the schedule's to say: a late driver shows in
            // the delays the peer measures (and in the release stamps), but
            // neither bunches the send stamps of two ticks (which the
            // adaptive playout would take for two samples due at once) nor
            // makes a late release find the next sample due too.
            let release = self.policy.next_release();
            match (release.filter(|&r| r <= now), tick) {
                (Some(r), Some(t)) if r <= t => self.release(r, now),
                (Some(r), None) => self.release(r, now),
                (_, Some(t)) => {
                    self.next_tick = Some(self.following_tick(t));
                    self.tick(t, now);
                }
                (None, None) => break,
            }
            if self.phase == Phase::Closed {
                return;
            }
        }
        if self.deadline.is_some_and(|d| d <= now) {
            self.fail(LinkError::Timeout);
        } else if let Some(silent_for) = self.silent_past_liveness(now) {
            self.fail(LinkError::PeerSilent { silent_for });
        }
    }

    /// Whether ticks or releases due by `now` are still to run:
    /// [`handle_timeout`](Self::handle_timeout) stopped its catch-up at a
    /// full event queue. Take the events, then call it again.
    #[must_use]
    pub fn catching_up(&self, now: Instant) -> bool {
        self.phase != Phase::Closed
            && (self.next_tick.is_some_and(|t| t <= now)
                || self.policy.next_release().is_some_and(|r| r <= now))
    }

    /// The next time [`handle_timeout`](Self::handle_timeout) must be called.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        [
            self.next_tick,
            self.policy.next_release(),
            self.deadline,
            self.liveness_deadline(),
            self.repeat_due(),
        ]
        .into_iter()
        .flatten()
        .min()
    }

    /// Writes the next frame to send into `buf` (use [`wire::MAX_FRAME_LEN`]
    /// bytes) and returns its length; `Ok(None)` when nothing is due.
    #[must_use = "a frame written to the buffer must be sent"]
    pub fn poll_transmit(
        &mut self,
        now: Instant,
        buf: &mut [u8],
    ) -> Result<Option<usize>, LinkError> {
        let Some(&item) = self.out.tx.front() else {
            match self.poll_applied(now, buf) {
                Ok(None) => {}
                Ok(Some(n)) => return Ok(Some(n)),
                Err(wire::WireError::BufferTooSmall { needed, got }) => {
                    return Err(LinkError::BufferTooSmall { needed, got });
                }
                Err(e) => return Err(LinkError::Wire(e)),
            }
            return self.poll_repeat(now, buf);
        };
        let (seq, sent_at) = match item {
            Tx::Probe { seq } | Tx::Sample { seq } => (seq, self.tick_of(seq).unwrap_or(now)),
            _ => (self.out.next_seq, now),
        };
        let header = Header {
            seq,
            sent_at,
            // The hold runs to this frame's stamp, so that the peer's
            // `stamp − hold` is the echoed frame's arrival: a frame that
            // arrived after the stamp (a late driver) is echoed by the next.
            echo: self.heard.echo_at(sent_at),
            // A sample names what it answers; other frames the newest release.
            released: match item {
                Tx::Sample { .. } => self.out.answers,
                _ => self.rel.released_seq,
            },
            term: self.seating.announced,
        };
        let n = match self.write_item(&header, item, buf) {
            Ok(n) => n,
            Err(wire::WireError::BufferTooSmall { needed, got }) => {
                return Err(LinkError::BufferTooSmall { needed, got });
            }
            // Our own frames are valid by construction (samples are checked in
            // `set_sample`); anything else is a bug worth surfacing, not a panic.
            Err(e) => return Err(LinkError::Wire(e)),
        };
        let _ = self.out.tx.pop_front();
        self.stats.frames_sent += 1;
        if let Tx::Sample { .. } = item {
            self.arm_repeats(now);
            self.stats.samples_sent += 1;
            if !self.out.sample_fresh {
                self.stats.samples_repeated += 1;
            }
            self.out.sample_fresh = false;
        }
        Ok(Some(n))
    }

    /// The next event for the application.
    #[must_use]
    pub fn poll_event(&mut self) -> Option<Event<S::Values>> {
        self.events.pop_front()
    }

    // ----- application interface ---------------------------------------------

    /// Sets the sample the next frame carries: that of the tick now running
    /// when the application answers in the driver's loop (the drive
    /// contract's step 3), else the next tick's. The latest one given wins;
    /// if none is given, the previous one is sent again and counted in
    /// [`Stats::samples_repeated`]. Before the first call the sample is all
    /// zeros. It answers the newest peer sample released so far: its
    /// frame's `released` names that one, and the peer's GRTT runs from it.
    pub fn set_sample(&mut self, values: &[f64]) -> Result<(), LinkError> {
        let width = self.config.sent_width();
        check_sample(values, width)?;
        if let Some(dst) = self.out.sample.as_mut().get_mut(..usize::from(width)) {
            dst.copy_from_slice(values);
        }
        self.out.sample_fresh = true;
        self.out.answers = self.rel.released_seq;
        Ok(())
    }

    /// Ends the link because the driver found it broken — the connection
    /// dropped ([`LinkError::Disconnected`]) or the byte stream cannot be
    /// deframed ([`LinkError::Wire`]). A Close frame is queued (the driver
    /// may still be able to send it) and [`Event::Closed`] reports `error`.
    pub fn abort(&mut self, error: LinkError) {
        self.fail(error);
    }

    /// Ends the link: a Close frame is queued for the peer.
    pub fn close(&mut self) {
        if self.phase != Phase::Closed {
            self.queue_tx(Tx::Close {
                reason: wire::CloseReason::Normal,
            });
            self.enter_closed(None);
        }
    }

    // ----- observation -------------------------------------------------------

    /// Where the protocol is.
    #[must_use]
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// Whether the link is over.
    #[must_use]
    pub fn is_closed(&self) -> bool {
        self.phase == Phase::Closed
    }

    /// The configuration.
    #[must_use]
    pub fn config(&self) -> &Config {
        &self.config
    }

    /// The current period.
    #[must_use]
    pub fn period(&self) -> Duration {
        self.period
    }

    /// The regulator's current nominal size (0 before the first start).
    #[must_use]
    pub fn ns(&self) -> usize {
        self.ns
    }

    /// How many samples the regulator can hold: its nominal size stays
    /// below this.
    #[must_use]
    pub fn capacity(&self) -> usize {
        self.regulator.capacity()
    }

    /// Samples in the regulator now.
    #[must_use]
    pub fn queue_len(&self) -> usize {
        self.regulator.len()
    }

    /// Occupancy before each release since the current parameters started.
    #[must_use]
    pub fn occupancy(&self) -> Option<Occupancy> {
        self.regulator.occupancy()
    }

    /// The counters.
    #[must_use]
    pub fn stats(&self) -> Stats {
        let mut stats = self.stats;
        if let Some(d) = self.policy.delay() {
            stats.playout_delay_s = d.as_secs_f64();
            stats.playout_delay_ticks = d.as_nanos().div_ceil(self.period.as_nanos().max(1));
        }
        stats
    }

    /// Events the application did not drain in time (the queue holds 32).
    #[must_use]
    pub fn events_dropped(&self) -> u64 {
        self.events_dropped
    }

    /// The network predictor's latest forecast.
    #[must_use]
    pub fn prediction(&self) -> Option<Prediction> {
        self.predictor.last()
    }

    /// The network predictor.
    #[must_use]
    pub fn predictor(&self) -> &NetworkPredictor {
        &self.predictor
    }

    /// The latest network round trip measured.
    #[must_use]
    pub fn last_nrtt(&self) -> Option<Duration> {
        self.heard.last_nrtt
    }

    /// The estimate of the peer's clock offset and skew.
    #[must_use]
    pub fn clock_sync(&self) -> &ClockSync {
        &self.sync
    }

    #[cfg(test)]
    /// The end-to-end delay the playout policy holds now (the release time
    /// on the local clock minus the send time on the peer's, corrected by
    /// the offset estimate for a policy that maps the clocks); `None` for
    /// the FIFO, whose delay is its queue's, and before the policy has one.
    #[must_use]
    pub(crate) fn playout_delay(&self) -> Option<Duration> {
        self.last_tick()?;
        self.policy.delay()
    }

    // ----- internals ---------------------------------------------------------

    fn hello(&self) -> Hello {
        Hello {
            role: self.config.role,
            mode: self.config.mode.into(),
            underflow: self.config.underflow.into(),
            command_width: self.config.command_width,
            state_width: self.config.state_width,
            period: self.config.period,
            layout: self.config.layout,
            seat: match self.config.role {
                Role::Base => self.config.seat,
                Role::Remote => self.seating.given.unwrap_or(Seat::Observe),
            },
            session: match self.config.transport {
                Transport::Stream => 0,
                Transport::Datagram { .. } => self.config.session,
            },
            regulation: self.regulation_name(),
        }
    }

    /// This side's regulation as its Hello names it.
    pub(super) fn regulation_name(&self) -> wire::RegulationName {
        wire::RegulationName::lossy(crate::Regulation::name_of(
            self.config.mode,
            self.config.playout,
        ))
    }

    fn queue_tx(&mut self, item: Tx) {
        if self.out.tx.push_back(item).is_err() {
            // The driver stopped draining: give up the oldest waiting frame
            // rather than the newest, and count it.
            let _ = self.out.tx.pop_front();
            self.stats.tx_dropped += 1;
            let _ = self.out.tx.push_back(item);
        }
    }

    fn emit(&mut self, event: Event<S::Values>) {
        if self.events.push_back(event).is_err() {
            self.events_dropped += 1;
        }
    }

    /// Ends the link because of `error`; returns it for the caller.
    fn fail(&mut self, error: LinkError) -> LinkError {
        if self.phase != Phase::Closed {
            if !matches!(
                error,
                LinkError::PeerClosed { .. } | LinkError::Disconnected
            ) {
                self.queue_tx(Tx::Close {
                    reason: error.close_reason(),
                });
            }
            self.enter_closed(Some(error));
        }
        error
    }

    fn enter_closed(&mut self, error: Option<LinkError>) {
        self.phase = Phase::Closed;
        self.next_tick = None;
        self.policy.stop();
        self.deadline = None;
        self.drop_repeats();
        self.applied.clear();
        self.emit(Event::Closed { error });
    }

    /// The first tick of the grid `tick_origin + k·T` at or after `now`.
    fn next_grid_tick(&self, now: Instant) -> Instant {
        let origin = self.config.tick_origin;
        let Some(since) = now.checked_duration_since(origin) else {
            return origin;
        };
        let t = self.period.as_nanos().max(1);
        let k = since.as_nanos().div_ceil(t);
        origin + Duration::from_nanos(k.saturating_mul(t))
    }

    /// The tick scheduled at `at`, run at `t`.
    fn tick(&mut self, at: Instant, t: Instant) {
        match self.phase {
            Phase::Init | Phase::Pausing => {
                let seq = self.take_seq(at);
                self.queue_tx(Tx::Probe { seq });
            }
            Phase::Running => {
                let next_tick = self.next_tick;
                let (policy, view) = self.policy_view();
                let due = policy.tick(at, t, next_tick, &view);
                self.heed();
                if let Some(due) = due {
                    self.take(at, t, due);
                }
                let seq = self.take_seq(at);
                // An adaptive remote ticks with its releases: its grid moves
                // to them after the first ones. States sent from a tick
                // before that, on the old grid, would reach the base closer
                // than a period to the next (a rise and a repeat there), and
                // answer no command yet: probes go out until a tick falls on
                // a release and the next release is a period later, or for
                // GRID_SETTLE_TICKS at most (a loaded host can keep the two
                // apart, and a remote that sends only probes is no link).
                if !self.regime.grid_settled
                    && (self.config.role == Role::Base
                        || self.regime.ticks_running >= GRID_SETTLE_TICKS
                        || self.policy.grid_settled(at))
                {
                    self.regime.grid_settled = true;
                }
                // A remote's link whose base holds no control (an observer,
                // a base waiting for it) answers no command: its states
                // wait for no grid.
                let answers_none = self.config.role == Role::Remote
                    && self.seating.held.is_none()
                    && self.seating.asked != crate::wire::Seat::Control;
                if (self.regime.grid_settled || answers_none) && self.sends_samples() {
                    self.queue_tx(Tx::Sample { seq });
                } else {
                    self.queue_tx(Tx::Probe { seq });
                }
                self.regime.ticks_running += 1;
            }
            Phase::Handshake | Phase::Closed => return,
        }
        let prediction = self.predictor.step();
        if let Some(p) = prediction {
            self.maybe_adapt(t, p);
        }
    }

    /// Where the tick that took `seq` is kept in `sent_ticks`.
    fn tick_index(&self, seq: u64) -> usize {
        let len = self.out.sent_ticks.as_ref().len().max(1);
        (seq % len as u64) as usize
    }

    /// The scheduled time of the tick that took `seq`, while it is within
    /// the last [`capacity`](Self::capacity) ticks.
    fn tick_of(&self, seq: u64) -> Option<Instant> {
        match self.out.sent_ticks.as_ref().get(self.tick_index(seq)) {
            Some(&(s, at)) if s == seq => Some(at),
            _ => None,
        }
    }

    fn take_seq(&mut self, t: Instant) -> u64 {
        let seq = self.out.next_seq;
        self.out.next_seq += 1;
        let i = self.tick_index(seq);
        if let Some(cell) = self.out.sent_ticks.as_mut().get_mut(i) {
            *cell = (seq, t);
        }
        seq
    }

    /// When the peer will have been silent for [`Config::liveness`], after
    /// the handshake.
    fn liveness_deadline(&self) -> Option<Instant> {
        if matches!(self.phase, Phase::Handshake | Phase::Closed) {
            return None;
        }
        let (_, arrived) = self.heard.newest?;
        Some(arrived + self.config.liveness?)
    }

    /// How long the peer has been silent, once that is past
    /// [`Config::liveness`].
    fn silent_past_liveness(&self, now: Instant) -> Option<Duration> {
        let due = self.liveness_deadline()?;
        let (_, arrived) = self.heard.newest?;
        (now >= due).then(|| now - arrived)
    }

    /// The tick after the one scheduled at `t`: a period later, unless the
    /// policy moves a remote's ticks onto its releases
    /// ([`Policy::following_tick`]). Two hubs start their grids anywhere
    /// within a period of each other, and a grid left apart by `φ` made each
    /// direction's true delay its announced one plus or minus `φ`.
    fn following_tick(&self, t: Instant) -> Instant {
        self.policy.following_tick(t + self.period)
    }

    #[cfg(test)]
    fn last_tick(&self) -> Option<Instant> {
        Some(self.next_tick? - self.period)
    }
}

/// An application's sample of `width` finite values, or why not.
pub(super) fn check_sample(values: &[f64], width: u16) -> Result<(), LinkError> {
    if values.len() != usize::from(width) {
        return Err(LinkError::SampleShape {
            expected: width,
            got: values.len(),
        });
    }
    match values.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(LinkError::NonFinite { index }),
        None => Ok(()),
    }
}
