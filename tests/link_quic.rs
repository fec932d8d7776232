//! The link over QUIC on loopback: mutual TLS 1.3 with the TLS link's
//! identities, the samples as QUIC datagrams, the handshake and control on
//! a QUIC stream; the same constant round trip as the other transports,
//! and a peer with an unknown certificate refused.

mod common;

use std::net::SocketAddr;
use std::path::PathBuf;

use ndr::core::endpoint::Config;
use ndr::core::time::Duration;
use ndr::core::wire::Role;
use ndr::keygen::{self, KeyPair};
use ndr::net::{HandshakeError, Link, LinkConfig, Listener, NetError, TlsConfig, Transport};

fn config() -> LinkConfig {
    let mut c = Config::paper(Role::Base).with_width(2);
    c.period = Duration::from_millis(10);
    LinkConfig::new(c).with_transport(Transport::QUIC)
}

/// Throwaway certificates for one test: base, remote and a stranger.
struct Certs {
    dir: PathBuf,
    base: KeyPair,
    remote: KeyPair,
    other: KeyPair,
}

impl Certs {
    fn new(test: &str) -> Certs {
        let dir = std::env::temp_dir().join(format!("ndr-link-quic-{}-{test}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        Certs {
            base: keygen::write(&dir, "base").unwrap(),
            remote: keygen::write(&dir, "remote").unwrap(),
            other: keygen::write(&dir, "other").unwrap(),
            dir,
        }
    }
}

impl Drop for Certs {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// `own` trusting `peer` by its certificate file.
fn tls(own: &KeyPair, peer: &KeyPair) -> TlsConfig {
    TlsConfig::from_files(&own.cert, &own.key, &peer.cert).unwrap()
}

fn listener(rt: &tokio::runtime::Runtime, certs: &Certs) -> Listener {
    let addr: SocketAddr = "127.0.0.1:0".parse().unwrap();
    let config = config().with_tls(tls(&certs.remote, &certs.base));
    rt.block_on(Listener::listen(addr, config)).unwrap()
}

/// The listener's next link and a base's link to `to` (the listener, or a
/// path to it) with `base_tls`: (remote, base).
fn accept_and_connect(
    rt: &tokio::runtime::Runtime,
    listener: &Listener,
    to: SocketAddr,
    base_tls: TlsConfig,
) -> (Link, Link) {
    let (remote, base) = rt.block_on(async {
        tokio::join!(
            listener.accept(),
            Link::connect(to, config().with_tls(base_tls))
        )
    });
    (remote.unwrap(), base.unwrap())
}

/// The ticks `sender`'s hub may have sent together, at most: a hub a
/// period late or more at a release runs the ticks it missed at once, as
/// many as periods in its lateness. QUIC may put them in one packet, which
/// one loss takes whole.
fn served_late(sender: &ndr::net::LinkStats) -> u64 {
    let late = sender.release_lateness;
    late.mean.as_nanos() * late.count / sender.period.as_nanos().max(1)
}

#[test]
fn quic_on_loopback_delivers_every_sample_once_in_order_with_a_constant_grtt() {
    let _serial = common::serial();
    let certs = Certs::new("grtt");
    let rt = common::runtime();
    let run = common::assert_regulated(|| {
        let listener = listener(&rt, &certs);
        let addr = listener.local_addr().unwrap();
        let base_tls = tls(&certs.base, &certs.remote);
        let (remote, base) = accept_and_connect(&rt, &listener, addr, base_tls);
        let run = common::echo_run(base, remote);
        assert_eq!(listener.stats().accepted, 1);
        run
    });
    let remote = run.remote.expect("the remote's stats");
    for (side, s, peer) in [("base", &run.base, &remote), ("remote", &remote, &run.base)] {
        let (e, dropped) = (&s.endpoint, peer.endpoint.tx_dropped);
        // Every sample went as a QUIC datagram, and quinn took them all:
        // one for each of the peer's 300 ticks and more, but those its hub,
        // held by the host past its transmit queue, never sent
        // (`tx_dropped`). Loopback loses none and keeps the order: a sample
        // is lost only among those. That the copies make good every loss
        // they can is judged in simulated time
        // (crates/ndr-core/tests/endpoint_datagram.rs).
        assert!(
            e.datagrams_received + dropped > 250,
            "{side}: {s:?}; peer {peer:?}"
        );
        assert!(
            e.samples_lost <= dropped,
            "{side}: {} lost, {dropped} dropped: {s:?}; peer {peer:?}",
            e.samples_lost
        );
        assert_eq!(s.datagrams_unsent, 0, "{side}: {s:?}");
    }
    assert_eq!(
        run.base.datagram_peer.map(|a| a.ip()),
        Some([127, 0, 0, 1].into())
    );
}

#[test]
fn a_peer_with_an_unknown_certificate_is_refused_with_a_clear_error() {
    let _serial = common::serial();
    let certs = Certs::new("refused");
    let rt = common::runtime();
    let listener = listener(&rt, &certs);
    let addr = listener.local_addr().unwrap();
    // A stranger the remote does not trust, and a base that does not trust
    // the remote: neither becomes a link.
    let stranger = tls(&certs.other, &certs.remote);
    let refused = rt.block_on(Link::connect(addr, config().with_tls(stranger)));
    let err = refused.expect_err("a stranger's link");
    assert!(
        matches!(
            err,
            NetError::Handshake(HandshakeError::UnknownCertificate(_))
        ),
        "{err:?}"
    );
    assert!(err.to_string().contains("--peer-cert"), "{err}");
    let distrustful = tls(&certs.base, &certs.other);
    let refused = rt.block_on(Link::connect(addr, config().with_tls(distrustful)));
    assert!(
        matches!(
            refused,
            Err(NetError::Handshake(HandshakeError::UnknownCertificate(_)))
        ),
        "{refused:?}"
    );
    // The listener counted the stranger; the good base still gets in.
    let good = tls(&certs.base, &certs.remote);
    let (mut remote, base) = accept_and_connect(&rt, &listener, addr, good);
    base.send(&[1.0, 2.0]).unwrap();
    let got = remote.recv_timeout(std::time::Duration::from_secs(5));
    assert!(got.is_ok(), "{got:?}");
    let stats = listener.stats();
    assert!(stats.refused_certificate >= 1, "{stats:?}");
    assert_eq!(stats.accepted, 1, "{stats:?}");
}

#[test]
fn through_a_lossy_relay_quic_keeps_its_rate_and_redundancy_makes_good_the_losses() {
    use ndr::net::{Relay, RelayConfig};
    use ndr::netem::{DelayModel, LossModel};

    let _serial = common::serial();
    let certs = Certs::new("lossy");
    let rt = common::runtime();
    let any: SocketAddr = "127.0.0.1:0".parse().unwrap();
    // The handshake crosses the loss too: room for QUIC's retransmissions.
    let patient = |mut t: TlsConfig| {
        t.handshake_timeout = std::time::Duration::from_secs(20);
        t
    };
    let mut remote_config = config().with_tls(patient(tls(&certs.remote, &certs.base)));
    remote_config.admission.preauth_timeout = Duration::from_secs(20);
    let listener = rt.block_on(Listener::listen(any, remote_config)).unwrap();
    let lossy = RelayConfig::default().with_loss(LossModel::Bernoulli { rate: 0.1 });
    let relay = rt.block_on(async {
        let model = DelayModel::profile("constant:5").unwrap();
        Relay::listen(any, listener.local_addr().unwrap(), model, 7)
            .await
            .unwrap()
            .with_config(lossy)
            .spawn()
            .unwrap()
    });
    let base_tls = patient(tls(&certs.base, &certs.remote));
    let (remote, base) = accept_and_connect(&rt, &listener, relay.local_addr(), base_tls);
    let run = common::echo_run(base, remote);
    let relayed = relay.stats().datagrams;
    let remote = run.remote.expect("the remote's stats");
    // The relay lost about one packet in ten each way.
    assert!(relayed.forward.lost > 10, "{relayed:?}");
    assert!(relayed.backward.lost > 10, "{relayed:?}");
    for (side, s, sent_packets) in [
        ("base", &run.base, relayed.forward.received),
        ("remote", &remote, relayed.backward.received),
    ] {
        let e = &s.endpoint;
        // quinn neither held back nor dropped a datagram: the window does
        // not shrink on loss, and each Bundle left as a packet of its own
        // (the relay received at least 80 % as many: a relay the host holds
        // may have some dropped by the kernel before it reads them; a
        // window shrunk by the loss would send far fewer).
        assert_eq!(s.datagrams_unsent, 0, "{side}: {s:?}");
        let bundles = e.samples_sent + e.datagrams_repeated;
        assert!(
            sent_packets >= bundles * 4 / 5,
            "{side}: {sent_packets} packets, {bundles} bundles"
        );
        assert!(bundles > 300, "{side}: {s:?}");
    }
    // The copies made good what the loss took. A sample is lost for good
    // only if its datagram, its repeats and the next three datagrams (its
    // copies) all are: never, at a tenth lost each, but where the host held
    // the sender's hub. Its transmit queue then drops what it cannot hold
    // (`tx_dropped`), and the ticks it serves late go out together
    // (`served_late`).
    // (That the copies make good every loss they can is judged in
    // simulated time: crates/ndr-core/tests/endpoint_datagram.rs.)
    let e = &remote.endpoint;
    assert!(e.samples_recovered + e.datagrams_received > 250, "{e:?}");
    for (side, s, peer) in [("base", &run.base, &remote), ("remote", &remote, &run.base)] {
        let (lost, dropped) = (s.endpoint.samples_lost, peer.endpoint.tx_dropped);
        let late = served_late(peer);
        assert!(
            lost <= dropped + late,
            "{side}: {lost} lost, {dropped} dropped, {late} served late: {s:?}; peer {peer:?}"
        );
    }
}

/// A UDP path between a base and its listener whose address on the
/// listener's side can change mid-link, as a robot's does when it moves to
/// another Wi-Fi access point (or a NAT gives it a new mapping).
struct MovingPath {
    /// Where the base sends.
    addr: SocketAddr,
    /// The address the listener sees now: 0 or 1.
    current: std::sync::Arc<std::sync::atomic::AtomicUsize>,
    /// The two addresses the listener may see.
    sides: [SocketAddr; 2],
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl MovingPath {
    fn new(upstream: SocketAddr) -> MovingPath {
        use std::net::UdpSocket;
        use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
        use std::sync::{Arc, Mutex};
        let bind = || {
            let s = UdpSocket::bind("127.0.0.1:0").unwrap();
            s.set_read_timeout(Some(std::time::Duration::from_millis(50)))
                .unwrap();
            s
        };
        let front = bind();
        let sides = [bind(), bind()];
        let addrs = [
            sides[0].local_addr().unwrap(),
            sides[1].local_addr().unwrap(),
        ];
        let current = Arc::new(AtomicUsize::new(0));
        let stop = Arc::new(AtomicBool::new(false));
        let client: Arc<Mutex<Option<SocketAddr>>> = Arc::default();
        let mut threads = Vec::new();
        // Base → listener, from the side in use.
        {
            let (front, sides) = (
                front.try_clone().unwrap(),
                sides.each_ref().map(|s| s.try_clone().unwrap()),
            );
            let (current, stop, client) =
                (Arc::clone(&current), Arc::clone(&stop), Arc::clone(&client));
            threads.push(std::thread::spawn(move || {
                let mut buf = [0u8; 2048];
                while !stop.load(Ordering::Relaxed) {
                    if let Ok((n, from)) = front.recv_from(&mut buf) {
                        *client.lock().unwrap() = Some(from);
                        let side = &sides[current.load(Ordering::Relaxed)];
                        let _ = side.send_to(&buf[..n], upstream);
                    }
                }
            }));
        }
        // Listener → base, from either side.
        for side in sides {
            let front = front.try_clone().unwrap();
            let (stop, client) = (Arc::clone(&stop), Arc::clone(&client));
            threads.push(std::thread::spawn(move || {
                let mut buf = [0u8; 2048];
                while !stop.load(Ordering::Relaxed) {
                    if let Ok(n) = side.recv(&mut buf)
                        && let Some(to) = *client.lock().unwrap()
                    {
                        let _ = front.send_to(&buf[..n], to);
                    }
                }
            }));
        }
        MovingPath {
            addr: front.local_addr().unwrap(),
            current,
            sides: addrs,
            stop,
            threads,
        }
    }

    fn moved(&self) {
        self.current.store(1, std::sync::atomic::Ordering::Relaxed);
    }
}

impl Drop for MovingPath {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

#[test]
fn a_base_that_moves_to_another_address_keeps_its_link() {
    let _serial = common::serial();
    let certs = Certs::new("moves");
    let rt = common::runtime();
    let listener = listener(&rt, &certs);
    let path = MovingPath::new(listener.local_addr().unwrap());
    let base_tls = tls(&certs.base, &certs.remote);
    let (mut remote, mut base) = accept_and_connect(&rt, &listener, path.addr, base_tls);
    let robot = std::thread::spawn(move || {
        let mut seqs = Vec::new();
        let mut peers = Vec::new();
        while let Ok(s) = remote.recv_timeout(std::time::Duration::from_secs(2)) {
            seqs.push(s.seq);
            let _ = remote.send(s.values());
            let peer = remote.stats().and_then(|s| s.datagram_peer);
            if peers.last() != Some(&peer) {
                peers.push(peer);
            }
        }
        (seqs, peers, remote.stats())
    });
    let mut answered = 0;
    for k in 0..300 {
        if k == 150 {
            // The robot's new access point: the listener sees another address.
            path.moved();
        }
        base.send(&[f64::from(k), 0.0]).unwrap();
        let s = base
            .recv_timeout(std::time::Duration::from_secs(2))
            .unwrap();
        if k >= 160 && s.values()[0] > 150.0 {
            answered += 1;
        }
    }
    let base_stats = base.close().unwrap();
    let (seqs, peers, remote_stats) = robot.join().unwrap();
    // The link went on across the move, the remote answering to the new
    // address, and the samples around it were made good by their copies.
    // An answer comes a round trip after its command: a queue the host's
    // pauses sized long (its `ns`) leaves fewer of the 140 releases after
    // the move with one, as many fewer as round-trip ticks past 10.
    let round_trip = (base_stats.endpoint.grtt.mean() / 0.01).ceil() as u64;
    assert!(
        answered + round_trip.saturating_sub(10) > 100,
        "{answered} answers after the move, round trip {round_trip} ticks; {base_stats:?}"
    );
    assert!(
        peers.contains(&Some(path.sides[0])) && peers.contains(&Some(path.sides[1])),
        "{peers:?} (the sides: {:?})",
        path.sides
    );
    assert!(seqs.len() > 250, "{}", seqs.len());
    let remote_stats = remote_stats.unwrap();
    assert_eq!(remote_stats.datagram_path_changes, 1, "{remote_stats:?}");
    assert_eq!(base_stats.datagram_path_changes, 0, "{base_stats:?}");
    // At most two lost around the move, besides those a hub the host held
    // past its transmit queue dropped (counted).
    let (base_dropped, remote_dropped) = (
        base_stats.endpoint.tx_dropped,
        remote_stats.endpoint.tx_dropped,
    );
    assert!(
        remote_stats.endpoint.samples_lost <= 2 + base_dropped,
        "{remote_stats:?}; base {base_stats:?}"
    );
    assert!(
        base_stats.endpoint.samples_lost <= 2 + remote_dropped,
        "{base_stats:?}; remote {remote_stats:?}"
    );
}

/// A UDP path to `upstream` that passes a client's first packet (its
/// Initial: the listener takes it as a new connection), sent from `ip`,
/// and nothing after: the client's handshake stalls at the listener. If
/// the listener asks the client to prove its address (a QUIC Retry), the
/// Retry and the client's answer pass too, unless the hole is `blind`,
/// standing for a spoofed source that never gets what is sent to it.
struct Hole {
    addr: SocketAddr,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Hole {
    fn new(upstream: SocketAddr, ip: &str, blind: bool) -> Hole {
        use std::sync::atomic::{AtomicBool, Ordering};
        let hole = std::net::UdpSocket::bind((ip, 0)).unwrap();
        hole.set_read_timeout(Some(std::time::Duration::from_millis(50)))
            .unwrap();
        let addr = hole.local_addr().unwrap();
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let stopped = std::sync::Arc::clone(&stop);
        let thread = std::thread::spawn(move || {
            let mut buf = [0u8; 2048];
            // Client packets still to pass, and where the client is.
            let mut to_pass = 1;
            let mut client = None;
            let mut retried = false;
            while !stopped.load(Ordering::Relaxed) {
                let Ok((n, from)) = hole.recv_from(&mut buf) else {
                    continue;
                };
                if from != upstream {
                    client = Some(from);
                    if to_pass > 0 {
                        let _ = hole.send_to(&buf[..n], upstream);
                        to_pass -= 1;
                    }
                } else if let Some(client) = client
                    && !blind
                    && !retried
                    // A long header of type Retry.
                    && buf[0] & 0xf0 == 0xf0
                {
                    let _ = hole.send_to(&buf[..n], client);
                    retried = true;
                    to_pass += 1;
                }
            }
        });
        Hole {
            addr,
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for Hole {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Strangers (trusted by nobody here, but that is never found out) whose
/// handshakes with the listener at `upstream` stall, one from each of
/// `ips`, all at once, through [`Hole`]s; each gives up after a second
/// (time to answer a Retry on a busy host), its handshake left pending at
/// the listener if it got a slot.
fn stall_through(
    rt: &tokio::runtime::Runtime,
    certs: &Certs,
    upstream: SocketAddr,
    ips: &[&str],
    blind: bool,
) {
    let holes: Vec<Hole> = ips
        .iter()
        .map(|ip| Hole::new(upstream, ip, blind))
        .collect();
    let mut stranger = tls(&certs.other, &certs.remote);
    stranger.handshake_timeout = std::time::Duration::from_secs(1);
    let tries: Vec<_> = holes
        .iter()
        .map(|h| rt.spawn(Link::connect(h.addr, config().with_tls(stranger.clone()))))
        .collect();
    for t in tries {
        let stalled = rt.block_on(t).unwrap();
        assert!(
            matches!(
                stalled,
                Err(NetError::Handshake(HandshakeError::Timeout(_)))
            ),
            "{stalled:?}"
        );
    }
}

/// Strangers that get what is sent to them stall (see [`stall_through`]).
fn stall(rt: &tokio::runtime::Runtime, certs: &Certs, upstream: SocketAddr, ips: &[&str]) {
    stall_through(rt, certs, upstream, ips, false);
}

/// A listener with `slots` handshakes at once, `per_source` per source,
/// and a budget long enough that strangers hold their slots throughout a
/// test unless evicted.
fn guarded_listener(
    rt: &tokio::runtime::Runtime,
    certs: &Certs,
    slots: usize,
    per_source: usize,
) -> Listener {
    let mut remote_tls = tls(&certs.remote, &certs.base);
    remote_tls.max_pending_handshakes = slots;
    remote_tls.handshake_timeout = std::time::Duration::from_secs(20);
    let mut remote_config = config().with_tls(remote_tls);
    remote_config.admission.preauth_timeout = Duration::from_secs(20);
    remote_config.admission.max_pending_per_source = per_source;
    let any: SocketAddr = "127.0.0.1:0".parse().unwrap();
    rt.block_on(Listener::listen(any, remote_config)).unwrap()
}

/// The good base connects to `listener` from 127.0.0.1 and is accepted
/// within 5 s (well within the strangers' budget of 20 s).
fn good_base_gets_in(rt: &tokio::runtime::Runtime, certs: &Certs, listener: &Listener) {
    let mut good = tls(&certs.base, &certs.remote);
    good.handshake_timeout = std::time::Duration::from_secs(5);
    let addr = listener.local_addr().unwrap();
    let (remote, base) = rt.block_on(async {
        let accept = tokio::time::timeout(std::time::Duration::from_secs(5), listener.accept());
        tokio::join!(accept, Link::connect(addr, config().with_tls(good)))
    });
    assert!(
        remote.as_ref().is_ok_and(Result::is_ok) && base.is_ok(),
        "{remote:?} {base:?} {:?}",
        listener.stats()
    );
}

#[test]
fn a_stranger_that_never_finishes_its_handshake_does_not_keep_its_slot() {
    let _serial = common::serial();
    let certs = Certs::new("stalled");
    let rt = common::runtime();
    // One handshake at a time.
    let listener = guarded_listener(&rt, &certs, 1, 8);
    stall(&rt, &certs, listener.local_addr().unwrap(), &["127.0.0.1"]);
    // The stranger holds the only slot until the good base comes: the base
    // takes it.
    good_base_gets_in(&rt, &certs, &listener);
    let stats = listener.stats();
    assert_eq!(stats.evicted, 1, "{stats:?}");
    assert_eq!(stats.accepted, 1, "{stats:?}");
    assert_eq!(stats.timeouts, 0, "{stats:?}");
    // The only slot taken, the base proved its address first.
    assert_eq!(stats.retried, 1, "{stats:?}");
}

#[test]
fn one_source_may_hold_only_a_few_pending_quic_handshakes() {
    let _serial = common::serial();
    let certs = Certs::new("per-source");
    let rt = common::runtime();
    let listener = guarded_listener(&rt, &certs, 8, 2);
    // Five from one address: two get a slot, three are refused at once.
    let upstream = listener.local_addr().unwrap();
    stall(&rt, &certs, upstream, &["127.0.0.2"; 5]);
    let stats = listener.stats();
    assert_eq!(stats.refused_per_source, 3, "{stats:?}");
    // Another address is not held back by that one.
    stall(&rt, &certs, upstream, &["127.0.0.3"]);
    good_base_gets_in(&rt, &certs, &listener);
    let stats = listener.stats();
    assert_eq!(stats.refused_per_source, 3, "{stats:?}");
    assert_eq!(stats.evicted, 0, "{stats:?}");
    assert_eq!(stats.accepted, 1, "{stats:?}");
}

#[test]
fn strangers_holding_every_quic_slot_make_room_for_a_base() {
    let _serial = common::serial();
    let certs = Certs::new("evicted");
    let rt = common::runtime();
    // Two slots, each held by a stranger from its own address.
    let listener = guarded_listener(&rt, &certs, 2, 8);
    let upstream = listener.local_addr().unwrap();
    stall(&rt, &certs, upstream, &["127.0.0.2", "127.0.0.3"]);
    good_base_gets_in(&rt, &certs, &listener);
    let stats = listener.stats();
    assert_eq!(stats.evicted, 1, "{stats:?}");
    assert_eq!(stats.accepted, 1, "{stats:?}");
    assert_eq!(stats.refused_per_source, 0, "{stats:?}");
    assert_eq!(stats.timeouts, 0, "{stats:?}");
    // And again: the newcomer evicts the remaining stranger, not a link.
    stall(&rt, &certs, upstream, &["127.0.0.4"]);
    good_base_gets_in(&rt, &certs, &listener);
    let stats = listener.stats();
    assert_eq!(stats.evicted, 2, "{stats:?}");
    assert_eq!(stats.accepted, 2, "{stats:?}");
}

#[test]
fn strangers_handshakes_run_apart_from_the_hub_that_drives_the_links() {
    use ndr::net::Hub;

    let _serial = common::serial();
    let certs = Certs::new("apart");
    let rt = common::runtime();
    // The links' hub, named: it drives what the listener accepts.
    let hub = Hub::with_defaults().unwrap();
    let mut remote_tls = tls(&certs.remote, &certs.base);
    remote_tls.handshake_timeout = std::time::Duration::from_secs(20);
    let mut remote_config = config().with_tls(remote_tls).on_hub(hub.clone());
    remote_config.admission.preauth_timeout = Duration::from_secs(20);
    let any: SocketAddr = "127.0.0.1:0".parse().unwrap();
    let listener = rt.block_on(Listener::listen(any, remote_config)).unwrap();
    let upstream = listener.local_addr().unwrap();
    // Three strangers' handshakes pending at the listener: none on the
    // links' hub, where each would be work for anyone who asks.
    stall(
        &rt,
        &certs,
        upstream,
        &["127.0.0.2", "127.0.0.3", "127.0.0.4"],
    );
    assert_eq!(hub.links(), 0, "{:?}", listener.stats());
    // A base that authenticates is driven there.
    let base_tls = tls(&certs.base, &certs.remote);
    let (mut remote, mut base) = accept_and_connect(&rt, &listener, upstream, base_tls);
    assert_eq!(hub.links(), 1, "{:?}", listener.stats());
    // And its link works from there: samples both ways.
    base.send(&[1.0, 2.0]).unwrap();
    let got = remote
        .recv_timeout(std::time::Duration::from_secs(5))
        .unwrap();
    remote.send(got.values()).unwrap();
    let back = (0..100)
        .filter_map(|_| base.recv_timeout(std::time::Duration::from_secs(5)).ok())
        .find(|s| s.values()[0] == 1.0);
    assert!(back.is_some(), "{:?}", base.stats());
    let stats = listener.stats();
    assert_eq!(stats.accepted, 1, "{stats:?}");
    // It leaves the hub when it ends, and the hub's count says so.
    drop((base, remote));
    let end = std::time::Instant::now() + std::time::Duration::from_secs(2);
    while hub.links() != 0 && std::time::Instant::now() < end {
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    assert_eq!(hub.links(), 0);
}

#[test]
fn once_half_the_quic_slots_are_taken_spoofed_sources_take_none() {
    let _serial = common::serial();
    let certs = Certs::new("retry");
    let rt = common::runtime();
    let listener = guarded_listener(&rt, &certs, 2, 8);
    let upstream = listener.local_addr().unwrap();
    // One stranger takes half the slots; then sources that never get what
    // is sent to them are asked to prove their address, and cannot.
    stall(&rt, &certs, upstream, &["127.0.0.2"]);
    stall_through(
        &rt,
        &certs,
        upstream,
        &["127.0.0.3", "127.0.0.4", "127.0.0.5"],
        true,
    );
    let stats = listener.stats();
    assert_eq!(stats.retried, 3, "{stats:?}");
    assert_eq!(stats.evicted, 0, "{stats:?}");
    // The base proves its address and takes the free slot: no one evicted.
    good_base_gets_in(&rt, &certs, &listener);
    let stats = listener.stats();
    assert_eq!(stats.retried, 4, "{stats:?}");
    assert_eq!(stats.evicted, 0, "{stats:?}");
    assert_eq!(stats.accepted, 1, "{stats:?}");
}

#[test]
fn garbage_datagrams_are_counted_as_strays_and_the_link_carries_on() {
    let _serial = common::serial();
    let certs = Certs::new("strays");
    let rt = common::runtime();
    let listener = listener(&rt, &certs);
    let addr = listener.local_addr().unwrap();
    let base_tls = tls(&certs.base, &certs.remote);
    let (remote, base) = accept_and_connect(&rt, &listener, addr, base_tls);
    let stranger = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    // Short headers naming no connection (one large enough for quinn to
    // answer with a stateless reset), a long header of an unknown version,
    // a cut one, and an empty datagram: none opens a connection.
    let mut unknown_version = vec![0xc3, 0x0a, 0x0a, 0x0a, 0x0a, 8];
    unknown_version.extend([7; 8]);
    unknown_version.push(8);
    unknown_version.extend([9; 8]);
    unknown_version.resize(1200, 0);
    // And version 1 Initials that do not decrypt (random connection ids
    // and payloads): about one in four has reserved bits that read right
    // once its header protection is off, so that quinn takes it for a
    // client's first packet and refuses it only when the listener accepts.
    let mut x = 0x9e37_79b9_7f4a_7c15u64;
    let mut next = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let initials: Vec<Vec<u8>> = (0..8)
        .map(|_| {
            let mut d = vec![0xc3, 0, 0, 0, 1, 8];
            d.extend(next().to_be_bytes());
            d.extend([0, 0, 0x44, 0x9e]);
            d.extend((d.len()..1200).map(|_| next() as u8));
            d
        })
        .collect();
    let mut junk: Vec<&[u8]> = vec![
        b"not a QUIC packet",
        &[0x5a; 1200],
        &[0x5a; 65_000],
        &unknown_version,
        &unknown_version[..7],
        &[],
    ];
    junk.extend(initials.iter().map(Vec::as_slice));
    common::send_to_both_sides(&stranger, addr, &remote, &junk);
    std::thread::sleep(std::time::Duration::from_millis(200));
    // Counted while the links are up (once they close, their peers' last
    // packets are strays too).
    let n = junk.len() as u64;
    let listener_stats = listener.stats();
    assert_eq!(listener_stats.datagrams_stray, n, "{listener_stats:?}");
    assert_eq!(listener_stats.accepted, 1, "{listener_stats:?}");
    for (name, link) in [("remote", &remote), ("base", &base)] {
        let stats = link.stats().expect("stats");
        assert_eq!(stats.datagrams_stray, n, "{name}: {stats:?}");
    }
    let run = common::echo_run(base, remote);
    common::assert_every_sample_once_in_order(&run);
    let remote = run.remote.expect("the remote's stats");
    // The strays cost no sample: none lost but those the peer's hub, held
    // by the host past its transmit queue, never sent (`tx_dropped`).
    for (s, peer) in [(&run.base, &remote), (&remote, &run.base)] {
        assert!(
            s.endpoint.samples_lost <= peer.endpoint.tx_dropped,
            "{s:?}; peer {peer:?}"
        );
        assert_ne!(s.datagram_peer, Some(stranger.local_addr().unwrap()));
    }
}
