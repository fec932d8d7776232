//! The link endpoint driven by hand-advanced time: a pair of endpoints and a
//! tiny network that jumps to the next deadline (quinn-proto's test `Pair`).
//! Included by `endpoint_inline.rs` and `endpoint_heap.rs`: every case runs
//! on both storages, `super::Store`.

// Inline storage's values are `Copy`, heap storage's are not: one body
// clones for both.
#![allow(clippy::clone_on_copy)]

#[allow(unused_imports)]
use std::{borrow::ToOwned, boxed::Box, string::String, string::ToString, vec::Vec};
#[allow(unused_imports)]
use std::{eprintln, format, println, vec};

use std::collections::BTreeMap;
use std::convert::Infallible;
use std::ops::{Deref, DerefMut};

use crate::endpoint::{Config, Endpoint, Event, LinkError, Mode, Phase, Status, Underflow};
use crate::pair::{self, World};
use crate::storage::Storage;
use crate::time::{Duration, Instant};
use crate::wire::{self, CloseReason, MAX_FRAME_LEN, Role};

type Ep = Endpoint<super::Store>;
type Values = <super::Store as Storage>::Values;

const T: Duration = Duration::from_millis(200);

/// Delay of the n-th frame sent in a direction.
type DelayFn = Box<dyn FnMut(u64) -> Duration>;

/// The shared [`pair::Pair`] over the tests' world.
struct Pair(pair::Pair<super::Store, Net>);

/// The tests' world: an in-order wire each way whose delays the test
/// gives, drivers that may serve their deadlines late or stop, a remote
/// that answers each command with it and a base that sends its tick count;
/// everything recorded.
struct Net {
    sent: [u64; 2],
    last_arrival: [Instant; 2],
    delay: [DelayFn; 2],
    base_events: Vec<Event<Values>>,
    remote_events: Vec<Event<Values>>,
    base_errors: Vec<LinkError>,
    remote_errors: Vec<LinkError>,
    tick: u64,
    /// What each side actually sent, by sequence number.
    sent_values: [BTreeMap<u64, Vec<f64>>; 2],
    /// How late each side's driver serves its n-th deadline.
    lag: [DelayFn; 2],
    wakes: [u64; 2],
    /// Each side's deadline being waited for, and how late it will be served.
    lagged: [Option<(Instant, Duration)>; 2],
    /// The last Data frame each side was handed.
    last_data: [Vec<u8>; 2],
    /// A side whose process is stopped from one instant to another (a
    /// SIGSTOP): it runs nothing, and what arrives for it waits.
    frozen: Option<(Role, Instant, Instant)>,
    /// Whether the frames that waited for a stopped side carry the time
    /// they came (a kernel stamp), or that time only when it is less than
    /// a second old and else the time the stopped side reads them (a
    /// driver that takes an older stamp for a step of the wall clock).
    kernel_stamps: bool,
}

pub(super) fn config(role: Role) -> Config {
    let mut c = Config::paper(role).with_width(2);
    c.period = T;
    c
}

impl Net {
    /// The end of `side`'s stop, if `t` falls in it.
    fn stopped(&self, side: Role, t: Instant) -> Option<Instant> {
        match self.frozen {
            Some((s, from, to)) if s == side && t >= from && t < to => Some(to),
            _ => None,
        }
    }
}

impl World<super::Store> for Net {
    type Error = Infallible;

    fn arrival(&mut self, from: Role, sent: Instant, frame: &[u8]) -> Option<Instant> {
        let dir = from as usize;
        let f = wire::Frame::new_checked(frame).unwrap();
        if let wire::Payload::Data(ch) = f.payload()
            && !ch.is_empty()
        {
            self.sent_values[dir].insert(f.seq(), ch.iter().collect());
        }
        let d = (self.delay[dir])(self.sent[dir]);
        self.sent[dir] += 1;
        let arrival = (sent + d).max(self.last_arrival[dir]);
        self.last_arrival[dir] = arrival;
        Some(arrival)
    }

    fn wake(&mut self, side: Role, deadline: Instant) -> Instant {
        let i = side as usize;
        let t = self.stopped(side, deadline).unwrap_or(deadline);
        let lag = match self.lagged[i] {
            Some((d, lag)) if d == t => lag,
            _ => {
                let lag = (self.lag[i])(self.wakes[i]);
                self.wakes[i] += 1;
                self.lagged[i] = Some((t, lag));
                lag
            }
        };
        t + lag
    }

    fn read(&self, side: Role, arrived: Instant) -> Instant {
        self.stopped(side, arrived).unwrap_or(arrived)
    }

    // Stamped by the kernel when it came, read when the side runs.
    fn stamp(&self, _: Role, arrived: Instant, read: Instant) -> Instant {
        if self.kernel_stamps || read - arrived < Duration::from_secs(1) {
            arrived
        } else {
            read
        }
    }

    fn received(&mut self, side: Role, _: Instant, frame: &[u8]) {
        if let Ok(f) = wire::Frame::new_checked(frame)
            && matches!(f.payload(), wire::Payload::Data(ch) if !ch.is_empty())
        {
            self.last_data[side as usize] = frame.to_vec();
        }
    }

    fn event(
        &mut self,
        side: Role,
        ep: &mut Ep,
        _: Instant,
        ev: Event<Values>,
    ) -> Result<(), Infallible> {
        // The remote's "plant" returns the command it was given.
        if let Event::Released(r) = &ev
            && side == Role::Remote
        {
            ep.set_sample(r.values()).unwrap();
        }
        match side {
            Role::Base => self.base_events.push(ev),
            Role::Remote => self.remote_events.push(ev),
        }
        Ok(())
    }

    // The base's operator sends its tick count.
    fn sample(&mut self, side: Role, ep: &mut Ep, _: Instant) -> Result<(), Infallible> {
        if side == Role::Base && ep.phase() == Phase::Running {
            self.tick += 1;
            let k = self.tick as f64;
            ep.set_sample(&[k, -k]).unwrap();
        }
        Ok(())
    }

    fn failed(&mut self, side: Role, _: Instant, e: LinkError) -> Result<(), Infallible> {
        match side {
            Role::Base => self.base_errors.push(e),
            Role::Remote => self.remote_errors.push(e),
        }
        Ok(())
    }
}

impl Deref for Pair {
    type Target = pair::Pair<super::Store, Net>;
    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl DerefMut for Pair {
    fn deref_mut(&mut self) -> &mut Self::Target {
        &mut self.0
    }
}

impl Pair {
    fn new(base: Config, remote: Config, fwd: DelayFn, bwd: DelayFn) -> Pair {
        let net = Net {
            sent: [0; 2],
            last_arrival: [Instant::ZERO; 2],
            delay: [fwd, bwd],
            base_events: Vec::new(),
            remote_events: Vec::new(),
            base_errors: Vec::new(),
            remote_errors: Vec::new(),
            tick: 0,
            sent_values: [BTreeMap::new(), BTreeMap::new()],
            lag: [Box::new(|_| Duration::ZERO), Box::new(|_| Duration::ZERO)],
            wakes: [0; 2],
            lagged: [None; 2],
            last_data: [Vec::new(), Vec::new()],
            frozen: None,
            kernel_stamps: true,
        };
        let now = Instant::ZERO;
        Pair(pair::Pair::new(
            Ep::new(base, now).unwrap(),
            Ep::new(remote, now).unwrap(),
            net,
        ))
    }

    fn constant(ms: u64) -> Pair {
        let d = Duration::from_millis(ms);
        Pair::new(
            config(Role::Base),
            config(Role::Remote),
            Box::new(move |_| d),
            Box::new(move |_| d),
        )
    }

    fn run_until(&mut self, end: Instant) {
        let Ok(()) = self.0.run_until(end);
    }

    fn releases(events: &[Event<Values>]) -> Vec<crate::endpoint::Release<Values>> {
        events
            .iter()
            .filter_map(|e| match e {
                Event::Released(r) => Some(r.clone()),
                _ => None,
            })
            .collect()
    }
}

fn secs(s: u64) -> Instant {
    Instant::ZERO + Duration::from_secs(s)
}

#[test]
fn lan_static_link_starts_with_ns_2_and_a_grtt_of_six_periods() {
    let mut p = Pair::constant(10);
    p.run_until(secs(60));
    assert!(p.world.base_errors.is_empty() && p.world.remote_errors.is_empty());
    assert_eq!(p.base.phase(), Phase::Running);
    assert_eq!((p.base.ns(), p.remote.ns()), (2, 2));
    assert!(matches!(p.world.base_events[0], Event::Connected { .. }));
    assert!(
        p.world
            .base_events
            .iter()
            .any(|e| matches!(e, Event::Started { ns: 2, .. }))
    );
    // Ticks on one grid, 10 ms each way: each regulator holds a sample for
    // 2·T plus the wait to the next tick, so GRTT = 6·T exactly (the paper's 1.2 s).
    let grtt = p.base.stats().grtt;
    assert!(grtt.count() > 200, "{grtt:?}");
    assert!(
        (grtt.mean() - 1.2).abs() < 1e-9 && grtt.std() < 1e-9,
        "{grtt:?}"
    );
    let nrtt = p.base.stats().nrtt;
    assert!((nrtt.mean() - 0.020).abs() < 1e-9, "{nrtt:?}");
    // Occupancy before each release: ns + 1 = 3.
    let occ = p.remote.occupancy().unwrap();
    assert_eq!((occ.min, occ.max), (3, 3));
}

#[test]
fn every_sample_is_released_once_in_order() {
    // Jitter up to 150 ms on a 200 ms period, in order: nothing lost.
    let jitter = |seed: u64| -> DelayFn {
        let mut x = seed;
        Box::new(move |_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            Duration::from_millis(5 + x % 150)
        })
    };
    let mut p = Pair::new(
        config(Role::Base),
        config(Role::Remote),
        jitter(7),
        jitter(11),
    );
    p.run_until(secs(120));
    assert!(p.world.base_errors.is_empty() && p.world.remote_errors.is_empty());
    for (ep, events) in [
        (&p.base, &p.world.base_events),
        (&p.remote, &p.world.remote_events),
    ] {
        let fresh: Vec<u64> = Pair::releases(events)
            .iter()
            .filter(|r| r.status == Status::Fresh)
            .map(|r| r.seq)
            .collect();
        assert!(fresh.len() > 400);
        assert!(
            fresh.windows(2).all(|w| w[1] == w[0] + 1),
            "gap or repeat in {fresh:?}"
        );
        let s = ep.stats();
        assert_eq!(s.released_fresh, fresh.len() as u64);
        assert_eq!(
            s.samples_received,
            s.released_fresh + ep.queue_len() as u64 + s.rejected + s.discarded
        );
    }
    // What each side released is exactly what the other sent under that number.
    for (events, sent) in [
        (&p.world.remote_events, &p.world.sent_values[0]),
        (&p.world.base_events, &p.world.sent_values[1]),
    ] {
        for r in Pair::releases(events) {
            assert_eq!(
                Some(&r.values().to_vec()),
                sent.get(&r.seq),
                "seq {}",
                r.seq
            );
        }
    }
}

fn spike_pair(underflow: Underflow) -> Pair {
    // Forward frame 40 (a sample) is delayed by 900 ms: more than the stock of
    // 2 periods. In order, the frames behind it wait too.
    let mut base = config(Role::Base);
    base.underflow = underflow;
    let mut remote = config(Role::Remote);
    remote.underflow = underflow;
    Pair::new(
        base,
        remote,
        Box::new(|n| Duration::from_millis(if n == 40 { 900 } else { 10 })),
        Box::new(|_| Duration::from_millis(10)),
    )
}

#[test]
fn hold_repeats_and_then_carries_the_extra_delay() {
    let mut p = spike_pair(Underflow::Hold);
    p.run_until(secs(40));
    let s = p.remote.stats();
    assert!(s.underflows >= 1, "{s:?}");
    assert_eq!(s.late, s.underflows);
    assert_eq!(s.released_held, s.underflows);
    let rel = Pair::releases(&p.world.remote_events);
    let fresh: Vec<_> = rel.iter().filter(|r| r.status == Status::Fresh).collect();
    // Nothing is lost: consecutive sequence numbers.
    assert!(fresh.windows(2).all(|w| w[1].seq == w[0].seq + 1));
    // After the spike every sample spends `underflows` more periods in the queue.
    let before = fresh[5].released_at - fresh[5].sent_at;
    let after = fresh[fresh.len() - 1].released_at - fresh[fresh.len() - 1].sent_at;
    assert_eq!(after, before + T * s.underflows);
}

#[test]
fn drop_late_keeps_the_delay_and_counts_what_it_discards() {
    let mut p = spike_pair(Underflow::DropLate);
    p.run_until(secs(40));
    let s = p.remote.stats();
    assert!(s.late >= 1 && s.underflows >= s.late, "{s:?}");
    let rel = Pair::releases(&p.world.remote_events);
    let fresh: Vec<_> = rel.iter().filter(|r| r.status == Status::Fresh).collect();
    let first = fresh[2].released_at - fresh[2].sent_at;
    assert!(
        fresh
            .iter()
            .skip(2)
            .all(|r| r.released_at - r.sent_at == first)
    );
    assert_eq!(
        s.samples_received,
        s.released_fresh + p.remote.queue_len() as u64 + s.late + s.rejected + s.discarded
    );
    // Every tick released something: fresh or held.
    assert_eq!(s.released_held, s.underflows);
}

fn mismatch(edit: impl FnOnce(&mut Config)) -> (Vec<LinkError>, Vec<LinkError>) {
    let mut remote = config(Role::Remote);
    edit(&mut remote);
    mismatch_of(config(Role::Base), remote)
}

fn mismatch_of(base: Config, remote: Config) -> (Vec<LinkError>, Vec<LinkError>) {
    let d = Duration::from_millis(10);
    let mut p = Pair::new(base, remote, Box::new(move |_| d), Box::new(move |_| d));
    p.run_until(secs(5));
    assert!(p.base.is_closed() && p.remote.is_closed());
    let (_, _, mut net) = p.0.into_parts();
    // Each side hangs up after its Close; the simulated wire still hands it
    // the other's Close, which a closed endpoint refuses.
    for errors in [&mut net.base_errors, &mut net.remote_errors] {
        if errors.len() > 1 {
            assert_eq!(errors.pop(), Some(LinkError::Closed));
        }
    }
    (net.base_errors, net.remote_errors)
}

#[test]
fn handshake_mismatches_end_the_link_with_their_error() {
    let (b, r) = mismatch(|c| c.state_width = 3);
    assert_eq!(
        r,
        vec![LinkError::WidthMismatch {
            which: "state",
            ours: 3,
            theirs: 2
        }]
    );
    // The remote answers with its Hello before its Close: the base names
    // the mismatch from its own side, with both values.
    assert_eq!(
        b,
        vec![LinkError::WidthMismatch {
            which: "state",
            ours: 2,
            theirs: 3
        }]
    );

    // A robot that names its channels, an operator that names none.
    let arm = crate::fingerprint(&["q1", "q2"], &["q1", "q2"]);
    let (b, r) = mismatch(|c| c.layout = arm);
    assert_eq!(
        r,
        vec![LinkError::LayoutMismatch {
            ours: arm,
            theirs: 0
        }]
    );
    assert_eq!(
        b,
        vec![LinkError::LayoutMismatch {
            ours: 0,
            theirs: arm
        }]
    );
    let msg = r[0].to_string();
    assert!(
        msg.contains(&format!("{arm:#018x}")) && msg.contains("none"),
        "{msg}"
    );

    let (b, r) = mismatch(|c| c.period = Duration::from_millis(100));
    assert!(matches!(r[0], LinkError::PeriodMismatch { .. }));
    assert_eq!(
        b,
        vec![LinkError::PeriodMismatch {
            ours: T,
            theirs: Duration::from_millis(100)
        }]
    );
    let msg = b[0].to_string();
    assert!(
        msg.contains("this side runs at 200.000ms, the peer at 100.000ms")
            && msg.contains("configure both with the same period"),
        "{msg}"
    );
    assert_eq!(b[0].close_reason(), CloseReason::PeriodMismatch);

    let (b, r) = mismatch(|c| c.mode = Mode::PaperDynamic);
    assert!(matches!(
        r[0],
        LinkError::ModeMismatch {
            ours: Mode::PaperDynamic,
            theirs: wire::ModeCode::PaperStatic,
            ..
        }
    ));
    assert!(matches!(
        b[..],
        [LinkError::ModeMismatch {
            ours: Mode::PaperStatic,
            theirs: wire::ModeCode::PaperDynamic,
            ..
        }]
    ));

    let (_, r) = mismatch(|c| c.role = Role::Base);
    assert_eq!(r[0], LinkError::RoleMismatch { role: Role::Base });
    let msg = r[0].to_string();
    assert!(msg.contains("one side must be the base"), "{msg}");
}

#[test]
fn a_mode_mismatch_names_each_side_s_regulation_as_the_peer_s_hello_says() {
    // An adaptive base against a paper-dynamic remote: the Hello's mode
    // code says only that the base sizes its regulator once; its name says
    // which regulation it runs, with its values.
    let mut base = config(Role::Base);
    base.playout = crate::Playout::ADAPTIVE;
    let mut remote = config(Role::Remote);
    remote.mode = Mode::PaperDynamic;
    let (b, r) = mismatch_of(base, remote);
    let adaptive = crate::Regulation::ADAPTIVE.to_string();
    match r[..] {
        [
            LinkError::ModeMismatch {
                ours_named,
                theirs_named,
                ..
            },
        ] => {
            assert_eq!(ours_named.as_str(), "paper-dynamic");
            assert_eq!(theirs_named.as_str(), adaptive);
        }
        _ => panic!("{r:?}"),
    }
    let msg = r[0].to_string();
    assert!(
        msg.starts_with(&format!(
            "mode mismatch: the peer runs {adaptive} (its regulator sized once, at the \
             handshake), this side paper-dynamic"
        )),
        "{msg}"
    );
    assert!(msg.contains("the same --regulation"), "{msg}");
    let msg = b[0].to_string();
    assert!(
        msg.starts_with(&format!(
            "mode mismatch: the peer runs paper-dynamic (its FIFO resized, with a pause, as \
             the network changes), this side {adaptive} (its regulator sized once"
        )),
        "{msg}"
    );
    assert_eq!(r[0].close_reason(), CloseReason::ModeMismatch);
}

#[test]
fn garbage_and_wrong_version_end_the_link_with_a_close() {
    let now = Instant::from_millis(1);
    let mut remote = Ep::new(config(Role::Remote), Instant::ZERO).unwrap();
    let err = remote
        .handle_frame(now, b"definitely not a frame at all...")
        .unwrap_err();
    assert!(matches!(err, LinkError::Wire(_)), "{err:?}");
    assert!(remote.is_closed());
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = remote.poll_transmit(now, &mut buf).unwrap().unwrap();
    let close = wire::Frame::new_checked(&buf[..n]).unwrap();
    assert!(
        matches!(close.payload(), wire::Payload::Close(c) if c.reason == CloseReason::ProtocolError)
    );
    assert_eq!(remote.handle_frame(now, &buf[..n]), Err(LinkError::Closed));

    // A valid Hello from a newer version, and a version-1 peer's Hello
    // (3 axes, 200 ms: the bytes an older build sends).
    let mut base = Ep::new(config(Role::Base), Instant::ZERO).unwrap();
    let n = base.poll_transmit(now, &mut buf).unwrap().unwrap();
    buf[4] = wire::VERSION + 1;
    let newer = buf[..n].to_vec();
    let v1: Vec<u8> = [
        [0x40, 0, 0, 0, 1, 2, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
        [
            0xe8, 3, 0, 0, 0, 0, 0, 0, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff,
        ],
        [
            0, 0, 0, 0, 0, 0, 0, 0, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff, 0xff,
        ],
        [0, 1, 0, 0, 3, 0, 0, 0, 0, 0xc2, 0xeb, 0x0b, 0, 0, 0, 0],
    ]
    .concat();
    for (peer, hello) in [(wire::VERSION + 1, newer), (1, v1)] {
        let mut remote = Ep::new(config(Role::Remote), Instant::ZERO).unwrap();
        let err = remote.handle_frame(now, &hello).unwrap_err();
        assert_eq!(err, LinkError::VersionMismatch { peer });
        assert!(err.to_string().contains("upgrade the older side"), "{err}");
        let n = remote.poll_transmit(now, &mut buf).unwrap().unwrap();
        let close = wire::Frame::new_checked(&buf[..n]).unwrap();
        assert!(
            matches!(close.payload(), wire::Payload::Close(c) if c.reason == CloseReason::VersionMismatch)
        );
    }
}

#[test]
fn arbitrary_bytes_never_panic_the_endpoint() {
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    for len in 0..600usize {
        let mut ep = Ep::new(config(Role::Remote), Instant::ZERO).unwrap();
        let mut bytes: Vec<u8> = (0..len)
            .map(|_| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                x as u8
            })
            .collect();
        if len >= 8 {
            // A plausible prefix so that deeper checks run too.
            bytes[..4].copy_from_slice(&(len as u32).to_le_bytes());
            bytes[4] = 1;
            bytes[5] = (x % 5) as u8;
            bytes[6] = 0;
            bytes[7] = 0;
        }
        let _ = ep.handle_frame(Instant::from_millis(1), &bytes);
        ep.handle_timeout(Instant::from_secs_f64(100.0));
        let mut buf = [0u8; MAX_FRAME_LEN];
        while let Ok(Some(_)) = ep.poll_transmit(Instant::from_secs_f64(100.0), &mut buf) {}
    }
}

#[test]
fn a_silent_peer_times_the_handshake_out() {
    let mut base = Ep::new(config(Role::Base), Instant::ZERO).unwrap();
    let mut buf = [0u8; MAX_FRAME_LEN];
    assert!(
        base.poll_transmit(Instant::ZERO, &mut buf)
            .unwrap()
            .is_some()
    );
    let deadline = base.poll_timeout().unwrap();
    assert_eq!(deadline, secs(10));
    base.handle_timeout(deadline);
    assert!(base.is_closed());
    assert!(matches!(
        base.poll_event(),
        Some(Event::Closed {
            error: Some(LinkError::Timeout)
        })
    ));
}

#[test]
fn the_application_sample_is_checked() {
    let mut base = Ep::new(config(Role::Base), Instant::ZERO).unwrap();
    assert_eq!(
        base.set_sample(&[1.0]),
        Err(LinkError::SampleShape {
            expected: 2,
            got: 1
        })
    );
    assert_eq!(
        base.set_sample(&[1.0, f64::NAN]),
        Err(LinkError::NonFinite { index: 1 })
    );
    assert!(!LinkError::NonFinite { index: 1 }.is_fatal());
    assert!(!base.is_closed());
}

#[test]
fn dynamic_mode_moves_a_lan_link_to_50_ms() {
    let mut base = config(Role::Base);
    base.mode = Mode::PaperDynamic;
    let mut remote = config(Role::Remote);
    remote.mode = Mode::PaperDynamic;
    let d = Duration::from_millis(11);
    let mut p = Pair::new(base, remote, Box::new(move |_| d), Box::new(move |_| d));
    p.run_until(secs(120));
    assert!(
        p.world.base_errors.is_empty() && p.world.remote_errors.is_empty(),
        "{:?}",
        p.world.base_errors
    );
    // NRTT 22 ms: T = max(50 ms, 22/3 ms) = 50 ms; ns = 2.
    assert_eq!(p.base.period(), Duration::from_millis(50));
    assert_eq!(p.remote.period(), Duration::from_millis(50));
    assert_eq!((p.base.ns(), p.remote.ns()), (2, 2));
    let s = p.base.stats();
    assert_eq!((s.pauses, s.resizes), (1, 1));
    assert_eq!(p.remote.stats().pauses, 1);
    // The settled GRTT: 6 periods of 50 ms.
    let last = Pair::releases(&p.world.base_events)
        .iter()
        .rev()
        .find_map(|r| r.grtt)
        .unwrap();
    assert_eq!(last, Duration::from_millis(300));
    assert!(
        p.world
            .base_events
            .iter()
            .any(|e| matches!(e, Event::Paused { .. }))
    );
}

#[test]
fn the_watchdog_raises_link_lost_once_and_then_restored() {
    // Forward frames 60..=69 (2 s of samples) are held 2.5 s: the remote's
    // regulator runs dry for well over its 1 s watchdog.
    let mut p = Pair::new(
        config(Role::Base),
        config(Role::Remote),
        Box::new(|n| Duration::from_millis(if (60..70).contains(&n) { 2500 } else { 10 })),
        Box::new(|_| Duration::from_millis(10)),
    );
    p.run_until(secs(60));
    let lost: Vec<_> = p
        .world
        .remote_events
        .iter()
        .filter(|e| matches!(e, Event::LinkLost { .. }))
        .collect();
    assert_eq!(lost.len(), 1, "{lost:?}");
    assert!(
        matches!(lost[0], Event::LinkLost { silent_for } if *silent_for >= Duration::from_secs(1))
    );
    let Event::LinkLost { silent_for } = *lost[0] else {
        unreachable!()
    };
    // The outage runs from the last fresh release to the first after it:
    // longer than the silence the watchdog saw, within the hold of 2.5 s.
    let restored: Vec<Duration> = p
        .world
        .remote_events
        .iter()
        .filter_map(|e| match e {
            Event::LinkRestored { outage } => Some(*outage),
            _ => None,
        })
        .collect();
    assert_eq!(restored.len(), 1, "{restored:?}");
    assert!(
        restored[0] > silent_for && restored[0] <= Duration::from_millis(2600),
        "{restored:?} after {silent_for:?}"
    );
    assert_eq!(p.remote.stats().link_lost, 1);
    assert_eq!(p.base.stats().link_lost, 0);
}

#[test]
fn abort_reports_the_drivers_error_and_sends_no_close_for_a_lost_connection() {
    let mut ep = Ep::new(config(Role::Base), Instant::ZERO).unwrap();
    let mut buf = [0u8; MAX_FRAME_LEN];
    let _ = ep.poll_transmit(Instant::ZERO, &mut buf).unwrap();
    ep.abort(LinkError::Disconnected);
    assert!(ep.is_closed());
    assert_eq!(ep.poll_transmit(Instant::ZERO, &mut buf).unwrap(), None);
    assert!(matches!(
        ep.poll_event(),
        Some(Event::Closed {
            error: Some(LinkError::Disconnected)
        })
    ));
}

#[test]
fn an_adaptive_quantum_out_of_range_is_refused_with_the_range() {
    use crate::endpoint::ConfigError;
    use crate::playout::Playout;
    let with = |quantum| {
        let mut c = config(Role::Base);
        c.playout = Playout::Adaptive {
            epsilon_ppm: 1000,
            quantum,
        };
        Ep::new(c, Instant::ZERO).err()
    };
    for bad in [
        Duration::ZERO,
        Duration::from_micros(999),
        Duration::from_secs(11),
    ] {
        let refused = with(Some(bad));
        let asked = Playout::Adaptive {
            epsilon_ppm: 1000,
            quantum: Some(bad),
        };
        assert!(
            matches!(refused, Some(ConfigError::Playout(e)) if e.playout() == asked),
            "{refused:?}"
        );
        let message = refused.unwrap().to_string();
        assert!(message.contains("1.000ms to 10.000s"), "{message}");
    }
    for good in [
        None,
        Some(Duration::from_millis(1)),
        Some(Duration::from_secs(10)),
    ] {
        assert_eq!(with(good), None);
    }
}

/// The remote's stats after 300 s of an adaptive link, 10 ms each way on a
/// 200 ms period, with `side`'s driver serving one deadline in three
/// `lag_ms` late.
fn adaptive_with_a_late_driver(side: Role, lag_ms: u64) -> crate::endpoint::Stats {
    use crate::playout::Playout;
    let d = Duration::from_millis(10);
    let (mut base, mut remote) = (config(Role::Base), config(Role::Remote));
    base.playout = Playout::ADAPTIVE;
    remote.playout = Playout::ADAPTIVE;
    let mut p = Pair::new(base, remote, Box::new(move |_| d), Box::new(move |_| d));
    p.world.lag[side as usize] =
        Box::new(move |n| Duration::from_millis(if n % 3 == 2 { lag_ms } else { 0 }));
    p.run_until(secs(300));
    assert!(p.world.base_errors.is_empty() && p.world.remote_errors.is_empty());
    let released = Pair::releases(&p.world.remote_events);
    assert!(
        released.len() > 1000,
        "{} {:?} {:?} {:?}",
        released.len(),
        p.remote.phase(),
        p.remote.stats(),
        &p.world.remote_events[..p.world.remote_events.len().min(8)]
    );
    p.remote.stats()
}

#[test]
fn an_adaptive_release_served_late_is_its_own_slot_not_a_reason_to_raise_the_delay() {
    // A busy hub on the receiving side: each late release is the sample of
    // the slot it was late for; the delay stays where the network puts it,
    // and nothing repeats.
    let on_time = adaptive_with_a_late_driver(Role::Remote, 0);
    let late = adaptive_with_a_late_driver(Role::Remote, 120);
    assert_eq!(late.playout_delay_ticks, on_time.playout_delay_ticks);
    assert!(late.playout_delay_ticks <= 2, "{late:?}");
    assert_eq!(
        (late.underflows, late.late, late.skipped),
        (0, 0, 0),
        "{late:?}"
    );
    assert_eq!(late.delay_changes, on_time.delay_changes, "{late:?}");
}

#[test]
fn an_adaptive_link_takes_a_late_sender_as_delay_not_as_a_ratchet() {
    // A busy hub on the sending side: one send in three leaves 0.6·T late
    // (and is stamped with its tick's time), so its frame takes 130 ms where
    // the others take 10. The delay covers the late sends once, in quanta
    // of 1 ms (under the tick a delay in whole ticks took), and does not
    // keep rising: before the sends were stamped with their tick's time it
    // climbed to 460 ticks, a quantum at a time. On time, it is the 10 ms
    // and the warm-up's margin in whole milliseconds, not 20 ms steps.
    let on_time = adaptive_with_a_late_driver(Role::Base, 0);
    let late = adaptive_with_a_late_driver(Role::Base, 120);
    assert!(on_time.playout_delay_s >= 0.01, "{on_time:?}");
    assert!(on_time.playout_delay_s <= 0.012 + 1e-9, "{on_time:?}");
    assert!(late.playout_delay_s >= 0.13, "{late:?}");
    assert!(late.playout_delay_s <= 0.13 + 0.04 + 1e-9, "{late:?}");
    // Fine steps settle in a few more changes than 20 ms ones; a ratchet
    // would be hundreds.
    assert!(late.delay_changes <= 20, "{late:?}");
    assert_eq!(late.skipped, 0, "{late:?}");
}

#[test]
fn an_adaptive_link_holds_a_stall_once_its_late_rate_is_spent_but_not_an_outage() {
    // 10 ms each way at T = 20 ms, and two silences of the forward path,
    // their frames held to the end and then delivered at once: 300 ms at
    // about 30 s (a TCP stall), 5 s at about 60 s (an outage: past the 1 s
    // watchdog). ε = 0.1 % of some 1 500 delays lets one sample go; the
    // rest of the stall is held, and released in order. The outage is let
    // go: the delay is back where it was once the watchdog fires, and the
    // ticks repeat the last sample once a period through it.
    use crate::playout::Playout;
    let t = Duration::from_millis(20);
    let (mut base, mut remote) = (config(Role::Base), config(Role::Remote));
    for c in [&mut base, &mut remote] {
        c.period = t;
        c.playout = Playout::ADAPTIVE;
        c.underflow = Underflow::DropLate;
    }
    let held = move |n: u64, from: u64, to: u64| (from..to).contains(&n).then(|| t * (to - n));
    let fwd = Box::new(move |n: u64| {
        Duration::from_millis(10)
            + held(n, 1500, 1515)
                .or(held(n, 3000, 3250))
                .unwrap_or(Duration::ZERO)
    });
    let mut p = Pair::new(base, remote, fwd, Box::new(|_| Duration::from_millis(10)));
    p.run_until(secs(90));
    assert!(p.world.base_errors.is_empty() && p.world.remote_errors.is_empty());
    let released = Pair::releases(&p.world.remote_events);
    let fresh: Vec<_> = released
        .iter()
        .filter(|r| r.status == Status::Fresh)
        .collect();
    assert!(fresh.windows(2).all(|w| w[0].seq < w[1].seq));
    // The stall's 15 samples (the frames held, sent before the outage):
    // all but one released.
    let kept = fresh
        .iter()
        .filter(|r| r.sent_at < secs(45) && r.arrived_at - r.sent_at > t)
        .count();
    assert!(
        (14..=15).contains(&kept),
        "{kept} of the stall's 15 released"
    );
    let stats = p.remote.stats();
    assert!(stats.outage_delays > 0, "{stats:?}");
    // Through the outage (held, then let go when the watchdog fires): a
    // repeat once a period, not two while the next slot catches up.
    let repeats: Vec<Instant> = released
        .iter()
        .filter(|r| r.status == Status::Held)
        .map(|r| r.released_at)
        .filter(|&at| at > secs(60) && at < secs(65))
        .collect();
    assert!(repeats.len() >= 200, "{} repeats", repeats.len());
    for w in repeats.windows(2) {
        assert!(w[1] - w[0] >= t * 9 / 10, "repeats {:?} apart", w[1] - w[0]);
    }
    // Right after the outage the delay is what it was before it (300 ms),
    // not what is left of the second it had followed before the watchdog
    // fired (falling from 554 ms when it was left to slide back).
    let after = fresh
        .iter()
        .filter(|r| (secs(60)..secs(68)).contains(&r.sent_at))
        .map(|r| r.released_at - r.sent_at)
        .max();
    assert!(
        after.is_some_and(|d| d <= Duration::from_millis(300)),
        "{after:?}"
    );
}

/// A xorshift stream of delays `base_us + (0..spread_us)`, one per frame.
fn jittered(seed: u64, base_us: u64, spread_us: u64) -> DelayFn {
    let mut x = seed;
    Box::new(move |_| {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        Duration::from_micros(base_us + x % spread_us.max(1))
    })
}

#[test]
fn an_adaptive_link_starts_without_a_repeat_whatever_the_grids_phase() {
    // A loopback link (50 to 150 µs each way) at T = 10 ms, its remote's
    // grid anywhere within a period of the base's. Its first delay holds: no
    // rise of a quantum right after the first release (a repeat), whether
    // the warm-up margin puts the need a hair under a quantum boundary that
    // the first clock estimates cross, or the remote's first states would
    // go out on its grid before it moves to its releases.
    use crate::playout::Playout;
    let t = Duration::from_millis(10);
    for phase_us in (0..10_000).step_by(500) {
        for spread_us in [1, 100, 200] {
            let (mut base, mut remote) = (config(Role::Base), config(Role::Remote));
            for c in [&mut base, &mut remote] {
                c.period = t;
                c.playout = Playout::ADAPTIVE;
            }
            remote.tick_origin = Instant::ZERO + Duration::from_micros(phase_us);
            let fwd = jittered(12345 + spread_us, 50, spread_us);
            let bwd = jittered(999 + spread_us, 50, spread_us);
            let mut p = Pair::new(base, remote, fwd, bwd);
            p.run_until(secs(5));
            let case = format!("phase {phase_us} µs, jitter {spread_us} µs");
            assert!(
                p.world.base_errors.is_empty() && p.world.remote_errors.is_empty(),
                "{case}"
            );
            for (side, events) in [
                ("base", &p.world.base_events),
                ("remote", &p.world.remote_events),
            ] {
                let released = Pair::releases(events);
                assert!(
                    released.len() > 400,
                    "{case}: {side} released {}",
                    released.len()
                );
                assert!(
                    released.iter().all(|r| r.status == Status::Fresh)
                        && released.windows(2).all(|w| w[1].seq == w[0].seq + 1),
                    "{case}: {side} repeated or skipped a sample"
                );
                let delays: Vec<Duration> = events
                    .iter()
                    .filter_map(|e| match e {
                        Event::DelayChanged { delay, .. } => Some(*delay),
                        _ => None,
                    })
                    .collect();
                assert!(
                    delays.windows(2).all(|w| w[1] <= w[0]),
                    "{case}: {side}'s delay rose: {delays:?}"
                );
            }
        }
    }
}

#[test]
fn every_change_of_the_round_trip_in_ticks_is_announced_before_its_release() {
    // The adaptive playout releases between ticks and its remote's grid is
    // a fraction of a period off the base's: the round trip in ticks moves
    // between delay changes. Each move, and only a move, comes as a
    // `RoundTripChanged` just before the release that shows it; the FIFO
    // whose stock a step of the delay (after 10 s) runs out says so too.
    use crate::playout::Playout;
    let t = Duration::from_millis(10);
    for (playout, step_us) in [(Playout::ADAPTIVE, 0), (Playout::Fifo, 25_000)] {
        let (mut base, mut remote) = (config(Role::Base), config(Role::Remote));
        for c in [&mut base, &mut remote] {
            c.period = t;
            c.playout = playout;
        }
        remote.tick_origin = Instant::ZERO + Duration::from_micros(4_321);
        let mut jitter = jittered(7, 3_000, 2_000);
        let fwd: DelayFn = Box::new(move |n| {
            jitter(n) + Duration::from_micros(if n > 1_000 { step_us } else { 0 })
        });
        let bwd = jittered(8, 3_000, 2_000);
        let mut p = Pair::new(base, remote, fwd, bwd);
        p.run_until(secs(30));
        let case = format!("{playout:?}");
        assert!(p.world.base_errors.is_empty(), "{case}");
        let (mut announced, mut last, mut changes) = (None, None, 0);
        for e in &p.world.base_events {
            match e {
                Event::RoundTripChanged { grtt, ticks } => {
                    assert_eq!(*ticks, grtt.as_nanos().div_ceil(t.as_nanos()), "{case}");
                    assert_ne!(announced, Some(*ticks), "{case}: announced twice");
                    announced = Some(*ticks);
                }
                Event::Released(r) => {
                    if let Some(g) = r.grtt {
                        let ticks = g.as_nanos().div_ceil(t.as_nanos());
                        assert_eq!(announced, Some(ticks), "{case}: unannounced at {r:?}");
                        if last.is_some_and(|l| l != ticks) {
                            changes += 1;
                        }
                        last = Some(ticks);
                    }
                }
                _ => {}
            }
        }
        assert!(changes > 0, "{case}: the round trip never moved");
        let stats = p.base.stats();
        assert_eq!(stats.round_trip_changes, changes + 1, "{case}");
        assert_eq!(Some(stats.round_trip_ticks), last, "{case}");
    }
}

/// The last sample the remote was handed, re-encoded with `edit` applied
/// to its header: what a peer that repeats, replays or forges frames sends.
fn forged(p: &Pair, edit: impl FnOnce(&mut wire::Header)) -> Vec<u8> {
    let bytes = &p.world.last_data[Role::Remote as usize];
    let f = wire::Frame::new_checked(&bytes[..]).expect("a sample was delivered");
    let mut header = wire::Header {
        term: 0,
        seq: f.seq(),
        sent_at: f.sent_at(),
        echo: f.echo(),
        released: f.released(),
    };
    edit(&mut header);
    let values: Vec<f64> = match f.payload() {
        wire::Payload::Data(ch) => ch.iter().collect(),
        _ => unreachable!("a Data frame"),
    };
    let mut buf = [0u8; MAX_FRAME_LEN];
    let n = wire::encode(&header, &wire::Message::Data(&values), &mut buf).unwrap();
    buf[..n].to_vec()
}

/// What a forged frame is, what it does to the header, which error it
/// gets, and its Close reason.
type ForgeCase = (
    &'static str,
    Box<dyn Fn(&mut wire::Header)>,
    fn(&LinkError) -> bool,
    CloseReason,
);

#[test]
fn repeated_stale_and_forged_frames_end_the_link_and_are_never_released() {
    let next = |h: &mut wire::Header| {
        h.seq += 1;
        h.sent_at += T;
    };
    let cases: Vec<ForgeCase> = vec![
        (
            "the same frame again",
            Box::new(|_| {}),
            |e| matches!(e, LinkError::OutOfSequence { .. }),
            CloseReason::Sequence,
        ),
        (
            "five back",
            Box::new(|h| {
                h.seq -= 5;
                h.sent_at -= T * 5;
            }),
            |e| matches!(e, LinkError::OutOfSequence { .. }),
            CloseReason::Sequence,
        ),
        (
            "2^63 ahead",
            Box::new(move |h| {
                next(h);
                h.seq += 1 << 63;
            }),
            |e| matches!(e, LinkError::OutOfSequence { .. }),
            CloseReason::Sequence,
        ),
        (
            "stamped 2^63 ns",
            Box::new(move |h| {
                next(h);
                h.sent_at = Instant::from_nanos(1 << 63);
            }),
            |e| matches!(e, LinkError::StampAhead { .. }),
            CloseReason::Stamp,
        ),
        (
            "stamped a minute ahead",
            Box::new(move |h| {
                next(h);
                h.sent_at += Duration::from_secs(60);
            }),
            |e| matches!(e, LinkError::StampAhead { .. }),
            CloseReason::Stamp,
        ),
        (
            "the next one stamped in the past",
            Box::new(move |h| {
                next(h);
                h.sent_at -= T * 3;
            }),
            |e| matches!(e, LinkError::StampBehind { .. }),
            CloseReason::Stamp,
        ),
    ];
    for (what, edit, is_it, reason) in cases {
        let mut p = Pair::constant(10);
        p.run_until(secs(10));
        assert_eq!(p.remote.phase(), Phase::Running, "{what}");
        let bad = forged(&p, |h| edit(h));
        let now = p.now();
        let err = p.remote.handle_frame(now, &bad).expect_err(what);
        assert!(is_it(&err), "{what}: {err:?}");
        assert_eq!(err.close_reason(), reason, "{what}");
        assert!(p.remote.is_closed(), "{what}");
        // The Close frame with its reason goes out; no release follows.
        let mut buf = [0u8; MAX_FRAME_LEN];
        let mut closes = Vec::new();
        while let Some(n) = p.remote.poll_transmit(now, &mut buf).unwrap() {
            if let wire::Payload::Close(c) = wire::Frame::new_checked(&buf[..n]).unwrap().payload()
            {
                closes.push(c.reason);
            }
        }
        assert_eq!(closes, [reason], "{what}");
        let mut released = Pair::releases(&p.world.remote_events);
        while let Some(e) = p.remote.poll_event() {
            if let Event::Released(r) = e {
                released.push(r);
            }
        }
        assert!(
            released.windows(2).all(|w| w[0].seq < w[1].seq),
            "{what}: a release repeated or went back"
        );
    }
}

#[test]
fn a_peer_that_goes_silent_is_dropped_after_the_liveness_time() {
    // 10 ms each way at T = 200 ms; at 30 s the base stops (a hung
    // operator): the remote raises LinkLost after the watchdog (1 s), then
    // ends the link after its liveness time (3 s here) with PeerSilent, and
    // its Close goes out.
    let (base, mut remote) = (config(Role::Base), config(Role::Remote));
    remote.liveness = Some(Duration::from_secs(3));
    let d = Duration::from_millis(10);
    let mut p = Pair::new(base, remote, Box::new(move |_| d), Box::new(move |_| d));
    p.run_until(secs(30));
    assert_eq!(p.remote.phase(), Phase::Running);
    // The base's process stops: nothing of it runs or arrives any more.
    p.drop_in_flight(Role::Base);
    let mut now = p.now();
    let mut closed_at = None;
    for _ in 0..10_000 {
        if now >= secs(40) || closed_at.is_some() {
            break;
        }
        // At least a microsecond on: a deadline that stays past must not
        // hold the test.
        now = p
            .remote
            .poll_timeout()
            .expect("a deadline")
            .max(now + Duration::from_micros(1));
        p.remote.handle_timeout(now);
        while let Some(e) = p.remote.poll_event() {
            if let Event::Closed { error } = e {
                closed_at = Some((now, error));
            }
            p.world.remote_events.push(e);
        }
    }
    let (at, error) = closed_at.expect("the remote closed the link");
    assert!(
        matches!(error, Some(LinkError::PeerSilent { silent_for }) if silent_for >= Duration::from_secs(3)),
        "{error:?}"
    );
    // Within a period of the liveness time after the last frame.
    assert!(at <= secs(30) + Duration::from_secs(3) + T, "{at:?}");
    assert!(
        p.world
            .remote_events
            .iter()
            .any(|e| matches!(e, Event::LinkLost { .. }))
    );
    let mut buf = [0u8; MAX_FRAME_LEN];
    let mut reasons = Vec::new();
    while let Some(n) = p.remote.poll_transmit(at, &mut buf).unwrap() {
        if let wire::Payload::Close(c) = wire::Frame::new_checked(&buf[..n]).unwrap().payload() {
            reasons.push(c.reason);
        }
    }
    assert_eq!(reasons, [CloseReason::Timeout]);
}

/// GRTTs before and after, both sides' delays before and after (s).
type Stopped = (Vec<f64>, Vec<f64>, (f64, f64), (f64, f64));

/// An adaptive link at T = 50 ms, 10 ms each way, whose remote's process
/// stops from 30 s to 33 s (a SIGSTOP): the base's frames wait in the
/// kernel, and the remote runs the ticks it missed when it resumes. The
/// base's GRTTs before the stop and from 34 s, and both sides' delays
/// before and at 60 s.
fn stopped_remote(kernel_stamps: bool) -> Stopped {
    use crate::playout::Playout;
    let t = Duration::from_millis(50);
    let (mut base, mut remote) = (config(Role::Base), config(Role::Remote));
    for c in [&mut base, &mut remote] {
        c.period = t;
        c.playout = Playout::ADAPTIVE;
    }
    let mut p = Pair::new(
        base,
        remote,
        jittered(5, 10_000, 2_000),
        jittered(6, 10_000, 2_000),
    );
    p.world.frozen = Some((Role::Remote, secs(30), secs(33)));
    p.world.kernel_stamps = kernel_stamps;
    p.run_until(secs(30));
    let delays = |p: &Pair| {
        (
            p.base.stats().playout_delay_s,
            p.remote.stats().playout_delay_s,
        )
    };
    let before = delays(&p);
    p.run_until(secs(60));
    assert!(p.world.base_errors.is_empty() && p.world.remote_errors.is_empty());
    let grtts = |from: Instant, to: Instant| -> Vec<f64> {
        Pair::releases(&p.world.base_events)
            .iter()
            .filter(|r| r.released_at >= from && r.released_at < to)
            .filter_map(|r| r.grtt.map(Duration::as_secs_f64))
            .collect()
    };
    (
        grtts(secs(20), secs(30)),
        grtts(secs(34), secs(60)),
        before,
        delays(&p),
    )
}

#[test]
fn a_side_whose_process_stopped_for_3_s_is_back_on_its_delay_at_once() {
    // Samples that were on time to the kernel are no delay to cover: the
    // delays stay where the network puts them, and the round trip is back
    // within a second. So it is when the driver stamps the older ones with
    // the time it read them, three seconds late: the endpoint sees that the
    // driver missed its deadlines, and takes them for an outage (the real
    // link held 650 ms for good).
    for kernel_stamps in [true, false] {
        let (settled, back, before, after) = stopped_remote(kernel_stamps);
        assert_eq!(after, before, "kernel stamps {kernel_stamps}");
        let (lo, hi) = span(&settled);
        assert!(!back.is_empty());
        for g in back {
            assert!(
                g >= lo - 1e-9 && g <= hi + 1e-9,
                "kernel stamps {kernel_stamps}: {g} outside {lo}..{hi}"
            );
        }
    }
}

/// The smallest and the largest of `xs`.
fn span(xs: &[f64]) -> (f64, f64) {
    let lo = xs.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = xs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (lo, hi)
}

/// A link at T = 20 ms over a loopback-like wire (100 to 300 µs each way),
/// the two grids aligned, `side`'s driver serving every deadline late by
/// up to `lag_us` (a loaded host): the base's fresh releases in 10 s, the
/// instant of its first, and the NRTTs it measured.
fn with_a_driver_late_past_the_wire(side: Role, lag_us: u64) -> (usize, Instant, u64) {
    use crate::playout::Playout;
    let t = Duration::from_millis(20);
    let (mut base, mut remote) = (config(Role::Base), config(Role::Remote));
    for c in [&mut base, &mut remote] {
        c.playout = Playout::ADAPTIVE;
        c.period = t;
    }
    let wire = |n: u64| Duration::from_micros(100 + n * 7919 % 200);
    let mut p = Pair::new(base, remote, Box::new(wire), Box::new(wire));
    p.world.lag[side as usize] =
        Box::new(move |n| Duration::from_micros(n * 104_729 % 1000 * lag_us / 1000));
    p.run_until(secs(10));
    assert!(p.world.base_errors.is_empty() && p.world.remote_errors.is_empty());
    let fresh: Vec<_> = Pair::releases(&p.world.base_events)
        .into_iter()
        .filter(|r| r.status == Status::Fresh)
        .collect();
    let first = fresh.first().map_or(secs(10), |r| r.released_at);
    (fresh.len(), first, p.base.stats().nrtt.count())
}

#[test]
fn a_driver_late_past_the_wire_still_echoes_and_the_link_starts_at_once() {
    // A tick run late finds the peer's next frame already in: it echoes
    // the newest frame that came by its stamp. Were only the newest kept,
    // every tick later than the wire would echo nothing, and the base
    // would wait for ten round trips to size the link.
    for side in [Role::Remote, Role::Base] {
        let on_time = with_a_driver_late_past_the_wire(side, 0);
        for lag_us in [2_000, 8_000, 19_000] {
            let (fresh, first, nrtts) = with_a_driver_late_past_the_wire(side, lag_us);
            assert!(
                first <= on_time.1 + Duration::from_millis(200),
                "{side:?} {lag_us}: {first:?}"
            );
            assert!(
                fresh + 10 >= on_time.0,
                "{side:?} {lag_us}: {fresh} of {}",
                on_time.0
            );
            assert!(nrtts >= 450, "{side:?} {lag_us}: {nrtts} NRTTs");
        }
    }
}

#[test]
fn a_driver_back_from_a_long_stop_releases_every_sample_it_missed() {
    // The base's process stops for 60 periods while the remote goes on:
    // at the end it reads the 60 samples and runs the 60 ticks at once,
    // more releases than the event queue holds. The catch-up stops at a
    // full queue and the driver (the `Pair`) takes the events and calls
    // again: none is dropped.
    let t = Duration::from_millis(10);
    let (mut base, mut remote) = (config(Role::Base), config(Role::Remote));
    base.period = t;
    remote.period = t;
    let wire = Duration::from_millis(2);
    let mut p = Pair::new(
        base,
        remote,
        Box::new(move |_| wire),
        Box::new(move |_| wire),
    );
    let (from, to) = (secs(20), secs(20) + t * 60);
    p.world.frozen = Some((Role::Base, from, to));
    p.run_until(secs(40));
    assert!(
        p.world.base_errors.is_empty() && p.world.remote_errors.is_empty(),
        "{:?} {:?}",
        p.world.base_errors,
        p.world.remote_errors
    );
    let releases = Pair::releases(&p.world.base_events);
    let at_resume = releases.iter().filter(|r| r.released_at == to).count();
    let fresh: Vec<u64> = releases
        .iter()
        .filter(|r| r.status == Status::Fresh)
        .map(|r| r.seq)
        .collect();
    let s = p.base.stats();
    let gaps: Vec<&[u64]> = fresh.windows(2).filter(|w| w[1] > w[0] + 1).collect();
    assert_eq!(
        p.base.events_dropped(),
        0,
        "{at_resume} released at once; fresh seqs skip {gaps:?}"
    );
    assert!(at_resume > 40, "{at_resume} released at once");
    assert_eq!(s.released_fresh, fresh.len() as u64);
    let missing: u64 = fresh.windows(2).map(|w| w[1] - w[0] - 1).sum();
    assert!(fresh.windows(2).all(|w| w[1] > w[0]), "{fresh:?}");
    assert!(
        missing <= s.late + s.skipped + s.discarded + s.rejected,
        "{missing} missing, skipped {gaps:?}; {s:?}"
    );
}
