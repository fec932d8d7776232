//! Release-clock precision: the hub's deadlines against a tokio `interval`.
//!
//! The hub keeps every link's deadlines on its one thread: a native sleep
//! to a spin margin before each, then a spin. Here one hub runs both ends of
//! a loopback link at T = 1 ms until the base has released N samples (5 s),
//! once learning its margin from the timer (the default), once spinning the
//! whole default margin; the hub records how late it woke for each of its
//! deadlines against the ideal instant (`LinkStats::lateness`: one wake-up
//! serves both links, which share the grid; the handshake included). The baseline, in the same run: a tokio `interval` at the same
//! period on a current-thread runtime, each tick's lateness against its
//! ideal deadline by `std::time::Instant`. Prints the machine, the command
//! and a table of p50, p99, p99.9, max and mean lateness, with the hub
//! thread's CPU and its margin at the end.
//!
//! ```sh
//! cargo bench --bench release_clock
//! NDR_CLOCK_TICKS=20000 cargo bench --bench release_clock
//! ```
//!
//! `NDR_CLOCK_TICKS` sets N (default 5000). A first link of `NDR_CLOCK_WARMUP`
//! releases (default 1000) runs before them and is discarded: a process's
//! first link pays for its first touches of memory, whichever margin it has. The hubs run with the default
//! [`Realtime`](ndr::net::Realtime) (`try`): `SCHED_FIFO` where the host
//! grants it (root, or `CAP_SYS_NICE`), else a warning and the default
//! policy; the table's notes say which the hub threads had. tokio's thread
//! keeps the policy the bench was started with (`chrt -f 50` gives it
//! `SCHED_FIFO` too).

use std::net::SocketAddr;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::endpoint::Config;
use ndr::core::time::Duration;
use ndr::core::wire::Role;
use ndr::net::Hub;
use ndr::net::clock::{
    DEFAULT_SPIN_MARGIN, LatenessHistogram, LatenessStats, SchedPolicy, current_thread_policy,
};
use ndr::net::realtime::thread_policies;
use ndr::net::spin::SpinMargin;
use ndr::net::{Link, LinkConfig, Listener};
use tokio::time::MissedTickBehavior;

const PERIOD: Duration = Duration::from_millis(1);

fn env_u64(name: &str) -> Option<u64> {
    std::env::var(name).ok()?.trim().parse().ok()
}

fn machine() -> String {
    let cpus = std::thread::available_parallelism().map_or(0, usize::from);
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let model = cpuinfo
        .lines()
        .find_map(|l| l.strip_prefix("model name")?.split_once(':'))
        .map_or("unknown CPU", |(_, m)| m.trim())
        .to_owned();
    let kernel = std::fs::read_to_string("/proc/sys/kernel/osrelease").unwrap_or_default();
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    let load: Vec<&str> = load.split_whitespace().take(3).collect();
    format!(
        "machine: {cpus} CPUs, {model}, Linux {}, load average {}",
        kernel.trim(),
        load.join(" ")
    )
}

/// CPU time of this process's hub threads (`ndr-hub`), nanoseconds on a
/// CPU (Linux's schedstat).
fn hub_cpu_nanos() -> Option<u64> {
    let mut total = None;
    for task in std::fs::read_dir("/proc/self/task").ok()?.flatten() {
        let path = task.path();
        let named_hub =
            std::fs::read_to_string(path.join("comm")).is_ok_and(|name| name.trim() == "ndr-hub");
        if !named_hub {
            continue;
        }
        let text = std::fs::read_to_string(path.join("schedstat")).ok()?;
        let nanos: u64 = text.split_whitespace().next()?.parse().ok()?;
        total = Some(total.unwrap_or(0) + nanos);
    }
    total
}

/// The scheduling policies of this process's hub threads, as granted.
fn hub_policies() -> String {
    match thread_policies("ndr-hub") {
        Ok(mut all) if !all.is_empty() => {
            all.dedup();
            let names: Vec<String> = all.iter().map(ToString::to_string).collect();
            let granted = if all.iter().all(|p| p.is_realtime()) {
                "real-time scheduling granted"
            } else {
                "real-time scheduling NOT granted"
            };
            format!("{granted} ({})", names.join(", "))
        }
        _ => "scheduling policy unknown".to_owned(),
    }
}

/// A hub keeping both ends of a loopback link at T = 1 ms until the base
/// has released `n` samples: the hub's lateness, and a line on its margin
/// and CPU.
fn hub_clock(n: u64, spin: SpinMargin) -> (LatenessStats, String) {
    let learned = spin.is_adaptive();
    let hub = Hub::new(spin).expect("a hub thread");
    let config = |role| {
        let mut c = Config::paper(role);
        c.period = PERIOD;
        LinkConfig::new(c).on_hub(hub.clone())
    };
    let any: SocketAddr = "127.0.0.1:0".parse().expect("an address");
    let listener = Listener::listen_blocking(any, config(Role::Remote)).expect("a listener");
    let addr = listener.local_addr().expect("its address");
    let accept = std::thread::spawn(move || listener.accept_blocking());
    let mut base = Link::connect_blocking(addr, config(Role::Base)).expect("a link");
    let mut remote = accept
        .join()
        .expect("the accepting thread")
        .expect("the remote's link");
    // The remote's samples go back unread but its queue is drained, so
    // nothing waits for an application that is not there.
    let drain = std::thread::spawn(move || {
        while remote.recv_timeout(StdDuration::from_secs(2)).is_ok() {}
        remote.close()
    });
    let policy = hub_policies();
    let cpu_start = hub_cpu_nanos();
    let started = StdInstant::now();
    let mut released = 0;
    while released < n {
        base.send(&[0.0]).expect("the link runs");
        base.recv_timeout(StdDuration::from_secs(2))
            .expect("a release within 2 s");
        released += 1;
    }
    let elapsed = started.elapsed();
    let cpu = cpu_start.zip(hub_cpu_nanos()).map(|(a, b)| b - a);
    let stats = base.close().expect("the base's stats");
    let _ = drain.join();
    let cpu = cpu.map_or_else(
        || "unknown".to_owned(),
        #[allow(clippy::cast_precision_loss)]
        |nanos| {
            format!(
                "{:.1} % of a core",
                100.0 * nanos as f64 / elapsed.as_nanos().max(1) as f64
            )
        },
    );
    let margin = if learned {
        format!(
            "learned, up to {DEFAULT_SPIN_MARGIN}: {} at the end",
            stats.spin_margin
        )
    } else {
        format!("fixed, {}", stats.spin_margin)
    };
    let info =
        format!("ndr hub: {policy}, spin margin {margin}, hub thread CPU {cpu} (both links)");
    (stats.lateness, info)
}

/// A tokio `interval` on a current-thread runtime: the lateness of each of `n`
/// ticks against the same ideal deadlines.
fn tokio_interval(n: u64) -> (LatenessHistogram, u64) {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_time()
        .build()
        .expect("a tokio runtime");
    runtime.block_on(async {
        let t0 = StdInstant::now() + std::time::Duration::from_millis(20);
        let period = std::time::Duration::from(PERIOD);
        let mut interval = tokio::time::interval_at(tokio::time::Instant::from_std(t0), period);
        interval.set_missed_tick_behavior(MissedTickBehavior::Burst);
        let mut histogram = LatenessHistogram::new(PERIOD);
        let mut early = 0;
        for k in 0..n {
            interval.tick().await;
            let now = StdInstant::now();
            let deadline = t0 + std::time::Duration::from_nanos(PERIOD.as_nanos() * k);
            if now < deadline {
                early += 1;
            }
            histogram.record(Duration::from(now.saturating_duration_since(deadline)));
        }
        (histogram, early)
    })
}

fn us(d: Duration) -> String {
    #[allow(clippy::cast_precision_loss)]
    let us = d.as_nanos() as f64 / 1_000.0;
    format!("{us:.1}")
}

fn ratio(a: Duration, b: Duration) -> String {
    if b.is_zero() {
        return "—".to_owned();
    }
    #[allow(clippy::cast_precision_loss)]
    let r = a.as_nanos() as f64 / b.as_nanos() as f64;
    format!("{r:.0}×")
}

fn row(name: &str, s: &LatenessStats) -> String {
    format!(
        "| {name} | {} | {} | {} | {} | {} | {} | {} |",
        us(s.p50),
        us(s.p99),
        us(s.p999),
        us(s.max),
        us(s.mean),
        s.count,
        s.missed
    )
}

fn main() {
    let n = env_u64("NDR_CLOCK_TICKS").unwrap_or(5_000).max(1);
    let warmup = env_u64("NDR_CLOCK_WARMUP").unwrap_or(1_000).max(1);
    // The hubs' warning if real-time scheduling is refused.
    let _ = tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_max_level(tracing_subscriber::filter::LevelFilter::WARN)
        .try_init();
    println!("{}", machine());
    let overrides: Vec<String> = ["NDR_CLOCK_TICKS", "NDR_CLOCK_WARMUP"]
        .iter()
        .filter_map(|v| Some(format!("{v}={} ", std::env::var(v).ok()?)))
        .collect();
    println!(
        "command: {}cargo bench --bench release_clock",
        overrides.concat()
    );
    println!(
        "T = {PERIOD}, {n} releases at the base after {warmup} discarded, lateness vs the ideal \
         deadline t0 + k·T, in µs\n"
    );

    // The process's first link pays for its first touches of memory (page
    // faults, the first memory lock): a run of its own, discarded, so that
    // the measured runs differ only in their margin.
    let _ = hub_clock(warmup, SpinMargin::fixed(DEFAULT_SPIN_MARGIN));
    let (ours, info) = hub_clock(n, SpinMargin::adaptive(DEFAULT_SPIN_MARGIN));
    let (fixed, fixed_info) = hub_clock(n, SpinMargin::fixed(DEFAULT_SPIN_MARGIN));
    let (theirs, early) = tokio_interval(n);
    let theirs = theirs.stats();

    println!("| clock | p50 | p99 | p99.9 | max | mean | wake-ups | missed |");
    println!("|---|---|---|---|---|---|---|---|");
    println!("{}", row("ndr hub (margin learned)", &ours));
    println!("{}", row("ndr hub (margin fixed)", &fixed));
    println!("{}", row("tokio interval (current thread, Burst)", &theirs));
    println!(
        "| tokio / ndr | {} | {} | {} | {} | {} | | |",
        ratio(theirs.p50, ours.p50),
        ratio(theirs.p99, ours.p99),
        ratio(theirs.p999, ours.p999),
        ratio(theirs.max, ours.max),
        ratio(theirs.mean, ours.mean)
    );
    println!(
        "\npercentiles are the upper edges of 1 µs buckets (capped by the max); means are exact"
    );
    println!("{info}");
    println!("{fixed_info}");
    let tokio_policy =
        current_thread_policy().map_or_else(|_| "unknown".to_owned(), |p| p.to_string());
    println!("tokio interval: {tokio_policy} (the bench's own thread)");
    if !info.contains("NOT granted") && !current_thread_policy().is_ok_and(SchedPolicy::is_realtime)
    {
        println!(
            "note: tokio ran under the default policy; for it to run SCHED_FIFO too, start \
             the built binary under `chrt -f 50`"
        );
    }
    if early > 0 {
        println!("tokio: {early} ticks fired before their deadline (counted as 0 late)");
    }
}
