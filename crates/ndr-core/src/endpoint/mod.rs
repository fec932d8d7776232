//! The link endpoint: a sans-IO state machine for one side of the link.
//!
//! An [`Endpoint`] never reads a clock and never touches a socket. Its driver
//! (the simulator, the tokio link, a test) passes time in and moves bytes:
//!
//! ```text
//! loop {
//!     bytes arrived  → endpoint.handle_frame(now, frame_bytes)
//!     deadline hit   → endpoint.handle_timeout(now)
//!     while let Some(event) = endpoint.poll_event() { app reacts; maybe endpoint.set_sample(..) }
//!     while let Some(n) = endpoint.poll_transmit(now, &mut buf)? { send buf[..n] }
//!     sleep until endpoint.poll_timeout()
//! }
//! ```
//!
//! Events are drained before transmits, so a sample the application sets in
//! response to a release goes out in the same tick: the remote's state sent
//! at tick `m` reflects the command released at tick `m`.
//!
//! # Protocol
//!
//! 1. **Handshake.** The base sends Hello (role, mode, axes, period); the
//!    remote checks it against its own configuration and answers with its
//!    Hello. Any mismatch ends the link with a specific [`LinkError`] and a
//!    Close frame carrying its reason.
//! 2. **Initialization pattern.** Both sides send a probe (a Data frame
//!    without channels) every tick and echo the newest frame they received.
//!    Once the base has measured [`INIT_EXCHANGES`] round trips it sets
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

mod config;
mod error;
mod event;
mod rx_check;
mod stats;

use heapless::Deque;

pub use config::{
    Adaptation, Config, ConfigError, DEFAULT_LIVENESS, MIN_PERIOD, Mode, Underflow, UnknownName,
};
pub use error::LinkError;
pub use event::{Event, Release, Status};
pub use stats::{Running, Stats};

pub use crate::playout::schedule::{
    DELAY_QUANTUM, MAPPING_SLEW, RELEASE_SLEW_STEPS, delay_quantum, delay_quantum_for,
};

use crate::playout::schedule::{self, Context, Plan, Queued, Schedule};
use crate::playout::{Adaptive, AdaptiveSlot, Target, TargetDelay};
use crate::predictor::{NetworkPredictor, Prediction};
use crate::regulator::{self, Occupancy, Regulator, Tick};
use crate::sizing::{INIT_EXCHANGES, InitPattern};
use crate::sync::ClockSync;
use crate::time::{Duration, Instant};
use crate::wire::{
    self, Control, Echo, Frame, Header, Hello, Kind, Message, Payload, Role, control_op,
};
use event::Head;
use rx_check::RxCheck;

/// A pause or a re-run initialization pattern may take this many times
/// what it needs (its probes at the period, plus the slowest round trip
/// seen) before it times out, if that is longer than the handshake timeout.
pub const PATTERN_SLACK: u64 = 3;

fn ns_i64(t: Instant) -> i64 {
    i64::try_from(t.as_nanos()).unwrap_or(i64::MAX)
}

/// Where the endpoint is in the protocol.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
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
struct Slot<const C: usize> {
    head: Head,
    peer_released: Option<u64>,
    len: u16,
    values: [f64; C],
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Tx {
    Hello,
    Probe { seq: u64 },
    Sample { seq: u64 },
    Control { op: u8, ns: u16, period: Duration },
    Close { reason: u16 },
}

/// Transmissions that may wait for the driver: a few ticks' worth.
const TX_QUEUE: usize = 8;
/// Events that may wait for the application.
const EVENT_QUEUE: usize = 32;

/// One side of a regulated link, with samples of up to `C` channels and a
/// regulator of capacity `N`.
///
/// The endpoint holds `N` queued samples of `C` values inline (no heap):
/// about `N·(8·C + 48)` bytes. Box it when `N` is large. `A` holds the
/// adaptive playout's histogram (about 7 KiB): an endpoint that never runs
/// [`Playout::Adaptive`](crate::playout::Playout::Adaptive) can drop it with
/// [`NoAdaptive`](crate::playout::NoAdaptive).
#[derive(Clone, Debug)]
pub struct Endpoint<const C: usize, const N: usize, A: AdaptiveSlot = Adaptive> {
    config: Config,
    phase: Phase,
    period: Duration,
    ns: usize,
    regulator: Regulator<Slot<C>, N>,
    /// Target-delay playout: the policy's state (`None`: the paper's FIFO).
    target: Option<Target<A>>,
    /// Target-delay playout: frames sent at or before this (peer clock) had
    /// their slot at a tick already run.
    passed: Option<Instant>,
    /// The peer's clock offset and skew.
    sync: ClockSync,
    /// A target playout other than the adaptive one: the constant
    /// end-to-end delay now, in ticks (rounded up).
    delay_ticks: Option<u64>,
    /// Adaptive playout: its release schedule.
    schedule: Option<Schedule>,
    predictor: NetworkPredictor,
    pattern: InitPattern,
    next_tick: Option<Instant>,
    deadline: Option<Instant>,
    ticks_running: u64,
    /// Running: the ticks send samples (an adaptive remote's only once its
    /// grid has moved to its releases).
    grid_settled: bool,
    started_once: bool,
    /// Dynamic mode: the parameters the current pause will resume with.
    pending: Option<(Duration, usize)>,
    tx: Deque<Tx, TX_QUEUE>,
    next_seq: u64,
    sample: [f64; C],
    sample_fresh: bool,
    /// Scheduled time of each tick that sent a sample or probe, by `seq mod
    /// N`: its frame's send stamp, and the start of its GRTT.
    sent_ticks: [(u64, Instant); N],
    /// What the next frames from the peer may be.
    rx_check: RxCheck,
    /// Newest frame received: (its `sent_at`, our arrival time), echoed back.
    newest_rx: Option<(Instant, Instant)>,
    /// Previous Data frame received, for the reception gap.
    prev_data_rx: Option<(Instant, Instant)>,
    /// Adaptive: the frames now arriving drain an outage's backlog.
    outage_burst: bool,
    /// Newest of our frames an NRTT was measured on.
    newest_echo: Option<Instant>,
    init_started: Instant,
    last_nrtt: Option<Duration>,
    released_seq: Option<u64>,
    grtt_acked: Option<u64>,
    due_seq: Option<u64>,
    last_release: Option<Release<C>>,
    /// Last fresh release, or the start of the running phase, for the watchdog.
    last_fresh: Instant,
    lost: bool,
    peer: Option<Hello>,
    events: Deque<Event<C>, EVENT_QUEUE>,
    events_dropped: u64,
    stats: Stats,
}

impl<const C: usize, const N: usize, A: AdaptiveSlot> Endpoint<C, N, A> {
    /// An endpoint that starts at `now`. A base queues its Hello at once.
    pub fn new(config: Config, now: Instant) -> Result<Self, ConfigError> {
        config.validate()?;
        if usize::from(config.axes) > C {
            return Err(ConfigError::Channels {
                axes: config.axes,
                capacity: C,
            });
        }
        let predictor =
            NetworkPredictor::new(config.predictor_config()).map_err(ConfigError::Predictor)?;
        let mut ep = Endpoint {
            phase: Phase::Handshake,
            period: config.period,
            ns: 0,
            regulator: Regulator::new(0).map_err(|_| ConfigError::Channels {
                axes: config.axes,
                capacity: N,
            })?,
            target: config
                .playout
                .target_in(config.period)
                .map_err(ConfigError::NoAdaptiveRoom)?,
            passed: None,
            sync: ClockSync::new(),
            delay_ticks: None,
            schedule: None,
            predictor,
            pattern: InitPattern::new(),
            next_tick: None,
            deadline: Some(now + config.handshake_timeout),
            ticks_running: 0,
            grid_settled: false,
            started_once: false,
            pending: None,
            tx: Deque::new(),
            next_seq: 0,
            sample: [0.0; C],
            sample_fresh: false,
            sent_ticks: [(u64::MAX, Instant::ZERO); N],
            rx_check: RxCheck::new(config.period),
            newest_rx: None,
            prev_data_rx: None,
            outage_burst: false,
            newest_echo: None,
            init_started: now,
            last_nrtt: None,
            released_seq: None,
            grtt_acked: None,
            due_seq: None,
            last_release: None,
            last_fresh: now,
            lost: false,
            peer: None,
            events: Deque::new(),
            events_dropped: 0,
            stats: Stats::default(),
            config,
        };
        if ep.is_adaptive() {
            ep.schedule = Some(Schedule::new(
                config.role,
                config.period,
                ep.quantum_at(config.period),
                config.watchdog,
            ));
        }
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
    pub fn handle_timeout(&mut self, now: Instant) {
        if self.phase == Phase::Closed {
            return;
        }
        loop {
            let tick = self.next_tick.filter(|&t| t <= now);
            // A sample is stamped with its tick's scheduled time, and which
            // sample is due is the schedule's to say: a late driver shows in
            // the delays the peer measures (and in the release stamps), but
            // neither bunches the send stamps of two ticks (which the
            // adaptive playout would take for two samples due at once) nor
            // makes a late release find the next sample due too.
            let release = self.schedule.as_ref().and_then(Schedule::next_release);
            match (release.filter(|&r| r <= now), tick) {
                (Some(r), Some(t)) if r <= t => self.release_apart(r, now),
                (Some(r), None) => self.release_apart(r, now),
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

    /// The next time [`handle_timeout`](Self::handle_timeout) must be called.
    #[must_use]
    pub fn poll_timeout(&self) -> Option<Instant> {
        [
            self.next_tick,
            self.schedule.as_ref().and_then(Schedule::next_release),
            self.deadline,
            self.liveness_deadline(),
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
        let Some(&item) = self.tx.front() else {
            return Ok(None);
        };
        let (seq, sent_at) = match item {
            Tx::Probe { seq } | Tx::Sample { seq } => (seq, self.tick_of(seq).unwrap_or(now)),
            _ => (self.next_seq, now),
        };
        let header = Header {
            seq,
            sent_at,
            // The hold runs to this frame's stamp, so that the peer's
            // `stamp − hold` is the echoed frame's arrival; a frame that
            // arrived after the stamp (a late driver) is echoed by the next.
            echo: self
                .newest_rx
                .filter(|&(_, arrived)| arrived <= sent_at)
                .map(|(echoed, arrived)| Echo {
                    sent_at: echoed,
                    hold: sent_at - arrived,
                }),
            released: self.released_seq,
        };
        let axes = usize::from(self.config.axes);
        let msg = match item {
            Tx::Hello => Message::Hello(self.hello()),
            Tx::Probe { .. } => Message::Data(&[]),
            Tx::Sample { .. } => Message::Data(self.sample.get(..axes).unwrap_or(&self.sample)),
            Tx::Control { op, ns, period } => Message::Control(Control { op, ns, period }),
            Tx::Close { reason } => Message::Close(wire::Close { reason }),
        };
        let n = match wire::encode(&header, &msg, buf) {
            Ok(n) => n,
            Err(wire::WireError::BufferTooSmall { needed, got }) => {
                return Err(LinkError::BufferTooSmall { needed, got });
            }
            // Our own frames are valid by construction (samples are checked in
            // `set_sample`); anything else is a bug worth surfacing, not a panic.
            Err(e) => return Err(LinkError::Wire(e)),
        };
        let _ = self.tx.pop_front();
        self.stats.frames_sent += 1;
        if let Tx::Sample { .. } = item {
            self.stats.samples_sent += 1;
            if !self.sample_fresh {
                self.stats.samples_repeated += 1;
            }
            self.sample_fresh = false;
        }
        Ok(Some(n))
    }

    /// The next event for the application.
    #[must_use]
    pub fn poll_event(&mut self) -> Option<Event<C>> {
        self.events.pop_front()
    }

    // ----- application interface ---------------------------------------------

    /// Sets the sample sent at the next tick (the latest one given wins; if
    /// none is given before a tick, the previous one is sent again and
    /// counted in [`Stats::samples_repeated`]). Before the first call the
    /// sample is all zeros.
    pub fn set_sample(&mut self, values: &[f64]) -> Result<(), LinkError> {
        let axes = usize::from(self.config.axes);
        if values.len() != axes {
            return Err(LinkError::SampleShape {
                expected: self.config.axes,
                got: values.len(),
            });
        }
        if let Some(index) = values.iter().position(|v| !v.is_finite()) {
            return Err(LinkError::NonFinite { index });
        }
        if let Some(dst) = self.sample.get_mut(..axes) {
            dst.copy_from_slice(values);
        }
        self.sample_fresh = true;
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
                reason: wire::close_reason::NORMAL,
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
        if let Some(s) = &self.schedule
            && let (Some(d), Some(ticks)) = (s.delay(), s.delay_ticks())
        {
            stats.playout_delay_s = d.as_secs_f64();
            stats.playout_delay_ticks = ticks;
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
        self.last_nrtt
    }

    /// The estimate of the peer's clock offset and skew.
    #[must_use]
    pub fn clock_sync(&self) -> &ClockSync {
        &self.sync
    }

    /// Target-delay playout: the end-to-end delay samples get now (the
    /// release time on the local clock minus the send time on the peer's,
    /// corrected by the offset estimate for [`Playout::Adaptive`]); `None`
    /// for the FIFO and before the policy has a target.
    ///
    /// [`Playout::Adaptive`]: crate::playout::Playout::Adaptive
    #[must_use]
    pub fn playout_delay(&self) -> Option<Duration> {
        self.current_delay(self.last_tick()?)
    }

    /// The peer's Hello, once the handshake is done.
    #[must_use]
    pub fn peer(&self) -> Option<Hello> {
        self.peer
    }

    // ----- internals ---------------------------------------------------------

    fn hello(&self) -> Hello {
        Hello {
            role: self.config.role,
            mode: self.config.mode.code(),
            underflow: self.config.underflow.code(),
            axes: self.config.axes,
            period: self.config.period,
        }
    }

    fn queue_tx(&mut self, item: Tx) {
        if self.tx.push_back(item).is_err() {
            // The driver stopped draining: give up the oldest waiting frame
            // rather than the newest, and count it.
            let _ = self.tx.pop_front();
            self.stats.tx_dropped += 1;
            let _ = self.tx.push_back(item);
        }
    }

    fn emit(&mut self, event: Event<C>) {
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
        if let Some(s) = &mut self.schedule {
            s.stop();
        }
        self.deadline = None;
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

    fn receive(&mut self, now: Instant, frame: &Frame<&[u8]>) -> Result<(), LinkError> {
        let sent_at = frame.sent_at();
        // A frame handed over a watchdog's time after a deadline the driver
        // missed: the driver itself stalled (its process stopped), and what
        // the frame's arrival says is the stall's, not the network's.
        let stalled = match (self.config.watchdog, self.poll_timeout()) {
            (Some(w), Some(due)) => now >= due + w,
            _ => false,
        };
        // Checked before anything of the frame is used (see `rx_check`).
        if let Some(echo) = frame.echo() {
            self.rx_check
                .observe_echo(echo.sent_at, echo.hold, sent_at, now);
        }
        self.rx_check.check_stamp(sent_at, now)?;
        if let Payload::Data(_) = frame.payload() {
            if self.phase == Phase::Handshake {
                return Err(self.unexpected(Kind::Data));
            }
            self.stats.frames_missing += self.rx_check.accept_data(frame.seq(), sent_at)?;
        }
        let (floor, shifts) = (self.floor_ns(now), self.sync.rx().shifts());
        // A stamp nothing could check yet (the first Hello) stays out of the
        // clock estimate.
        if self.rx_check.bounded() {
            self.sync.observe_arrival(sent_at, now);
        }
        // A level shift of the received floor (a route change): the delays
        // in the adaptive window since the shift were measured above the
        // old floor, and would count the shift twice on top of the new one
        // (a +150 ms step held the delay 150 ms too high for two minutes).
        if self.sync.rx().shifts() != shifts
            && let (Some(before), Some(after), Some(Target::Adaptive(a))) =
                (floor, self.floor_ns(now), &mut self.target)
        {
            a.rebase(
                Duration::from_nanos(after.saturating_sub(before).unsigned_abs()),
                after > before,
            );
        }
        if let Some(theta) = self.sync.offset_at(now) {
            self.stats.clock_offset_s = theta;
        }
        self.stats.clock_skew_ppm = self.sync.skew() * 1e6;
        if let Some(echo) = frame.echo() {
            self.measure_nrtt(now, echo, sent_at)?;
        }
        self.newest_rx = Some((sent_at, now));
        match frame.payload() {
            Payload::Hello(hello) => self.receive_hello(now, hello),
            Payload::Data(channels) => {
                let prev = self.prev_data_rx.replace((sent_at, now));
                if let Some((prev_sent, prev_arrived)) = prev {
                    // How much later than its schedule this frame came,
                    // relative to the previous one (never negative).
                    let gap = (now - prev_arrived).saturating_sub(sent_at - prev_sent);
                    self.predictor.observe_gap(gap);
                }
                self.observe_one_way(sent_at, now, prev, stalled);
                if channels.is_empty() {
                    self.stats.probes_received += 1;
                    return match self.phase {
                        Phase::Handshake => Err(self.unexpected(Kind::Data)),
                        _ => Ok(()),
                    };
                }
                let mut values = [0.0; C];
                let axes = usize::from(self.config.axes);
                if channels.len() != axes || channels.copy_to(&mut values).is_err() {
                    return Err(LinkError::ChannelCount {
                        expected: self.config.axes,
                        got: channels.len(),
                    });
                }
                let slot = Slot {
                    head: Head {
                        seq: frame.seq(),
                        sent_at,
                        arrived_at: now,
                    },
                    peer_released: frame.released(),
                    len: self.config.axes,
                    values,
                };
                self.receive_sample(now, slot)
            }
            Payload::Control(control) => self.receive_control(now, control),
            Payload::Close(close) => Err(LinkError::PeerClosed {
                reason: close.reason,
            }),
        }
    }

    fn unexpected(&self, kind: Kind) -> LinkError {
        LinkError::Unexpected {
            kind,
            phase: self.phase.name(),
        }
    }

    fn measure_nrtt(&mut self, now: Instant, echo: Echo, t3: Instant) -> Result<(), LinkError> {
        // Several peer frames can echo the same one of ours: measure once.
        if self.newest_echo.is_some_and(|t| echo.sent_at <= t) {
            return Ok(());
        }
        let Some(rtt) = now.checked_duration_since(echo.sent_at) else {
            // An echo of a frame we have not sent yet: the peer is lying.
            return Err(LinkError::Unexpected {
                kind: Kind::Data,
                phase: "an echo from the future",
            });
        };
        self.newest_echo = Some(echo.sent_at);
        self.sync.observe_echo(echo.sent_at, echo.hold, t3);
        if let Some(d) = self.sync.one_way_tx(echo.sent_at, echo.hold, t3) {
            self.stats.one_way_tx.push(d);
        }
        let nrtt = rtt.saturating_sub(echo.hold);
        self.last_nrtt = Some(nrtt);
        self.stats.nrtt.push_duration(nrtt);
        self.predictor.observe_nrtt(nrtt);
        if self.phase == Phase::Init
            && self.config.role == Role::Base
            && echo.sent_at >= self.init_started
        {
            let _ = self.pattern.record_nrtt(nrtt);
            if self.pattern.len() >= INIT_EXCHANGES {
                self.finish_init(now)?;
            }
        }
        Ok(())
    }

    fn receive_hello(&mut self, now: Instant, hello: Hello) -> Result<(), LinkError> {
        if self.phase != Phase::Handshake {
            return Err(self.unexpected(Kind::Hello));
        }
        let ours = self.config;
        if hello.role == ours.role {
            return Err(LinkError::RoleMismatch { role: ours.role });
        }
        if hello.axes != ours.axes {
            return Err(LinkError::AxesMismatch {
                ours: ours.axes,
                theirs: hello.axes,
            });
        }
        if hello.period != ours.period {
            return Err(LinkError::PeriodMismatch {
                ours: ours.period,
                theirs: hello.period,
            });
        }
        if hello.mode != ours.mode.code() {
            return Err(LinkError::ModeMismatch {
                ours: ours.mode,
                theirs: hello.mode,
            });
        }
        self.peer = Some(hello);
        if ours.role == Role::Remote {
            self.queue_tx(Tx::Hello);
        }
        self.emit(Event::Connected { peer: hello });
        self.enter_init(now);
        Ok(())
    }

    fn receive_sample(&mut self, now: Instant, slot: Slot<C>) -> Result<(), LinkError> {
        // Before the handshake a Data frame is a protocol error, not a sample.
        if self.phase == Phase::Handshake {
            return Err(self.unexpected(Kind::Data));
        }
        self.stats.samples_received += 1;
        match self.phase {
            Phase::Running => {}
            // A sample of the stream a pause ended, still in flight.
            _ => {
                self.stats.discarded += 1;
                return Ok(());
            }
        }
        if self.config.underflow == Underflow::DropLate && self.slot_passed(&slot) {
            self.stats.late += 1;
            self.note_lost();
            return Ok(());
        }
        // Adaptive under hold: a sample held behind an outage, past its
        // slot, is stale; kept, it would stretch the delay to the outage's
        // length and replay the outage's commands.
        if self.outage_burst
            && self
                .schedule
                .as_ref()
                .and_then(|s| s.slot_at(slot.head.sent_at, now, &self.sync))
                .is_some_and(|s| s < now)
        {
            self.stats.discarded += 1;
            return Ok(());
        }
        if self.regulator.push(slot).is_err() {
            self.stats.rejected += 1;
        }
        if let Some((s, cx)) = self.adaptive() {
            s.on_queued(&cx);
        }
        Ok(())
    }

    fn receive_control(&mut self, now: Instant, control: Control) -> Result<(), LinkError> {
        let role = self.config.role;
        match (role, control.op, self.phase) {
            (Role::Remote, control_op::PAUSE_REQUEST, Phase::Running) => {
                let ns = self.checked_ns(control.ns, control.period)?;
                self.queue_tx(Tx::Control {
                    op: control_op::PAUSE_ACK,
                    ns: control.ns,
                    period: control.period,
                });
                self.stats.pauses += 1;
                self.emit(Event::Paused {
                    period: control.period,
                    ns,
                });
                self.change_period(control.period)?;
                self.enter_init(now);
                Ok(())
            }
            (Role::Base, control_op::PAUSE_ACK, Phase::Pausing) => {
                let (period, _) = self.pending.ok_or(self.unexpected(Kind::Control))?;
                self.change_period(period)?;
                self.enter_init(now);
                Ok(())
            }
            (Role::Remote, control_op::RESUME, Phase::Init) => {
                let ns = self.checked_ns(control.ns, control.period)?;
                if control.period != self.period {
                    return Err(LinkError::BadParameters {
                        ns: control.ns,
                        period: control.period,
                    });
                }
                self.start_running(ns);
                Ok(())
            }
            _ => Err(self.unexpected(Kind::Control)),
        }
    }

    fn checked_ns(&self, ns: u16, period: Duration) -> Result<usize, LinkError> {
        let fits = usize::from(ns) < N && period >= MIN_PERIOD;
        fits.then_some(usize::from(ns))
            .ok_or(LinkError::BadParameters { ns, period })
    }

    fn change_period(&mut self, period: Duration) -> Result<(), LinkError> {
        self.period = period;
        let quantum = self.quantum_at(period);
        if let Some(s) = &mut self.schedule {
            s.set_period(period, quantum);
        }
        self.rx_check.period_changed(period);
        self.predictor
            .set_period(period)
            .map_err(|_| LinkError::BadParameters { ns: 0, period })
    }

    fn enter_init(&mut self, now: Instant) {
        self.discard_queue();
        self.phase = Phase::Init;
        self.pattern.clear();
        self.init_started = now;
        self.deadline = Some(self.pattern_deadline(now));
        // Half a period after the last frame sent at least, whatever the
        // new grid: the peer refuses a stamp closer than that.
        let from = match self.next_seq.checked_sub(1).and_then(|s| self.tick_of(s)) {
            Some(last) => now.max(last + self.period / 2),
            None => now,
        };
        self.next_tick = Some(self.next_grid_tick(from));
    }

    /// The deadline of a pause or of an initialization pattern that starts
    /// at `now`: the handshake timeout, or longer when the pattern itself
    /// needs more — [`INIT_EXCHANGES`] probes at the current period and the
    /// slowest round trip seen so far, with a margin of [`PATTERN_SLACK`].
    /// The dynamic mode's period law (`NRTT/3`) makes a slow network's
    /// pattern long: at NRTT 2.6 s it takes 11 s, and a fixed limit ended
    /// the link there.
    fn pattern_deadline(&self, now: Instant) -> Instant {
        let probes = self.period * (INIT_EXCHANGES as u64 + 1);
        let slowest = Duration::from_secs_f64(self.stats.nrtt.max());
        let need = (probes + slowest).saturating_mul(PATTERN_SLACK);
        now + self.config.handshake_timeout.max(need)
    }

    fn discard_queue(&mut self) {
        self.stats.discarded += self.regulator.clear() as u64;
    }

    /// Base: the initialization pattern is complete.
    fn finish_init(&mut self, _now: Instant) -> Result<(), LinkError> {
        let ns = match self.pending.take() {
            Some((_, ns)) => ns,
            None => match self.pattern.stats() {
                Some(s) => self.config.sizing.nominal_size_for(&s, self.period),
                None => return Err(LinkError::Timeout),
            },
        };
        let ns = self.clamp_ns(ns);
        self.queue_tx(Tx::Control {
            op: control_op::RESUME,
            ns: u16::try_from(ns).unwrap_or(u16::MAX),
            period: self.period,
        });
        self.start_running(ns);
        Ok(())
    }

    fn clamp_ns(&mut self, ns: usize) -> usize {
        let limit = (N - 1).min(usize::from(u16::MAX));
        if ns > limit {
            self.stats.clamped += 1;
            limit
        } else {
            ns
        }
    }

    fn start_running(&mut self, ns: usize) {
        self.discard_queue();
        // `ns < N` was checked by the caller. A target delay keeps no stock:
        // each sample waits for its own slot.
        let stock = if self.target.is_some() { 0 } else { ns };
        let _ = self.regulator.set_nominal(stock);
        self.regulator.restart_prefill();
        // Occupancy statistics describe the current parameters.
        self.regulator.reset_occupancy();
        self.ns = ns;
        // Round trips count from this regime's first sample: an echo of a
        // sample sent before a pause would measure the pause.
        self.grtt_acked = self.next_seq.checked_sub(1);
        self.due_seq = None;
        self.passed = None;
        if let Some(s) = &mut self.schedule {
            s.restart();
        }
        self.ticks_running = 0;
        self.grid_settled = false;
        self.deadline = None;
        self.phase = Phase::Running;
        if self.started_once {
            self.stats.resizes += 1;
        }
        self.started_once = true;
        self.emit(Event::Started {
            period: self.period,
            ns,
        });
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
                if let Some((s, cx)) = self.adaptive() {
                    // Its releases have their own schedule, each at its
                    // sample's slot; until the delay is set, the ticks.
                    s.on_tick(at, t, next_tick, &cx);
                    self.delay_events();
                } else {
                    self.track_delay(t);
                    self.release(at, t);
                    self.watch(t);
                }
                let seq = self.take_seq(at);
                // An adaptive remote ticks with its releases: its grid moves
                // to them after the first ones. States sent from a tick
                // before that, on the old grid, would reach the base closer
                // than a period to the next (a rise and a repeat there), and
                // answer no command yet: probes go out until a tick falls on
                // a release and the next release is a period later.
                if !self.grid_settled
                    && (self.config.role == Role::Base
                        || self.schedule.as_ref().is_none_or(|s| s.on_release_grid(at)))
                {
                    self.grid_settled = true;
                }
                if self.grid_settled {
                    self.queue_tx(Tx::Sample { seq });
                } else {
                    self.queue_tx(Tx::Probe { seq });
                }
                self.ticks_running += 1;
            }
            Phase::Handshake | Phase::Closed => return,
        }
        let prediction = self.predictor.step();
        if let Some(p) = prediction {
            self.maybe_adapt(t, p);
        }
    }

    /// The scheduled time of the tick that took `seq`, while it is within
    /// the last `N` ticks.
    fn tick_of(&self, seq: u64) -> Option<Instant> {
        match self.sent_ticks.get((seq % N as u64) as usize) {
            Some(&(s, at)) if s == seq => Some(at),
            _ => None,
        }
    }

    fn take_seq(&mut self, t: Instant) -> u64 {
        let seq = self.next_seq;
        self.next_seq += 1;
        if let Some(cell) = self.sent_ticks.get_mut((seq % N as u64) as usize) {
            *cell = (seq, t);
        }
        seq
    }

    fn is_adaptive(&self) -> bool {
        matches!(self.target, Some(Target::Adaptive(_)))
    }

    /// The adaptive schedule and what it decides on now, `None` under
    /// another playout.
    fn adaptive(&mut self) -> Option<(&mut Schedule, Context<'_, A>)> {
        let (Some(schedule), Some(Target::Adaptive(policy))) = (&mut self.schedule, &self.target)
        else {
            return None;
        };
        let mut queue = self.regulator.iter().map(|s| s.head.sent_at);
        let queued = Queued {
            front: queue.next(),
            second: queue.next(),
            len: self.regulator.len(),
        };
        // The paper's predictor steers the delay ahead: half the rise of the
        // mean round trip it forecasts over its horizon.
        let lead = self
            .predictor
            .last()
            .map_or(0.0, |p| (p.nrtt_ahead - p.nrtt_mean).max(0.0) / 2.0);
        let cx = Context {
            policy,
            sync: &self.sync,
            queued,
            newest: self.prev_data_rx,
            outage: self.outage_burst,
            lead,
        };
        Some((schedule, cx))
    }

    /// Each delay the adaptive schedule settled on, as an event.
    fn delay_events(&mut self) {
        while let Some((delay, ticks)) = self
            .schedule
            .as_mut()
            .and_then(Schedule::poll_delay_changed)
        {
            self.stats.delay_changes += 1;
            self.emit(Event::DelayChanged { delay, ticks });
        }
    }

    /// The adaptive delay's quantum at `period`.
    fn quantum_at(&self, period: Duration) -> Duration {
        self.config
            .playout
            .quantum(period)
            .unwrap_or_else(|| delay_quantum(period))
    }

    /// Adaptive playout: one release, at its sample's slot, the schedule
    /// deciding when and at what delay (see [`Schedule`]).
    fn release_apart(&mut self, at: Instant, t: Instant) {
        let running = self.phase == Phase::Running;
        let Some((s, cx)) = self.adaptive() else {
            return;
        };
        let plan = if running {
            s.before_release(at, t, &cx)
        } else {
            s.stop();
            return;
        };
        self.delay_events();
        let pending = match plan {
            Plan::Later(slot) => {
                // A remote's tick moves with its release, so that its state
                // still answers the command.
                if self.config.role == Role::Remote && self.next_tick == Some(at) {
                    self.next_tick = Some(slot);
                }
                return;
            }
            Plan::Now(pending) => pending,
        };
        let fresh = self.stats.released_fresh;
        self.release(at, t);
        self.watch(t);
        let stamp = match self.last_release {
            Some(r) if self.stats.released_fresh > fresh => Some(r.sent_at),
            _ => None,
        };
        if let Some((s, cx)) = self.adaptive() {
            s.after_release(at, t, pending, stamp, &cx);
        }
        self.delay_events();
    }

    /// Adaptive: a sample lost (late or skipped) spends the late rate.
    fn note_lost(&mut self) {
        if let Some(Target::Adaptive(a)) = &mut self.target {
            a.note_late();
        }
    }

    /// When the peer will have been silent for [`Config::liveness`], after
    /// the handshake.
    fn liveness_deadline(&self) -> Option<Instant> {
        if matches!(self.phase, Phase::Handshake | Phase::Closed) {
            return None;
        }
        let (_, arrived) = self.newest_rx?;
        Some(arrived + self.config.liveness?)
    }

    /// How long the peer has been silent, once that is past
    /// [`Config::liveness`].
    fn silent_past_liveness(&self, now: Instant) -> Option<Duration> {
        let due = self.liveness_deadline()?;
        let (_, arrived) = self.newest_rx?;
        (now >= due).then(|| now - arrived)
    }

    /// The release scheduled at `at`, run (and stamped) at `t`.
    fn release(&mut self, at: Instant, t: Instant) {
        let unset = self.schedule.as_ref().map(Schedule::delay) == Some(None);
        let outcome = match self.target.as_ref().map(TargetDelay::target) {
            // Adaptive: nothing is due before the delay is set.
            Some(_) if unset => self.not_started(),
            Some(target) => self.release_target(at, target),
            None => self.release_fifo(),
        };
        self.deliver(t, outcome);
    }

    fn release_fifo(&mut self) -> Tick<Slot<C>> {
        match (self.config.underflow, self.due_seq) {
            (Underflow::DropLate, Some(due)) => {
                while self.regulator.front().is_some_and(|s| s.head.seq < due) {
                    let _ = self.regulator.discard_front();
                    self.stats.late += 1;
                }
                self.regulator.tick_if(|s| s.head.seq == due)
            }
            _ => self.regulator.tick(),
        }
    }

    /// One tick of a target-delay playout: the sample whose slot (the first
    /// tick at or after `sent_at + D`) is this tick is released. Until the
    /// policy has a target and the first sample is due, ticks release
    /// nothing and count nothing (like the FIFO's pre-fill).
    fn release_target(&mut self, t: Instant, target: Option<Duration>) -> Tick<Slot<C>> {
        let Some(d) = target else {
            return self.not_started();
        };
        let mut cutoff = self.release_cutoff(t, d);
        // Adaptive, more than one due: stamps bunched (a send that left late,
        // or the clock estimate moved the slots earlier). The delay rises by
        // as many ticks instead of skipping samples, and this release takes
        // the oldest of them, so that each later release has one due: were
        // it to take none, the same samples would be due again at the next
        // release, and the delay would rise without end.
        let mut oldest = false;
        let bunched = self.schedule.is_some()
            && self
                .regulator
                .iter()
                .take_while(|s| s.head.sent_at <= cutoff)
                .count()
                > 1;
        let second = self.regulator.iter().nth(1).map(|s| s.head.sent_at);
        if let (Some(s), true, Some(second)) = (&mut self.schedule, bunched, second)
            && s.rise_past(cutoff, second)
        {
            self.delay_events();
            cutoff = self.release_cutoff(t, d);
            oldest = true;
        }
        let due = |s: &Slot<C>| s.head.sent_at <= cutoff;
        if self.config.underflow == Underflow::DropLate {
            // The target fell: older samples share this tick's slot with a
            // newer one. The newest due is released, the others skipped.
            while self.regulator.iter().nth(1).is_some_and(due) {
                let _ = self.regulator.discard_front();
                self.stats.skipped += 1;
                self.note_lost();
            }
            self.passed = Some(self.passed.map_or(cutoff, |p| p.max(cutoff)));
        }
        let release = |s: &Slot<C>| oldest || due(s);
        if self.regulator.phase() == regulator::Phase::Prefilling
            && !self.regulator.front().is_some_and(release)
        {
            return self.not_started();
        }
        self.regulator.tick_if(release)
    }

    /// Nothing released yet: not an underflow.
    fn not_started(&self) -> Tick<Slot<C>> {
        Tick::Prefilling {
            have: self.regulator.len(),
            need: 1,
        }
    }

    /// The end-to-end delay a sample released at `t` gets: for the adaptive
    /// policy the delay it keeps, for the others their target.
    fn current_delay(&self, _t: Instant) -> Option<Duration> {
        match &self.schedule {
            Some(s) => s.delay(),
            None => self.target.as_ref()?.target(),
        }
    }

    /// Frames sent (peer clock) at or before this have their slot at or
    /// before the tick `t` for a target delay `d` (the adaptive schedule's
    /// own delay and clock mapping once it has them; the other policies
    /// take the two clocks as one).
    fn release_cutoff(&self, t: Instant, d: Duration) -> Instant {
        match &self.schedule {
            Some(s) => s.release_cutoff(t, d, &self.sync),
            None => t - d,
        }
    }

    /// Adaptive: the floor of the raw delays at `t` (ns), to which its
    /// target is relative; `None` under another playout.
    fn floor_ns(&self, t: Instant) -> Option<i64> {
        self.schedule.as_ref()?;
        schedule::floor_ns(&self.sync, t)
    }

    /// A target playout other than the adaptive one: sets the delay and
    /// emits [`Event::DelayChanged`] when the delay in ticks changes.
    fn track_delay(&mut self, t: Instant) {
        let Some(d) = self.current_delay(t) else {
            return;
        };
        let ticks = d.as_nanos().div_ceil(self.period.as_nanos().max(1));
        self.announce(d, ticks);
    }

    fn announce(&mut self, d: Duration, ticks: u64) {
        self.stats.playout_delay_s = d.as_secs_f64();
        self.stats.playout_delay_ticks = ticks;
        if self.delay_ticks != Some(ticks) {
            self.delay_ticks = Some(ticks);
            self.stats.delay_changes += 1;
            self.emit(Event::DelayChanged { delay: d, ticks });
        }
    }

    /// The tick after the one scheduled at `t`: a period later, but for an
    /// adaptive remote, whose ticks follow its releases
    /// ([`Schedule::following_tick`]). Two hubs start their grids anywhere
    /// within a period of each other, and a grid left apart by `φ` made each
    /// direction's true delay its announced one plus or minus `φ`.
    fn following_tick(&self, t: Instant) -> Instant {
        let plain = t + self.period;
        self.schedule
            .as_ref()
            .map_or(plain, |s| s.following_tick(plain))
    }

    fn last_tick(&self) -> Option<Instant> {
        Some(self.next_tick? - self.period)
    }

    /// A one-way delay sample for the playout policy, from a frame's send
    /// stamp (peer clock) and its arrival (local clock). The one place where
    /// the two clocks meet: the adaptive policy gets the delay above the
    /// floor of the clock estimate; the others take the clocks as one (a
    /// simulation, or hosts synchronized by PTP or GPS).
    fn observe_one_way(
        &mut self,
        sent_at: Instant,
        arrived: Instant,
        prev: Option<(Instant, Instant)>,
        stalled: bool,
    ) {
        if let Some(d) = self.sync.one_way_rx(sent_at, arrived) {
            self.stats.one_way_rx.push(d);
        }
        let delay = match self.floor_ns(arrived) {
            // Adaptive: the delay above the floor, whatever the clocks.
            Some(floor) => {
                let raw = ns_i64(arrived).saturating_sub(ns_i64(sent_at));
                let above =
                    Duration::from_nanos(u64::try_from(raw.saturating_sub(floor)).unwrap_or(0));
                // A frame after a silence longer than the watchdog allows
                // ends an outage, not a delay; so do the frames after it
                // while they are still held longer than the watchdog, or
                // come in the burst held behind them (faster than they
                // were sent). Counted as delays, they would fill the
                // window's tail, and the target would cover the outage for
                // the window's length (after a 5 s stall, 5 s of delay for
                // two minutes). So do the frames a stalled driver hands over
                // late, stamped when it read them.
                let over = |d: Duration| self.config.watchdog.is_some_and(|w| d > w);
                self.outage_burst = stalled
                    || prev.is_some_and(|(ps, pa)| {
                        let silence = arrived - pa;
                        over(silence)
                            || (self.outage_burst && (over(above) || silence * 2 < sent_at - ps))
                    });
                if self.outage_burst {
                    self.stats.outage_delays += 1;
                    return;
                }
                above
            }
            None => arrived - sent_at,
        };
        if let Some(target) = &mut self.target {
            target.observe(sent_at, delay);
        }
    }

    /// Under drop-late: whether `slot` arrived after its release slot.
    fn slot_passed(&self, slot: &Slot<C>) -> bool {
        if self.target.is_some() {
            self.released_seq.is_some_and(|r| slot.head.seq <= r)
                || self.passed.is_some_and(|p| slot.head.sent_at <= p)
        } else {
            self.due_seq.is_some_and(|due| slot.head.seq < due)
        }
    }

    fn deliver(&mut self, t: Instant, outcome: Tick<Slot<C>>) {
        match outcome {
            Tick::Released(slot) => {
                self.stats.released_fresh += 1;
                self.last_fresh = t;
                self.released_seq = Some(slot.head.seq);
                self.due_seq = Some(slot.head.seq + 1);
                let grtt = slot.peer_released.and_then(|k| self.measure_grtt(t, k));
                let release = Release::fresh(slot.head, slot.values, slot.len, t, grtt);
                self.last_release = Some(release);
                self.emit(Event::Released(release));
            }
            Tick::Underflow => {
                self.stats.underflows += 1;
                if self.config.underflow == Underflow::Hold {
                    self.stats.late += 1;
                }
                if self.target.is_none() {
                    // FIFO slots are one per tick: this tick's slot is gone.
                    self.due_seq = self.due_seq.map(|d| d + 1);
                }
                if let Some(mut held) = self.last_release {
                    held.status = Status::Held;
                    held.released_at = t;
                    held.grtt = None;
                    self.stats.released_held += 1;
                    self.emit(Event::Released(held));
                }
            }
            Tick::Prefilling { .. } => {}
        }
    }

    /// The watchdog: an application must know when fresh samples stop.
    fn watch(&mut self, t: Instant) {
        // Armed from the first release of a regime: pre-fill is silent by design.
        let (Some(limit), Some(_)) = (self.config.watchdog, self.due_seq) else {
            return;
        };
        let silent_for = t - self.last_fresh;
        if silent_for >= limit && !self.lost {
            self.lost = true;
            self.stats.link_lost += 1;
            self.emit(Event::LinkLost { silent_for });
        } else if silent_for.is_zero() && self.lost {
            self.lost = false;
            self.emit(Event::LinkRestored);
        }
    }

    /// The peer had released our sample `k` when it sent what we release now.
    fn measure_grtt(&mut self, t: Instant, k: u64) -> Option<Duration> {
        if self.grtt_acked.is_some_and(|a| k <= a) {
            return None;
        }
        self.grtt_acked = Some(k);
        match self.tick_of(k) {
            Some(sent) => {
                let grtt = t - sent;
                self.stats.grtt.push_duration(grtt);
                Some(grtt)
            }
            _ => {
                self.stats.grtt_unmeasured += 1;
                None
            }
        }
    }

    /// Dynamic mode, base side: pause and resize when the forecast says so.
    fn maybe_adapt(&mut self, t: Instant, p: Prediction) {
        let settle = u64::from(self.config.adaptation.settle_periods);
        if self.config.mode != Mode::PaperDynamic
            || self.config.role != Role::Base
            || self.phase != Phase::Running
            || self.ticks_running < settle
        {
            return;
        }
        let band = self.config.adaptation.band;
        // Whole microseconds: a period both peers can state exactly.
        let period = Duration::from_micros(p.period.as_micros()).max(MIN_PERIOD);
        let current = self.period.as_secs_f64();
        let off = |forecast: f64, now: f64| libm::fabs(forecast - now) > band * now;
        let drift = off(period.as_secs_f64(), current) || off(p.ns as f64, self.ns as f64);
        // The forecast lag would use up the whole stock: the queue would empty.
        let drain = p.mt_ahead >= self.ns as f64 * current;
        if !(drift || drain) {
            return;
        }
        let ns = self.clamp_ns(p.ns);
        self.discard_queue();
        self.pending = Some((period, ns));
        self.phase = Phase::Pausing;
        self.deadline = Some(self.pattern_deadline(t));
        self.stats.pauses += 1;
        self.queue_tx(Tx::Control {
            op: control_op::PAUSE_REQUEST,
            ns: u16::try_from(ns).unwrap_or(u16::MAX),
            period,
        });
        self.emit(Event::Paused { period, ns });
    }
}
