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

use ndr_core::endpoint::{
    Config, Endpoint, Event, LinkError, Mode, Phase, Stats, Status, Underflow,
};
use ndr_core::playout::Playout;
use ndr_core::storage::Heap;
use ndr_core::time::{Duration, Instant};
use ndr_core::wire::{
    self, Close, Control, Echo, Frame, Header, Hello, MAX_CHANNELS, MAX_FRAME_LEN, Message,
    Payload, Role,
};
use ndr_net::Deframer;

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
    let msg = match payload {
        Payload::Data(ch) => {
            let n = ch
                .copy_to(&mut values)
                .expect("a checked frame's channels fit");
            Message::Data(&values[..n])
        }
        Payload::Hello(h) => Message::Hello(h),
        Payload::Control(c) => Message::Control(c),
        Payload::Close(c) => Message::Close(c),
    };
    let mut buf = [0u8; MAX_FRAME_LEN];
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
    let mut cfg = Config::new(role);
    cfg.axes = 1 + u16::from(input.byte() % 4);
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
    let mut last_fresh = LastFresh::default();
    let mut last = ep.stats();
    let mut was_closed = false;
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
                    axes: if input.byte() % 4 == 0 {
                        u16::from(input.byte())
                    } else {
                        cfg.axes
                    },
                    period: if input.byte() % 4 == 0 {
                        Duration::from_micros(u64::from(input.u16()))
                    } else {
                        cfg.period
                    },
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
                    usize::from(cfg.axes)
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
                    let _ = ep.set_sample(&[f64::NAN; 4][..usize::from(cfg.axes)]);
                }
                2 => ep.close(),
                _ => ep.abort(LinkError::Disconnected),
            },
        }
        drain(&mut ep, now, &mut frame, &mut last_fresh);
        let stats = ep.stats();
        counters_never_go_back(&last, &stats);
        received_samples_are_accounted_for(&stats, ep.queue_len(), cfg.underflow);
        if was_closed {
            assert_eq!(ep.phase(), Phase::Closed, "a closed endpoint stays closed");
            assert_eq!(ep.handle_frame(now, &frame[..0]), Err(LinkError::Closed));
        }
        was_closed = ep.is_closed();
        last = stats;
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

/// The last fresh release seen, and whether no event was dropped since.
#[derive(Default)]
struct LastFresh {
    seq: Option<u64>,
    exact: bool,
    /// The endpoint's dropped events, as last seen.
    dropped: u64,
}

/// Takes everything the endpoint has to send and to say, as a driver does.
fn drain(ep: &mut Ep, now: Instant, buf: &mut [u8; MAX_FRAME_LEN], last_fresh: &mut LastFresh) {
    loop {
        match ep.poll_transmit(now, buf) {
            Ok(Some(n)) => {
                let frame =
                    Frame::new_checked(&buf[..n]).expect("the endpoint writes valid frames");
                round_trip(&frame);
            }
            Ok(None) => break,
            Err(e) => panic!("poll_transmit failed with a full-size buffer: {e}"),
        }
    }
    // Events the endpoint had no room for (a long time step runs many
    // ticks): the queue kept the oldest, so what comes here is a prefix,
    // and until a fresh release comes in a whole batch, a held one may
    // repeat a fresh one not seen here.
    let cut = ep.events_dropped() != last_fresh.dropped;
    last_fresh.dropped = ep.events_dropped();
    if cut {
        last_fresh.exact = false;
    }
    while let Some(event) = ep.poll_event() {
        if let Event::Released(r) = event {
            assert!(r.values().len() <= 4);
            assert!(
                r.values().iter().all(|v| v.is_finite()),
                "released values are finite"
            );
            match r.status {
                Status::Fresh => {
                    assert!(
                        last_fresh.seq.is_none_or(|l| r.seq > l),
                        "a fresh release after {:?} repeats or goes back: {}",
                        last_fresh.seq,
                        r.seq
                    );
                    last_fresh.seq = Some(r.seq);
                    last_fresh.exact = !cut;
                }
                Status::Held if last_fresh.exact => assert_eq!(
                    Some(r.seq),
                    last_fresh.seq,
                    "a held release repeats the last fresh one"
                ),
                Status::Held => assert!(
                    last_fresh.seq.is_none_or(|l| r.seq >= l),
                    "a held release repeats a fresh one at least as new as the last seen"
                ),
            }
        }
    }
}

/// The counters that only ever grow.
fn counters(s: &Stats) -> [u64; 14] {
    [
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
