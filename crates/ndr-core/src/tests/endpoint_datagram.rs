//! The datagram transport: samples in bundles over a wire that loses,
//! reorders and repeats, the handshake and control on a reliable path.

#[allow(unused_imports)]
use std::{borrow::ToOwned, boxed::Box, string::String, string::ToString, vec::Vec};
#[allow(unused_imports)]
use std::{eprintln, format, println, vec};

use crate::endpoint::{
    Config, ConfigError, DatagramError, Endpoint, Event, LinkError, Origin, RenewError, Status,
    Taken, Transport, Underflow,
};
use crate::pair::{Pair, World};
use crate::playout::Playout;
use crate::storage::Heap;
use crate::time::{Duration, Instant};
use crate::wire::{CloseReason, Kind, Role};

const T: Duration = Duration::from_millis(10);
const SESSIONS: [u64; 2] = [0x1111_2222_3333_4444, 0x5555_6666_7777_8888];
/// Copies only: each datagram lost is one sample's only send.
const COPIES_ONLY: Transport = Transport::Datagram {
    redundancy: 3,
    repeats: 0,
};

fn config(role: Role, transport: Transport, playout: Playout) -> Config {
    let mut c = Config::new(role).with_widths(2, 3);
    c.period = T;
    c.playout = playout;
    c.transport = transport;
    c.session = match transport {
        Transport::Stream => 0,
        _ => SESSIONS[role as usize],
    };
    c
}

/// A wire whose datagrams (bundles) are each lost when `lose(n)` says so
/// and otherwise take `delay(n)` (so they may overtake each other), while
/// the reliable path (everything else) takes 5 ms, in order. The base
/// sends its count of releases, the remote answers with the command it
/// released; what each side released, fresh, is kept.
struct Lossy<L, D> {
    lose: L,
    delay: D,
    datagrams: [u64; 2],
    reliable_last: [Instant; 2],
    k: f64,
    fresh: [Vec<(u64, Vec<f64>)>; 2],
    errors: Vec<LinkError>,
}

impl<L: FnMut(u64) -> bool, D: FnMut(u64) -> Duration> World<Heap> for Lossy<L, D> {
    type Error = LinkError;

    fn arrival(&mut self, from: Role, sent: Instant, frame: &[u8]) -> Option<Instant> {
        let i = from as usize;
        if frame.get(5) == Some(&(Kind::Bundle as u8)) {
            let n = self.datagrams[i];
            self.datagrams[i] += 1;
            return (!(self.lose)(n)).then(|| sent + (self.delay)(n));
        }
        let at = (sent + Duration::from_millis(5)).max(self.reliable_last[i]);
        self.reliable_last[i] = at;
        Some(at)
    }

    fn event(
        &mut self,
        side: Role,
        ep: &mut Endpoint<Heap>,
        _: Instant,
        event: Event<Box<[f64]>>,
    ) -> Result<(), LinkError> {
        if let Event::Released(r) = event {
            if r.status == Status::Fresh {
                self.fresh[side as usize].push((r.seq, r.values().to_vec()));
            }
            let answer = match side {
                Role::Base => {
                    self.k += 1.0;
                    vec![self.k, -self.k]
                }
                Role::Remote => {
                    let v = r.values();
                    vec![v[0], v[1], v[0] + v[1]]
                }
            };
            ep.set_sample(&answer)?;
        }
        Ok(())
    }

    fn failed(&mut self, _: Role, _: Instant, error: LinkError) -> Result<(), LinkError> {
        self.errors.push(error);
        Ok(())
    }
}

/// A [`Lossy`] wire, nothing sent yet.
fn lossy<L, D>(lose: L, delay: D) -> Lossy<L, D> {
    Lossy {
        lose,
        delay,
        datagrams: [0; 2],
        reliable_last: [Instant::ZERO; 2],
        k: 0.0,
        fresh: [Vec::new(), Vec::new()],
        errors: Vec::new(),
    }
}

fn run<L: FnMut(u64) -> bool, D: FnMut(u64) -> Duration>(
    transport: Transport,
    lose: L,
    delay: D,
    secs: u64,
) -> Pair<Heap, Lossy<L, D>> {
    let ep = |role| {
        Endpoint::<Heap>::new(config(role, transport, Playout::ADAPTIVE), Instant::ZERO).unwrap()
    };
    let world = Lossy {
        lose,
        delay,
        datagrams: [0; 2],
        reliable_last: [Instant::ZERO; 2],
        k: 0.0,
        fresh: [Vec::new(), Vec::new()],
        errors: Vec::new(),
    };
    let mut pair = Pair::new(ep(Role::Base), ep(Role::Remote), world);
    pair.run_until(Instant::from_millis(secs * 1000)).unwrap();
    pair
}

/// Every tenth datagram lost, every seventh late enough to be overtaken.
fn lose_tenth(n: u64) -> bool {
    n % 10 == 9
}
fn late_seventh(n: u64) -> Duration {
    Duration::from_millis(if n % 7 == 3 { 25 } else { 4 })
}

#[test]
fn lost_and_reordered_datagrams_are_recovered_from_the_next_ones_copies() {
    let p = run(COPIES_ONLY, lose_tenth, late_seventh, 20);
    assert!(p.world.errors.is_empty(), "{:?}", p.world.errors);
    for (side, ep) in [(0, &p.base), (1, &p.remote)] {
        let fresh = &p.world.fresh[side];
        assert!(fresh.len() > 1500, "{side}: {}", fresh.len());
        // In order, none twice, none missing: the copies filled every gap.
        assert!(
            fresh.windows(2).all(|w| w[1].0 == w[0].0 + 1),
            "{side}: a gap or a repeat"
        );
        let s = ep.stats();
        assert!(s.samples_recovered > 150, "{side}: {s:?}");
        assert_eq!(s.samples_lost, 0, "{side}");
        assert!(s.datagrams_stale > 100, "{side}: {s:?}");
        assert_eq!((s.datagrams_foreign, s.datagrams_refused), (0, 0), "{side}");
    }
    // What the remote released is what the base sent: its count, negated.
    for (_, v) in &p.world.fresh[1] {
        assert_eq!(v[1], -v[0]);
    }
    for (_, v) in &p.world.fresh[0] {
        assert_eq!(v[2], v[0] + v[1]);
    }
}

#[test]
fn a_burst_longer_than_the_copies_loses_samples_but_never_reorders_them() {
    // Five datagrams in a row lost every 100: two are recovered, three lost.
    let p = run(COPIES_ONLY, |n| n % 100 >= 95, |_| T / 2, 20);
    for (side, ep) in [(0, &p.base), (1, &p.remote)] {
        let fresh = &p.world.fresh[side];
        assert!(
            fresh.windows(2).all(|w| w[1].0 > w[0].0),
            "{side}: out of order"
        );
        let s = ep.stats();
        assert!(
            s.samples_lost > 30 && s.samples_recovered > 20,
            "{side}: {s:?}"
        );
    }
}

#[test]
fn over_a_stream_the_same_losses_cannot_happen_and_bundles_are_refused() {
    // On a stream nothing is lost: the same run, no datagram at all.
    let p = run(Transport::Stream, lose_tenth, late_seventh, 5);
    assert_eq!(p.world.datagrams, [0, 0]);
    assert!(p.world.fresh[1].len() > 300);
    // A bundle handed to a stream endpoint ends its link as a protocol error.
    let mut remote = Endpoint::<Heap>::new(
        config(Role::Remote, Transport::Stream, Playout::Fifo),
        Instant::ZERO,
    )
    .unwrap();
    assert_eq!(
        remote.handle_datagram(Instant::ZERO, &[0; 60], Origin::Path),
        Err(DatagramError::NotDatagram)
    );
}

#[test]
fn stray_spoofed_garbage_and_replayed_datagrams_are_counted_and_harm_nothing() {
    let mut p = run(COPIES_ONLY, |_| false, |_| T / 2, 5);
    // The last bundle the base sent, as the network would repeat it.
    let mut bundle = None;
    let mut buf = vec![0; crate::wire::MAX_DATAGRAM_LEN];
    let now = p.now();
    p.base.set_sample(&[1.0, 2.0]).unwrap();
    let ep = &mut p.base;
    ep.handle_timeout(now + T);
    while let Some(n) = ep.poll_transmit(now + T, &mut buf).unwrap() {
        if buf[5] == Kind::Bundle as u8 {
            bundle = Some(buf[..n].to_vec());
        }
    }
    let bundle = bundle.expect("the base sent a bundle");
    let remote = &mut p.remote;
    let at = now + T + Duration::from_millis(3);
    assert_eq!(
        remote.handle_datagram(at, &bundle, Origin::Path),
        Ok(Taken::Samples)
    );
    // Repeated by the network, or replayed.
    assert!(matches!(
        remote.handle_datagram(at, &bundle, Origin::Path),
        Err(DatagramError::Stale { .. })
    ));
    // Another session's token (a stray, or a spoof that guessed wrong).
    let mut foreign = bundle.clone();
    foreign[48] ^= 0xff;
    assert!(matches!(
        remote.handle_datagram(at, &foreign, Origin::Path),
        Err(DatagramError::Foreign { .. })
    ));
    // Truncated, oversized, garbage, and a frame of the reliable path.
    let err = remote
        .handle_datagram(at, &bundle[..bundle.len() - 3], Origin::Path)
        .unwrap_err();
    assert!(matches!(err, DatagramError::Wire(_)), "{err}");
    let mut oversized = bundle.clone();
    oversized.extend([0; 8]);
    assert!(matches!(
        remote.handle_datagram(at, &oversized, Origin::Path),
        Err(DatagramError::Wire(_))
    ));
    assert!(matches!(
        remote.handle_datagram(at, b"GET / HTTP/1.1\r\n\r\n", Origin::Path),
        Err(DatagramError::Wire(_))
    ));
    let s = remote.stats();
    assert_eq!((s.datagrams_stale, s.datagrams_foreign), (1, 1), "{s:?}");
    assert_eq!(s.datagrams_refused, 3, "{s:?}");
    // The link is unharmed: it runs on.
    assert!(!remote.is_closed());
    let released = p.remote.stats().released_fresh;
    p.run_until(now + Duration::from_secs(2)).unwrap();
    assert!(p.remote.stats().released_fresh > released + 150);
    assert!(p.world.errors.is_empty(), "{:?}", p.world.errors);
}

#[test]
fn a_stream_peer_and_a_datagram_peer_refuse_each_other() {
    let base = Endpoint::<Heap>::new(
        config(Role::Base, Transport::DATAGRAM, Playout::Fifo),
        Instant::ZERO,
    )
    .unwrap();
    let remote = Endpoint::<Heap>::new(
        config(Role::Remote, Transport::Stream, Playout::Fifo),
        Instant::ZERO,
    )
    .unwrap();
    let world = lossy(|_| false, |_| T);
    let mut p = Pair::new(base, remote, world);
    p.run_until(Instant::from_millis(500)).unwrap();
    assert_eq!(
        p.world.errors[0],
        LinkError::TransportMismatch {
            ours: "stream",
            theirs: "datagram"
        }
    );
    assert!(
        p.world.errors[0]
            .to_string()
            .contains("give both the same transport")
    );
    // The base finds the mismatch in the remote's Hello, sent before its Close.
    assert_eq!(
        p.world.errors[1],
        LinkError::TransportMismatch {
            ours: "datagram",
            theirs: "stream"
        }
    );
    assert_eq!(
        p.world.errors[1].close_reason(),
        CloseReason::TransportMismatch
    );
}

#[test]
fn the_datagram_transport_needs_a_token_and_a_redundancy_in_range() {
    for (redundancy, repeats, session) in [(3, 2, 0), (0, 2, 7), (9, 2, 7), (3, 5, 7)] {
        let mut c = config(
            Role::Base,
            Transport::Datagram {
                redundancy,
                repeats,
            },
            Playout::Fifo,
        );
        c.session = session;
        let err = Endpoint::<Heap>::new(c, Instant::ZERO).unwrap_err();
        assert_eq!(
            err,
            ConfigError::Datagram {
                redundancy,
                repeats,
                session
            }
        );
        assert!(
            err.to_string().contains("session token") || err.to_string().contains("0 to 4 repeats"),
            "{err}"
        );
    }
}

/// The `seq` a bundle's newest sample carries.
fn seq_of(frame: &[u8]) -> u64 {
    u64::from_le_bytes(frame[8..16].try_into().unwrap())
}

#[test]
fn a_lost_datagram_is_made_good_by_its_repeat_a_millisecond_later() {
    // Every sample's first datagram is lost, every repeat arrives: no
    // sample waits for the next period's copies.
    let mut p = {
        let ep = |role| {
            Endpoint::<Heap>::new(
                config(role, Transport::DATAGRAM, Playout::ADAPTIVE),
                Instant::ZERO,
            )
            .unwrap()
        };
        // The first datagram of each sample is lost; its repeats (and the
        // probes, which have none) go through.
        let mut seen: [std::collections::BTreeSet<u64>; 2] = Default::default();
        let world = Dropping {
            inner: lossy(|_| false, |_| Duration::from_millis(4)),
            lose: move |from: Role, _: Instant, frame: &[u8]| {
                // A bundle's width (offset 58) is 0 for a probe.
                let sample = frame.get(58..60).is_some_and(|w| w != [0, 0]);
                is_bundle(frame) && sample && seen[from as usize].insert(seq_of(frame))
            },
        };
        Pair::new(ep(Role::Base), ep(Role::Remote), world)
    };
    p.run_until(Instant::from_millis(20_000)).unwrap();
    let w = &p.world.inner;
    assert!(w.errors.is_empty(), "{:?}", w.errors);
    for (side, ep) in [(0, &p.base), (1, &p.remote)] {
        let fresh = &w.fresh[side];
        assert!(fresh.len() > 1500, "{side}: {}", fresh.len());
        assert!(
            fresh.windows(2).all(|w| w[1].0 == w[0].0 + 1),
            "{side}: a gap or a repeat"
        );
        let s = ep.stats();
        // Each sample came in its first repeat (the second is stale), not
        // from the next datagram's copies.
        assert_eq!(
            (s.samples_lost, s.samples_recovered),
            (0, 0),
            "{side}: {s:?}"
        );
        assert!(s.datagrams_repeated > 3000, "{side}: {s:?}");
        assert!(s.datagrams_stale > 1500, "{side}: {s:?}");
        // The one-way delay the playout holds: 4 ms and the repeat's 1 ms.
        let d = s.one_way_rx;
        assert!((d.mean() - 5e-3).abs() < 1e-4, "{side}: {d:?}");
    }
}

/// [`Lossy`] that also loses the frames `lose(from, sent, frame)` picks.
struct Dropping<L, D, F> {
    inner: Lossy<L, D>,
    lose: F,
}

impl<L, D, F> World<Heap> for Dropping<L, D, F>
where
    L: FnMut(u64) -> bool,
    D: FnMut(u64) -> Duration,
    F: FnMut(Role, Instant, &[u8]) -> bool,
{
    type Error = LinkError;

    fn arrival(&mut self, from: Role, sent: Instant, frame: &[u8]) -> Option<Instant> {
        if (self.lose)(from, sent, frame) {
            return None;
        }
        self.inner.arrival(from, sent, frame)
    }

    fn event(
        &mut self,
        side: Role,
        ep: &mut Endpoint<Heap>,
        at: Instant,
        event: Event<Box<[f64]>>,
    ) -> Result<(), LinkError> {
        self.inner.event(side, ep, at, event)
    }

    fn failed(&mut self, side: Role, at: Instant, error: LinkError) -> Result<(), LinkError> {
        self.inner.failed(side, at, error)
    }
}

fn is_bundle(frame: &[u8]) -> bool {
    frame.get(5) == Some(&(Kind::Bundle as u8))
}

#[test]
fn only_the_repeats_that_fit_before_the_next_sample_go() {
    // 1 ms apart, or half a period where that is shorter: one at T = 1 ms
    // and at 2.5 ms, the three asked for at 10 ms.
    for (period_us, per_sample) in [(1_000, 1), (2_500, 1), (10_000, 3)] {
        let ep = |role| {
            let mut c = config(role, Transport::DATAGRAM, Playout::ADAPTIVE);
            c.period = Duration::from_micros(period_us);
            Endpoint::<Heap>::new(c, Instant::ZERO).unwrap()
        };
        let world = lossy(|_| false, |_| Duration::from_micros(300));
        let mut p = Pair::new(ep(Role::Base), ep(Role::Remote), world);
        p.run_until(Instant::from_millis(3_000)).unwrap();
        for ep in [&p.base, &p.remote] {
            let s = ep.stats();
            assert!(s.samples_sent > 100, "{s:?}");
            // The last sample's may not all have gone when the run ends.
            let all = per_sample * s.samples_sent;
            assert!(
                (all.saturating_sub(per_sample)..=all).contains(&s.datagrams_repeated),
                "{period_us} µs: {s:?}"
            );
        }
        // The peer took each sample once: its repeats were stale (but
        // those in flight at the end).
        let r = p.remote.stats();
        let repeated = p.base.stats().datagrams_repeated;
        assert!(
            r.datagrams_stale.abs_diff(repeated) <= 2,
            "{repeated}: {r:?}"
        );
    }
}

#[test]
fn a_link_closed_between_a_sample_and_its_repeats_leaves_no_deadline() {
    // A repeat still armed on a closed endpoint was a deadline in the past
    // that `handle_timeout` never cleared: a driver looping on
    // `poll_timeout` spun on it for ever.
    let ep = |role| {
        Endpoint::<Heap>::new(
            config(role, Transport::DATAGRAM, Playout::ADAPTIVE),
            Instant::ZERO,
        )
        .unwrap()
    };
    let world = lossy(|_| false, |_| Duration::from_millis(4));
    let mut p = Pair::new(ep(Role::Base), ep(Role::Remote), world);
    let end = Instant::from_millis(3_000);
    p.run_until(Instant::from_millis(2_000)).unwrap();
    let sent = p.base.stats().samples_sent;
    assert!(sent > 100, "{:?}", p.base.stats());
    // Up to the base's next sample: its two repeats are due in 1 and 2 ms.
    while p.base.stats().samples_sent == sent {
        assert!(p.step(end).unwrap());
    }
    let at = p.now();
    assert_eq!(
        p.base.poll_timeout(),
        Some(at + Duration::from_millis(1)),
        "a repeat is due"
    );
    p.base.close();
    p.drain(Role::Base).unwrap();
    assert_eq!(p.base.poll_timeout(), None, "closed, nothing is due");
    // The remote, closed by the base's Close, has nothing due either.
    p.run_until(end).unwrap();
    assert!(p.remote.is_closed());
    assert_eq!(p.remote.poll_timeout(), None);
    assert_eq!(
        p.base.stats().datagrams_repeated,
        p.remote.stats().datagrams_stale
    );
}

#[test]
fn a_datagram_numbered_the_wires_none_is_refused_and_the_link_runs_on() {
    // Taken, sample 2⁶⁴ − 1 was released: the remote's next frames had to
    // name it in `released`, where it is the wire's "none", and none could
    // be written any more (and the next `seq` due overflowed).
    let mut p = run(COPIES_ONLY, |_| false, |_| T / 2, 5);
    let mut bundle = None;
    let mut buf = vec![0; crate::wire::MAX_DATAGRAM_LEN];
    let now = p.now();
    let ep = &mut p.base;
    ep.handle_timeout(now + T);
    while let Some(n) = ep.poll_transmit(now + T, &mut buf).unwrap() {
        if buf[5] == Kind::Bundle as u8 {
            bundle = Some(buf[..n].to_vec());
        }
    }
    let mut forged = bundle.expect("the base sent a bundle");
    forged[8..16].copy_from_slice(&u64::MAX.to_le_bytes());
    let at = now + T + Duration::from_millis(3);
    assert_eq!(
        p.remote.handle_datagram(at, &forged, Origin::Path),
        Err(DatagramError::Sequence { seq: u64::MAX })
    );
    let s = p.remote.stats();
    assert_eq!((s.datagrams_refused, s.datagrams_stale), (1, 0), "{s:?}");
    let released = s.released_fresh;
    p.run_until(now + Duration::from_secs(2)).unwrap();
    assert!(p.world.errors.is_empty(), "{:?}", p.world.errors);
    assert!(p.remote.stats().released_fresh > released + 150);
    assert!(p.base.stats().released_fresh > 150);
}

/// A lossless wire whose datagrams take half a period.
type Plain = Lossy<fn(u64) -> bool, fn(u64) -> Duration>;

/// A pair run 5 s, and the next bundle the base sends: what a stranger
/// who sees one datagram of the link gets.
fn running_and_a_sniffed_bundle() -> (Pair<Heap, Plain>, Vec<u8>) {
    let ep = |role| {
        let mut c = config(role, COPIES_ONLY, Playout::Fifo);
        c.underflow = Underflow::Hold;
        Endpoint::<Heap>::new(c, Instant::ZERO).unwrap()
    };
    let world: Plain = lossy(|_| false, |_| T / 2);
    let mut p = Pair::new(ep(Role::Base), ep(Role::Remote), world);
    p.run_until(Instant::from_millis(5_000)).unwrap();
    let mut bundle = None;
    let mut buf = vec![0; crate::wire::MAX_DATAGRAM_LEN];
    let now = p.now();
    let ep = &mut p.base;
    ep.handle_timeout(now + T);
    while let Some(n) = ep.poll_transmit(now + T, &mut buf).unwrap() {
        if buf[5] == Kind::Bundle as u8 {
            bundle = Some(buf[..n].to_vec());
        }
    }
    (p, bundle.expect("the base sent a bundle"))
}

/// `bundle` with its newest sample numbered `seq` and its values `v`.
fn forge(bundle: &[u8], seq: u64, v: f64) -> Vec<u8> {
    let mut forged = bundle.to_vec();
    forged[8..16].copy_from_slice(&seq.to_le_bytes());
    // One sample, so that no copy's order gives the forgery away.
    forged[56] = 1;
    forged[64..72].copy_from_slice(&v.to_le_bytes());
    forged[72..80].copy_from_slice(&v.to_le_bytes());
    forged.truncate(80);
    forged[0..4].copy_from_slice(&80u32.to_le_bytes());
    forged
}

#[test]
fn a_forged_datagram_numbered_far_ahead_is_refused_and_the_link_runs_on() {
    // Taken, one datagram numbered 2⁶⁴ − 2 made the robot apply its values
    // and every real datagram stale until both ends gave up.
    let (mut p, bundle) = running_and_a_sniffed_bundle();
    let now = p.now();
    let at = now + T + Duration::from_millis(3);
    for (i, seq) in [u64::MAX - 1, 1 << 40, bundle_seq(&bundle) + 400]
        .into_iter()
        .enumerate()
    {
        let err = p
            .remote
            .handle_datagram(at, &forge(&bundle, seq, 777.0), Origin::Path)
            .unwrap_err();
        assert!(matches!(err, DatagramError::Ahead { .. }), "{i}: {err}");
    }
    let s = p.remote.stats();
    assert_eq!(s.datagrams_refused, 3, "{s:?}");
    p.run_until(now + Duration::from_secs(1)).unwrap();
    let after = p.remote.stats();
    assert!(p.world.errors.is_empty(), "{:?}", p.world.errors);
    assert!(
        p.world.fresh[1].iter().all(|r| r.0 < 1 << 40),
        "nothing forged released"
    );
    assert_eq!(after.datagrams_stale, s.datagrams_stale, "{after:?}");
    assert_eq!(after.underflows, s.underflows, "{after:?}");
    assert!(after.released_fresh > s.released_fresh + 90, "{after:?}");
}

fn bundle_seq(bundle: &[u8]) -> u64 {
    u64::from_le_bytes(bundle[8..16].try_into().unwrap())
}

#[test]
fn a_copy_stamped_after_its_newest_sample_is_refused() {
    let (mut p, bundle) = running_and_a_sniffed_bundle();
    let frame = crate::wire::Frame::new_checked(&bundle[..]).unwrap();
    assert!(frame_copies(&bundle) > 0, "a bundle with copies");
    let newest = frame.sent_at().as_nanos();
    // The first copy's stamp, at 64 + 8 · width + 8.
    let mut forged = bundle.clone();
    let at = 64 + 8 * 2 + 8;
    for stamp in [newest + 1, u64::MAX - 5] {
        forged[at..at + 8].copy_from_slice(&stamp.to_le_bytes());
        let seq = u64::from_le_bytes(forged[at - 8..at].try_into().unwrap());
        let when = p.now() + T + Duration::from_millis(3);
        assert_eq!(
            p.remote.handle_datagram(when, &forged, Origin::Path),
            Err(DatagramError::CopyStamp { seq })
        );
    }
    assert_eq!(p.remote.stats().datagrams_refused, 2);
}

fn frame_copies(bundle: &[u8]) -> usize {
    usize::from(bundle[56]) - 1
}

#[test]
fn a_datagrams_seq_may_run_ahead_by_the_ticks_its_stamp_leaves_room_for() {
    let (mut p, bundle) = running_and_a_sniffed_bundle();
    let seq = bundle_seq(&bundle);
    let stamp = u64::from_le_bytes(bundle[16..24].try_into().unwrap());
    let at = p.now() + T + Duration::from_millis(3);
    assert_eq!(
        p.remote.handle_datagram(at, &bundle, Origin::Path),
        Ok(Taken::Samples)
    );
    // Stamped one period later: two half-period ticks fit, so the next
    // seq but one passes, and one more does not.
    let later = |seq: u64| {
        let mut b = forge(&bundle, seq, 1.0);
        b[16..24].copy_from_slice(&(stamp + T.as_nanos()).to_le_bytes());
        b
    };
    assert_eq!(
        p.remote
            .handle_datagram(at + T, &later(seq + 3), Origin::Path)
            .unwrap_err(),
        DatagramError::Ahead {
            seq: seq + 3,
            expected: seq + 1,
            room: 2
        }
    );
    assert_eq!(
        p.remote
            .handle_datagram(at + T, &later(seq + 2), Origin::Path),
        Ok(Taken::Samples)
    );
}

/// Runs `p` until the remote's next bundle for the base carries `token`,
/// and returns it.
fn base_bundle_with(p: &mut Pair<Heap, Plain>, token: u64) -> Vec<u8> {
    let mut buf = vec![0; crate::wire::MAX_DATAGRAM_LEN];
    for _ in 0..100 {
        let now = p.now() + T;
        p.base.handle_timeout(now);
        let mut found = None;
        while let Some(n) = p.base.poll_transmit(now, &mut buf).unwrap() {
            if buf[5] == Kind::Bundle as u8 && buf[48..56] == token.to_le_bytes() {
                found = Some(buf[..n].to_vec());
            }
        }
        if let Some(b) = found {
            return b;
        }
        p.run_until(now).unwrap();
    }
    panic!("no bundle with the new token");
}

#[test]
fn a_datagram_from_elsewhere_is_not_taken_until_a_new_token_validates_its_address() {
    let (mut p, bundle) = running_and_a_sniffed_bundle();
    let now = p.now();
    let at = now + T + Duration::from_millis(3);
    // A stranger's datagram, well numbered, from its own address.
    let forged = forge(&bundle, bundle_seq(&bundle), 777.0);
    assert_eq!(
        p.remote.handle_datagram(at, &forged, Origin::Elsewhere),
        Err(DatagramError::OffPath)
    );
    assert_eq!(p.remote.stats().datagrams_off_path, 1);
    assert_eq!(
        p.remote.stats().released_fresh,
        p.world.fresh[1].len() as u64
    );
    // The driver validates that address: a new token, on the reliable path.
    let fresh = 0x0123_4567_89ab_cdef;
    assert_eq!(p.remote.renew_session(0), Err(RenewError::Token));
    assert_eq!(p.remote.renew_session(fresh), Ok(None));
    assert_eq!(p.remote.pending_session(), Some(fresh));
    // The old token stays good meanwhile, from the path.
    assert_eq!(
        p.remote.handle_datagram(at, &bundle, Origin::Path),
        Ok(Taken::Samples)
    );
    // The base gets the Token frame, and its datagrams carry the new token:
    // the first one taken validates the address it comes from.
    let with_fresh = base_bundle_with(&mut p, fresh);
    let stamp = u64::from_le_bytes(with_fresh[16..24].try_into().unwrap());
    let at = Instant::from_nanos(stamp) + Duration::from_millis(3);
    let retired = SESSIONS[1];
    assert_eq!(
        p.remote.handle_datagram(at, &with_fresh, Origin::Elsewhere),
        Ok(Taken::Validated { retired })
    );
    assert_eq!(p.remote.pending_session(), None);
    let s = p.remote.stats();
    assert_eq!((s.tokens_renewed, s.paths_validated), (1, 1), "{s:?}");
    // The old token is another session's now.
    let old = forge(&bundle, bundle_seq(&with_fresh) + 1, 1.0);
    assert!(matches!(
        p.remote.handle_datagram(at, &old, Origin::Path),
        Err(DatagramError::Foreign { .. })
    ));
    p.run_until(p.now() + Duration::from_secs(1)).unwrap();
    assert!(p.world.errors.is_empty(), "{:?}", p.world.errors);
    assert!(p.world.fresh[1].iter().all(|r| r.0 < 1 << 40));
}

#[test]
fn a_sample_that_goes_out_after_the_close_arms_no_repeat() {
    // The application closes the link on a release, in the turn of the
    // tick that queued a sample: the sample still goes out before the
    // Close, and its repeats, armed on a closed endpoint, stayed due.
    let ep = |role| {
        Endpoint::<Heap>::new(
            config(role, Transport::DATAGRAM, Playout::ADAPTIVE),
            Instant::ZERO,
        )
        .unwrap()
    };
    let world = lossy(|_| false, |_| Duration::from_millis(4));
    let mut p = Pair::new(ep(Role::Base), ep(Role::Remote), world);
    let tick = Instant::from_millis(2_000);
    p.run_until(tick - Duration::from_nanos(1)).unwrap();
    let sent = p.base.stats().samples_sent;
    assert!(sent > 100, "{:?}", p.base.stats());
    p.base.handle_timeout(tick);
    p.base.close();
    let mut buf = vec![0; crate::wire::MAX_DATAGRAM_LEN];
    let mut kinds = Vec::new();
    while let Some(n) = p.base.poll_transmit(tick, &mut buf).unwrap() {
        kinds.push(buf[..n][5]);
    }
    assert_eq!(kinds, [Kind::Bundle as u8, Kind::Close as u8]);
    assert_eq!(p.base.stats().samples_sent, sent + 1);
    assert_eq!(p.base.poll_timeout(), None, "closed, nothing is due");
}

#[test]
fn repeats_go_while_the_peer_reports_losses_and_stop_on_a_clean_path() {
    let s = |secs: u64| Instant::from_millis(secs * 1000);
    let ep = |role| {
        Endpoint::<Heap>::new(
            config(role, Transport::DATAGRAM, Playout::ADAPTIVE),
            Instant::ZERO,
        )
        .unwrap()
    };
    // A clean path, but for a spell from 20 to 25 s in which one of the
    // base's datagrams in 7 is lost.
    let mut seen = 0u64;
    let world = Dropping {
        inner: lossy(|_| false, |_| Duration::from_millis(4)),
        lose: move |from: Role, sent: Instant, frame: &[u8]| {
            let spell = from == Role::Base && is_bundle(frame) && (s(20)..s(25)).contains(&sent);
            seen += u64::from(spell);
            spell && seen.is_multiple_of(7)
        },
    };
    let mut p = Pair::new(ep(Role::Base), ep(Role::Remote), world);
    let repeated = |p: &Pair<Heap, _>| {
        [&p.base, &p.remote].map(|ep: &Endpoint<Heap>| ep.stats().datagrams_repeated)
    };

    // Nothing known of the path: every sample repeated three times (T =
    // 10 ms) for the first 10 s.
    p.run_until(s(9)).unwrap();
    for ep in [&p.base, &p.remote] {
        let st = ep.stats();
        assert!(st.samples_sent > 800, "{st:?}");
        assert!(st.datagrams_repeated + 3 >= 3 * st.samples_sent, "{st:?}");
    }
    // Then nothing lost, nothing reported: one datagram a sample.
    p.run_until(s(11)).unwrap();
    let quiet = repeated(&p);
    p.run_until(s(20)).unwrap();
    assert_eq!(repeated(&p), quiet, "repeats on a clean path");

    // The spell: the remote reports the base's samples it missed, and the
    // base repeats again; the remote, whose datagrams all arrive, does not.
    p.run_until(s(26)).unwrap();
    let spell = repeated(&p);
    assert!(spell[0] > quiet[0] + 1000, "{spell:?} after {quiet:?}");
    assert_eq!(spell[1], quiet[1], "the remote repeated");
    let (b, r) = (p.base.stats(), p.remote.stats());
    assert!(b.loss_reports > 10, "{b:?}");
    assert_eq!(r.loss_reports, 0, "{r:?}");
    // The first loss waited for the next datagram's copies; once the
    // repeats went, a lost first send was made good by a repeat.
    assert!(r.samples_recovered >= 1, "{r:?}");
    assert!(r.samples_from_repeats > 50, "{r:?}");
    assert_eq!((r.samples_lost, b.samples_from_repeats), (0, 0), "{r:?}");

    // 10 s after the last report the base stops repeating.
    p.run_until(s(36)).unwrap();
    let after = repeated(&p);
    p.run_until(s(45)).unwrap();
    assert_eq!(repeated(&p), after, "repeats after the hold");
    let w = &p.world.inner;
    assert!(w.errors.is_empty(), "{:?}", w.errors);
    for fresh in &w.fresh {
        assert!(fresh.len() > 4000, "{}", fresh.len());
        assert!(
            fresh.windows(2).all(|w| w[1].0 == w[0].0 + 1),
            "a gap or a repeat"
        );
    }
}

/// A well-mixed 64-bit hash of `n` (splitmix64's finaliser): the lossy
/// wire's coin, the same in every run.
fn mix(n: u64) -> u64 {
    let mut z = n.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

#[test]
fn at_1_khz_a_lost_datagram_is_made_good_within_its_period() {
    // One datagram in ten lost at random (5 % on each of two hops), 4 to
    // 4.6 ms each way, for two minutes at T = 1 ms: with no repeat a lost
    // sample waited a period for the next datagram's copies, and one in
    // 10 000 lost its copies too. The repeat half a period later makes
    // good all but one in a hundred within the period.
    let ep = |role| {
        let mut c = config(role, Transport::DATAGRAM, Playout::ADAPTIVE);
        c.period = Duration::from_millis(1);
        Endpoint::<Heap>::new(c, Instant::ZERO).unwrap()
    };
    let world = lossy(
        |n: u64| mix(n) % 1000 < 100,
        |n: u64| Duration::from_micros(4_000 + mix(!n) % 600),
    );
    let mut p = Pair::new(ep(Role::Base), ep(Role::Remote), world);
    p.run_until(Instant::from_millis(120_000)).unwrap();
    assert!(p.world.errors.is_empty(), "{:?}", p.world.errors);
    for (side, ep) in [(0, &p.base), (1, &p.remote)] {
        let s = ep.stats();
        assert!(s.released_fresh > 119_000, "{side}: {s:?}");
        assert!(
            s.samples_from_repeats > s.released_fresh / 20,
            "{side}: {s:?}"
        );
        assert!(s.samples_recovered < s.released_fresh / 50, "{side}: {s:?}");
        assert_eq!(s.samples_lost, 0, "{side}: {s:?}");
        // Under a tenth of the playout's default target (ε = 0.1 %).
        assert!(s.late * 10_000 < s.released_fresh, "{side}: {s:?}");
    }
}
