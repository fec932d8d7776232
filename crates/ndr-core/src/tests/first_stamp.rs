//! A base written from `docs/wire.md` alone against a remote endpoint that
//! has been up for a while, in simulated time: whatever its clock reads
//! when it starts (0, a Unix time) and whatever its first frames' stamps
//! (a first probe at its clock's start that echoes nothing, a probe stamped
//! before its Hello), the remote serves it, at the delay of the wire.

#[allow(unused_imports)]
use std::{borrow::ToOwned, boxed::Box, string::String, string::ToString, vec::Vec};
#[allow(unused_imports)]
use std::{eprintln, format, println, vec};

use crate::endpoint::{Config, Endpoint, Event, LinkError, Status};
use crate::playout::Playout;
use crate::storage::Heap;
use crate::time::{Duration, Instant};
use crate::wire::{
    self, Control, ControlOp, Echo, Frame, Header, Hello, MAX_FRAME_LEN, Message, Payload, Role,
};

/// One way on the wire.
const WIRE: Duration = Duration::from_micros(100);
const T: Duration = Duration::from_millis(50);
/// Commands the remote must release, each once and in order.
const COMMANDS: u64 = 100;

/// How a hand-written base starts.
#[derive(Clone, Copy, Debug)]
struct Start {
    /// The remote's clock when the base's starts.
    remote_up: Duration,
    /// The base's clock when it starts (ns).
    clock: u64,
    /// Its Hello's stamp, after its start.
    hello: Duration,
    /// Its tick 0's scheduled time, after its start: its first probe's stamp.
    first_tick: Duration,
}

/// The base: its ticks at `first_tick + k·T`, those before the remote's
/// Hello run once it has come; each frame echoes the newest remote frame
/// that had come by its stamp (none for a tick before the Hello came);
/// after 10 round trips it resumes, then sends commands numbered from 1.
struct HandBase {
    start: Start,
    handshaken: Option<Instant>,
    next_tick: u64,
    /// (remote stamp, arrival on the base's clock), newest last.
    heard: Vec<(Instant, Instant)>,
    nrtts: Vec<Duration>,
    running: bool,
    newest_state: Option<u64>,
    sent: u64,
    /// The term the remote's Hello announced.
    term: u16,
}

impl HandBase {
    fn new(start: Start) -> Self {
        HandBase {
            start,
            handshaken: None,
            next_tick: 0,
            heard: Vec::new(),
            nrtts: Vec::new(),
            running: false,
            newest_state: None,
            sent: 0,
            term: 0,
        }
    }

    fn zero(&self) -> Instant {
        Instant::from_nanos(self.start.clock)
    }

    /// The base's clock at remote time `t` (never before its start).
    fn local(&self, t: Instant) -> Instant {
        self.zero() + (t - (Instant::ZERO + self.start.remote_up))
    }

    /// Remote time at the base's `t`.
    fn remote(&self, t: Instant) -> Instant {
        Instant::ZERO + self.start.remote_up + (t - self.zero())
    }

    fn echo_at(&self, stamp: Instant) -> Option<Echo> {
        self.heard
            .iter()
            .rev()
            .find(|&&(_, arrived)| arrived <= stamp)
            .map(|&(sent_at, arrived)| Echo {
                sent_at,
                hold: stamp - arrived,
            })
    }

    fn hello(&self) -> (Instant, Vec<u8>) {
        let stamp = self.zero() + self.start.hello;
        let hello = Hello {
            seat: crate::wire::Seat::Control,
            role: Role::Base,
            mode: wire::ModeCode::PaperStatic,
            underflow: wire::UnderflowCode::Hold,
            command_width: 1,
            state_width: 1,
            period: T,
            layout: 0,
            session: 0,
            regulation: crate::wire::RegulationName::NONE,
        };
        (stamp, frame(&Header::new(0, stamp), &Message::Hello(hello)))
    }

    fn tick_at(&self, k: u64) -> Instant {
        self.zero() + self.start.first_tick + T * k
    }

    /// When its next tick runs, on the remote's clock.
    fn next_tick_due(&self) -> Option<Instant> {
        let handshaken = self.handshaken?;
        Some(self.remote(self.tick_at(self.next_tick).max(handshaken)))
    }

    /// Runs its next tick: the frame it sends.
    fn tick(&mut self) -> Vec<u8> {
        let stamp = self.tick_at(self.next_tick);
        let header = Header {
            // The term the remote's Hello announced: its commands apply.
            term: self.term,
            seq: self.next_tick,
            sent_at: stamp,
            echo: self.echo_at(stamp),
            released: self.newest_state.filter(|_| self.running),
        };
        self.next_tick += 1;
        if self.running {
            self.sent += 1;
            frame(&header, &Message::Data(&[self.sent as f64]))
        } else {
            frame(&header, &Message::Data(&[]))
        }
    }

    /// A frame from the remote came at remote time `at`: what the base
    /// answers at once.
    fn receive(&mut self, at: Instant, bytes: &[u8]) -> Option<Vec<u8>> {
        let now = self.local(at);
        let frame_in = Frame::new_checked(bytes).expect("the remote sends valid frames");
        if let (Some(echo), Some(_), false) = (frame_in.echo(), self.handshaken, self.running)
            && self.nrtts.len() < 10
        {
            self.nrtts
                .push((now - echo.sent_at).saturating_sub(echo.hold));
        }
        self.heard.push((frame_in.sent_at(), now));
        match frame_in.payload() {
            Payload::Hello(h) => {
                assert_eq!(h.role, Role::Remote);
                self.handshaken = Some(now);
                self.term = frame_in.term();
            }
            Payload::Data(values) if !values.is_empty() => {
                self.newest_state = Some(frame_in.seq());
            }
            Payload::Close(c) => panic!("the remote closed the link: {c}"),
            _ => {}
        }
        if self.running || self.nrtts.len() < 10 {
            return None;
        }
        self.running = true;
        let lo = self.nrtts.iter().min()?.as_secs_f64();
        let hi = self.nrtts.iter().max()?.as_secs_f64();
        let ns = 2 + (1.3 * (hi - lo) / T.as_secs_f64()) as u16;
        let header = Header {
            term: 0,
            seq: self.next_tick,
            sent_at: now,
            echo: self.echo_at(now),
            released: None,
        };
        let resume = Control {
            op: ControlOp::Resume,
            ns,
            period: T,
        };
        Some(frame(&header, &Message::Control(resume)))
    }
}

fn frame(header: &Header, msg: &Message<'_>) -> Vec<u8> {
    let mut buf = vec![0; MAX_FRAME_LEN];
    let n = wire::encode(header, msg, &mut buf).expect("a valid frame");
    buf.truncate(n);
    buf
}

/// What the remote (of `playout`) did with a hand-written base started as
/// `start`, over `COMMANDS` commands and two seconds more: the commands it
/// released fresh, in order, and its playout delay then; or the error that
/// ended the link.
fn serve(start: Start, playout: Playout) -> Result<(Vec<u64>, Option<Duration>), LinkError> {
    let mut c = Config::new(Role::Remote);
    c.period = T;
    c.playout = playout;
    // The remote's endpoint starts when the base connects.
    let up = Instant::ZERO + start.remote_up;
    let mut remote = Endpoint::<Heap>::new(c, up).expect("a valid configuration");
    let mut base = HandBase::new(start);
    let (stamp, hello) = base.hello();
    // In flight, by arrival (remote time), each way.
    let mut to_remote = vec![(base.remote(stamp) + WIRE, hello)];
    let mut to_base: Vec<(Instant, Vec<u8>)> = Vec::new();
    let mut released = Vec::new();
    let mut buf = [0u8; MAX_FRAME_LEN];
    let end = up + T * (COMMANDS + 40);
    let delay = |r: &Endpoint<Heap>| r.playout_delay();
    loop {
        let now = [
            to_remote.first().map(|f| f.0),
            to_base.first().map(|f| f.0),
            remote.poll_timeout(),
            base.next_tick_due(),
        ]
        .into_iter()
        .flatten()
        .min()
        .expect("something is due");
        if now > end {
            break;
        }
        while to_remote.first().is_some_and(|f| f.0 <= now) {
            let (at, bytes) = to_remote.remove(0);
            remote.handle_frame(at, &bytes)?;
        }
        while to_base.first().is_some_and(|f| f.0 <= now) {
            let (at, bytes) = to_base.remove(0);
            to_remote.extend(base.receive(at, &bytes).map(|f| (now + WIRE, f)));
        }
        if remote.poll_timeout().is_some_and(|t| t <= now) {
            remote.handle_timeout(now);
        }
        while let Some(event) = remote.poll_event() {
            match event {
                Event::Released(r) => {
                    if r.status == Status::Fresh {
                        released.push(r.values()[0] as u64);
                    }
                    remote.set_sample(r.values()).expect("a valid sample");
                }
                Event::Closed { error } => return Err(error.unwrap_or(LinkError::Closed)),
                _ => {}
            }
        }
        while let Ok(Some(n)) = remote.poll_transmit(now, &mut buf) {
            to_base.push((now + WIRE, buf[..n].to_vec()));
        }
        if base.next_tick_due().is_some_and(|t| t <= now) {
            let f = base.tick();
            to_remote.push((now + WIRE, f));
        }
    }
    Ok((released, delay(&remote)))
}

#[test]
fn a_base_whose_first_probe_is_stamped_at_its_clocks_start_is_served() {
    let us = Duration::from_micros;
    let (ms, s) = (Duration::from_millis, Duration::from_secs);
    let unix_time = 1_700_000_000_000_000_000;
    // The last hour of the stamps a clock may read.
    let last_hour = (1 << 63) - 3_600_000_000_000;
    let (mut cases, mut failed) = (0, Vec::new());
    for playout in [Playout::ADAPTIVE, Playout::Fifo] {
        for remote_up in [ms(1400), Duration::ZERO, s(3600)] {
            for clock in [0, 1, unix_time, last_hour] {
                // The Hello at its start or just after, or a period after
                // its first probe's stamp; the first tick at its start, a
                // nanosecond after, or a period after.
                for hello in [Duration::ZERO, us(50), T] {
                    for first_tick in [Duration::ZERO, Duration::from_nanos(1), T] {
                        cases += 1;
                        let start = Start {
                            remote_up,
                            clock,
                            hello,
                            first_tick,
                        };
                        let (released, delay) = match serve(start, playout) {
                            Ok(served) => served,
                            Err(e) => {
                                failed.push(format!("{playout:?} {start:?}: {e}"));
                                continue;
                            }
                        };
                        let first = released.iter().take_while(|&&v| v <= COMMANDS);
                        let in_order = first.copied().eq(1..=COMMANDS);
                        // The adaptive playout at the wire's delay, not at
                        // the clocks' offset.
                        let prompt = playout == Playout::Fifo || delay.is_some_and(|d| d <= T);
                        if !(in_order && prompt) {
                            let n = released.iter().filter(|&&v| v <= COMMANDS).count();
                            failed.push(format!(
                                "{playout:?} {start:?}: {n} of {COMMANDS} released, delay {delay:?}"
                            ));
                        }
                    }
                }
            }
        }
    }
    assert_eq!(cases, 2 * 3 * 4 * 3 * 3);
    assert!(
        failed.is_empty(),
        "{} of {cases} not served:\n{}",
        failed.len(),
        failed.join("\n")
    );
}

#[test]
fn a_base_whose_clock_passes_2_to_the_63_is_refused_with_that_error() {
    // 2⁶³ ns is 292 years: no clock reads it, and the clock arithmetic
    // takes stamps as signed nanoseconds. A base whose clock gets there a
    // second into the link is refused at its first frame stamped there.
    let start = Start {
        remote_up: Duration::from_millis(1400),
        clock: (1 << 63) - 1_000_000_000,
        hello: Duration::ZERO,
        first_tick: Duration::ZERO,
    };
    for playout in [Playout::ADAPTIVE, Playout::Fifo] {
        let refused = serve(start, playout).map(|_| ());
        // Its tick 20, a second on.
        let got = Instant::from_nanos(1 << 63);
        assert_eq!(
            refused,
            Err(LinkError::StampOutOfRange { got }),
            "{playout:?}"
        );
    }
}
