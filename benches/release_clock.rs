//! Release-clock precision: ndr's clock thread against a tokio `interval`.
//!
//! Both keep the deadlines `t0 + k·T` at T = 1 ms for N ticks (5 s each),
//! one after the other, and each tick's lateness is measured against its ideal
//! deadline with `std::time::Instant`. Prints the machine, the command and a
//! table of p50, p99, p99.9, max and mean lateness for both, with the ratio.
//!
//! ```sh
//! cargo bench --bench release_clock
//! NDR_CLOCK_TICKS=20000 NDR_CLOCK_MARGIN_US=500 cargo bench --bench release_clock
//! ```
//!
//! `NDR_CLOCK_TICKS` sets N (default 5000), `NDR_CLOCK_MARGIN_US` the clock's
//! spin margin (default: the library's). Our clock runs twice, one run after
//! the other: learning its margin from its sleeps up to that one (the
//! default), and spinning the whole of it; each run reports its thread's
//! CPU. Under a real-time policy (start the built binary with `chrt -f 50`)
//! both sides run `SCHED_FIFO`.

use std::ops::ControlFlow;
use std::time::Instant as StdInstant;

use ndr::core::time::Duration;
use ndr::net::clock::{LatenessHistogram, LatenessStats, ReleaseClock, SchedPolicy};
use tokio::time::MissedTickBehavior;

const PERIOD: Duration = Duration::from_millis(1);

fn env_u64(name: &str) -> Option<u64> {
    std::env::var(name).ok()?.trim().parse().ok()
}

/// Nanoseconds this thread has run on a CPU (Linux), for the clock's CPU cost.
fn thread_cpu_nanos() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    text.split_whitespace().next()?.parse().ok()
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

/// ndr's clock thread, its spin margin learned (`adaptive`) or fixed: the
/// lateness of each of `n` ticks.
fn ndr_clock(n: u64, adaptive: bool) -> (LatenessHistogram, String, bool) {
    let mut clock = ReleaseClock::new(
        StdInstant::now() + std::time::Duration::from_millis(20),
        PERIOD,
    )
    .expect("a 1 ms period is valid")
    .with_adaptive_spin(adaptive);
    if let Some(us) = env_u64("NDR_CLOCK_MARGIN_US") {
        clock = clock
            .with_spin_margin(Duration::from_micros(us))
            .expect("NDR_CLOCK_MARGIN_US below the period");
    }
    let mut cpu_start = None;
    let (tx, rx) = std::sync::mpsc::channel();
    let thread = clock
        .spawn(0, move |tick| {
            if tick.index == 0 {
                cpu_start = thread_cpu_nanos();
            }
            if tick.index + 1 < n {
                return ControlFlow::Continue(());
            }
            let cpu = cpu_start.zip(thread_cpu_nanos()).map(|(a, b)| b - a);
            let _ = tx.send(cpu);
            ControlFlow::Break(())
        })
        .expect("the clock thread starts");
    let report = thread.join().expect("the closure does not panic");
    let cpu = rx.try_recv().ok().flatten().map_or_else(
        || "unknown".to_owned(),
        #[allow(clippy::cast_precision_loss)]
        |nanos| {
            let span = PERIOD.as_nanos() * n.saturating_sub(1).max(1);
            format!("{:.1} % of a core", 100.0 * nanos as f64 / span as f64)
        },
    );
    let setup = report.setup;
    let policy = setup.policy.map_or("unknown".to_owned(), |p| p.to_string());
    let slack = setup
        .timer_slack
        .map_or("unknown".to_owned(), |s| s.to_string());
    let margin = if adaptive {
        format!(
            "learned, up to {}: {} at the end",
            clock.spin_margin(),
            report.spin_margin
        )
    } else {
        format!("fixed, {}", clock.spin_margin())
    };
    let info = format!(
        "ndr clock: spin margin {margin}, timer slack {slack}, policy {policy}, thread CPU {cpu}"
    );
    let realtime = setup.policy.is_some_and(SchedPolicy::is_realtime);
    (report.histogram, info, realtime)
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

fn row(name: &str, h: &LatenessHistogram) -> String {
    let s: LatenessStats = h.stats();
    #[allow(clippy::cast_precision_loss)]
    let within = 100.0 * h.count_under_micros(20) as f64 / s.count.max(1) as f64;
    format!(
        "| {name} | {} | {} | {} | {} | {} | {within:.1} % | {} |",
        us(s.p50),
        us(s.p99),
        us(s.p999),
        us(s.max),
        us(s.mean),
        s.missed
    )
}

fn main() {
    let n = env_u64("NDR_CLOCK_TICKS").unwrap_or(5_000).max(1);
    println!("{}", machine());
    let overrides: Vec<String> = ["NDR_CLOCK_TICKS", "NDR_CLOCK_MARGIN_US"]
        .iter()
        .filter_map(|v| Some(format!("{v}={} ", std::env::var(v).ok()?)))
        .collect();
    println!(
        "command: {}cargo bench --bench release_clock",
        overrides.concat()
    );
    println!("T = {PERIOD}, N = {n} ticks each, lateness vs the ideal deadline t0 + k·T, in µs\n");

    let (ours, info, realtime) = ndr_clock(n, true);
    let (fixed, fixed_info, _) = ndr_clock(n, false);
    let (theirs, early) = tokio_interval(n);
    let (a, b) = (ours.stats(), theirs.stats());

    println!("| clock | p50 | p99 | p99.9 | max | mean | < 20 µs | missed |");
    println!("|---|---|---|---|---|---|---|---|");
    println!("{}", row("ndr clock thread (margin learned)", &ours));
    println!("{}", row("ndr clock thread (margin fixed)", &fixed));
    println!("{}", row("tokio interval (current thread, Burst)", &theirs));
    println!(
        "| tokio / ndr | {} | {} | {} | {} | {} | | |",
        ratio(b.p50, a.p50),
        ratio(b.p99, a.p99),
        ratio(b.p999, a.p999),
        ratio(b.max, a.max),
        ratio(b.mean, a.mean)
    );
    println!(
        "\npercentiles are the upper edges of 1 µs buckets (capped by the max); means are exact"
    );
    println!("{info}");
    println!("{fixed_info}");
    if !realtime {
        println!(
            "note: the clock thread ran under the default policy: on a loaded machine its tail is \
             the scheduler's; for SCHED_FIFO run the built binary under `chrt -f 50`"
        );
    }
    if early > 0 {
        println!("tokio: {early} ticks fired before their deadline (counted as 0 late)");
    }
}
