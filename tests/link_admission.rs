//! Admission that evicts rather than refuses: an attacker at the base's own
//! address (the same NAT, or any client of the same relay) that reopens
//! each dropped connection at once cannot keep a base out, directly or
//! through `ndr relay`; one-datagram senders cannot keep a udp base from
//! its samples through the relay; and a peer whose handshake is cut short
//! to make room is told why.
//!
//! Everything runs on loopback; distinct hosts are distinct 127.0.0.x. The
//! base connects from 127.0.0.1, and so does the attacker "at its
//! address". Which handshake gives way to whom is decided (and tested in
//! simulated time) in `listener/gate.rs` and `relay/datagram.rs`; these
//! tests check the whole with margins a loaded host cannot break: a base
//! retrying once a second is served within 5 s.

// Its runtime only.
#[allow(dead_code)]
mod common;

use std::io::{Read, Write};
use std::net::{Ipv4Addr, SocketAddr};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::endpoint::{Config, Transport};
use ndr::core::time::{Duration, Instant};
use ndr::core::wire::{self, CloseReason, Header, Hello, MAX_FRAME_LEN, Message, Payload, Role};
use ndr::net::{Link, LinkConfig, Listener, NetError, Relay, RelayHandle};
use ndr::sim::delay::DelayModel;
use tokio::io::AsyncReadExt;

/// How long a base may take to be served, from its first attempt.
const SERVED_WITHIN: StdDuration = StdDuration::from_secs(5);

fn config(datagrams: bool) -> LinkConfig {
    let mut c = Config::paper(Role::Base).with_width(1);
    c.period = Duration::from_millis(10);
    if datagrams {
        c.transport = Transport::DATAGRAM;
    }
    LinkConfig::new(c)
}

/// A robot: accepts every base and echoes its commands, each on a thread
/// of its own, until dropped.
struct Robot {
    listener: Arc<Listener>,
    stop: Arc<AtomicBool>,
    _rt: tokio::runtime::Runtime,
}

impl Robot {
    fn start(datagrams: bool) -> Robot {
        let rt = common::runtime();
        let listener = Arc::new(
            rt.block_on(Listener::listen(
                "127.0.0.1:0".parse().unwrap(),
                config(datagrams),
            ))
            .unwrap(),
        );
        let stop = Arc::new(AtomicBool::new(false));
        let (serving, stopping) = (Arc::clone(&listener), Arc::clone(&stop));
        rt.spawn(async move {
            while !stopping.load(Ordering::Relaxed) {
                let Ok(Ok(mut link)) =
                    tokio::time::timeout(StdDuration::from_millis(100), serving.accept()).await
                else {
                    continue;
                };
                let stopping = Arc::clone(&stopping);
                std::thread::spawn(move || {
                    while !stopping.load(Ordering::Relaxed) {
                        match link.recv_timeout(StdDuration::from_millis(200)) {
                            Ok(s) => {
                                let _ = link.send(s.values());
                            }
                            Err(NetError::Timeout) => {}
                            Err(_) => return,
                        }
                    }
                });
            }
        });
        Robot {
            listener,
            stop,
            _rt: rt,
        }
    }

    fn addr(&self) -> SocketAddr {
        self.listener.local_addr().unwrap()
    }
}

impl Drop for Robot {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// A relay with 5 ms each way in front of `upstream`.
fn relay(rt: &tokio::runtime::Runtime, upstream: SocketAddr) -> RelayHandle {
    rt.block_on(async {
        Relay::listen(
            "127.0.0.1:0".parse().unwrap(),
            upstream,
            DelayModel::profile("constant:5").unwrap(),
            1,
        )
        .await
        .unwrap()
        .spawn()
        .unwrap()
    })
}

// ----- the attacker ------------------------------------------------------------

async fn connect_from(source: Ipv4Addr, to: SocketAddr) -> std::io::Result<tokio::net::TcpStream> {
    let socket = tokio::net::TcpSocket::new_v4()?;
    socket.bind((source, 0).into())?;
    socket.connect(to).await
}

/// `n` connections from `source` that say nothing, each reopened as soon
/// as it is closed, on a runtime of their own.
struct Reopener {
    stop: Arc<AtomicBool>,
    opened: Arc<AtomicU64>,
    rt: Option<tokio::runtime::Runtime>,
}

impl Reopener {
    fn start(source: Ipv4Addr, to: SocketAddr, n: usize) -> Reopener {
        let rt = common::runtime();
        let stop = Arc::new(AtomicBool::new(false));
        let opened = Arc::new(AtomicU64::new(0));
        for _ in 0..n {
            let (stop, opened) = (Arc::clone(&stop), Arc::clone(&opened));
            rt.spawn(async move {
                let mut buf = [0u8; 256];
                while !stop.load(Ordering::Relaxed) {
                    let Ok(mut s) = connect_from(source, to).await else {
                        // Out of ports or refused: not a spin.
                        tokio::time::sleep(StdDuration::from_millis(1)).await;
                        continue;
                    };
                    opened.fetch_add(1, Ordering::Relaxed);
                    while !stop.load(Ordering::Relaxed) {
                        let read =
                            tokio::time::timeout(StdDuration::from_millis(100), s.read(&mut buf))
                                .await;
                        if let Ok(Ok(0) | Err(_)) = read {
                            break;
                        }
                    }
                }
            });
        }
        Reopener {
            stop,
            opened,
            rt: Some(rt),
        }
    }

    /// Stops; how many connections it opened.
    fn stop(mut self) -> u64 {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(rt) = self.rt.take() {
            rt.shutdown_timeout(StdDuration::from_secs(1));
        }
        self.opened.load(Ordering::Relaxed)
    }
}

impl Drop for Reopener {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(rt) = self.rt.take() {
            rt.shutdown_background();
        }
    }
}

// ----- the base ----------------------------------------------------------------

/// One attempt: connected, handshaken and a first sample released by
/// `deadline`.
fn attempt(addr: SocketAddr, datagrams: bool, deadline: StdInstant) -> Result<(), String> {
    let left = || deadline.saturating_duration_since(StdInstant::now());
    let mut link = Link::connect_blocking(addr, config(datagrams)).map_err(|e| e.to_string())?;
    loop {
        link.send(&[1.0]).map_err(|e| e.to_string())?;
        match link.recv_timeout(left().min(StdDuration::from_millis(100))) {
            Ok(_) => return Ok(()),
            Err(NetError::Timeout) if !left().is_zero() => {}
            Err(e) => return Err(e.to_string()),
        }
    }
}

/// A base that tries once a second until it is served; how long it took,
/// or what each attempt met.
fn base_retrying(addr: SocketAddr, datagrams: bool) -> Result<StdDuration, Vec<String>> {
    let start = StdInstant::now();
    let mut errors = Vec::new();
    for k in 0.. {
        let at = start + StdDuration::from_secs(k);
        if at >= start + SERVED_WITHIN {
            break;
        }
        std::thread::sleep(at.saturating_duration_since(StdInstant::now()));
        let deadline = (at + StdDuration::from_secs(1)).min(start + SERVED_WITHIN);
        match attempt(addr, datagrams, deadline) {
            Ok(()) => {
                if !errors.is_empty() {
                    eprintln!("served after: {errors:?}");
                }
                return Ok(start.elapsed());
            }
            Err(e) => errors.push(format!(
                "{:.1} s: {e}",
                at.duration_since(start).as_secs_f64()
            )),
        }
    }
    Err(errors)
}

/// An attacker at the base's address, `pending` connections reopened at
/// once, against `to` (the robot, or a relay in front of it).
fn served_beside_a_reopener(name: &str, robot: &Robot, to: SocketAddr, pending: usize) {
    let attacker = Reopener::start(Ipv4Addr::LOCALHOST, to, pending);
    // Let it take every slot its address may have first.
    std::thread::sleep(StdDuration::from_millis(1500));
    let served = base_retrying(to, false);
    let opened = attacker.stop();
    // The listener counts a link accepted when the robot's thread takes it,
    // which may come after the base's first release.
    let counted_by = StdInstant::now() + StdDuration::from_secs(5);
    let mut stats = robot.listener.stats();
    while served.is_ok() && stats.accepted == 0 && StdInstant::now() < counted_by {
        std::thread::sleep(StdDuration::from_millis(20));
        stats = robot.listener.stats();
    }
    eprintln!("{name}: served {served:?}; the attacker opened {opened}; listener {stats:?}");
    if let Err(errors) = served {
        panic!("{name}: not served within {SERVED_WITHIN:?}: {errors:?}; {stats:?}");
    }
    assert!(
        opened >= pending as u64,
        "{name}: the attacker opened {opened}"
    );
    assert!(stats.accepted >= 1, "{name}: {stats:?}");
}

#[test]
fn an_attacker_at_the_base_address_with_8_pending_does_not_keep_it_out() {
    let robot = Robot::start(false);
    served_beside_a_reopener("direct, 8", &robot, robot.addr(), 8);
    assert!(robot.listener.stats().refused_per_source > 0);
}

#[test]
fn an_attacker_at_the_base_address_with_300_pending_does_not_keep_it_out() {
    let robot = Robot::start(false);
    served_beside_a_reopener("direct, 300", &robot, robot.addr(), 300);
    assert!(robot.listener.stats().refused_per_source > 0);
}

#[test]
fn through_the_relay_an_attacker_with_8_pending_does_not_keep_a_base_out() {
    let robot = Robot::start(false);
    let rt = common::runtime();
    let relay = relay(&rt, robot.addr());
    served_beside_a_reopener("relay, 8", &robot, relay.local_addr(), 8);
}

#[test]
fn through_the_relay_an_attacker_with_300_pending_does_not_keep_a_base_out() {
    let robot = Robot::start(false);
    let rt = common::runtime();
    let relay = relay(&rt, robot.addr());
    served_beside_a_reopener("relay, 300", &robot, relay.local_addr(), 300);
}

#[test]
fn one_datagram_senders_do_not_keep_a_udp_base_from_its_samples_through_the_relay() {
    const SENDERS: usize = 1100;
    let robot = Robot::start(true);
    let rt = common::runtime();
    let relay = relay(&rt, robot.addr());
    let to = relay.local_addr();
    // Each from an address and port of its own, as spoofed ones would be,
    // in paced batches until the relay has had 1 100 (loopback drops what
    // a busy relay does not read in time).
    let max_flows = ndr::net::relay::DEFAULT_MAX_FLOWS as u64;
    let give_up = StdInstant::now() + StdDuration::from_secs(10);
    let mut sent = 0usize;
    while relay.stats().datagrams.forward.received < SENDERS as u64 {
        assert!(
            StdInstant::now() < give_up,
            "{sent} sent; {:?}",
            relay.stats()
        );
        for _ in 0..25 {
            let host = Ipv4Addr::new(
                127,
                0,
                1 + u8::try_from(sent / 250).unwrap(),
                1 + (sent % 250) as u8,
            );
            let socket = std::net::UdpSocket::bind((host, 0)).unwrap();
            socket.send_to(&[0x5a; 72], to).unwrap();
            sent += 1;
        }
        std::thread::sleep(StdDuration::from_millis(2));
    }
    let before = relay.stats().datagrams;
    assert_eq!(before.flows_active, max_flows, "{before:?}");
    assert_eq!(before.flows_refused, 0, "{before:?}");
    let served = base_retrying(to, true);
    let stats = relay.stats().datagrams;
    eprintln!("udp through the relay: served {served:?}; relay {stats:?}");
    if let Err(errors) = served {
        panic!("not served within {SERVED_WITHIN:?}: {errors:?}; {stats:?}");
    }
    // Senders gave way to the base's flow, which was never refused.
    assert!(stats.flows_evicted > before.flows_evicted, "{stats:?}");
    assert_eq!(stats.flows_refused, 0, "{stats:?}");
}

// ----- what an evicted peer is told ----------------------------------------------

fn partial_hello() -> Vec<u8> {
    let hello = Hello {
        seat: ndr_core::wire::Seat::Control,
        role: Role::Base,
        mode: wire::ModeCode::PaperStatic,
        underflow: wire::UnderflowCode::Hold,
        command_width: 1,
        state_width: 1,
        period: Duration::from_millis(10),
        layout: 0,
        session: 0,
        regulation: ndr::core::wire::RegulationName::NONE,
    };
    let mut buf = vec![0; MAX_FRAME_LEN];
    let n = wire::encode(
        &Header::new(0, Instant::ZERO),
        &Message::Hello(hello),
        &mut buf,
    )
    .unwrap();
    buf.truncate(n / 2);
    buf
}

/// A blocking connection from `source`.
fn plain_from(source: Ipv4Addr, to: SocketAddr) -> std::net::TcpStream {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let stream = rt.block_on(connect_from(source, to)).unwrap();
    let stream = stream.into_std().unwrap();
    stream.set_nonblocking(false).unwrap();
    stream
}

/// The Close reason `s` got before its end of stream (a reset is an error).
fn told(mut s: std::net::TcpStream) -> Result<Option<CloseReason>, std::io::Error> {
    s.set_read_timeout(Some(StdDuration::from_secs(3)))?;
    let mut got = Vec::new();
    s.read_to_end(&mut got)?;
    let Ok(Some(len)) = wire::frame_len(&got) else {
        return Ok(None);
    };
    let frame = wire::Frame::new_checked(&got[..len]).map_err(std::io::Error::other)?;
    Ok(match frame.payload() {
        Payload::Close(c) => Some(c.reason),
        _ => None,
    })
}

#[test]
fn a_handshake_cut_short_for_its_source_is_told_so_not_reset() {
    let robot = Robot::start(false);
    let to = robot.addr();
    let source = Ipv4Addr::new(127, 0, 0, 5);
    let cap = config(false).admission.max_pending_per_source;
    // The first speaks half its Hello (left unread: the listener only
    // peeks), the others nothing; all of them stale when the last comes,
    // the first the longest.
    let mut first = plain_from(source, to);
    first.write_all(&partial_hello()).unwrap();
    std::thread::sleep(StdDuration::from_millis(150));
    let mut rest: Vec<_> = (1..cap).map(|_| plain_from(source, to)).collect();
    std::thread::sleep(StdDuration::from_millis(300));
    rest.push(plain_from(source, to));
    assert_eq!(told(first).unwrap(), Some(CloseReason::EvictedSource));
    let stats = robot.listener.stats();
    assert_eq!(stats.refused_per_source, 1, "{stats:?}");
    assert_eq!(stats.evicted, 0, "{stats:?}");
}

#[test]
fn a_handshake_cut_short_for_want_of_any_slot_is_told_so() {
    let robot = Robot::start(false);
    let to = robot.addr();
    let slots = ndr::net::tls::DEFAULT_MAX_PENDING_HANDSHAKES;
    // One silent connection per host, as many hosts as slots.
    let first = plain_from(Ipv4Addr::new(127, 0, 2, 1), to);
    std::thread::sleep(StdDuration::from_millis(200));
    let mut rest: Vec<_> = (1..slots)
        .map(|i| plain_from(Ipv4Addr::new(127, 0, 2, 1 + u8::try_from(i).unwrap()), to))
        .collect();
    std::thread::sleep(StdDuration::from_millis(200));
    rest.push(plain_from(Ipv4Addr::new(127, 0, 3, 1), to));
    assert_eq!(told(first).unwrap(), Some(CloseReason::Evicted));
    let stats = robot.listener.stats();
    assert_eq!(stats.evicted, 1, "{stats:?}");
}

/// A remote that answers the first Hello with a Close `reason`, as a
/// listener does to a base whose handshake it cut short (or that it
/// refuses as busy), then waits for the base to hang up.
fn refusing_remote(reason: CloseReason) -> (SocketAddr, std::thread::JoinHandle<()>) {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let serving = std::thread::spawn(move || {
        let (mut s, _) = listener.accept().unwrap();
        s.set_read_timeout(Some(StdDuration::from_secs(5))).unwrap();
        let mut hello = [0u8; 80];
        s.read_exact(&mut hello).unwrap();
        let mut close = [0u8; MAX_FRAME_LEN];
        let close_msg = Message::Close(wire::Close { reason });
        let n = wire::encode(&Header::new(0, Instant::ZERO), &close_msg, &mut close).unwrap();
        s.write_all(&close[..n]).unwrap();
        let _ = s.read_to_end(&mut Vec::new());
    });
    (addr, serving)
}

#[test]
fn a_base_whose_handshake_was_cut_short_says_why() {
    for (reason, says) in [
        (
            CloseReason::EvictedSource,
            "too many handshakes pending from this side's address",
        ),
        (CloseReason::Evicted, "every handshake slot was taken"),
        (CloseReason::Busy, "busy"),
    ] {
        let (addr, remote) = refusing_remote(reason);
        let mut base = Link::connect_blocking(addr, config(false)).unwrap();
        let e = loop {
            base.send(&[1.0]).unwrap_or_default();
            match base.recv_timeout(StdDuration::from_secs(3)) {
                Ok(_) => continue,
                Err(e) => break e,
            }
        };
        assert!(
            matches!(e, NetError::Link(ndr::core::endpoint::LinkError::PeerClosed { reason: r }) if r == reason),
            "{e:?}"
        );
        assert!(e.to_string().contains(says), "{e}");
        drop(base);
        remote.join().unwrap();
    }
}
