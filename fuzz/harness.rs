//! Fuzz harnesses: what every input must satisfy.
//!
//! Shared by the cargo-fuzz targets (`fuzz/fuzz_targets`) and the corpus
//! replay in the test command (`tests/fuzz_corpus.rs`), so a crash the
//! fuzzer found once stays a test case. A harness panics only when a
//! property fails; the code under test must never panic.
//!
//! - [`decode`]: bytes as one frame, then as a TCP stream cut into pieces
//!   through the [`Deframer`]. Every frame accepted re-encodes and decodes to
//!   the same header and payload; the deframer's buffer stays bounded.
//! - [`endpoint`]: bytes as a script for an endpoint — raw frames, valid
//!   frames with fuzzed fields (to get past the handshake), time steps, the
//!   application's calls, any playout policy — drained like a driver does. The endpoint writes
//!   only valid frames, its counters never go back, every received sample is
//!   accounted for, a release never repeats a fresh sample or goes back (a
//!   held one repeats the last fresh one), and once closed it stays closed.
//! - [`pair`]: bytes as a script for a whole link, two endpoints on the
//!   shared [`Pair`] (the simulator's and the endpoint tests' harness): the
//!   configuration both share, the wire's delay each way, lost frames,
//!   stopped processes, garbage and replayed frames, time steps and the
//!   applications' calls. The same properties on both sides, and each
//!   side's frames valid.

use ndr_core::drive::{self, Turn};
use ndr_core::endpoint::{
    Config, Endpoint, Event, LinkError, Mode, Phase, Stats, Status, Transport, Underflow,
};
use ndr_core::pair::{Pair, World};
use ndr_core::playout::Playout;
use ndr_core::storage::Heap;
use ndr_core::time::{Duration, Instant};
use ndr_core::wire::{
    self, Close, Control, Echo, Frame, Header, Hello, MAX_CHANNELS, MAX_DATAGRAM_LEN,
    MAX_FRAME_LEN, Message, OlderSample, Payload, Role,
};
use ndr_net::Deframer;
use std::convert::Infallible;

/// Bytes as one frame, then as a stream.
pub fn decode(data: &[u8]) {
    if let Ok(frame) = Frame::new_checked(data) {
        round_trip(&frame);
    }
    // Cut the stream into pieces of a size the input picks.
    let step = usize::from(data.first().copied().unwrap_or(1)).max(1);
    let mut deframer = Deframer::new();
    let mut rest = data;
    let mut good = 0u64;
    'stream: while !rest.is_empty() {
        let taken = deframer.extend(&rest[..step.min(rest.len())]);
        assert!(
            taken > 0,
            "the deframer always has room for an incomplete frame"
        );
        rest = &rest[taken..];
        loop {
            match deframer.next_frame() {
                Ok(Some(frame)) => {
                    round_trip(&frame);
                    good += 1;
                }
                Ok(None) => break,
                // A corrupt stream ends the connection, as the hub does.
                Err(_) => break 'stream,
            }
        }
        assert!(
            deframer.buffered() < MAX_FRAME_LEN,
            "at most one partial frame is kept"
        );
        assert_eq!(deframer.frames(), good);
    }
}

/// A decoded frame re-encodes, and decodes again to the same fields.
fn round_trip<T: AsRef<[u8]>>(frame: &Frame<T>) {
    let header = frame.header();
    let payload = frame.payload();
    let mut values = [0.0; MAX_CHANNELS];
    // A bundle's values, newest first, and its older samples.
    let mut flat = Vec::new();
    let mut older = Vec::new();
    let msg = match payload {
        Payload::Data(ch) => {
            let n = ch
                .copy_to(&mut values)
                .expect("a checked frame's channels fit");
            Message::Data(&values[..n])
        }
        Payload::Bundle(b) => {
            let width = b.width();
            flat.extend(b.newest().iter());
            for o in b.older() {
                flat.extend(o.values.iter());
            }
            assert_eq!(flat.len(), width * b.count());
            for (i, o) in b.older().enumerate() {
                let at = (i + 1) * width;
                older.push(OlderSample {
                    seq: o.seq,
                    sent_at: o.sent_at,
                    released: o.released,
                    values: &flat[at..at + width],
                });
            }
            Message::Bundle {
                session: b.session(),
                newest: &flat[..width],
                older: &older,
            }
        }
        Payload::Hello(h) => Message::Hello(h),
        Payload::Control(c) => Message::Control(c),
        Payload::Close(c) => Message::Close(c),
    };
    let mut buf = vec![0u8; MAX_DATAGRAM_LEN];
    let n = wire::encode(&header, &msg, &mut buf).expect("a decoded frame re-encodes");
    assert_eq!(n, frame.as_bytes().len(), "the same length");
    let again = Frame::new_checked(&buf[..n]).expect("a re-encoded frame decodes");
    assert_eq!(again.header(), header);
    assert_eq!(again.payload(), payload);
}

/// The fuzzer's bytes, read as small numbers; zeros once they run out.
struct Input<'a>(&'a [u8]);

impl Input<'_> {
    fn byte(&mut self) -> u8 {
        let (&b, rest) = self.0.split_first().unwrap_or((&0, &[]));
        self.0 = rest;
        b
    }

    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.byte(), self.byte()])
    }

    fn u64(&mut self) -> u64 {
        u64::from(self.u16()) | u64::from(self.u16()) << 16 | u64::from(self.u16()) << 32
    }

    fn take(&mut self, n: usize) -> &[u8] {
        let (head, rest) = self.0.split_at(n.min(self.0.len()));
        self.0 = rest;
        head
    }

    fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

// The drivers' storage: buffers sized from the configuration.
type Ep = Endpoint<Heap>;

/// A script of frames, time steps and calls for one endpoint.
pub fn endpoint(data: &[u8]) {
    let mut input = Input(data);
    let role = if input.byte() & 1 == 0 {
        Role::Base
    } else {
        Role::Remote
    };
    let cfg = config(role, &mut input);
    let mut now = Instant::ZERO;
    let Ok(ep) = Ep::with_capacity(cfg, now, 64) else {
        return;
    };
    let mut ep = Box::new(ep);
    let mut peer = Peer {
        seq: 0,
        sent: None,
        period: cfg.period,
    };
    let mut checker = Checker::default();
    let mut invariants = Invariants::new(&ep);
    let mut frame = [0u8; MAX_FRAME_LEN];
    while !input.is_empty() {
        match input.byte() % 9 {
            0 => {
                let n = usize::from(input.byte());
                let bytes = input.take(n).to_vec();
                let _ = ep.handle_frame(now, &bytes);
            }
            1 => {
                let hello = Hello {
                    role: if input.byte() % 4 == 0 {
                        role
                    } else {
                        role.peer()
                    },
                    mode: if input.byte() % 4 == 0 {
                        input.byte()
                    } else {
                        cfg.mode.code()
                    },
                    underflow: input.byte() % 3,
                    command_width: if input.byte() % 4 == 0 {
                        u16::from(input.byte())
                    } else {
                        cfg.command_width
                    },
                    state_width: cfg.state_width,
                    period: if input.byte() % 4 == 0 {
                        Duration::from_micros(u64::from(input.u16()))
                    } else {
                        cfg.period
                    },
                    layout: if input.byte() % 8 == 0 { 7 } else { 0 },
                    session: 0,
                };
                send(
                    &mut ep,
                    now,
                    &mut input,
                    &mut peer,
                    &Message::Hello(hello),
                    &mut frame,
                );
            }
            2 | 3 => {
                let count = if input.byte() % 8 == 0 {
                    usize::from(input.byte() % 6)
                } else {
                    usize::from(cfg.received_width())
                };
                let mut values = [0.0; 8];
                for v in values.iter_mut().take(count) {
                    *v = f64::from(input.u16() as i16) / 64.0;
                }
                let msg = Message::Data(&values[..count]);
                send(&mut ep, now, &mut input, &mut peer, &msg, &mut frame);
            }
            4 => {
                let control = Control {
                    op: input.byte() % 5,
                    ns: input.u16() % 300,
                    period: Duration::from_micros(u64::from(input.u16()) * 10),
                };
                send(
                    &mut ep,
                    now,
                    &mut input,
                    &mut peer,
                    &Message::Control(control),
                    &mut frame,
                );
            }
            5 => {
                let close = Close {
                    reason: input.u16() % 10,
                };
                send(
                    &mut ep,
                    now,
                    &mut input,
                    &mut peer,
                    &Message::Close(close),
                    &mut frame,
                );
            }
            6 => {
                now += Duration::from_micros(u64::from(input.u16()) * 10);
                ep.handle_timeout(now);
            }
            7 => {
                if let Some(t) = ep.poll_timeout() {
                    now = now.max(t);
                    ep.handle_timeout(now);
                }
            }
            _ => match input.byte() % 4 {
                0 => {
                    let n = usize::from(input.byte() % 6);
                    let values = [f64::from(input.byte()); 6];
                    let _ = ep.set_sample(&values[..n]);
                }
                1 => {
                    let _ = ep.set_sample(&[f64::NAN; 4][..usize::from(cfg.sent_width())]);
                }
                2 => ep.close(),
                _ => ep.abort(LinkError::Disconnected),
            },
        }
        checker.drain(&mut ep, now, &mut frame);
        invariants.check(&mut ep, now);
    }
}

/// A script for a whole link on the shared [`Pair`].
pub fn pair(data: &[u8]) {
    let _ = pair_stats(data);
}

/// [`pair`], and both sides' stats at the end (none if the script's
/// configuration was refused).
pub fn pair_stats(data: &[u8]) -> Option<[Stats; 2]> {
    let mut input = Input(data);
    let mut cfg = config(Role::Base, &mut input);
    // A third of the scripts run on datagrams, with a redundancy of 1 to 8
    // and 0 to 2 repeats.
    let pick = input.byte();
    let datagram = pick % 3 == 0;
    if datagram {
        cfg.transport = Transport::Datagram {
            redundancy: 1 + pick / 3 % 8,
            repeats: pick / 24 % 3,
        };
        cfg.session = input.u64() | 1;
    }
    let mut remote = cfg;
    remote.role = Role::Remote;
    remote.session = cfg.session.rotate_left(17) | 1;
    // The remote's grid anywhere within a period of the base's.
    remote.tick_origin = Instant::ZERO + cfg.period * u64::from(input.byte()) / 256;
    let (Ok(base), Ok(remote)) = (
        Ep::with_capacity(cfg, Instant::ZERO, 64),
        Ep::with_capacity(remote, Instant::ZERO, 64),
    ) else {
        return None;
    };
    let world = Script {
        datagram,
        reorder: [Duration::ZERO; 2],
        datagrams: [0; 2],
        delay: [Duration::from_millis(5); 2],
        last: [Instant::ZERO; 2],
        lose: [0; 2],
        stopped: None,
        checkers: [Checker::default(), Checker::default()],
        sent: [Vec::new(), Vec::new()],
    };
    let mut invariants = [Invariants::new(&base), Invariants::new(&remote)];
    let mut pair = Box::new(Pair::new(base, remote, world));
    while !input.is_empty() {
        let side = if input.byte() & 1 == 0 {
            Role::Base
        } else {
            Role::Remote
        };
        match input.byte() % 8 {
            // Time runs, up to 65 periods.
            0..=2 => {
                let until = pair.now() + cfg.period * u64::from(input.byte()) / 4;
                let Ok(()) = pair.run_until(until);
            }
            // The wire from `side` takes 0 to 2.5 s from now on.
            3 => {
                pair.world.delay[side as usize] =
                    Duration::from_millis(u64::from(input.u16()) % 2500)
            }
            // It loses its next frames (on datagrams: its next datagrams),
            // or its datagrams come up to 0.25 s apart from their order.
            4 => match input.byte() {
                b if b < 128 => pair.world.lose[side as usize] = b % 8,
                b => {
                    pair.world.reorder[side as usize] =
                        Duration::from_millis(u64::from(b - 128) * 2)
                }
            },
            // `side`'s process stops for up to 6.4 s.
            5 => {
                let from = pair.now();
                let to = from + Duration::from_millis(u64::from(input.byte()) * 25);
                pair.world.stopped = Some((side, from, to));
            }
            // Bytes that are not the peer's: garbage, or its last frame again.
            6 => {
                let now = pair.now();
                let bytes = if input.byte() & 1 == 0 {
                    pair.world.sent[side.peer() as usize].clone()
                } else {
                    let n = usize::from(input.byte());
                    input.take(n).to_vec()
                };
                if bytes.get(5) == Some(&(wire::Kind::Bundle as u8)) {
                    let _ = pair.endpoint(side).handle_datagram(now, &bytes);
                } else {
                    let _ = pair.endpoint(side).handle_frame(now, &bytes);
                }
                let Ok(()) = pair.drain(side);
            }
            // The application's calls.
            _ => {
                let ep = pair.endpoint(side);
                let width = usize::from(ep.config().sent_width());
                match input.byte() % 4 {
                    0 => {
                        let _ = ep.set_sample(&[f64::NAN; 4][..width]);
                    }
                    1 => {
                        let _ = ep.set_sample(&[1.0; 5][..=width]);
                    }
                    2 => ep.close(),
                    _ => ep.abort(LinkError::Disconnected),
                }
                let Ok(()) = pair.drain(side);
            }
        }
        for side in [Role::Base, Role::Remote] {
            let now = pair.now();
            invariants[side as usize].check(pair.endpoint(side), now);
        }
    }
    Some([pair.base.stats(), pair.remote.stats()])
}

/// The link's surroundings as the script sets them: each way an in-order
/// wire of a constant delay that may lose frames, a side that may be
/// stopped, and applications that check what they get and answer
/// each release.
struct Script {
    /// Whether the link runs on datagrams: then its bundles may be lost
    /// or reordered, and the reliable path loses nothing.
    datagram: bool,
    /// How far a datagram may be held past the next ones.
    reorder: [Duration; 2],
    /// Datagrams sent each way.
    datagrams: [u64; 2],
    delay: [Duration; 2],
    last: [Instant; 2],
    /// Frames each way still to lose.
    lose: [u8; 2],
    /// A side stopped from one instant to another.
    stopped: Option<(Role, Instant, Instant)>,
    checkers: [Checker; 2],
    /// The last frame each side sent.
    sent: [Vec<u8>; 2],
}

impl Script {
    fn stop_end(&self, side: Role, t: Instant) -> Option<Instant> {
        match self.stopped {
            Some((s, from, to)) if s == side && t >= from && t < to => Some(to),
            _ => None,
        }
    }
}

impl World<Heap> for Script {
    type Error = Infallible;

    fn arrival(&mut self, from: Role, sent: Instant, frame: &[u8]) -> Option<Instant> {
        let i = from as usize;
        let Ok(()) = self.checkers[i].transmit(frame);
        self.sent[i].clear();
        self.sent[i].extend_from_slice(frame);
        let bundle = frame.get(5) == Some(&(wire::Kind::Bundle as u8));
        if self.lose[i] > 0 && (bundle || !self.datagram) {
            self.lose[i] -= 1;
            return None;
        }
        if bundle {
            let n = self.datagrams[i];
            self.datagrams[i] += 1;
            return Some(sent + self.delay[i] + self.reorder[i] * (n % 3));
        }
        let at = (sent + self.delay[i]).max(self.last[i]);
        self.last[i] = at;
        Some(at)
    }

    fn wake(&mut self, side: Role, deadline: Instant) -> Instant {
        self.stop_end(side, deadline).unwrap_or(deadline)
    }

    fn read(&self, side: Role, arrived: Instant) -> Instant {
        self.stop_end(side, arrived).unwrap_or(arrived)
    }

    fn stamp(&self, _: Role, arrived: Instant, _: Instant) -> Instant {
        arrived
    }

    fn event(
        &mut self,
        side: Role,
        ep: &mut Ep,
        _: Instant,
        event: Event<Box<[f64]>>,
    ) -> Result<(), Infallible> {
        let answer = match &event {
            Event::Released(r) => Some(r.values().to_vec()),
            _ => None,
        };
        let Ok(()) = self.checkers[side as usize].event(ep, event);
        // Each side answers a release with the values it released, repeated
        // to the width it sends.
        if let Some(values) = answer {
            let width = usize::from(ep.config().sent_width());
            let values: Vec<f64> = values.iter().copied().cycle().take(width).collect();
            let _ = ep.set_sample(&values);
        }
        Ok(())
    }

    fn sample(&mut self, side: Role, ep: &mut Ep, _: Instant) -> Result<(), Infallible> {
        self.checkers[side as usize].sample(ep)
    }

    fn failed(&mut self, _: Role, _: Instant, _: LinkError) -> Result<(), Infallible> {
        // A refused frame ends the link; the invariants check what follows.
        Ok(())
    }
}

/// The peer as the script plays it: mostly honest (its Data frames in
/// sequence, a period apart at least), so that the endpoint gets past its
/// receive checks, and sometimes not.
struct Peer {
    seq: u64,
    sent: Option<Instant>,
    period: Duration,
}

/// A configuration the input picks: widths, period, mode, underflow, playout
/// policy and watchdog.
fn config(role: Role, input: &mut Input<'_>) -> Config {
    let mut cfg = Config::new(role);
    // The command width and the state width, 1 to 4 each.
    let widths = input.byte();
    cfg.command_width = 1 + u16::from(widths % 4);
    cfg.state_width = 1 + u16::from(widths / 4 % 4);
    cfg.period = Duration::from_millis(1 + u64::from(input.byte() % 50));
    cfg.mode = if input.byte() & 1 == 0 {
        Mode::PaperStatic
    } else {
        Mode::PaperDynamic
    };
    cfg.underflow = if input.byte() & 1 == 0 {
        Underflow::Hold
    } else {
        Underflow::DropLate
    };
    // One byte picks the watchdog (its remainder by 3) and the playout policy.
    let pick = input.byte();
    cfg.playout = match pick / 3 % 8 {
        0 => Playout::Ramjee1,
        1 => Playout::Ramjee4,
        2 => Playout::NetEq,
        3 => Playout::FixedAboveMin {
            latency: Duration::from_millis(u64::from(input.byte())),
        },
        4 => Playout::Constant {
            delay: Duration::from_millis(u64::from(input.byte())),
        },
        5 => Playout::ADAPTIVE,
        // A late rate and a step of its own (1 to 64 ms, against periods of
        // 1 to 50 ms).
        6 => Playout::Adaptive {
            epsilon_ppm: 1 + u32::from(input.byte()) * 1000,
            quantum: Some(Duration::from_millis(1 + u64::from(input.byte() % 64))),
        },
        _ => Playout::Fifo,
    };
    cfg.watchdog = match pick % 3 {
        0 => None,
        n => Some(cfg.period * u64::from(n) * 5),
    };
    cfg
}

/// Encodes `msg` from the peer, with header fields the input picks, and
/// hands it to the endpoint.
fn send(
    ep: &mut Ep,
    now: Instant,
    input: &mut Input<'_>,
    peer: &mut Peer,
    msg: &Message<'_>,
    buf: &mut [u8; MAX_FRAME_LEN],
) {
    let seq = if input.byte().is_multiple_of(8) {
        input.u64()
    } else {
        peer.seq
    };
    let back = Duration::from_micros(u64::from(input.u16()));
    let mut sent_at = now.checked_sub(back).unwrap_or(Instant::ZERO);
    if let Message::Data(_) = msg {
        peer.seq = peer.seq.wrapping_add(1);
        if !input.byte().is_multiple_of(8)
            && let Some(next) = peer.sent.and_then(|s| s.checked_add(peer.period))
        {
            sent_at = sent_at.max(next);
        }
        peer.sent = Some(sent_at);
    }
    let header = Header {
        seq,
        sent_at,
        echo: match input.byte() % 3 {
            0 => None,
            _ => Some(Echo {
                sent_at: now.checked_sub(back + back).unwrap_or(Instant::ZERO),
                hold: Duration::from_micros(u64::from(input.byte())),
            }),
        },
        released: match input.byte() % 3 {
            0 => None,
            _ => Some(
                seq.saturating_sub(u64::from(input.byte()))
                    .min(u64::MAX - 1),
            ),
        },
    };
    if let Ok(n) = wire::encode(&header, msg, buf) {
        let _ = ep.handle_frame(now, &buf[..n]);
    }
}

/// What one side's driver checks of its endpoint's turn: every frame it
/// writes is valid and round-trips; releases are finite, a fresh one never
/// repeats or goes back, a held one repeats the last fresh one.
#[derive(Default)]
struct Checker {
    /// The last fresh release seen.
    seq: Option<u64>,
    /// Whether no event was dropped since it.
    exact: bool,
    /// Whether events were dropped from the batch being drained.
    cut: bool,
    /// The endpoint's dropped events, as last seen.
    dropped: u64,
    /// Whether a batch of events is being drained.
    open: bool,
}

impl Checker {
    /// Takes everything the endpoint has to say and to send, as a driver does.
    fn drain(&mut self, ep: &mut Ep, now: Instant, buf: &mut [u8; MAX_FRAME_LEN]) {
        let Ok(()) = drive::turn(ep, now, buf, self);
    }

    /// A batch of events starts. Events the endpoint had no room for (a
    /// long time step runs many ticks): the queue kept the oldest, so what
    /// comes here is a prefix, and until a fresh release comes in a whole
    /// batch, a held one may repeat a fresh one not seen here.
    fn begin(&mut self, ep: &Ep) {
        if self.open {
            return;
        }
        self.open = true;
        self.cut = ep.events_dropped() != self.dropped;
        self.dropped = ep.events_dropped();
        if self.cut {
            self.exact = false;
        }
    }
}

impl Turn<Heap> for Checker {
    type Error = Infallible;

    fn event(&mut self, ep: &mut Ep, event: Event<Box<[f64]>>) -> Result<(), Infallible> {
        self.begin(ep);
        let Event::Released(r) = event else {
            return Ok(());
        };
        assert!(r.values().len() <= 4);
        assert!(
            r.values().iter().all(|v| v.is_finite()),
            "released values are finite"
        );
        match r.status {
            Status::Fresh => {
                assert!(
                    self.seq.is_none_or(|l| r.seq > l),
                    "a fresh release after {:?} repeats or goes back: {}",
                    self.seq,
                    r.seq
                );
                self.seq = Some(r.seq);
                self.exact = !self.cut;
            }
            Status::Held if self.exact => assert_eq!(
                Some(r.seq),
                self.seq,
                "a held release repeats the last fresh one"
            ),
            Status::Held => assert!(
                self.seq.is_none_or(|l| r.seq >= l),
                "a held release repeats a fresh one at least as new as the last seen"
            ),
        }
        Ok(())
    }

    fn sample(&mut self, _: &mut Ep) -> Result<(), Infallible> {
        self.open = false;
        Ok(())
    }

    fn transmit(&mut self, frame: &[u8]) -> Result<(), Infallible> {
        let frame = Frame::new_checked(frame).expect("the endpoint writes valid frames");
        round_trip(&frame);
        Ok(())
    }

    fn failed(&mut self, error: LinkError) -> Result<(), Infallible> {
        panic!("poll_transmit failed with a full-size buffer: {error}")
    }
}

/// The properties every endpoint keeps between two steps.
struct Invariants {
    last: Stats,
    was_closed: bool,
    underflow: Underflow,
}

impl Invariants {
    fn new(ep: &Ep) -> Self {
        Invariants {
            last: ep.stats(),
            was_closed: false,
            underflow: ep.config().underflow,
        }
    }

    fn check(&mut self, ep: &mut Ep, now: Instant) {
        let stats = ep.stats();
        counters_never_go_back(&self.last, &stats);
        received_samples_are_accounted_for(&stats, ep.queue_len(), self.underflow);
        if self.was_closed {
            assert_eq!(ep.phase(), Phase::Closed, "a closed endpoint stays closed");
            assert_eq!(ep.handle_frame(now, &[]), Err(LinkError::Closed));
        }
        self.was_closed = ep.is_closed();
        self.last = stats;
    }
}

/// The counters that only ever grow.
fn counters(s: &Stats) -> [u64; 21] {
    [
        s.frames_missing,
        s.datagrams_received,
        s.samples_recovered,
        s.samples_lost,
        s.datagrams_stale,
        s.datagrams_foreign,
        s.datagrams_refused,
        s.frames_sent,
        s.frames_received,
        s.samples_sent,
        s.samples_repeated,
        s.samples_received,
        s.released_fresh,
        s.released_held,
        s.underflows,
        s.late,
        s.rejected,
        s.discarded,
        s.skipped,
        s.pauses,
        s.link_lost,
    ]
}

fn counters_never_go_back(a: &Stats, b: &Stats) {
    for (i, (before, after)) in counters(a).into_iter().zip(counters(b)).enumerate() {
        assert!(
            after >= before,
            "counter #{i} went back: {before} → {after}"
        );
    }
}

/// Every sample received is released, queued, refused or dropped, once.
/// Under `hold` a late sample is still released (one tick later), and
/// `late` counts the underflows it caused, so it is not a separate share.
fn received_samples_are_accounted_for(s: &Stats, queued: usize, underflow: Underflow) {
    let dropped_late = match underflow {
        Underflow::DropLate => s.late,
        Underflow::Hold => 0,
    };
    let accounted =
        s.released_fresh + queued as u64 + dropped_late + s.rejected + s.discarded + s.skipped;
    assert_eq!(
        s.samples_received, accounted,
        "received = released fresh + queued + late (drop-late) + rejected + discarded + skipped \
         ({s:?}, queued {queued})"
    );
}
