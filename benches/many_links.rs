//! Many concurrent links on loopback at 100 Hz (or another period): CPU and
//! memory per link.
//!
//! Both ends of every link run in this process: the bases on one hub (or a
//! pool of them), the remotes on another, one application thread echoing
//! the remotes' commands and draining the bases' states and every link's
//! events; tokio (2 workers) only connects and accepts. CPU is the
//! scheduler's count of the process's threads over a window after start-up
//! (see [`Cpu`]), memory the growth of the resident set from before the
//! first link.
//!
//! The baseline, in the same run after the links are gone: as many raw
//! tokio TCP connections on loopback carrying the same bytes (one 1-axis
//! Data frame each way every period), one thread and current-thread runtime
//! a side, as our two hubs are, a writer and a reader task a socket. It is
//! what the frames cost in the kernel and in an ordinary event loop: the
//! share of the CPU left to the links' own work is the difference. With
//! NDR_TRANSPORT=udp[:K[:R]] the links run on the datagram transport and the
//! baseline is raw tokio UDP: a connected socket pair a link, each socket
//! sending the same datagrams as a link (a 1-axis Bundle with its copies,
//! as many times a period, 1 ms apart, as the links sent in the window:
//! their R repeats go only while a peer reports losses, and the window
//! opens after the first REPEAT_HOLD, in which every link repeats).
//! NDR_TRANSPORT=quic[:K[:R]]:
//! the same datagrams over QUIC (mutual TLS between throwaway identities),
//! beside the same raw UDP baseline.
//!
//! `cargo bench --bench many_links` (NDR_LINKS, default 1000; NDR_SECONDS,
//! default 10; NDR_QUEUE, the regulators' capacity, default 256;
//! NDR_APP_QUEUE, the bound on what waits for the application, default 16;
//! NDR_HUBS, hubs in each side's pool, default 1; NDR_PLAYOUT, the playout
//! policy by its command-line name, default `fifo`; NDR_TRANSPORT, tcp
//! (the default), udp[:K[:R]] or quic[:K[:R]]; NDR_PERIOD_MS, the
//! period, default 10; NDR_SPIN=fixed, hubs that spin the whole default
//! margin instead of learning a shorter one; NDR_APP=handlers, the control
//! loops on the hubs (`Link::on_release`) instead of an application thread
//! polling every link; the process needs
//! 2·NDR_LINKS + 50 file descriptors).

mod common;

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use common::{bundle, frame, tls_pair};
use ndr::core::endpoint::{Config, REPEAT_HOLD};
use ndr::core::time::Duration;
use ndr::core::wire::Role;
use ndr::net::clock::DEFAULT_SPIN_MARGIN;
use ndr::net::spin::SpinMargin;
use ndr::net::{HubPool, Link, LinkConfig, Listener, Transport};

fn env(name: &str, default: f64) -> f64 {
    std::env::var(name)
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(default)
}

/// Resident set size, KiB.
fn rss_kib() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmRSS:"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|v| v.parse().ok()))
        })
        .unwrap_or(0)
}

/// CPU time of this process, seconds.
///
/// The total is the scheduler's exact count (`schedstat`, nanoseconds on
/// the CPU, summed over the threads). The split between user space and the
/// kernel is the tick-sampled one of `stat` (USER_HZ = 100), which a load
/// that wakes at 100 Hz, as the links do, can alias: it is reported as the
/// kernel's share of the sampled time, the total is not taken from it.
#[derive(Clone, Copy)]
struct Cpu {
    total: f64,
    user_ticks: f64,
    system_ticks: f64,
}

/// The times of a /proc `stat` line: user and system, seconds.
fn stat_times(stat: &str) -> Option<(f64, f64)> {
    let (_, after) = stat.rsplit_once(')')?;
    // By position: fields before the times can be negative (the terminal's
    // process group is -1 without a terminal), so a filter on what parses as
    // unsigned would shift them and read other fields as the CPU times.
    // Fields 14 and 15 are utime and stime; the first after the name is
    // field 3.
    let mut times = after.split_whitespace().skip(14 - 3);
    let mut next = || times.next()?.parse::<u64>().ok().map(|t| t as f64 / 100.0);
    Some((next()?, next()?))
}

/// The exact CPU time (s) of this process's threads whose name `keep`s.
fn run_time_s(keep: impl Fn(&str) -> bool) -> f64 {
    let tasks = std::fs::read_dir("/proc/self/task").expect("/proc/self/task");
    tasks
        .filter_map(Result::ok)
        .filter(|t| {
            std::fs::read_to_string(t.path().join("comm")).is_ok_and(|c| keep(c.trim_end()))
        })
        .filter_map(|t| std::fs::read_to_string(t.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .map(|ns| ns as f64 * 1e-9)
        .sum()
}

impl Cpu {
    /// This process's.
    fn now() -> Cpu {
        let stat = std::fs::read_to_string("/proc/self/stat").expect("/proc/self/stat");
        let (user_ticks, system_ticks) =
            stat_times(&stat).unwrap_or_else(|| panic!("no CPU times in /proc/self/stat: {stat}"));
        Cpu {
            total: run_time_s(|_| true),
            user_ticks,
            system_ticks,
        }
    }

    /// From `self` to `later` over `elapsed` s: the share of the machine
    /// (%) and the kernel's part of it (%).
    fn shares(self, later: Cpu, elapsed: f64, cpus: usize) -> Share {
        let (user, system) = (
            later.user_ticks - self.user_ticks,
            later.system_ticks - self.system_ticks,
        );
        Share {
            machine: 100.0 * (later.total - self.total) / elapsed / cpus as f64,
            kernel: 100.0 * system / (user + system).max(f64::MIN_POSITIVE),
        }
    }
}

/// A share of the machine over a window.
#[derive(Clone, Copy)]
struct Share {
    /// % of all the CPUs.
    machine: f64,
    /// % of that in the kernel (tick-sampled).
    kernel: f64,
}

/// One side of the baseline: on this thread's own current-thread runtime,
/// every socket writes `frame` every `period` and reads the peer's, until
/// `end`, counting the frames it reads in `received`.
fn raw_side(
    sockets: Vec<std::net::TcpStream>,
    period: StdDuration,
    end: StdInstant,
    received: Arc<AtomicU64>,
) {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async move {
        let msg = frame();
        for s in sockets {
            s.set_nonblocking(true).unwrap();
            let s = tokio::net::TcpStream::from_std(s).unwrap();
            let (mut rd, mut wr) = s.into_split();
            let len = msg.len();
            let received = Arc::clone(&received);
            tokio::spawn(async move {
                let mut buf = vec![0; len];
                while rd.read_exact(&mut buf).await.is_ok() {
                    received.fetch_add(1, Ordering::Relaxed);
                }
            });
            let msg = msg.clone();
            tokio::spawn(async move {
                let mut every = tokio::time::interval(period);
                every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
                loop {
                    every.tick().await;
                    if wr.write_all(&msg).await.is_err() {
                        return;
                    }
                }
            });
        }
        tokio::time::sleep_until(end.into()).await;
    });
}

/// A baseline's CPU shares of the machine over a `seconds` window after a
/// second's start, and the frames `received` counted a second in it; then
/// waits for its two `sides` to end.
fn window(
    sides: [std::thread::JoinHandle<()>; 2],
    received: &AtomicU64,
    seconds: f64,
    cpus: usize,
) -> (Share, f64) {
    std::thread::sleep(StdDuration::from_secs(1));
    let (cpu0, frames0, t0) = (
        Cpu::now(),
        received.load(Ordering::Relaxed),
        StdInstant::now(),
    );
    std::thread::sleep(StdDuration::from_secs_f64(seconds));
    let (cpu1, frames1, elapsed) = (
        Cpu::now(),
        received.load(Ordering::Relaxed),
        t0.elapsed().as_secs_f64(),
    );
    for side in sides {
        side.join().unwrap();
    }
    (
        cpu0.shares(cpu1, elapsed, cpus),
        (frames1 - frames0) as f64 / elapsed,
    )
}

/// One side of the UDP baseline: every socket sends `sends` datagrams
/// (`msg`, 1 ms apart) every `period` and reads the peer's, until `end`.
fn raw_udp_side(
    sockets: Vec<std::net::UdpSocket>,
    sends: usize,
    period: StdDuration,
    end: StdInstant,
    received: Arc<AtomicU64>,
) {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async move {
        let msg = bundle();
        for s in sockets {
            s.set_nonblocking(true).unwrap();
            let s = Arc::new(tokio::net::UdpSocket::from_std(s).unwrap());
            let (rd, received) = (Arc::clone(&s), Arc::clone(&received));
            tokio::spawn(async move {
                let mut buf = vec![0; 2048];
                while rd.recv(&mut buf).await.is_ok() {
                    received.fetch_add(1, Ordering::Relaxed);
                }
            });
            let msg = msg.clone();
            tokio::spawn(async move {
                let mut every = tokio::time::interval(period);
                every.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
                loop {
                    every.tick().await;
                    for i in 0..sends {
                        if i > 0 {
                            tokio::time::sleep(StdDuration::from_millis(1)).await;
                        }
                        let _ = s.send(&msg).await;
                    }
                }
            });
        }
        tokio::time::sleep_until(end.into()).await;
    });
}

/// The UDP baseline: `n` connected socket pairs, `sends` datagrams each
/// way a period; as [`raw_cpu`].
fn raw_udp_cpu(
    n: usize,
    sends: usize,
    period: StdDuration,
    seconds: f64,
    cpus: usize,
) -> (Share, f64) {
    let (mut a, mut b) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for _ in 0..n {
        let x = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        let y = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        x.connect(y.local_addr().unwrap()).unwrap();
        y.connect(x.local_addr().unwrap()).unwrap();
        a.push(x);
        b.push(y);
    }
    let end = StdInstant::now() + StdDuration::from_secs_f64(seconds + 2.0);
    let received = Arc::new(AtomicU64::new(0));
    let sides = [a, b].map(|socks| {
        let received = Arc::clone(&received);
        std::thread::spawn(move || raw_udp_side(socks, sends, period, end, received))
    });
    window(sides, &received, seconds, cpus)
}

/// The baseline's CPU shares of the machine over a `seconds` window (after
/// a second's start), `n` connections, and the frames it moved a second
/// (when the machine cannot keep up, its intervals skip ticks).
fn raw_cpu(n: usize, period: StdDuration, seconds: f64, cpus: usize) -> (Share, f64) {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let (mut a, mut b) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for _ in 0..n {
        let c = std::net::TcpStream::connect(addr).unwrap();
        let (s, _) = listener.accept().unwrap();
        c.set_nodelay(true).unwrap();
        s.set_nodelay(true).unwrap();
        a.push(c);
        b.push(s);
    }
    let end = StdInstant::now() + StdDuration::from_secs_f64(seconds + 2.0);
    let received = Arc::new(AtomicU64::new(0));
    let sides = [a, b].map(|socks| {
        let received = Arc::clone(&received);
        std::thread::spawn(move || raw_side(socks, period, end, received))
    });
    window(sides, &received, seconds, cpus)
}

fn main() {
    let n = env("NDR_LINKS", 1000.0) as usize;
    let seconds = env("NDR_SECONDS", 10.0);
    let hubs = env("NDR_HUBS", 1.0) as usize;
    let cpus = std::thread::available_parallelism().map_or(1, |c| c.get());
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let mut c = Config::new(Role::Base);
    c = c.with_width(1);
    let period_ms = env("NDR_PERIOD_MS", 10.0);
    c.period = Duration::from_secs_f64(period_ms / 1e3);
    // NDR_SPIN=fixed: the hubs spin the whole default margin at every tick
    // instead of learning a shorter one.
    let spin = match std::env::var("NDR_SPIN").as_deref() {
        Ok("fixed") => SpinMargin::fixed(DEFAULT_SPIN_MARGIN),
        _ => SpinMargin::adaptive(DEFAULT_SPIN_MARGIN),
    };
    let mut config = LinkConfig::new(c);
    config.app_queue = env("NDR_APP_QUEUE", 16.0) as usize;
    config.queue_capacity = env("NDR_QUEUE", ndr::net::QUEUE as f64) as usize;
    let playout = std::env::var("NDR_PLAYOUT").unwrap_or_else(|_| "fifo".into());
    config.endpoint.playout = playout
        .parse()
        .unwrap_or_else(|_| panic!("NDR_PLAYOUT={playout}: not a playout policy"));
    let name = std::env::var("NDR_TRANSPORT").unwrap_or_else(|_| "tcp".into());
    let transport: Transport = name
        .parse()
        .unwrap_or_else(|e| panic!("NDR_TRANSPORT={name}: {e}"));
    config = config.with_transport(transport);
    // quic[:K[:R]]: under mutual TLS between throwaway identities.
    let tls = transport.is_quic().then(tls_pair);
    // On datagrams, the repeats each link may send.
    let repeats = match transport {
        Transport::Udp { repeats, .. } | Transport::Quic { repeats, .. } => Some(repeats),
        _ => None,
    };
    let rss0 = rss_kib();
    let (bases, remotes) = rt.block_on(async {
        let remote_hubs = HubPool::new(hubs, spin).unwrap();
        let base_hubs = HubPool::new(hubs, spin).unwrap();
        let any: SocketAddr = "127.0.0.1:0".parse().unwrap();
        let (remote_config, base_config) = match tls.clone() {
            Some((remote, base)) => (
                config.clone().with_tls(remote),
                config.clone().with_tls(base),
            ),
            None => (config.clone(), config.clone()),
        };
        let listener = Listener::listen(any, remote_config.on_pool(remote_hubs))
            .await
            .unwrap();
        let addr = listener.local_addr().unwrap();
        // One link at a time, both ends: every base comes from 127.0.0.1,
        // and a source with more handshakes pending than the listener's
        // per-source cap has its oldest evicted, as a flood would.
        let (mut bases, mut remotes) = (Vec::new(), Vec::new());
        for _ in 0..n {
            let base = Link::connect(addr, base_config.clone().on_pool(base_hubs.clone()));
            let (remote, base) = tokio::join!(listener.accept(), base);
            remotes.push(remote.unwrap());
            bases.push(base.unwrap());
        }
        (bases, remotes)
    });
    let setup_rss = rss_kib();
    // NDR_APP=handlers: the control loops run on the hubs (`on_release`), as
    // a controller of many links would; the application thread then only
    // reads the events.
    let handlers = std::env::var("NDR_APP").as_deref() == Ok("handlers");
    let handled = Arc::new(AtomicU64::new(0));
    let (mut bases, mut remotes) = (bases, remotes);
    if handlers {
        for r in &mut remotes {
            let (tx, handled) = (r.sender(), Arc::clone(&handled));
            r.on_release(move |s| {
                let _ = tx.send(s.values());
                handled.fetch_add(1, Ordering::Relaxed);
            })
            .unwrap();
        }
        for b in &mut bases {
            let handled = Arc::clone(&handled);
            b.on_release(move |_| {
                handled.fetch_add(1, Ordering::Relaxed);
            })
            .unwrap();
        }
    }
    let stop = Arc::new(AtomicBool::new(false));
    // The frames the links have received so far, summed by the application
    // thread (which holds them) when `count` is raised, into `counted`.
    // And the samples and datagrams they have sent, into `sent`.
    let (count, counted, sent) = (
        Arc::new(AtomicBool::new(false)),
        Arc::new(AtomicU64::new(0)),
        Arc::new([AtomicU64::new(0), AtomicU64::new(0)]),
    );
    let app = {
        let stop = Arc::clone(&stop);
        let (count, counted, sent) = (Arc::clone(&count), Arc::clone(&counted), Arc::clone(&sent));
        std::thread::spawn(move || {
            let mut released = 0u64;
            while !stop.load(Ordering::Relaxed) {
                if count.load(Ordering::Acquire) {
                    // A repeat that finds its sample taken is dropped as
                    // stale: moved all the same.
                    let (frames, samples, datagrams) = bases
                        .iter()
                        .chain(&remotes)
                        .filter_map(Link::stats)
                        .map(|s| s.endpoint)
                        .fold((0, 0, 0), |(f, n, d), e| {
                            let sent = e.samples_sent;
                            let moved = e.frames_received + e.datagrams_stale;
                            (f + moved, n + sent, d + sent + e.datagrams_repeated)
                        });
                    counted.store(frames, Ordering::Relaxed);
                    sent[0].store(samples, Ordering::Relaxed);
                    sent[1].store(datagrams, Ordering::Relaxed);
                    count.store(false, Ordering::Release);
                }
                for r in &mut remotes {
                    while let Ok(Some(s)) = r.try_recv() {
                        let _ = r.send(s.values());
                        released += 1;
                    }
                    // Events (underflows, delay changes) are kept for the
                    // application, up to 256 a link: read them as it would.
                    r.drain_events().for_each(drop);
                }
                for b in &mut bases {
                    while let Ok(Some(_)) = b.try_recv() {
                        released += 1;
                    }
                    b.drain_events().for_each(drop);
                }
                std::thread::sleep(StdDuration::from_millis(5));
            }
            (bases, remotes, released)
        })
    };
    // Start-up: handshake, 10-probe pattern and pre-fill, all under a second;
    // on datagrams, the repeats every link sends until its path shows no
    // loss, too.
    std::thread::sleep(StdDuration::from_secs(3));
    if repeats.is_some_and(|r| r > 0) {
        std::thread::sleep(REPEAT_HOLD.into());
    }
    let frames_so_far = || {
        count.store(true, Ordering::Release);
        while count.load(Ordering::Acquire) {
            std::thread::sleep(StdDuration::from_millis(1));
        }
        counted.load(Ordering::Relaxed)
    };
    let frames0 = frames_so_far();
    let sent0 = sent.each_ref().map(|a| a.load(Ordering::Relaxed));
    let (cpu0, hubs0, t0) = (
        Cpu::now(),
        run_time_s(|name| name == "ndr-hub"),
        StdInstant::now(),
    );
    std::thread::sleep(StdDuration::from_secs_f64(seconds));
    let (cpu1, hubs1, elapsed) = (
        Cpu::now(),
        run_time_s(|name| name == "ndr-hub"),
        t0.elapsed().as_secs_f64(),
    );
    let frames = (frames_so_far() - frames0) as f64 / elapsed;
    // Datagrams a link sent a sample in the window: the raw baseline sends
    // as many.
    let sends = if repeats.is_some() {
        let [samples, datagrams] =
            [0, 1].map(|i| sent[i].load(Ordering::Relaxed).saturating_sub(sent0[i]));
        (datagrams as f64 / samples.max(1) as f64).round().max(1.0) as usize
    } else {
        0
    };
    let rss = rss_kib();
    stop.store(true, Ordering::Relaxed);
    let (bases, remotes, released) = app.join().unwrap();
    let released = released + handled.load(Ordering::Relaxed);
    let stats: Vec<_> = bases
        .iter()
        .chain(&remotes)
        .filter_map(Link::stats)
        .collect();
    let running = stats.iter().filter(|s| s.ns > 0).count();
    let underflows: u64 = stats.iter().map(|s| s.endpoint.underflows).sum();
    let dropped: u64 = stats.iter().map(|s| s.app_dropped).sum();
    let grtt_std_max = bases
        .iter()
        .filter_map(Link::stats)
        .map(|s| s.endpoint.grtt.std())
        .fold(0.0, f64::max);
    let share = cpu0.shares(cpu1, elapsed, cpus);
    let machine = share.machine;
    println!(
        "{n} links at T = {} on loopback (both ends in this process), {seconds} s window, {cpus} CPUs, transport {}, queue capacity {}, app queue {}, {hubs} hub(s) a side, playout {}, spin margin {}, control loops {}",
        c.period,
        format_args!(
            "{}{}",
            config.endpoint.transport,
            if tls.is_some() { " over QUIC" } else { "" }
        ),
        config.queue_capacity,
        config.app_queue,
        config.endpoint.playout,
        if spin.is_adaptive() {
            "learned"
        } else {
            "fixed"
        },
        if handlers {
            "on the hubs"
        } else {
            "on an application thread"
        }
    );
    println!("  endpoints running            {running} of {}", 2 * n);
    println!(
        "  CPU                          {machine:.1} % of the machine ({:.0} % of it in the kernel; {:.1} µs per link per second); the hubs {:.1} %, the bench's application loop and tokio the rest",
        share.kernel,
        1e6 * (cpu1.total - cpu0.total) / elapsed / n as f64,
        100.0 * (hubs1 - hubs0) / elapsed / cpus as f64
    );
    println!(
        "  memory                       {:.1} KiB per link, both ends ({:.0} MiB resident after set-up, {:.0} MiB at the end)",
        (rss.saturating_sub(rss0)) as f64 / n as f64,
        setup_rss as f64 / 1024.0,
        rss as f64 / 1024.0
    );
    println!(
        "  samples released             {released} ({:.0} per second)",
        released as f64 / (elapsed + 3.0)
    );
    println!("  underflows                   {underflows} · dropped by a slow app {dropped}");
    println!(
        "  worst GRTT std of a base     {:.3} ms",
        grtt_std_max * 1e3
    );
    for (side, links) in [("bases'", &bases), ("remotes'", &remotes)] {
        // Every link reports its hub's figures; take the worst hub's.
        let Some(s) = links
            .iter()
            .filter_map(Link::stats)
            .max_by_key(|s| s.release_lateness.p99)
        else {
            continue;
        };
        println!(
            "  {side:<9} worst hub: wake lateness p50 {} · p99 {} · max {}; release lateness p50 {} · p99 {} · max {}; spin margin learned {}",
            s.lateness.p50,
            s.lateness.p99,
            s.lateness.max,
            s.release_lateness.p50,
            s.release_lateness.p99,
            s.release_lateness.max,
            s.spin_margin
        );
    }
    let lag: Vec<f64> = stats.iter().map(|s| s.rx_lag.mean()).collect();
    println!(
        "  receive lag (mean per link)  p50 {:.1} µs · max {:.1} µs",
        1e6 * ndr::sim::percentile(&lag, 0.5),
        1e6 * lag.iter().copied().fold(0.0, f64::max)
    );
    drop((bases, remotes));
    // Let the hubs close their sockets and end before the baseline.
    std::thread::sleep(StdDuration::from_secs(1));
    let (raw, raw_frames, what) = if sends > 0 {
        let (raw, frames) = raw_udp_cpu(n, sends, c.period.into(), seconds, cpus);
        (
            raw,
            frames,
            format!(
                "UDP      {n} socket pairs, the same {sends} datagram(s) each way every period"
            ),
        )
    } else {
        let (raw, frames) = raw_cpu(n, c.period.into(), seconds, cpus);
        (
            raw,
            frames,
            format!("TCP      {n} connections, the same frame each way every period"),
        )
    };
    // CPU time per frame moved (sent by one end and read by the other), µs.
    let per_frame = |share: f64, fps: f64| share / 100.0 * cpus as f64 * 1e6 / fps;
    println!(
        "  baseline: raw tokio {what}, a thread a side: {:.1} % of the machine ({:.0} % of it in the kernel); links / raw {:.2}",
        raw.machine,
        raw.kernel,
        machine / raw.machine,
    );
    println!(
        "  frames moved                 links {frames:.0}/s, {:.2} µs of CPU each · raw {raw_frames:.0}/s, {:.2} µs each (of {} due a second); links / raw per frame {:.2}",
        per_frame(machine, frames),
        per_frame(raw.machine, raw_frames),
        (2.0 * n as f64 * 1e3 / period_ms * sends.max(1) as f64).round(),
        per_frame(machine, frames) / per_frame(raw.machine, raw_frames)
    );
}
