//! Many concurrent links on loopback at 100 Hz: CPU and memory per link.
//!
//! Both ends of every link run in this process: the bases on one hub (or a
//! pool of them), the remotes on another, one application thread echoing
//! the remotes' commands and draining the bases' states and every link's
//! events; tokio (2 workers) only connects and accepts. CPU is read from
//! /proc/self/stat over a window after start-up, memory as the growth of the
//! resident set from before the first link.
//!
//! The baseline, in the same run after the links are gone: as many raw
//! tokio TCP connections on loopback carrying the same bytes (one 1-axis
//! Data frame each way every 10 ms), one thread and current-thread runtime
//! a side, as our two hubs are, a writer and a reader task a socket. It is
//! what the frames cost in the kernel and in an ordinary event loop: the
//! share of the CPU left to the links' own work is the difference.
//!
//! `cargo bench --bench many_links` (NDR_LINKS, default 1000; NDR_SECONDS,
//! default 10; NDR_QUEUE, the regulators' capacity, default 256;
//! NDR_APP_QUEUE, the bound on what waits for the application, default 16;
//! NDR_HUBS, hubs in each side's pool, default 1; NDR_PLAYOUT, the playout
//! policy by its command-line name, default `fifo`; the process needs
//! 2·NDR_LINKS + 50 file descriptors).

mod common;

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use common::frame;
use ndr::core::endpoint::Config;
use ndr::core::time::Duration;
use ndr::core::wire::Role;
use ndr::net::clock::DEFAULT_SPIN_MARGIN;
use ndr::net::{HubPool, Link, LinkConfig, Listener};

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

/// User + system CPU time (seconds, USER_HZ = 100) in a /proc `stat` line.
fn stat_cpu_s(stat: &str) -> f64 {
    let after = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<u64> = after
        .split_whitespace()
        .filter_map(|x| x.parse().ok())
        .collect();
    // Fields 14 and 15 of the line are the 12th and 13th after the name.
    (f.get(10).copied().unwrap_or(0) + f.get(11).copied().unwrap_or(0)) as f64 / 100.0
}

/// CPU time of this process, seconds.
fn cpu_s() -> f64 {
    stat_cpu_s(&std::fs::read_to_string("/proc/self/stat").unwrap_or_default())
}

/// One side of the baseline: on this thread's own current-thread runtime,
/// every socket writes `frame` every 10 ms and reads the peer's, until `end`.
fn raw_side(sockets: Vec<std::net::TcpStream>, end: StdInstant) {
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
            tokio::spawn(async move {
                let mut buf = vec![0; len];
                while rd.read_exact(&mut buf).await.is_ok() {}
            });
            let msg = msg.clone();
            tokio::spawn(async move {
                let mut every = tokio::time::interval(StdDuration::from_millis(10));
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

/// The baseline's CPU share of the machine over a `seconds` window (after
/// a second's start), `n` connections.
fn raw_cpu(n: usize, seconds: f64, cpus: usize) -> f64 {
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
    let sides = [a, b].map(|socks| std::thread::spawn(move || raw_side(socks, end)));
    std::thread::sleep(StdDuration::from_secs(1));
    let (cpu0, t0) = (cpu_s(), StdInstant::now());
    std::thread::sleep(StdDuration::from_secs_f64(seconds));
    let (cpu1, elapsed) = (cpu_s(), t0.elapsed().as_secs_f64());
    for side in sides {
        side.join().unwrap();
    }
    100.0 * (cpu1 - cpu0) / elapsed / cpus as f64
}

/// CPU time (seconds) of this process's threads named `name` (the hubs:
/// `ndr-hub`), from /proc/self/task.
fn threads_cpu_s(name: &str) -> f64 {
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return 0.0;
    };
    tasks
        .filter_map(Result::ok)
        .filter_map(|t| std::fs::read_to_string(t.path().join("stat")).ok())
        .filter(|stat| {
            let comm = stat.split_once('(').and_then(|(_, r)| r.rsplit_once(')'));
            comm.is_some_and(|(comm, _)| comm == name)
        })
        .map(|stat| stat_cpu_s(&stat))
        .sum()
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
    c.axes = 1;
    c.period = Duration::from_millis(10);
    let mut config = LinkConfig::new(c);
    config.app_queue = env("NDR_APP_QUEUE", 16.0) as usize;
    config.queue_capacity = env("NDR_QUEUE", ndr::net::link::QUEUE as f64) as usize;
    let playout = std::env::var("NDR_PLAYOUT").unwrap_or_else(|_| "fifo".into());
    config.endpoint.playout = playout
        .parse()
        .unwrap_or_else(|_| panic!("NDR_PLAYOUT={playout}: not a playout policy"));
    let rss0 = rss_kib();
    let (bases, remotes) = rt.block_on(async {
        let remote_hubs = HubPool::new(hubs, DEFAULT_SPIN_MARGIN).unwrap();
        let base_hubs = HubPool::new(hubs, DEFAULT_SPIN_MARGIN).unwrap();
        let any: SocketAddr = "127.0.0.1:0".parse().unwrap();
        let listener = Listener::bind(any, config)
            .await
            .unwrap()
            .with_pool(remote_hubs);
        let addr = listener.local_addr().unwrap();
        let accept = tokio::spawn(async move {
            let mut remotes = Vec::new();
            for _ in 0..n {
                remotes.push(listener.accept().await.unwrap());
            }
            remotes
        });
        let mut bases = Vec::new();
        for _ in 0..n {
            bases.push(base_hubs.connect(addr, config).await.unwrap());
        }
        (bases, accept.await.unwrap())
    });
    let setup_rss = rss_kib();
    let stop = Arc::new(AtomicBool::new(false));
    let app = {
        let stop = Arc::clone(&stop);
        std::thread::spawn(move || {
            let (mut bases, mut remotes) = (bases, remotes);
            let mut released = 0u64;
            while !stop.load(Ordering::Relaxed) {
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
    // Start-up: handshake, 10-probe pattern and pre-fill, all under a second.
    std::thread::sleep(StdDuration::from_secs(3));
    let (cpu0, hubs0, t0) = (cpu_s(), threads_cpu_s("ndr-hub"), StdInstant::now());
    std::thread::sleep(StdDuration::from_secs_f64(seconds));
    let (cpu1, hubs1, elapsed) = (
        cpu_s(),
        threads_cpu_s("ndr-hub"),
        t0.elapsed().as_secs_f64(),
    );
    let rss = rss_kib();
    stop.store(true, Ordering::Relaxed);
    let (bases, remotes, released) = app.join().unwrap();
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
    let machine = 100.0 * (cpu1 - cpu0) / elapsed / cpus as f64;
    println!(
        "{n} links at 100 Hz on loopback (both ends in this process), {seconds} s window, {cpus} CPUs, queue capacity {}, app queue {}, {hubs} hub(s) a side, playout {}",
        config.queue_capacity, config.app_queue, config.endpoint.playout
    );
    println!("  endpoints running            {running} of {}", 2 * n);
    println!(
        "  CPU                          {machine:.1} % of the machine ({:.1} µs per link per second); the hubs {:.1} %, the bench's application loop and tokio the rest",
        1e6 * (cpu1 - cpu0) / elapsed / n as f64,
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
            "  {side:<9} worst hub: wake lateness p50 {} · p99 {} · max {}; release lateness p50 {} · p99 {} · max {}",
            s.lateness.p50,
            s.lateness.p99,
            s.lateness.max,
            s.release_lateness.p50,
            s.release_lateness.p99,
            s.release_lateness.max
        );
    }
    let lag: Vec<f64> = stats.iter().map(|s| s.rx_lag.mean()).collect();
    println!(
        "  receive lag (mean per link)  p50 {:.1} µs · max {:.1} µs",
        1e6 * ndr::core::sim::percentile(&lag, 0.5),
        1e6 * lag.iter().copied().fold(0.0, f64::max)
    );
    drop((bases, remotes));
    // Let the hubs close their sockets and end before the baseline.
    std::thread::sleep(StdDuration::from_secs(1));
    let raw = raw_cpu(n, seconds, cpus);
    println!(
        "  baseline: raw tokio TCP      {raw:.1} % of the machine ({n} connections, the same frame each way every 10 ms, a thread a side); links / raw {:.2}",
        machine / raw
    );
}
