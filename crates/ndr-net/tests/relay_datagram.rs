//! The relay's datagram path over real loopback UDP: delays both ways,
//! the loss model draw for draw, the flow limit, idle expiry, and two
//! clients at once.
//!
//! The machine may be loaded: timing assertions are lower bounds, or upper
//! bounds with wide margins; waits are bounded. Datagrams are sent in small
//! paced batches, so that no socket buffer on loopback overflows.

use std::net::SocketAddr;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr_core::time::Duration;
use ndr_net::relay::{Relay, RelayConfig, RelayHandle, RelayStats, connection_seed};
use ndr_netem::{DelayModel, Direction, LossModel};
use tokio::net::UdpSocket;
use tokio::sync::mpsc;
use tokio::time::timeout;

const LOOPBACK: &str = "127.0.0.1:0";

fn ms(n: u64) -> StdDuration {
    StdDuration::from_millis(n)
}

fn constant(fwd: u64, bwd: u64) -> DelayModel {
    DelayModel::Constant {
        fwd: Duration::from_millis(fwd),
        bwd: Duration::from_millis(bwd),
    }
}

/// What the echo upstream saw: the payload, where it came from, when.
type Arrival = (Vec<u8>, SocketAddr, StdInstant);

/// An upstream that sends every datagram back to where it came from, and
/// reports each.
async fn udp_echo() -> (SocketAddr, mpsc::UnboundedReceiver<Arrival>) {
    let socket = UdpSocket::bind(LOOPBACK).await.expect("bind echo");
    let addr = socket.local_addr().expect("echo address");
    let (tx, rx) = mpsc::unbounded_channel();
    tokio::spawn(async move {
        let mut buf = vec![0u8; 1 << 16];
        loop {
            let Ok((n, from)) = socket.recv_from(&mut buf).await else {
                continue;
            };
            let _ = tx.send((buf[..n].to_vec(), from, StdInstant::now()));
            let _ = socket.send_to(&buf[..n], from).await;
        }
    });
    (addr, rx)
}

async fn start(model: DelayModel, upstream: SocketAddr, config: RelayConfig) -> RelayHandle {
    Relay::listen(LOOPBACK.parse().unwrap(), upstream, model, 7)
        .await
        .expect("bind relay")
        .with_config(config)
        .spawn()
        .expect("spawn relay")
}

/// A client socket that sends to the relay and hears only from it.
async fn client(relay: &RelayHandle) -> UdpSocket {
    let socket = UdpSocket::bind(LOOPBACK).await.expect("bind client");
    socket
        .connect(relay.local_addr())
        .await
        .expect("connect client");
    socket
}

/// The next datagram within `wait`.
async fn recv(socket: &UdpSocket, wait: StdDuration) -> Option<Vec<u8>> {
    let mut buf = vec![0u8; 1 << 16];
    match timeout(wait, socket.recv(&mut buf)).await {
        Ok(Ok(n)) => Some(buf[..n].to_vec()),
        _ => None,
    }
}

/// Waits (up to 5 s) until the relay's counters satisfy `ok`.
async fn stats_until(handle: &RelayHandle, ok: impl Fn(&RelayStats) -> bool) -> RelayStats {
    let deadline = StdInstant::now() + ms(5000);
    loop {
        let stats = handle.stats();
        if ok(&stats) || StdInstant::now() > deadline {
            return stats;
        }
        tokio::time::sleep(ms(5)).await;
    }
}

fn tagged(tag: u8, seq: u32) -> Vec<u8> {
    let mut bytes = vec![tag];
    bytes.extend_from_slice(&seq.to_le_bytes());
    bytes
}

fn seq_of(bytes: &[u8]) -> u32 {
    u32::from_le_bytes(bytes[1..5].try_into().unwrap())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_relay_listens_on_one_port_over_tcp_and_udp() {
    let upstream: SocketAddr = "127.0.0.1:9".parse().unwrap();
    let relay = start(constant(1, 1), upstream, RelayConfig::default()).await;
    let addr = relay.local_addr();
    assert_ne!(addr.port(), 0);
    let taken = std::net::UdpSocket::bind(addr).expect_err("the relay holds UDP on its port");
    assert_eq!(taken.kind(), std::io::ErrorKind::AddrInUse);
    let _ = relay.shutdown().await;
    // Shut down: the port is free again, for a relay restarted there.
    std::net::UdpSocket::bind(addr).expect("UDP port released at shutdown");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_udp_port_taken_is_a_clear_error() {
    let upstream: SocketAddr = "127.0.0.1:9".parse().unwrap();
    // TCP may be taken on the port picked for UDP: pick again then.
    for _ in 0..5 {
        let udp = std::net::UdpSocket::bind(LOOPBACK).expect("bind UDP");
        let addr = udp.local_addr().expect("address");
        let e = Relay::listen(addr, upstream, constant(1, 1), 1)
            .await
            .expect_err("UDP is taken");
        if e.to_string().contains("over TCP") {
            continue;
        }
        assert_eq!(e.kind(), std::io::ErrorKind::AddrInUse, "{e}");
        let msg = e.to_string();
        assert!(
            msg.contains("over UDP") && msg.contains(&addr.to_string()),
            "{msg}"
        );
        return;
    }
    panic!("no port was free over TCP and taken over UDP");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn datagrams_cross_the_relay_both_ways_with_their_delays() {
    let (upstream, mut arrivals) = udp_echo().await;
    let relay = start(constant(40, 60), upstream, RelayConfig::default()).await;
    let socket = client(&relay).await;
    let n = 20u32;
    let mut sent = Vec::new();
    let mut back = Vec::new();
    for seq in 0..n {
        // The last one is the largest UDP payload over IPv4.
        let mut bytes = tagged(1, seq);
        if seq == n - 1 {
            bytes.resize(65_507, 0xA5);
        }
        sent.push(StdInstant::now());
        socket.send(&bytes).await.expect("send");
        tokio::time::sleep(ms(10)).await;
        // Echoes come back 100 ms later: read what has come so far.
        while let Some(echo) = recv(&socket, StdDuration::ZERO).await {
            back.push((echo, StdInstant::now()));
        }
    }
    while back.len() < n as usize {
        let Some(echo) = recv(&socket, ms(3000)).await else {
            break;
        };
        back.push((echo, StdInstant::now()));
    }
    assert_eq!(back.len(), n as usize, "every echo within 3 s");
    let mut flow_source = None;
    for (seq, (echo, at)) in back.iter().enumerate() {
        assert_eq!(seq_of(echo), seq as u32, "order");
        let len = if seq as u32 == n - 1 { 65_507 } else { 5 };
        assert_eq!(echo.len(), len, "datagram {seq} changed size");
        let rtt = at.duration_since(sent[seq]);
        // Collected at least every 10 ms: up to that late here.
        assert!(
            rtt >= ms(100) && rtt < ms(1000),
            "datagram {seq}: round trip {rtt:?}"
        );
        let (got, from, arrived) = arrivals.try_recv().expect("seen upstream");
        assert_eq!(&got, echo);
        let fwd = arrived.duration_since(sent[seq]);
        assert!(
            fwd >= ms(40) && fwd < ms(900),
            "datagram {seq}: forward {fwd:?}"
        );
        // The upstream sees the flow's socket, the same for all.
        assert_ne!(from, socket.local_addr().unwrap());
        assert_eq!(*flow_source.get_or_insert(from), from);
    }

    let stats = stats_until(&relay, |s| s.datagrams.backward.delivered == u64::from(n)).await;
    let d = stats.datagrams;
    assert_eq!((d.flows_opened, d.flows_active, d.flows_refused), (1, 1, 0));
    let bytes = u64::from(n - 1) * 5 + 65_507;
    for dir in [d.forward, d.backward] {
        assert_eq!((dir.received, dir.delivered), (u64::from(n), u64::from(n)));
        assert_eq!((dir.lost, dir.queue_full, dir.send_failed), (0, 0, 0));
        assert_eq!(dir.bytes_delivered, bytes);
    }
    // The TCP path saw nothing.
    assert_eq!(stats.connections, 0);
    let _ = relay.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn at_full_loss_no_datagram_arrives_and_the_counters_say_so() {
    let (upstream, mut arrivals) = udp_echo().await;
    let config = RelayConfig::default().with_loss(LossModel::Bernoulli { rate: 1.0 });
    let relay = start(constant(1, 1), upstream, config).await;
    let socket = client(&relay).await;
    let n = 50;
    for seq in 0..n {
        socket.send(&tagged(1, seq)).await.expect("send");
        tokio::time::sleep(ms(1)).await;
    }
    let stats = stats_until(&relay, |s| s.datagrams.forward.received == u64::from(n)).await;
    let fwd = stats.datagrams.forward;
    assert_eq!(
        (fwd.received, fwd.lost, fwd.delivered),
        (50, 50, 0),
        "{stats:?}"
    );
    assert_eq!(stats.datagrams.flows_opened, 1);
    // Nothing comes out either side.
    assert!(recv(&socket, ms(200)).await.is_none());
    assert!(
        arrivals.try_recv().is_err(),
        "a datagram reached the upstream"
    );
    let _ = relay.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bernoulli_loss_drops_exactly_what_the_seeded_sampler_draws() {
    let (upstream, mut arrivals) = udp_echo().await;
    let loss = LossModel::Bernoulli { rate: 0.3 };
    let config = RelayConfig::default().with_loss(loss);
    let relay = start(constant(2, 2), upstream, config).await;
    let socket = client(&relay).await;
    let n = 200u32;
    for batch in 0..n / 20 {
        for seq in batch * 20..(batch + 1) * 20 {
            socket.send(&tagged(1, seq)).await.expect("send");
        }
        let want = u64::from((batch + 1) * 20);
        let s = stats_until(&relay, |s| s.datagrams.forward.received == want).await;
        assert_eq!(s.datagrams.forward.received, want, "{s:?}");
    }

    // The first flow's losses: the relay's seed, one stream per direction.
    let mut draws = loss.sampler(connection_seed(7, 0));
    let upstream_gets: Vec<u32> = (0..n).filter(|_| !draws.lost(Direction::Forward)).collect();
    let client_gets: Vec<u32> = upstream_gets
        .iter()
        .copied()
        .filter(|_| !draws.lost(Direction::Backward))
        .collect();
    let m = upstream_gets.len() as u64;
    let stats = stats_until(&relay, |s| {
        let b = s.datagrams.backward;
        b.received == m && b.lost + b.delivered == m
    })
    .await;
    let d = stats.datagrams;
    assert_eq!(d.forward.lost, u64::from(n) - m, "{stats:?}");
    assert_eq!(d.forward.delivered, m, "{stats:?}");
    assert_eq!(d.backward.received, m, "{stats:?}");
    assert_eq!(d.backward.lost, m - client_gets.len() as u64, "{stats:?}");

    let seen: Vec<u32> = std::iter::from_fn(|| arrivals.try_recv().ok())
        .map(|(bytes, _, _)| seq_of(&bytes))
        .collect();
    assert_eq!(seen, upstream_gets);
    let mut got = Vec::new();
    while got.len() < client_gets.len() {
        let Some(echo) = recv(&socket, ms(3000)).await else {
            break;
        };
        got.push(seq_of(&echo));
    }
    assert_eq!(got, client_gets);
    let _ = relay.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn datagrams_from_a_client_over_the_flow_limit_are_dropped_and_counted() {
    let (upstream, mut arrivals) = udp_echo().await;
    let mut config = RelayConfig::default();
    config.max_flows = 2;
    let relay = start(constant(1, 1), upstream, config).await;
    let (a, b, c) = (
        client(&relay).await,
        client(&relay).await,
        client(&relay).await,
    );
    for (tag, socket) in [(1, &a), (2, &b)] {
        socket.send(&tagged(tag, 0)).await.expect("send");
        assert_eq!(recv(socket, ms(3000)).await, Some(tagged(tag, 0)));
    }
    for seq in 0..3 {
        c.send(&tagged(3, seq)).await.expect("send");
    }
    let stats = stats_until(&relay, |s| s.datagrams.flows_refused == 3).await;
    let d = stats.datagrams;
    assert_eq!(
        (d.flows_opened, d.flows_active, d.flows_refused),
        (2, 2, 3),
        "{stats:?}"
    );
    assert_eq!(d.forward.received, 2, "refused datagrams are in no flow");
    assert!(recv(&c, ms(100)).await.is_none());
    // The flows open go on.
    a.send(&tagged(1, 1)).await.expect("send");
    assert_eq!(recv(&a, ms(3000)).await, Some(tagged(1, 1)));
    let tags: Vec<u8> = std::iter::from_fn(|| arrivals.try_recv().ok())
        .map(|(bytes, _, _)| bytes[0])
        .collect();
    assert_eq!(tags, [1, 2, 1]);
    let _ = relay.shutdown().await;
}

/// An upstream that reports every datagram and answers only those tagged
/// `answered` (a remote answers its base, never a stray).
async fn picky_echo(answered: u8) -> (SocketAddr, mpsc::UnboundedReceiver<Arrival>) {
    let socket = UdpSocket::bind(LOOPBACK).await.expect("bind echo");
    let addr = socket.local_addr().expect("echo address");
    let (tx, rx) = mpsc::unbounded_channel();
    tokio::spawn(async move {
        let mut buf = vec![0u8; 1 << 16];
        loop {
            let Ok((n, from)) = socket.recv_from(&mut buf).await else {
                continue;
            };
            let _ = tx.send((buf[..n].to_vec(), from, StdInstant::now()));
            if buf[0] == answered {
                let _ = socket.send_to(&buf[..n], from).await;
            }
        }
    });
    (addr, rx)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn at_the_flow_limit_a_new_client_takes_an_unanswered_flow_never_an_answered_one() {
    let (upstream, mut arrivals) = picky_echo(1).await;
    let mut config = RelayConfig::default();
    config.max_flows = 2;
    let relay = start(constant(1, 1), upstream, config).await;
    let answered = client(&relay).await;
    answered.send(&tagged(1, 0)).await.expect("send");
    assert_eq!(recv(&answered, ms(3000)).await, Some(tagged(1, 0)));
    // Senders the upstream never answers, one after the other: each takes
    // the last one's flow.
    for tag in 2..6 {
        let sender = client(&relay).await;
        sender.send(&tagged(tag, 0)).await.expect("send");
        let stats = stats_until(&relay, |s| s.datagrams.forward.delivered == u64::from(tag)).await;
        assert_eq!(
            stats.datagrams.forward.delivered,
            u64::from(tag),
            "{stats:?}"
        );
    }
    let stats = relay.stats();
    let d = stats.datagrams;
    assert_eq!(
        (
            d.flows_opened,
            d.flows_active,
            d.flows_evicted,
            d.flows_refused
        ),
        (5, 2, 3, 0),
        "{stats:?}"
    );
    assert_eq!(d.forward.evicted, 0, "nothing was waiting: {stats:?}");
    // Every sender's datagram reached the upstream, and the answered flow
    // still carries its client's.
    answered.send(&tagged(1, 1)).await.expect("send");
    assert_eq!(recv(&answered, ms(3000)).await, Some(tagged(1, 1)));
    let tags: Vec<u8> = std::iter::from_fn(|| arrivals.try_recv().ok())
        .map(|(bytes, _, _)| bytes[0])
        .collect();
    assert_eq!(tags, [1, 2, 3, 4, 5, 1]);
    let _ = relay.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_idle_flow_expires_with_its_socket_but_not_while_a_datagram_waits() {
    let (upstream, mut arrivals) = udp_echo().await;
    // Each datagram waits 600 ms each way, longer than the idle timeout.
    let mut config = RelayConfig::default();
    config.max_flows = 1;
    config.flow_idle_timeout = ms(200);
    let relay = start(constant(600, 600), upstream, config).await;
    let a = client(&relay).await;
    let sent = StdInstant::now();
    a.send(&tagged(1, 0)).await.expect("send");
    assert_eq!(
        recv(&a, ms(5000)).await,
        Some(tagged(1, 0)),
        "a flow with a datagram waiting is kept"
    );
    let (_, flow_source, _) = arrivals.try_recv().expect("seen upstream");

    let stats = stats_until(&relay, |s| s.datagrams.flows_expired == 1).await;
    let expired = StdInstant::now();
    let d = stats.datagrams;
    assert_eq!((d.flows_expired, d.flows_active), (1, 0), "{stats:?}");
    // The backward datagram came in 600 ms after the send and was waiting
    // 600 ms more.
    assert!(expired.duration_since(sent) >= ms(1200));
    // Its upstream socket is closed: a datagram to it is refused.
    let probe = std::net::UdpSocket::bind(LOOPBACK).expect("bind probe");
    probe.connect(flow_source).expect("connect probe");
    probe
        .set_read_timeout(Some(ms(2000)))
        .expect("read timeout");
    probe.send(b"anyone?").expect("send probe");
    let refused = probe.recv(&mut [0u8; 16]).expect_err("nobody there");
    assert_eq!(refused.kind(), std::io::ErrorKind::ConnectionRefused);

    // The flow's place is free: another client gets one.
    let b = client(&relay).await;
    b.send(&tagged(2, 0)).await.expect("send");
    assert_eq!(recv(&b, ms(5000)).await, Some(tagged(2, 0)));
    let stats = relay.shutdown().await;
    assert_eq!(stats.datagrams.flows_opened, 2, "{stats:?}");
    assert_eq!(stats.datagrams.flows_refused, 0, "{stats:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replies_reach_the_right_client_when_two_use_the_relay() {
    let (upstream, _arrivals) = udp_echo().await;
    let relay = start(constant(5, 5), upstream, RelayConfig::default()).await;
    let (a, b) = (client(&relay).await, client(&relay).await);
    let n = 20u32;
    for seq in 0..n {
        a.send(&tagged(1, seq)).await.expect("send");
        b.send(&tagged(2, seq)).await.expect("send");
        tokio::time::sleep(ms(2)).await;
    }
    for (tag, socket) in [(1, &a), (2, &b)] {
        let mut got = Vec::new();
        while got.len() < n as usize {
            let Some(echo) = recv(socket, ms(3000)).await else {
                break;
            };
            got.push(echo);
        }
        let want: Vec<Vec<u8>> = (0..n).map(|seq| tagged(tag, seq)).collect();
        assert_eq!(got, want, "client {tag}");
    }
    let stats = relay.shutdown().await;
    assert_eq!(stats.datagrams.flows_opened, 2, "{stats:?}");
}
