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
//! - [`datagram`]: bytes as a script for a link on the datagram transport
//!   (redundancy, repeats and both session tokens from the input), brought
//!   to running, whose datagrams the harness carries itself: the peer's
//!   bundles delivered late, twice, reordered or lost, replayed, forged at
//!   chosen fields and bytes, and raw bytes. Each `handle_datagram` call
//!   has the outcome and the counts a model of its checks predicts (never
//!   taken with another session's token, never a `seq` taken twice or
//!   going back, the copies recovered and the samples lost exactly); the
//!   properties of [`endpoint`] on both sides; bounded queues.

use ndr_core::drive::{self, Turn};
use ndr_core::endpoint::{
    Config, DatagramError, Endpoint, Event, LinkError, Mode, Origin, Phase, Stats, Status,
    Transport, Underflow,
};
use ndr_core::pair::{Pair, World};
use ndr_core::playout::Playout;
use ndr_core::storage::Heap;
use ndr_core::time::{Duration, Instant};
use ndr_core::wire::{
    self, Close, Control, Echo, Frame, HEADER_LEN, Header, Hello, MAX_CHANNELS, MAX_FRAME_LEN,
    Message, OlderSample, Payload, Role,
};
use ndr_net::Deframer;
use std::collections::VecDeque;
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
                repeat: b.repeat(),
                missed: b.missed(),
                newest: &flat[..width],
                older: &older,
            }
        }
        Payload::Hello(h) => Message::Hello(h),
        Payload::Control(c) => Message::Control(c),
        Payload::Close(c) => Message::Close(c),
        Payload::Token(t) => Message::Token(t),
        Payload::Applied(a) => {
            flat.extend(a.values.iter());
            Message::Applied {
                seq: a.seq,
                sent_at: a.sent_at,
                applied_at: a.applied_at,
                values: &flat,
            }
        }
    };
    // As long as the frame: a re-encoding that needs more is not the same.
    let mut buf = vec![0u8; frame.as_bytes().len()];
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

    /// Eight bytes, every bit the input's.
    fn word(&mut self) -> u64 {
        self.u64() | u64::from(self.u16()) << 48
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
                    seat: ndr_core::wire::Seat::Control,
                    role: if input.byte() % 4 == 0 {
                        role
                    } else {
                        role.peer()
                    },
                    mode: if input.byte() % 4 == 0 {
                        input.byte().into()
                    } else {
                        cfg.mode.into()
                    },
                    underflow: (input.byte() % 3).into(),
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
                    regulation: ndr_core::wire::RegulationName::NONE,
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
                    op: (input.byte() % 5).into(),
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
                    reason: (input.u16() % 10).into(),
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
                    // From the path, or from an address not validated.
                    let origin = if input.byte() & 1 == 0 {
                        Origin::Path
                    } else {
                        Origin::Elsewhere
                    };
                    let _ = pair.endpoint(side).handle_datagram(now, &bytes, origin);
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

/// A script for a link on the datagram transport, fed through its
/// datagrams.
pub fn datagram(data: &[u8]) {
    let _ = datagram_stats(data);
}

/// Datagrams in flight each way at most: the wire's queue drops the rest.
const IN_FLIGHT: usize = 64;
/// Bundles kept of each side's last ones, for replays and forgeries.
const CAPTURED: usize = 8;
/// The reliable path's delay (Hello, Control, Close), in order.
const RELIABLE_DELAY: Duration = Duration::from_millis(5);

/// [`datagram`], and both sides' stats at the end (none if the script's
/// configuration was refused).
pub fn datagram_stats(data: &[u8]) -> Option<[Stats; 2]> {
    let mut input = Input(data);
    let mut cfg = config(Role::Base, &mut input);
    let pick = input.byte();
    cfg.transport = Transport::Datagram {
        redundancy: 1 + pick % 8,
        repeats: pick / 8 % 5,
    };
    let mut remote = cfg;
    remote.role = Role::Remote;
    // Any tokens but 0 (refused by the configuration), the same one too.
    cfg.session = input.word().max(1);
    remote.session = input.word().max(1);
    remote.tick_origin = Instant::ZERO + cfg.period * u64::from(input.byte()) / 256;
    let (Ok(base), Ok(remote)) = (
        Ep::with_capacity(cfg, Instant::ZERO, 64),
        Ep::with_capacity(remote, Instant::ZERO, 64),
    ) else {
        return None;
    };
    let mut link = Box::new(DgramLink::new(base, remote));
    // One script in eight starts at once, its datagrams meeting the
    // handshake and the initialization pattern.
    if input.byte() % 8 != 0 {
        link.start();
    }
    link.check();
    while !input.is_empty() {
        let side = if input.byte() & 1 == 0 {
            Role::Base
        } else {
            Role::Remote
        };
        let i = side as usize;
        match input.byte() % 10 {
            // Time runs, up to 16 periods or (one step in three) 64.
            op @ 0..=2 => {
                let per = if op == 2 { 4 } else { 16 };
                let until = link.now + cfg.period * u64::from(input.byte()) / per;
                link.run(until);
            }
            // `side`'s datagrams take 0 to 255 ms, up to twice 63 ms more
            // for some (reordered).
            3 => {
                link.net.delay[i] = Duration::from_millis(u64::from(input.byte()));
                link.net.reorder[i] = Duration::from_millis(u64::from(input.byte() % 64));
            }
            // Its next datagrams are lost.
            4 => link.net.lose[i] = input.byte() % 8,
            // One of its last bundles again: late, twice, after newer ones;
            // now and then sent back to itself.
            5 => {
                let pick = input.byte();
                if let Some(bytes) = link.net.captured(side, pick) {
                    let to = if pick >= 224 { side } else { side.peer() };
                    link.deliver(to, &bytes);
                }
            }
            // One of them forged.
            6 => {
                let pick = input.byte();
                if let Some(mut bytes) = link.net.captured(side, pick) {
                    let tokens = [0, 1].map(|s| link.eps[s].config().session);
                    forge(&mut bytes, &mut input, tokens);
                    link.deliver(side.peer(), &bytes);
                }
            }
            // Raw bytes, some behind a bundle's first header fields.
            7 => {
                let n = usize::from(input.byte());
                let framed = input.byte() & 1 == 0;
                let mut bytes = input.take(n).to_vec();
                if framed && bytes.len() >= 8 {
                    set_length(&mut bytes);
                    bytes[4] = wire::VERSION;
                    bytes[5] = wire::Kind::Bundle as u8;
                    bytes[6..8].fill(0);
                }
                link.deliver(side, &bytes);
            }
            // The network reorders, repeats or loses one in flight.
            8 => {
                let flight = &mut link.net.flight[i];
                match input.byte() % 4 {
                    0 if flight.len() >= 2 => {
                        let (a, b) = (flight[0].0, flight[1].0);
                        flight.swap(0, 1);
                        flight[0].0 = a;
                        flight[1].0 = b;
                    }
                    1 if flight.len() < IN_FLIGHT => {
                        if let Some(front) = flight.front().cloned() {
                            flight.push_front(front);
                        }
                    }
                    2 => {
                        let _ = flight.pop_front();
                    }
                    _ => {
                        if let Some((_, bytes)) = flight.pop_back() {
                            link.deliver(side.peer(), &bytes);
                        }
                    }
                }
            }
            // The application's calls.
            _ => {
                let ep = &mut link.eps[i];
                let width = usize::from(ep.config().sent_width());
                match input.byte() % 8 {
                    0 => {
                        let _ = ep.set_sample(&[f64::NAN; 4][..width]);
                    }
                    1 => {
                        let _ = ep.set_sample(&[f64::INFINITY; 5][..=width]);
                    }
                    2 => ep.close(),
                    3 => ep.abort(LinkError::Disconnected),
                    _ => {
                        let _ = ep.set_sample(&[-2.5; 4][..width]);
                    }
                }
                link.drain(side);
            }
        }
        link.check();
    }
    Some([link.eps[0].stats(), link.eps[1].stats()])
}

/// Writes a frame's length field from its length.
fn set_length(bytes: &mut [u8]) {
    let n = u32::try_from(bytes.len()).unwrap_or(u32::MAX);
    if let Some(field) = bytes.first_chunk_mut::<4>() {
        *field = n.to_le_bytes();
    }
}

/// Changes a bundle where the input says: its header's and its fixed
/// part's fields, an older sample's fields, a value (NaN, infinities,
/// extremes, any bits), a byte, its length (cut or extended, with the
/// length field kept or not), its session token.
fn forge(bytes: &mut Vec<u8>, input: &mut Input<'_>, tokens: [u64; 2]) {
    let width = usize::from(u16::from_le_bytes([
        bytes.get(58).copied().unwrap_or(0),
        bytes.get(59).copied().unwrap_or(0),
    ]));
    let count = usize::from(bytes.get(56).copied().unwrap_or(1));
    let older_at = |k: usize| HEADER_LEN + 16 + 8 * width + k * (24 + 8 * width);
    for _ in 0..=input.byte() % 4 {
        match input.byte() % 8 {
            // seq, sent_at, echo, echo_hold, released, session, count and width.
            0 | 1 => {
                let at = [8, 16, 24, 32, 40, 48, 56][usize::from(input.byte() % 7)];
                put_word(bytes, at, input);
            }
            // An older sample's seq, sent_at or released.
            2 => {
                let k = usize::from(input.byte()) % count.max(2).saturating_sub(1);
                let at = older_at(k) + 8 * usize::from(input.byte() % 3);
                put_word(bytes, at, input);
            }
            3 => {
                let j = usize::from(input.byte()) % (count * width).max(1);
                let (s, c) = (j / width.max(1), j % width.max(1));
                let at = match s {
                    0 => HEADER_LEN + 16 + 8 * c,
                    s => older_at(s - 1) + 24 + 8 * c,
                };
                let v = match input.byte() % 9 {
                    0 => f64::NAN,
                    1 => f64::INFINITY,
                    2 => f64::NEG_INFINITY,
                    3 => f64::MAX,
                    4 => f64::MIN,
                    5 => -0.0,
                    6 => f64::MIN_POSITIVE / 2.0,
                    7 => 1e300,
                    _ => f64::from_bits(input.word()),
                };
                if let Some(dst) = bytes.get_mut(at..at + 8) {
                    dst.copy_from_slice(&v.to_le_bytes());
                }
            }
            4 => {
                let at = usize::from(input.u16()) % bytes.len().max(1);
                let b = input.byte();
                if let Some(dst) = bytes.get_mut(at) {
                    *dst = b;
                }
            }
            5 => {
                let cut = usize::from(input.byte());
                bytes.truncate(bytes.len().saturating_sub(cut));
                if input.byte() & 1 == 0 {
                    set_length(bytes);
                }
            }
            6 => {
                let n = usize::from(input.byte());
                let fix = input.byte() & 1 == 0;
                bytes.extend_from_slice(input.take(n));
                if fix {
                    set_length(bytes);
                }
            }
            _ => {
                let token = match input.byte() % 6 {
                    0 => tokens[0],
                    1 => tokens[1],
                    2 => tokens[0] ^ 1 << (input.byte() % 64),
                    3 => tokens[1] ^ 1 << (input.byte() % 64),
                    4 => 0,
                    _ => input.word(),
                };
                if let Some(dst) = bytes.get_mut(48..56) {
                    dst.copy_from_slice(&token.to_le_bytes());
                }
            }
        }
    }
}

/// Writes a `u64` at `at`: near the one there, an edge, or any bits.
fn put_word(bytes: &mut [u8], at: usize, input: &mut Input<'_>) {
    let Some(dst) = bytes.get_mut(at..at + 8) else {
        return;
    };
    let old = u64::from_le_bytes(dst.try_into().unwrap_or_default());
    let delta = u64::from(input.byte() % 16);
    let word = match input.byte() % 5 {
        0 => old.wrapping_add(1 + delta),
        1 => old.wrapping_sub(1 + delta),
        2 => [0, 1, u64::MAX, u64::MAX - 1, 1 << 63][usize::from(input.byte() % 5)],
        3 => old.wrapping_add(u64::from(input.u16()) << (input.byte() % 48)),
        _ => input.word(),
    };
    dst.copy_from_slice(&word.to_le_bytes());
}

/// The wire between the sides as the script sets it (index: the sender):
/// a reliable path in order, and datagrams that take their own delay.
struct Net {
    reliable: [VecDeque<(Instant, Vec<u8>)>; 2],
    /// Datagrams in flight, by arrival.
    flight: [VecDeque<(Instant, Vec<u8>)>; 2],
    /// The last bundles sent, oldest first, lost ones too.
    captured: [VecDeque<Vec<u8>>; 2],
    delay: [Duration; 2],
    /// How far a datagram may be held past the next ones.
    reorder: [Duration; 2],
    /// Datagrams still to lose.
    lose: [u8; 2],
    /// Datagrams sent.
    sent: [u64; 2],
}

impl Net {
    fn send(&mut self, from: Role, now: Instant, frame: &[u8]) {
        let i = from as usize;
        if !wire::is_bundle(frame) {
            // In order, as a stream delivers.
            let at = self.reliable[i]
                .back()
                .map_or(now + RELIABLE_DELAY, |&(t, _)| t.max(now + RELIABLE_DELAY));
            self.reliable[i].push_back((at, frame.to_vec()));
            return;
        }
        if self.captured[i].len() == CAPTURED {
            let _ = self.captured[i].pop_front();
        }
        self.captured[i].push_back(frame.to_vec());
        if self.lose[i] > 0 {
            self.lose[i] -= 1;
            return;
        }
        let n = self.sent[i];
        self.sent[i] += 1;
        let at = now + self.delay[i] + self.reorder[i] * (n % 3);
        let flight = &mut self.flight[i];
        if flight.len() < IN_FLIGHT {
            let k = flight.partition_point(|&(t, _)| t <= at);
            flight.insert(k, (at, frame.to_vec()));
        }
    }

    /// One of `from`'s last bundles, `pick` counting back from the newest.
    fn captured(&self, from: Role, pick: u8) -> Option<Vec<u8>> {
        let kept = &self.captured[from as usize];
        let back = usize::from(pick) % kept.len().max(1);
        kept.iter().rev().nth(back).cloned()
    }
}

/// What the harness knows of one side's datagram path, to predict what
/// each datagram does.
#[derive(Default)]
struct Taken {
    /// The newest `seq` taken, and whether it was a sample's.
    highest: Option<(u64, bool)>,
    /// Datagrams handed in while the link was open.
    handed: u64,
}

/// What a datagram must do, by the checks `handle_datagram` documents in
/// their order.
#[derive(Debug)]
enum Expected {
    /// Not a valid bundle, before the handshake, numbered the wire's
    /// "none", or another width.
    Refused,
    Foreign,
    Stale,
    /// Taken (unless its stamp is refused): its `seq`, width, and the
    /// copies newer than the newest taken.
    Fresh {
        seq: u64,
        width: usize,
        copies: u64,
    },
}

fn expected(cfg: &Config, phase: Phase, highest: Option<(u64, bool)>, bytes: &[u8]) -> Expected {
    let Ok(frame) = Frame::new_checked(bytes) else {
        return Expected::Refused;
    };
    let Payload::Bundle(bundle) = frame.payload() else {
        return Expected::Refused;
    };
    if bundle.session() != cfg.session {
        return Expected::Foreign;
    }
    if phase == Phase::Handshake {
        return Expected::Refused;
    }
    let seq = frame.seq();
    if highest.is_some_and(|(h, _)| seq <= h) {
        return Expected::Stale;
    }
    if seq == u64::MAX {
        return Expected::Refused;
    }
    let width = bundle.width();
    if width != 0 && width != usize::from(cfg.received_width()) {
        return Expected::Refused;
    }
    let copies = bundle
        .older()
        .filter(|o| highest.is_none_or(|(h, _)| o.seq > h))
        .count();
    Expected::Fresh {
        seq,
        width,
        copies: copies as u64,
    }
}

/// Two endpoints on the datagram transport, driven in one loop, with the
/// wire between them.
struct DgramLink {
    /// Index: the role.
    eps: [Box<Ep>; 2],
    now: Instant,
    net: Net,
    checkers: [Checker; 2],
    invariants: [Invariants; 2],
    taken: [Taken; 2],
    buf: Box<[u8; MAX_FRAME_LEN]>,
}

impl DgramLink {
    fn new(base: Ep, remote: Ep) -> Self {
        let invariants = [Invariants::new(&base), Invariants::new(&remote)];
        let mut link = DgramLink {
            eps: [Box::new(base), Box::new(remote)],
            now: Instant::ZERO,
            net: Net {
                reliable: [VecDeque::new(), VecDeque::new()],
                flight: [VecDeque::new(), VecDeque::new()],
                captured: [VecDeque::new(), VecDeque::new()],
                delay: [Duration::from_millis(5); 2],
                reorder: [Duration::ZERO; 2],
                lose: [0; 2],
                sent: [0; 2],
            },
            checkers: [Checker::default(), Checker::default()],
            invariants,
            taken: [Taken::default(), Taken::default()],
            buf: Box::new([0; MAX_FRAME_LEN]),
        };
        link.drain(Role::Base);
        link.drain(Role::Remote);
        link
    }

    /// Runs through the handshake and the initialization pattern, until
    /// both sides run (or ten simulated seconds pass).
    fn start(&mut self) {
        let period = self.eps[0].config().period;
        let end = Instant::ZERO + Duration::from_secs(10);
        while self.now < end && self.eps.iter().any(|ep| ep.phase() != Phase::Running) {
            self.run(self.now + period);
        }
    }

    /// Every arrival and deadline until `until`, in order.
    fn run(&mut self, until: Instant) {
        while let Some(t) = self.next_event().filter(|&t| t <= until) {
            self.now = self.now.max(t);
            self.step();
        }
        self.now = self.now.max(until);
    }

    fn next_event(&self) -> Option<Instant> {
        let heads = |q: &VecDeque<(Instant, Vec<u8>)>| q.front().map(|&(t, _)| t);
        (0..2)
            .flat_map(|i| {
                [
                    self.eps[i].poll_timeout(),
                    heads(&self.net.reliable[i]),
                    heads(&self.net.flight[i]),
                ]
            })
            .flatten()
            .min()
    }

    /// What is due now: arrivals, then deadlines.
    fn step(&mut self) {
        let now = self.now;
        for from in [Role::Base, Role::Remote] {
            let i = from as usize;
            while let Some((_, bytes)) = self.net.reliable[i]
                .front()
                .is_some_and(|&(t, _)| t <= now)
                .then(|| self.net.reliable[i].pop_front())
                .flatten()
            {
                let _ = self.eps[from.peer() as usize].handle_frame(now, &bytes);
                self.drain(from.peer());
            }
            while let Some((_, bytes)) = self.net.flight[i]
                .front()
                .is_some_and(|&(t, _)| t <= now)
                .then(|| self.net.flight[i].pop_front())
                .flatten()
            {
                self.deliver(from.peer(), &bytes);
            }
        }
        for side in [Role::Base, Role::Remote] {
            let ep = &mut self.eps[side as usize];
            if ep.poll_timeout().is_some_and(|t| t <= now) {
                ep.handle_timeout(now);
                self.drain(side);
                // A long catch-up stops at a full event queue: the events
                // drained, it goes on.
                while self.eps[side as usize].catching_up(now) {
                    self.eps[side as usize].handle_timeout(now);
                    self.drain(side);
                }
                // Else a driver would spin on it.
                assert!(
                    self.eps[side as usize]
                        .poll_timeout()
                        .is_none_or(|t| t > now),
                    "a deadline served is gone"
                );
            }
        }
    }

    /// `side`'s turn: its events to its application, its frames onto the wire.
    fn drain(&mut self, side: Role) {
        let i = side as usize;
        let mut turn = SideTurn {
            side,
            now: self.now,
            checker: &mut self.checkers[i],
            net: &mut self.net,
        };
        let Ok(()) = drive::turn(&mut self.eps[i], self.now, &mut self.buf[..], &mut turn);
    }

    /// Hands `bytes` to `side` as a datagram: its outcome and its counts
    /// are the ones the checks predict.
    fn deliver(&mut self, side: Role, bytes: &[u8]) {
        let i = side as usize;
        let ep = &mut self.eps[i];
        let (before, phase) = (ep.stats(), ep.phase());
        let result = ep.handle_datagram(self.now, bytes, Origin::Path);
        let after = ep.stats();
        let grew = |f: fn(&Stats) -> u64| f(&after) - f(&before);
        let counts = [
            grew(|s| s.datagrams_received),
            grew(|s| s.datagrams_stale),
            grew(|s| s.datagrams_foreign),
            grew(|s| s.datagrams_refused),
        ];
        let taken = &mut self.taken[i];
        if phase == Phase::Closed {
            assert_eq!(result, Err(DatagramError::Closed));
            assert_eq!(counts, [0; 4], "nothing counted once closed");
            return;
        }
        taken.handed += 1;
        let cfg = ep.config();
        if matches!(result, Ok(_) | Err(DatagramError::Link(_))) {
            let session = Frame::new_checked(bytes)
                .ok()
                .and_then(|f| match f.payload() {
                    Payload::Bundle(b) => Some(b.session()),
                    _ => None,
                });
            assert_eq!(
                session,
                Some(cfg.session),
                "a datagram taken carries this side's token"
            );
        }
        let expect = expected(cfg, phase, taken.highest, bytes);
        match (&expect, &result) {
            (
                Expected::Refused,
                Err(
                    DatagramError::Wire(_)
                    | DatagramError::NotABundle(_)
                    | DatagramError::BeforeHandshake
                    | DatagramError::Sequence { .. }
                    | DatagramError::Width { .. },
                ),
            )
            | (
                Expected::Fresh { .. },
                Err(DatagramError::Stamp(_) | DatagramError::CopyStamp { .. }),
            ) => {
                assert_eq!(counts, [0, 0, 0, 1], "refused: {result:?}");
            }
            // Further ahead than its stamp leaves room for: a forgery.
            (
                &Expected::Fresh { seq, .. },
                &Err(DatagramError::Ahead {
                    seq: got,
                    expected,
                    room,
                }),
            ) => {
                assert!(got == seq && seq > expected && seq - expected >= room);
                assert_eq!(counts, [0, 0, 0, 1], "refused: {result:?}");
            }
            (Expected::Foreign, Err(DatagramError::Foreign { session })) => {
                assert_ne!(*session, cfg.session);
                assert_eq!(counts, [0, 0, 1, 0], "foreign");
            }
            (Expected::Stale, Err(DatagramError::Stale { seq, newest })) => {
                assert!(
                    taken
                        .highest
                        .is_some_and(|(h, _)| *seq <= h && *newest == h)
                );
                assert_eq!(counts, [0, 1, 0, 0], "stale");
            }
            (
                &Expected::Fresh { seq, width, copies },
                Ok(ndr_core::endpoint::Taken::Samples) | Err(DatagramError::Link(_)),
            ) => {
                assert_eq!(counts, [1, 0, 0, 0], "taken");
                assert_eq!(after.frames_received - before.frames_received, 1);
                let prev = taken.highest.replace((seq, width > 0));
                if result.is_ok() {
                    let recovered = grew(|s| s.samples_recovered);
                    assert_eq!(recovered, copies, "each copy newer than the newest taken");
                    let lost = match prev {
                        Some((h, true)) if width > 0 => seq - h - 1 - copies,
                        _ => 0,
                    };
                    assert_eq!(grew(|s| s.samples_lost), lost, "the gap, less the copies");
                    // A command of a term this remote does not hold is
                    // fenced on arrival: refused, counted, not taken.
                    let fenced = grew(|s| s.commands_refused_stale_term)
                        + grew(|s| s.commands_refused_observer)
                        + grew(|s| s.commands_before_grant);
                    assert_eq!(
                        grew(|s| s.samples_received) + grew(|s| s.probes_received) + fenced,
                        copies + 1,
                        "each sample of the bundle taken or fenced once"
                    );
                }
            }
            _ => panic!("a datagram that must be {expect:?} came out {result:?}"),
        }
        self.drain(side);
    }

    /// The properties each side keeps between two steps.
    fn check(&mut self) {
        for i in 0..2 {
            let ep = &mut self.eps[i];
            self.invariants[i].check(ep, self.now);
            let s = ep.stats();
            assert_eq!(
                s.datagrams_received
                    + s.datagrams_stale
                    + s.datagrams_foreign
                    + s.datagrams_refused
                    + s.datagrams_off_path,
                self.taken[i].handed,
                "each datagram handed to an open link counted once ({s:?})"
            );
            assert!(
                !ep.is_closed() || ep.poll_timeout().is_none(),
                "a closed endpoint has nothing due"
            );
            assert!(ep.queue_len() <= ep.capacity());
            let net = &self.net;
            assert!(net.flight[i].len() <= IN_FLIGHT && net.captured[i].len() <= CAPTURED);
            assert!(
                net.reliable[i].len() <= IN_FLIGHT,
                "the reliable path carries a few frames, not a stream"
            );
        }
    }
}

/// One side's turn in a [`DgramLink`]: the application answers each
/// release with its values, and the frames go on the wire.
struct SideTurn<'a> {
    side: Role,
    now: Instant,
    checker: &'a mut Checker,
    net: &'a mut Net,
}

impl Turn<Heap> for SideTurn<'_> {
    type Error = Infallible;

    fn event(&mut self, ep: &mut Ep, event: Event<Box<[f64]>>) -> Result<(), Infallible> {
        let answer = match &event {
            Event::Released(r) => Some(r.values().to_vec()),
            _ => None,
        };
        let Ok(()) = self.checker.event(ep, event);
        if let Some(values) = answer {
            let width = usize::from(ep.config().sent_width());
            let values: Vec<f64> = values.iter().copied().cycle().take(width).collect();
            let _ = ep.set_sample(&values);
        }
        Ok(())
    }

    fn sample(&mut self, ep: &mut Ep) -> Result<(), Infallible> {
        self.checker.sample(ep)
    }

    fn transmit(&mut self, frame: &[u8]) -> Result<(), Infallible> {
        let Ok(()) = self.checker.transmit(frame);
        self.net.send(self.side, self.now, frame);
        Ok(())
    }

    fn failed(&mut self, error: LinkError) -> Result<(), Infallible> {
        self.checker.failed(error)
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
        term: 0,
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
fn counters(s: &Stats) -> [u64; 24] {
    [
        s.datagrams_off_path,
        s.tokens_renewed,
        s.paths_validated,
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
