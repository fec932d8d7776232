//! The release clock: exact deadlines, every tick served once and in order,
//! prompt stops, and the lateness histogram on hand-made data.
//!
//! The machine may be loaded (2 cores, other builds): the timing assertions
//! are properties with wide margins, never exact timings.

use std::ops::ControlFlow;
use std::sync::mpsc;
use std::time::Instant as StdInstant;

use ndr_core::time::{Duration, Instant};
use ndr_net::clock::{
    ClockEnd, ClockError, DEFAULT_SPIN_MARGIN, LatenessHistogram, LatenessStats, ReleaseClock,
    THREAD_NAME,
};

const MS: Duration = Duration::from_millis(1);
const US: Duration = Duration::from_micros(1);

fn ms(n: u64) -> std::time::Duration {
    std::time::Duration::from_millis(n)
}

#[test]
fn deadlines_are_exact_multiples_of_the_period() {
    let origin = StdInstant::now();
    // An awkward period: a float accumulation would drift within a few ticks.
    let period = Duration::from_nanos(1_000_003);
    let clock = ReleaseClock::new(origin, period).expect("non-zero period");
    for k in [0, 1, 2, 999, 1_000_000, 3_600_000_000] {
        let deadline = clock.deadline(k).expect("in range");
        assert_eq!(
            deadline.duration_since(origin).as_nanos(),
            u128::from(k) * 1_000_003
        );
        assert_eq!(
            clock.deadline_since_origin(k),
            Instant::from_nanos(k * 1_000_003)
        );
    }
    assert_eq!(clock.deadline(u64::MAX), None);

    assert_eq!(clock.first_tick_at_or_after(origin), 0);
    assert_eq!(
        clock.first_tick_at_or_after(origin - std::time::Duration::from_secs(1)),
        0
    );
    let at = |nanos| origin + std::time::Duration::from_nanos(nanos);
    assert_eq!(clock.first_tick_at_or_after(at(1)), 1);
    assert_eq!(clock.first_tick_at_or_after(at(1_000_003)), 1);
    assert_eq!(clock.first_tick_at_or_after(at(1_000_004)), 2);
}

#[test]
fn bad_configurations_are_refused_with_a_reason() {
    let now = StdInstant::now();
    let err = ReleaseClock::new(now, Duration::ZERO).expect_err("zero period");
    assert!(matches!(err, ClockError::ZeroPeriod));
    assert!(err.to_string().contains("period"));

    let clock = ReleaseClock::new(now, MS).expect("1 ms");
    assert_eq!(clock.spin_margin(), DEFAULT_SPIN_MARGIN);
    let err = clock.with_spin_margin(MS).expect_err("margin = period");
    assert!(matches!(err, ClockError::SpinMarginTooLong { .. }));
    assert!(err.to_string().contains("never sleep"), "{err}");
    let clock = clock.with_spin_margin(Duration::ZERO).expect("no spin");
    assert_eq!(clock.spin_margin(), Duration::ZERO);

    // The default margin never reaches the period.
    let fast = ReleaseClock::new(now, US * 100).expect("100 µs");
    assert_eq!(fast.spin_margin(), US * 50);
}

#[test]
fn wait_until_is_never_early_and_a_past_deadline_returns_at_once() {
    let clock = ReleaseClock::new(StdInstant::now(), MS * 2).expect("2 ms");

    let past = StdInstant::now() - ms(30);
    let start = StdInstant::now();
    let lateness = clock.wait_until(past);
    assert!(start.elapsed() < ms(5), "a past deadline returns at once");
    assert!(lateness >= MS * 30, "its lateness is reported: {lateness}");

    let first = clock.first_tick_at_or_after(StdInstant::now()) + 1;
    let mut late = Vec::new();
    for k in first..first + 25 {
        let deadline = clock.deadline(k).expect("in range");
        let lateness = clock.wait_until(deadline);
        let woke = StdInstant::now();
        assert!(woke >= deadline, "tick {k} woke early");
        assert!(Duration::from(woke.duration_since(deadline)) >= lateness);
        late.push(lateness);
    }
    late.sort();
    assert!(late[late.len() / 2] < MS, "median lateness {}", late[12]);
}

#[test]
fn the_thread_serves_every_deadline_once_in_order() {
    const N: u64 = 200;
    let period = MS * 2;
    let clock = ReleaseClock::new(StdInstant::now() + ms(5), period).expect("2 ms");
    let (tx, rx) = mpsc::channel();
    let thread = clock
        .spawn(0, move |tick| {
            let woke = StdInstant::now();
            let name = std::thread::current().name().map(str::to_owned);
            // The receiver lives until the end of the test.
            let _ = tx.send((tick, woke, name));
            if tick.index + 1 == N {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        })
        .expect("thread starts");
    let report = thread.join().expect("no panic");
    let ticks: Vec<_> = rx.try_iter().collect();

    assert_eq!(report.end, ClockEnd::Finished);
    assert_eq!(report.next_tick, N);
    assert_eq!(ticks.len(), 200);
    for (k, (tick, woke, name)) in (0..N).zip(&ticks) {
        assert_eq!(tick.index, k, "served in order, each once");
        assert_eq!(tick.deadline, Instant::from_nanos(k * period.as_nanos()));
        assert_eq!(tick.woke_at(), tick.deadline + tick.lateness);
        let deadline = clock.deadline(k).expect("in range");
        assert!(*woke >= deadline, "tick {k} served before its deadline");
        assert_eq!(name.as_deref(), Some(THREAD_NAME));
    }

    let stats = report.stats();
    assert_eq!(stats.count, N);
    assert!(stats.min <= stats.p50 && stats.p50 <= stats.p99 && stats.p99 <= stats.max);
    assert!(stats.p50 < MS, "median lateness {}", stats.p50);
    let mut late: Vec<_> = ticks.iter().map(|(t, _, _)| t.lateness).collect();
    late.sort();
    assert_eq!(stats.max, late[late.len() - 1]);
    assert_eq!(stats.min, late[0]);
    let missed = late.iter().filter(|&&l| l >= period).count();
    assert_eq!(stats.missed, missed as u64);
}

/// Runs a clock at 1 ms for `n` ticks; its report.
fn run_for(clock: ReleaseClock, n: u64) -> ndr_net::clock::ClockReport {
    let thread = clock
        .spawn(0, move |tick| {
            if tick.index + 1 == n {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        })
        .expect("thread starts");
    thread.join().expect("no panic")
}

#[test]
fn the_thread_learns_its_spin_margin_within_bounds_unless_told_not_to() {
    let clock = ReleaseClock::new(StdInstant::now() + ms(2), MS).expect("1 ms");
    assert!(clock.adaptive_spin());
    // Two blocks of sleeps: the margin is learned by then, whatever this
    // machine's timer does, and never leaves its bounds.
    let n = 2 * u64::from(ndr_net::spin::BLOCK) + 10;
    let learned = run_for(clock, n).spin_margin;
    assert!(
        (ndr_net::spin::MIN_SPIN_MARGIN..=DEFAULT_SPIN_MARGIN).contains(&learned),
        "{learned}"
    );
    let fixed = run_for(clock.with_adaptive_spin(false), 50).spin_margin;
    assert_eq!(fixed, DEFAULT_SPIN_MARGIN);
}

#[test]
fn stop_ends_a_sleeping_or_ticking_thread_promptly() {
    // Asleep for a 10 s period: stop must not wait for the deadline.
    let clock = ReleaseClock::new(StdInstant::now(), Duration::from_secs(10)).expect("10 s");
    let thread = clock
        .spawn(1, |_| ControlFlow::Continue(()))
        .expect("starts");
    std::thread::sleep(ms(20));
    let start = StdInstant::now();
    thread.stop();
    let report = thread.join().expect("no panic");
    assert!(
        start.elapsed() < ms(100),
        "stopped in {:?}",
        start.elapsed()
    );
    assert_eq!(report.end, ClockEnd::Stopped);
    assert_eq!(report.stats().count, 0);
    assert_eq!(report.next_tick, 1);

    // Ticking every 2 ms.
    let clock = ReleaseClock::new(StdInstant::now(), MS * 2).expect("2 ms");
    let thread = clock
        .spawn(0, |_| ControlFlow::Continue(()))
        .expect("starts");
    while thread.ticks() < 5 {
        std::thread::sleep(ms(2));
    }
    let start = StdInstant::now();
    thread.stop();
    let report = thread.join().expect("no panic");
    assert!(
        start.elapsed() < ms(100),
        "stopped in {:?}",
        start.elapsed()
    );
    assert_eq!(report.end, ClockEnd::Stopped);
    assert_eq!(report.stats().count, report.next_tick);
    assert!(report.next_tick >= 5);

    // Dropping the handle stops the thread too.
    let clock = ReleaseClock::new(StdInstant::now(), Duration::from_secs(10)).expect("10 s");
    let thread = clock
        .spawn(1, |_| ControlFlow::Continue(()))
        .expect("starts");
    let start = StdInstant::now();
    drop(thread);
    assert!(
        start.elapsed() < ms(100),
        "dropped in {:?}",
        start.elapsed()
    );
}

#[test]
fn late_ticks_are_served_in_a_burst_and_counted_as_missed() {
    let period = MS * 2;
    // The origin 20 ms in the past: ticks 0..=9 are a period late or more.
    let origin = StdInstant::now() - ms(20);
    let clock = ReleaseClock::new(origin, period).expect("2 ms");
    let thread = clock
        .spawn(0, |tick| {
            if tick.index == 14 {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        })
        .expect("starts");
    let report = thread.join().expect("no panic");
    assert_eq!(report.end, ClockEnd::Finished);
    let stats = report.stats();
    assert_eq!(stats.count, 15, "none skipped");
    assert!(stats.missed >= 10, "{stats}");
    assert!(stats.max >= MS * 20, "{stats}");
}

#[test]
fn a_panicking_closure_is_reported() {
    let clock = ReleaseClock::new(StdInstant::now(), MS).expect("1 ms");
    let thread = clock
        .spawn(0, |tick| {
            assert!(tick.index < 3, "deliberate panic in a test closure");
            ControlFlow::Continue(())
        })
        .expect("starts");
    assert!(matches!(thread.join(), Err(ClockError::Panicked)));
}

#[test]
fn the_report_tells_the_scheduling_on_linux() {
    if !std::path::Path::new("/proc/thread-self").exists() {
        return;
    }
    let clock = ReleaseClock::new(StdInstant::now(), MS).expect("1 ms");
    let thread = clock.spawn(0, |_| ControlFlow::Break(())).expect("starts");
    let report = thread.join().expect("no panic");
    let policy = report.setup.policy.expect("readable on Linux");
    assert!(!report.setup.timer_slack_refused);
    // The kernel gives real-time threads no slack whatever they ask.
    if !policy.is_realtime() {
        assert_eq!(report.setup.timer_slack, clock.timer_slack());
    }
}

#[test]
fn histogram_percentiles_on_hand_made_data() {
    let mut h = LatenessHistogram::new(MS);
    assert_eq!(h.percentile(50.0), None);
    assert_eq!(h.mean(), None);
    assert_eq!(h.stats(), LatenessStats::default());

    // 1.5 µs, 2.5 µs, …, 100.5 µs: one record in each bucket 1..=100.
    for i in 1..=100 {
        h.record(US * i + Duration::from_nanos(500));
    }
    assert_eq!(h.count(), 100);
    assert_eq!(h.min(), Some(Duration::from_nanos(1_500)));
    assert_eq!(h.max(), Some(Duration::from_nanos(100_500)));
    assert_eq!(h.mean(), Some(US * 51));
    // The upper edge of the bucket: at most 1 µs above the true value.
    assert_eq!(h.percentile(50.0), Some(US * 51));
    assert_eq!(h.percentile(99.0), Some(US * 100));
    assert_eq!(h.percentile(0.0), Some(US * 2));
    // Never above the maximum.
    assert_eq!(h.percentile(100.0), Some(Duration::from_nanos(100_500)));
    assert_eq!(h.percentile(250.0), h.percentile(100.0));
    assert_eq!(h.percentile(f64::NAN), None);
    assert_eq!(h.missed(), 0);
    assert_eq!(h.count_under_micros(0), 0);
    assert_eq!(h.count_under_micros(2), 1, "1.5 µs only");
    assert_eq!(h.count_under_micros(101), 100);

    // Past the linear range: counted in the overflow, reported by the max.
    h.record(MS * 20);
    h.record(MS);
    assert_eq!(h.overflow(), 1);
    assert_eq!(h.missed(), 2, "a tick a whole period late is missed");
    assert_eq!(h.percentile(100.0), Some(MS * 20));
    let stats = h.stats();
    assert_eq!(stats.count, 102);
    assert_eq!(stats.p999, MS * 20);
    assert_eq!(stats.max, MS * 20);
    assert_eq!(h.count_under_micros(10_001), 101, "not the overflow");
    assert_eq!(h.count_under_micros(20_001), 102, "all below the max");
    assert!(stats.to_string().starts_with("102 ticks, 2 missed: p50 "));

    h.clear();
    assert_eq!(h.count(), 0);
    assert_eq!(h.percentile(50.0), None);
    h.record(Duration::from_nanos(300));
    assert_eq!(h.percentile(50.0), Some(Duration::from_nanos(300)));
    assert_eq!(h.period(), MS);
}

#[test]
fn zero_lateness_reports_zero() {
    let mut h = LatenessHistogram::new(Duration::ZERO);
    for _ in 0..1000 {
        h.record(Duration::ZERO);
    }
    let stats = h.stats();
    assert_eq!(
        (stats.p50, stats.p999, stats.max),
        (Duration::ZERO, Duration::ZERO, Duration::ZERO)
    );
    assert_eq!(stats.missed, 0, "a zero period counts no miss");
}
