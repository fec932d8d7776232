//! One frame's round trip through two ndr links on loopback, beside a raw
//! tokio TCP ping-pong of the same bytes, in one run (target: ratio ≤ 1.3).
//!
//! Ours is the NRTT the base measures: its frame, stamped with its tick's
//! scheduled time and written by the base's hub, across loopback, stamped on
//! arrival by the remote's kernel, echoed in the remote's next frame (its
//! wait from that arrival to its own tick's scheduled time taken out), back
//! across loopback and stamped by the base's kernel. So it also holds both
//! hubs' time from a tick's deadline to its frame's write. That stops where TCP hands the
//! bytes over; a ping-pong counts until the bytes are in the application. So
//! the bench also prints the round trip up to the endpoints: NRTT plus the
//! mean receive-path lag (kernel arrival to the hub handling the frame) of
//! both ends.
//!
//! Three baselines: both ends of the ping-pong on one multi-thread tokio
//! runtime (a worker that writes the ping often runs the echo task itself,
//! so no thread is woken); each end on a thread and runtime of its own, as
//! the two links' hubs are (every frame wakes the other thread); and the
//! same with the echo holding each frame half a period, as the remote holds
//! the base's frame until its own tick, the hold taken out of the round
//! trip: the like-for-like one, since then, as with the links, each frame
//! wakes a thread that has slept for milliseconds (slower than one that
//! went to sleep microseconds ago, as the pinging thread does while the
//! echo answers at once). All run at the same pace, one frame per link
//! period.
//!
//! The plain link runs twice: with each application thread blocked on
//! `recv` (woken ahead of every release, spinning for it), and with both
//! applications as release handlers on their hubs' threads
//! (`Link::on_release`: no thread woken per tick but the hubs, as in the
//! raw ping-pong). With threads in `recv`, each end also times every
//! release's hand-off, from its release stamp to `recv` returning it (the
//! hub wakes a blocked reader ahead of the release and it spins for it),
//! and "frame to application" adds both ends' p50 of it to the frame to
//! endpoint's (target: ≤ 1.3 of the raw ping-pong, echo held, at p50).
//! The same link over mutual TLS 1.3 runs last, in the same
//! process: its rows beside the plain link's give TLS's cost (sealing and
//! opening one record each way, in the hubs).
//!
//! The link on the datagram transport (UDP) runs too, beside a raw UDP
//! ping-pong of its datagram (a Bundle with its copies), a thread per end,
//! the echo holding each datagram as the remote does (target: ≤ 1.2).
//! Then the same link over QUIC (the datagram transport with mutual TLS
//! 1.3: QUIC DATAGRAM frames, quinn driven by the hubs): its rows beside
//! the UDP link's give QUIC's cost over plain UDP (encryption, packet
//! protection, acknowledgements).
//!
//! `cargo bench --bench link_rtt` (NDR_RTT_SECONDS: how long each side runs,
//! default 5; NDR_RTT_PERIOD_MS: the pace, default 10).

mod common;

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use common::{bundle, frame, tls_pair};
use ndr::core::endpoint::Config;
use ndr::core::time::Duration;
use ndr::core::wire::Role;
use ndr::net::{Hub, Link, LinkConfig, LinkStats, Listener, TlsConfig, Transport};
use ndr::sim::percentile;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};

/// Echoes every frame back until the client hangs up; with a `hold`, each
/// one after that long, the time it really held the frame written into the
/// frame's last 8 bytes (the client takes it out, as the NRTT takes out the
/// remote's hold).
async fn echo(listener: TcpListener, len: usize, hold: StdDuration) {
    let (mut s, _) = listener.accept().await.unwrap();
    s.set_nodelay(true).unwrap();
    let mut buf = vec![0; len];
    while s.read_exact(&mut buf).await.is_ok() {
        if !hold.is_zero() {
            let t = StdInstant::now();
            tokio::time::sleep(hold).await;
            let held = u64::try_from(t.elapsed().as_nanos()).unwrap_or(u64::MAX);
            buf[len - 8..].copy_from_slice(&held.to_le_bytes());
        }
        if s.write_all(&buf).await.is_err() {
            return;
        }
    }
}

/// Pings at the link's pace (a thread woken from a longer sleep wakes
/// slower) and times each round trip, less the echo's hold if it held.
async fn ping(addr: SocketAddr, seconds: f64, period_ms: u64, hold: StdDuration) -> Vec<f64> {
    let msg = frame();
    let mut c = TcpStream::connect(addr).await.unwrap();
    c.set_nodelay(true).unwrap();
    let mut buf = vec![0; msg.len()];
    let mut rtts = Vec::new();
    let end = StdInstant::now() + StdDuration::from_secs_f64(seconds);
    let mut i = 0u64;
    while StdInstant::now() < end {
        let t0 = StdInstant::now();
        c.write_all(&msg).await.unwrap();
        c.read_exact(&mut buf).await.unwrap();
        let mut rtt = t0.elapsed();
        if !hold.is_zero() {
            let held = u64::from_le_bytes(buf[buf.len() - 8..].try_into().unwrap());
            rtt = rtt.saturating_sub(StdDuration::from_nanos(held));
        }
        if i >= 20 {
            rtts.push(rtt.as_secs_f64());
        }
        i += 1;
        let pace = StdDuration::from_millis(period_ms).saturating_sub(hold);
        tokio::time::sleep(pace).await;
    }
    rtts
}

/// Both ends on one multi-thread runtime: a worker that writes the ping
/// often runs the echo task itself, with no thread woken at all.
async fn raw_one_runtime(seconds: f64, period_ms: u64) -> Vec<f64> {
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(echo(listener, frame().len(), StdDuration::ZERO));
    ping(addr, seconds, period_ms, StdDuration::ZERO).await
}

/// Each end on a thread and runtime of its own, as the two links' hubs are:
/// every frame wakes the other thread. With a `hold`, the echo holds each
/// frame that long, as a remote holds the base's frame until its own tick:
/// then both threads have slept for milliseconds when a frame comes, as
/// both hubs have (the held time is taken out of the round trip).
fn raw_two_threads(seconds: f64, period_ms: u64, hold: StdDuration) -> Vec<f64> {
    let current = || {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
    };
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    listener.set_nonblocking(true).unwrap();
    let addr = listener.local_addr().unwrap();
    let server = std::thread::spawn(move || {
        current().block_on(async move {
            echo(
                TcpListener::from_std(listener).unwrap(),
                frame().len(),
                hold,
            )
            .await;
        });
    });
    let rtts = current().block_on(ping(addr, seconds, period_ms, hold));
    server.join().unwrap();
    rtts
}

/// [`raw_two_threads`] over UDP: a connected socket pair, the bundle a
/// datagram link sends as the ping, the echo holding each for `hold`
/// (written into the datagram's last 8 bytes, taken out of the round trip).
fn raw_udp_two_threads(seconds: f64, period_ms: u64, hold: StdDuration) -> Vec<f64> {
    let a = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let b = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    a.connect(b.local_addr().unwrap()).unwrap();
    b.connect(a.local_addr().unwrap()).unwrap();
    let current = || {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
    };
    let end = StdInstant::now() + StdDuration::from_secs_f64(seconds);
    b.set_nonblocking(true).unwrap();
    let server = std::thread::spawn(move || {
        current().block_on(async move {
            let s = tokio::net::UdpSocket::from_std(b).unwrap();
            let mut buf = vec![0; 2048];
            loop {
                let wait =
                    end.saturating_duration_since(StdInstant::now()) + StdDuration::from_secs(1);
                let Ok(Ok(n)) = tokio::time::timeout(wait, s.recv(&mut buf)).await else {
                    return;
                };
                let t = StdInstant::now();
                tokio::time::sleep(hold).await;
                let held = u64::try_from(t.elapsed().as_nanos()).unwrap_or(u64::MAX);
                buf[n - 8..n].copy_from_slice(&held.to_le_bytes());
                let _ = s.send(&buf[..n]).await;
            }
        });
    });
    a.set_nonblocking(true).unwrap();
    let rtts = current().block_on(async move {
        let s = tokio::net::UdpSocket::from_std(a).unwrap();
        let msg = bundle();
        let mut buf = vec![0; 2048];
        let mut rtts = Vec::new();
        let mut i = 0u64;
        while StdInstant::now() < end {
            let t0 = StdInstant::now();
            s.send(&msg).await.unwrap();
            let n = s.recv(&mut buf).await.unwrap();
            let held = u64::from_le_bytes(buf[n - 8..n].try_into().unwrap());
            let rtt = t0.elapsed().saturating_sub(StdDuration::from_nanos(held));
            if i >= 20 {
                rtts.push(rtt.as_secs_f64());
            }
            i += 1;
            tokio::time::sleep(StdDuration::from_millis(period_ms).saturating_sub(hold)).await;
        }
        rtts
    });
    server.join().unwrap();
    rtts
}

/// What the links measured.
struct LinkRun {
    nrtt: Vec<f64>,
    /// Applications in `recv`: from each release (its stamp) to `recv`
    /// returning it, at the base and at the remote.
    handoff: (Vec<f64>, Vec<f64>),
    /// The mean receive-path lag of both ends added up.
    rx_lag: f64,
    /// The base's and the remote's last stats.
    base: Option<LinkStats>,
    remote: Option<LinkStats>,
}

/// `handlers`: the applications run on their hubs' threads instead of
/// waiting in `recv`.
fn link_nrtt(
    rt: &tokio::runtime::Runtime,
    seconds: f64,
    period_ms: u64,
    tls: Option<&(TlsConfig, TlsConfig)>,
    handlers: bool,
    transport: Transport,
) -> LinkRun {
    // The paper's FIFO, as in the runs of docs/benchmarks.md.
    let mut c = Config::paper(Role::Base);
    c = c.with_width(1);
    c.period = Duration::from_millis(period_ms);
    let config = LinkConfig::new(c).with_transport(transport);
    let any: SocketAddr = "127.0.0.1:0".parse().unwrap();
    let hub = |margin| Hub::new(margin).unwrap();
    // Two machines' tick grids are unrelated; two hubs made at once in one
    // process would tick together, each busy with its own tick when the
    // other's frame arrives. Half a period apart, as if at random.
    let remote_hub = hub(config.spin_margin);
    std::thread::sleep(StdDuration::from_micros(period_ms * 500));
    let base_hub = hub(config.spin_margin);
    let (mut base, mut remote) = rt.block_on(async {
        let (mut remote_config, mut base_config) = (config.clone(), config.clone());
        if let Some((remote_tls, base_tls)) = tls {
            remote_config.tls = Some(remote_tls.clone());
            base_config.tls = Some(base_tls.clone());
        }
        let listener = Listener::listen(any, remote_config.on_hub(remote_hub))
            .await
            .unwrap();
        let addr = listener.local_addr().unwrap();
        let (r, b) = tokio::join!(
            listener.accept(),
            Link::connect(addr, base_config.on_hub(base_hub))
        );
        (b.unwrap(), r.unwrap())
    });
    let (nrtt, base_handoff, robot) = if handlers {
        // Both applications on their hubs' threads: the remote echoes, the
        // base sends and notes each new NRTT.
        let tx = remote.sender();
        remote
            .on_release(move |s| {
                let _ = tx.send(s.values());
            })
            .unwrap();
        let tx = base.sender();
        let log = Arc::new(Mutex::new((Vec::new(), None, 0u64)));
        let noted = Arc::clone(&log);
        base.on_release(move |_| {
            let _ = tx.send(&[0.5]);
            let Some(stats) = tx.stats() else { return };
            let mut log = noted.lock().unwrap();
            let (nrtt, last, ticks) = &mut *log;
            *ticks += 1;
            let count = stats.endpoint.nrtt.count();
            if *last != Some(count) && *ticks > 20 {
                nrtt.extend(stats.last_nrtt.map(|n| n.as_secs_f64()));
            }
            *last = Some(count);
        })
        .unwrap();
        std::thread::sleep(StdDuration::from_secs_f64(seconds));
        let nrtt = std::mem::take(&mut log.lock().unwrap().0);
        let robot = std::thread::spawn(move || {
            // The handler has the releases: this waits for the end.
            let _ = remote.recv_timeout(StdDuration::from_secs(2));
            (remote.stats(), Vec::new())
        });
        (nrtt, Vec::new(), robot)
    } else {
        let robot = std::thread::spawn(move || {
            let mut last = None;
            let mut handoff = Vec::new();
            while let Ok(s) = remote.recv_timeout(StdDuration::from_secs(2)) {
                handoff.push((remote.now() - s.released_at).as_secs_f64());
                let _ = remote.send(s.values());
                last = remote.stats();
            }
            (last, handoff)
        });
        let mut nrtt = Vec::new();
        let mut handoff = Vec::new();
        let end = StdInstant::now() + StdDuration::from_secs_f64(seconds);
        let mut last = None;
        let mut ticks = 0u64;
        while StdInstant::now() < end {
            let _ = base.send(&[0.5]);
            let Ok(s) = base.recv_timeout(StdDuration::from_secs(2)) else {
                break;
            };
            handoff.push((base.now() - s.released_at).as_secs_f64());
            ticks += 1;
            let stats = base.stats().unwrap();
            let count = stats.endpoint.nrtt.count();
            // One new NRTT sample per new echo; skip the start-up.
            if last != Some(count)
                && ticks > 20
                && let Some(n) = stats.last_nrtt
            {
                nrtt.push(n.as_secs_f64());
            }
            last = Some(count);
        }
        (nrtt, handoff, robot)
    };
    let base_stats = base.stats();
    drop(base);
    let (remote_stats, remote_handoff) = robot.join().unwrap_or_default();
    let lag = |s: &Option<LinkStats>| s.map_or(0.0, |s| s.rx_lag.mean());
    LinkRun {
        nrtt,
        handoff: (base_handoff, remote_handoff),
        rx_lag: lag(&base_stats) + lag(&remote_stats),
        base: base_stats,
        remote: remote_stats,
    }
}

fn main() {
    let seconds: f64 = std::env::var("NDR_RTT_SECONDS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(5.0);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let period_ms: u64 = std::env::var("NDR_RTT_PERIOD_MS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(10);
    let mut raw_one = rt.block_on(raw_one_runtime(seconds, period_ms));
    let mut raw = raw_two_threads(seconds, period_ms, StdDuration::ZERO);
    // The remote's hub ticks half a period after the base's (below): its
    // hold of each base frame is about that.
    let hold = StdDuration::from_micros(period_ms * 500);
    let mut raw_held = raw_two_threads(seconds, period_ms, hold);
    let LinkRun {
        nrtt: mut ours,
        handoff: mut tcp_handoff,
        rx_lag,
        base,
        remote,
    } = link_nrtt(&rt, seconds, period_ms, None, false, Transport::Tcp);
    let handled = link_nrtt(&rt, seconds, period_ms, None, true, Transport::Tcp);
    let tls_run = link_nrtt(
        &rt,
        seconds,
        period_ms,
        Some(&tls_pair()),
        false,
        Transport::Tcp,
    );
    let mut raw_udp_held = raw_udp_two_threads(seconds, period_ms, hold);
    let mut udp_run = link_nrtt(&rt, seconds, period_ms, None, false, Transport::UDP);
    let mut quic_run = link_nrtt(
        &rt,
        seconds,
        period_ms,
        Some(&tls_pair()),
        false,
        Transport::QUIC,
    );
    let cpus = std::thread::available_parallelism().map_or(0, |n| n.get());
    println!(
        "one frame's round trip on loopback, {seconds} s each, link period {period_ms} ms, {cpus} CPUs"
    );
    println!(
        "{:<40} {:>8} {:>10} {:>10} {:>10}",
        "", "samples", "p50 µs", "p99 µs", "mean µs"
    );
    let row = |name: &str, v: &mut Vec<f64>| {
        let mean = v.iter().sum::<f64>() / v.len().max(1) as f64;
        let (p50, p99) = (percentile(v, 0.5), percentile(v, 0.99));
        println!(
            "{name:<40} {:>8} {:>10.1} {:>10.1} {:>10.1}",
            v.len(),
            p50 * 1e6,
            p99 * 1e6,
            mean * 1e6
        );
        (p50, mean)
    };
    let (one_p50, one_mean) = row("raw tokio ping-pong, one runtime", &mut raw_one);
    let (raw_p50, raw_mean) = row("raw tokio ping-pong, a thread per end", &mut raw);
    let held = row("raw, a thread per end, echo held", &mut raw_held);
    // NRTT + the mean receive-path lag of both ends: (p50, mean).
    let to_endpoint = |name: &str, (p50, mean): (f64, f64), lag: f64| {
        println!(
            "{name:<40} {:>8} {:>10.1} {:>10} {:>10.1}   (NRTT + mean receive-path lag of both ends, {:.1} µs)",
            "",
            (p50 + lag) * 1e6,
            "",
            (mean + lag) * 1e6,
            lag * 1e6
        );
        (p50 + lag, mean + lag)
    };
    // "ratio {name}: p50 … · mean …" of two (p50, mean) pairs.
    let ratio = |name: &str, (p50, mean): (f64, f64), (base_p50, base_mean): (f64, f64)| {
        println!(
            "ratio {name}: p50 {:.2} · mean {:.2}",
            p50 / base_p50,
            mean / base_mean
        );
    };
    // The applications in `recv`: each release's hand-off to its thread,
    // at both ends (p50s added to the frame to endpoint's p50: the round
    // trip up to the applications, as the raw ping-pong's).
    let handoffs = |name: &str, (b, r): &mut (Vec<f64>, Vec<f64>), (p50, _): (f64, f64)| {
        let (b50, b99) = (percentile(b, 0.5), percentile(b, 0.99));
        let (r50, r99) = (percentile(r, 0.5), percentile(r, 0.99));
        println!(
            "{name}: release to `recv` p50 / p99: base {:.1} / {:.1} µs · remote {:.1} / {:.1} µs",
            b50 * 1e6,
            b99 * 1e6,
            r50 * 1e6,
            r99 * 1e6
        );
        p50 + b50 + r50
    };
    let (raw_pair, one_pair) = ((raw_p50, raw_mean), (one_p50, one_mean));
    let nrtt = row("ndr link NRTT (kernel-stamped)", &mut ours);
    let full = to_endpoint("ndr link, frame to endpoint", nrtt, rx_lag);
    let (full_p50, full_mean) = full;
    ratio("NRTT / raw (a thread per end)", nrtt, raw_pair);
    ratio("frame-to-endpoint / raw (a thread per end)", full, raw_pair);
    ratio("frame-to-endpoint / raw (one runtime)", full, one_pair);
    ratio("frame-to-endpoint / raw, echo held", full, held);
    let apps = handoffs("ndr link", &mut tcp_handoff, full);
    println!(
        "ratio frame-to-application / raw, echo held: p50 {:.2}",
        apps / held.0
    );
    let mut handled_nrtt = handled.nrtt;
    let nrtt = row("ndr link NRTT, release handlers", &mut handled_nrtt);
    let on_hub = to_endpoint(
        "ndr link, handlers, frame to endpoint",
        nrtt,
        handled.rx_lag,
    );
    ratio(
        "frame-to-endpoint / raw (a thread per end), release handlers",
        on_hub,
        raw_pair,
    );
    ratio(
        "frame-to-endpoint / raw, echo held, release handlers",
        on_hub,
        held,
    );
    let mut tls_nrtt = tls_run.nrtt;
    let nrtt = row("ndr link over TLS 1.3, NRTT", &mut tls_nrtt);
    let (tls_p50, tls_mean) = to_endpoint(
        "ndr link over TLS 1.3, frame to endpoint",
        nrtt,
        tls_run.rx_lag,
    );
    println!(
        "TLS / plain, frame to endpoint: p50 {:.2} · mean {:.2} (+{:.1} µs at p50)",
        tls_p50 / full_p50,
        tls_mean / full_mean,
        (tls_p50 - full_p50) * 1e6
    );
    let udp_held = row("raw UDP, a thread per end, echo held", &mut raw_udp_held);
    let mut udp_nrtt = udp_run.nrtt;
    let nrtt = row("ndr link over UDP, NRTT", &mut udp_nrtt);
    let udp_nrtt_pair = nrtt;
    let udp_full = to_endpoint("ndr link over UDP, frame to endpoint", nrtt, udp_run.rx_lag);
    ratio(
        "UDP frame-to-endpoint / raw UDP, echo held",
        udp_full,
        udp_held,
    );
    let apps = handoffs("ndr link over UDP", &mut udp_run.handoff, udp_full);
    println!(
        "ratio UDP frame-to-application / raw UDP, echo held: p50 {:.2}",
        apps / udp_held.0
    );
    println!(
        "UDP / TCP link, frame to endpoint: p50 {:.2} · mean {:.2}",
        udp_full.0 / full_p50,
        udp_full.1 / full_mean
    );
    let mut quic_nrtt = quic_run.nrtt;
    let nrtt = row("ndr link over QUIC, NRTT", &mut quic_nrtt);
    // The like-for-like figure: a QUIC link's receive lag counts every
    // packet (its acknowledgements too), a UDP link's only the Bundles.
    println!(
        "QUIC / UDP link, NRTT: p50 {:.2} · mean {:.2} (+{:.1} µs at p50)",
        nrtt.0 / udp_nrtt_pair.0,
        nrtt.1 / udp_nrtt_pair.1,
        (nrtt.0 - udp_nrtt_pair.0) * 1e6
    );
    let quic_full = to_endpoint(
        "ndr link over QUIC, frame to endpoint",
        nrtt,
        quic_run.rx_lag,
    );
    ratio(
        "QUIC frame-to-endpoint / raw UDP, echo held",
        quic_full,
        udp_held,
    );
    let apps = handoffs("ndr link over QUIC", &mut quic_run.handoff, quic_full);
    println!(
        "ratio QUIC frame-to-application / raw UDP, echo held: p50 {:.2}",
        apps / udp_held.0
    );
    println!(
        "QUIC / UDP link, frame to endpoint: p50 {:.2} · mean {:.2} (+{:.1} µs at p50)",
        quic_full.0 / udp_full.0,
        quic_full.1 / udp_full.1,
        (quic_full.0 - udp_full.0) * 1e6
    );
    for (side, stats) in [
        ("base", base),
        ("quic base", quic_run.base),
        ("quic remote", quic_run.remote),
        ("udp base", udp_run.base),
        ("udp remote", udp_run.remote),
        ("remote", remote),
        ("handler base", handled.base),
        ("handler remote", handled.remote),
        ("tls base", tls_run.base),
        ("tls remote", tls_run.remote),
    ] {
        if let Some(s) = stats {
            println!(
                "{side:<11} hub: wake lateness p50 {} · p99 {} · release lateness p50 {} · p99 {} · receive lag mean {:.1} µs",
                s.lateness.p50,
                s.lateness.p99,
                s.release_lateness.p50,
                s.release_lateness.p99,
                s.rx_lag.mean() * 1e6
            );
        }
    }
}
