//! Receiving: what each frame from the peer does to the endpoint.

use super::event::Head;
use super::rx_check::RxCheck;
use super::{Endpoint, Event, LinkError, Phase, Slot, Transport, Tx};
use crate::playout::{Admit, Arrival, Observed, Policy};
use crate::sizing::INIT_EXCHANGES;
use crate::storage::Storage;
use crate::time::{Duration, Instant};
use crate::wire::{
    Channels, Control, ControlOp, Echo, Frame, Hello, Kind, ModeCode, Payload, Role,
};

impl<S: Storage> Endpoint<S> {
    pub(super) fn receive(&mut self, now: Instant, frame: &Frame<&[u8]>) -> Result<(), LinkError> {
        // A datagram's samples never come on the stream.
        if frame.kind() == Kind::Bundle {
            return Err(self.unexpected(Kind::Bundle));
        }
        let sent_at = frame.sent_at();
        let stalled = self.driver_stalled(now);
        self.check_stamp(now, sent_at, frame.echo())?;
        if let Payload::Data(_) = frame.payload() {
            if self.phase == Phase::Handshake {
                return Err(self.unexpected(Kind::Data));
            }
            self.stats.frames_missing += self.heard.check.accept_data(frame.seq(), sent_at)?;
        }
        self.hear(now, sent_at, frame.echo())?;
        match frame.payload() {
            Payload::Hello(hello) => {
                self.receive_hello(now, hello, frame.term())?;
                self.anchor_datagrams(frame.seq(), sent_at);
                Ok(())
            }
            Payload::Data(channels) => {
                let head = Head {
                    seq: frame.seq(),
                    sent_at,
                    arrived_at: now,
                };
                let at = (frame.released(), frame.term());
                self.receive_data(head, at, channels, Some(stalled))
            }
            Payload::Control(control) => {
                if self.receive_seat_control(control, frame.term())? {
                    return Ok(());
                }
                self.receive_control(now, control)
            }
            Payload::Close(close) => Err(LinkError::PeerClosed {
                reason: close.reason,
            }),
            Payload::Bundle(_) => Err(self.unexpected(Kind::Bundle)),
            Payload::Token(token) => self.receive_token(token),
            Payload::Applied(applied) => self.receive_applied(now, frame.term(), applied),
        }
    }

    /// Whether a frame handed over at `now` comes a watchdog's time after a
    /// deadline the driver missed: the driver itself stalled (its process
    /// stopped), and what the frame's arrival says is the stall's, not the
    /// network's.
    pub(super) fn driver_stalled(&self, now: Instant) -> bool {
        match (self.config.watchdog, self.poll_timeout()) {
            (Some(w), Some(due)) => now >= due + w,
            _ => false,
        }
    }

    /// The receive checks every frame passes before anything of it is used
    /// (see `rx_check`).
    pub(super) fn check_stamp(
        &mut self,
        now: Instant,
        sent_at: Instant,
        echo: Option<Echo>,
    ) -> Result<(), LinkError> {
        if let Some(echo) = echo {
            self.heard
                .check
                .observe_echo(echo.sent_at, echo.hold, sent_at, now);
        }
        self.heard.check.check_stamp(sent_at, now)
    }

    /// What a frame's timing says: the clocks' offset and skew, a shift of
    /// the delay's floor, the round trip it echoes.
    pub(super) fn hear(
        &mut self,
        now: Instant,
        sent_at: Instant,
        echo: Option<Echo>,
    ) -> Result<(), LinkError> {
        let (floor, shifts) = (self.sync.floor_at(now), self.sync.rx().shifts());
        // A stamp nothing could check yet (the first Hello, a first probe
        // that echoes nothing) stays out of the clock estimate.
        if self.heard.check.bounded() {
            self.sync.observe_arrival(sent_at, now);
        }
        // A level shift of the received floor (a route change).
        if self.sync.rx().shifts() != shifts
            && let (Some(from), Some(to)) = (floor, self.sync.floor_at(now))
        {
            self.policy.floor_moved(from, to);
        }
        if let Some(theta) = self.sync.offset_at(now) {
            self.stats.clock_offset_s = theta;
        }
        self.stats.clock_skew_ppm = self.sync.skew() * 1e6;
        if let Some(echo) = echo {
            self.measure_nrtt(now, echo, sent_at)?;
        }
        self.heard.heard(sent_at, now);
        Ok(())
    }

    /// A sample (or a probe, without values) stamped as `head` says. Its
    /// own frame's arrival (`stalled` given) also measures the network; a
    /// copy in a later datagram's bundle (`None`) came late by design.
    pub(super) fn receive_data(
        &mut self,
        head: Head,
        (released, term): (Option<u64>, u16),
        channels: Channels<'_>,
        stalled: Option<bool>,
    ) -> Result<(), LinkError> {
        let (sent_at, now) = (head.sent_at, head.arrived_at);
        let arrival = match stalled {
            Some(stalled) => {
                let prev = self.heard.prev_data.replace((sent_at, now));
                if let Some((prev_sent, prev_arrived)) = prev {
                    // How much later than its schedule this frame came,
                    // relative to the previous one (never negative).
                    let gap = (now - prev_arrived).saturating_sub(sent_at - prev_sent);
                    self.predictor.observe_gap(gap);
                }
                if let Some(d) = self.sync.one_way_rx(sent_at, now) {
                    self.stats.one_way_rx.push(d);
                }
                Arrival::frame(sent_at, now, prev, stalled)
            }
            None => Arrival::copy(sent_at, now),
        };
        let (policy, view) = self.policy_view();
        if policy.arrival(&arrival, &view) == Observed::Outage {
            self.stats.outage_delays += 1;
        }
        if channels.is_empty() {
            self.stats.probes_received += 1;
            if self.phase == Phase::Handshake {
                return Err(self.unexpected(Kind::Data));
            }
            // Its own frame's: a copy's arrival says nothing of its delay.
            if stalled.is_some() {
                self.log_probe(head.seq, sent_at, now);
            }
            return Ok(());
        }
        let width = self.config.received_width();
        let mismatch = LinkError::ChannelCount {
            expected: width,
            got: channels.len(),
        };
        if channels.len() != usize::from(width) {
            return Err(mismatch);
        }
        let Some(mut values) = S::values(usize::from(width)) else {
            return Err(mismatch);
        };
        if channels.copy_to(values.as_mut()).is_err() {
            return Err(mismatch);
        }
        if !self.admit_command(term) {
            return Ok(());
        }
        let slot = Slot {
            head,
            term,
            peer_released: released,
            len: width,
            values,
        };
        self.receive_sample(now, slot)
    }

    pub(super) fn unexpected(&self, kind: Kind) -> LinkError {
        LinkError::Unexpected {
            kind,
            phase: self.phase.name(),
        }
    }

    pub(super) fn measure_nrtt(
        &mut self,
        now: Instant,
        echo: Echo,
        t3: Instant,
    ) -> Result<(), LinkError> {
        // Several peer frames can echo the same one of ours: measure once.
        if self.heard.newest_echo.is_some_and(|t| echo.sent_at <= t) {
            return Ok(());
        }
        let Some(rtt) = now.checked_duration_since(echo.sent_at) else {
            // An echo of a frame we have not sent yet: the peer is lying.
            return Err(LinkError::Unexpected {
                kind: Kind::Data,
                phase: "an echo from the future",
            });
        };
        self.heard.newest_echo = Some(echo.sent_at);
        self.sync.observe_echo(echo.sent_at, echo.hold, t3);
        if let Some(d) = self.sync.one_way_tx(echo.sent_at, echo.hold, t3) {
            self.stats.one_way_tx.push(d);
        }
        let nrtt = rtt.saturating_sub(echo.hold);
        self.heard.last_nrtt = Some(nrtt);
        self.stats.nrtt.push_duration(nrtt);
        self.predictor.observe_nrtt(nrtt);
        if self.phase == Phase::Init
            && self.config.role == Role::Base
            && echo.sent_at >= self.regime.init_started
        {
            let _ = self.regime.pattern.record_nrtt(nrtt);
            if self.regime.pattern.len() >= INIT_EXCHANGES {
                self.finish_init(now)?;
            }
        }
        Ok(())
    }

    pub(super) fn receive_hello(
        &mut self,
        now: Instant,
        hello: Hello,
        term: u16,
    ) -> Result<(), LinkError> {
        if self.phase != Phase::Handshake {
            return Err(self.unexpected(Kind::Hello));
        }
        if let Err(e) = self.check_hello(&hello) {
            // A remote that refuses the base's settings answers with its own
            // Hello before the Close: the base finds the same mismatch in it
            // and reports both sides' values, not only the Close code.
            if self.config.role == Role::Remote && !matches!(e, LinkError::RoleMismatch { .. }) {
                self.queue_tx(Tx::Hello);
            }
            return Err(e);
        }
        if let Err(e) = self.seat_hello(hello.seat) {
            if self.config.role == Role::Remote {
                self.queue_tx(Tx::Hello);
            }
            return Err(e);
        }
        let ours = self.config;
        if let Some(d) = &mut self.dgram {
            d.peer_session = hello.session;
        }
        self.peer = Some(hello);
        if ours.role == Role::Remote {
            self.queue_tx(Tx::Hello);
        }
        self.emit(Event::Connected { peer: hello });
        self.seated(term)?;
        self.enter_init(now);
        Ok(())
    }

    /// Whether the peer's Hello fits this side's configuration.
    fn check_hello(&self, hello: &Hello) -> Result<(), LinkError> {
        let ours = self.config;
        if hello.role == ours.role {
            return Err(LinkError::RoleMismatch { role: ours.role });
        }
        for (which, mine, theirs) in [
            ("command", ours.command_width, hello.command_width),
            ("state", ours.state_width, hello.state_width),
        ] {
            if mine != theirs {
                return Err(LinkError::WidthMismatch {
                    which,
                    ours: mine,
                    theirs,
                });
            }
        }
        if hello.layout != ours.layout {
            return Err(LinkError::LayoutMismatch {
                ours: ours.layout,
                theirs: hello.layout,
            });
        }
        // A peer on datagrams gives the token its datagrams must carry.
        let theirs = if hello.session == 0 {
            Transport::Stream
        } else {
            Transport::DATAGRAM
        };
        if theirs.name() != ours.transport.name() {
            return Err(LinkError::TransportMismatch {
                ours: ours.transport.name(),
                theirs: theirs.name(),
            });
        }
        if hello.period != ours.period {
            return Err(LinkError::PeriodMismatch {
                ours: ours.period,
                theirs: hello.period,
            });
        }
        if hello.mode != ModeCode::from(ours.mode) {
            return Err(LinkError::ModeMismatch {
                ours: ours.mode,
                theirs: hello.mode,
                ours_named: self.regulation_name(),
                theirs_named: hello.regulation,
            });
        }
        Ok(())
    }

    pub(super) fn receive_sample(
        &mut self,
        now: Instant,
        slot: Slot<S::Values>,
    ) -> Result<(), LinkError> {
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
        let (policy, view) = self.policy_view();
        match policy.admit(&slot.head, now, &view) {
            Admit::Queue => {}
            Admit::Late => {
                self.stats.late += 1;
                self.policy.lost();
                return Ok(());
            }
            Admit::Stale => {
                self.stats.discarded += 1;
                return Ok(());
            }
        }
        if self.regulator.push(slot).is_err() {
            self.stats.rejected += 1;
        }
        let (policy, view) = self.policy_view();
        policy.queued(&view);
        Ok(())
    }

    pub(super) fn receive_control(
        &mut self,
        now: Instant,
        control: Control,
    ) -> Result<(), LinkError> {
        let role = self.config.role;
        match (role, control.op, self.phase) {
            (Role::Remote, ControlOp::PauseRequest, Phase::Running) => {
                let ns = self.checked_ns(control.ns, control.period)?;
                self.queue_tx(Tx::Control {
                    op: ControlOp::PauseAck,
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
            (Role::Base, ControlOp::PauseAck, Phase::Pausing) => {
                let (period, _) = self.regime.pending.ok_or(self.unexpected(Kind::Control))?;
                self.change_period(period)?;
                self.enter_init(now);
                Ok(())
            }
            (Role::Remote, ControlOp::Resume, Phase::Init) => {
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
}

/// What came from the peer, and when.
/// Frames kept as echo candidates: a driver may run a tick up to this many
/// periods late, less one, and still echo.
const ECHO_CANDIDATES: usize = 4;

#[derive(Clone, Debug)]
pub(super) struct Heard {
    /// What the next frames from the peer may be.
    pub(super) check: RxCheck,
    /// Newest frame received: (its `sent_at`, our arrival time).
    pub(super) newest: Option<(Instant, Instant)>,
    /// The last few frames received, newest first, as `newest`: a frame
    /// echoes the newest of them that arrived by its stamp. A driver that
    /// runs a tick late may have received the next frame by then, and an
    /// echo of only the newest would be lost at every late tick.
    pub(super) recent: [Option<(Instant, Instant)>; ECHO_CANDIDATES],
    /// Previous Data frame received, for the reception gap.
    pub(super) prev_data: Option<(Instant, Instant)>,
    /// Newest of our frames an NRTT was measured on.
    pub(super) newest_echo: Option<Instant>,
    pub(super) last_nrtt: Option<Duration>,
}

impl Heard {
    /// A frame sent at `sent_at` (peer clock) arrived at `at`.
    pub(super) fn heard(&mut self, sent_at: Instant, at: Instant) {
        self.newest = Some((sent_at, at));
        self.recent.rotate_right(1);
        self.recent[0] = self.newest;
    }

    /// What a frame stamped `stamp` echoes: the newest frame that arrived
    /// by then, and how long it was held.
    pub(super) fn echo_at(&self, stamp: Instant) -> Option<Echo> {
        self.recent
            .iter()
            .flatten()
            .find(|&&(_, arrived)| arrived <= stamp)
            .map(|&(echoed, arrived)| Echo {
                sent_at: echoed,
                hold: stamp - arrived,
            })
    }

    pub(super) fn new(period: Duration) -> Self {
        Heard {
            check: RxCheck::new(period),
            newest: None,
            recent: [None; ECHO_CANDIDATES],
            prev_data: None,
            newest_echo: None,
            last_nrtt: None,
        }
    }
}
