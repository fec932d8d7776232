//! What the hub's release clock is made of and measured with: its default
//! spin margin and timer slack, the scheduling of a thread, and the
//! histogram of how late deadlines were served.
//!
//! The NDR releases one sample per period `T`. tokio's timers round up to
//! whole milliseconds, too coarse for that, so the hub
//! ([`Hub`](crate::Hub)) keeps its links' deadlines on its own thread: absolute
//! deadlines `origin + k·T` computed from integers (they never drift, and a
//! late tick does not delay the next one), a native sleep until a *spin
//! margin* before each, learned from how late its sleeps wake
//! ([`crate::spin`]) up to [`DEFAULT_SPIN_MARGIN`], then a spin on
//! [`std::time::Instant::now`]. Each deadline's lateness goes to a
//! [`LatenessHistogram`], allocated once; [`LatenessStats`] is its summary
//! (in [`LinkStats::lateness`](crate::LinkStats::lateness)). A deadline
//! served a whole period or more late is counted as *missed*
//! ([`LatenessStats::missed`]): the next one had passed too.
//!
//! # Scheduling
//!
//! Native sleeps overshoot by the thread's *timer slack* (50 µs by default on
//! Linux) plus the wake-up latency; the hub's thread therefore lowers its own
//! timer slack to [`DEFAULT_TIMER_SLACK`] by writing
//! `/proc/<tid>/timerslack_ns` (allowed for a thread's own entry, no privilege
//! needed), which lets the spin margin stay short. On a loaded machine the
//! tail of the lateness is set by the scheduler, not by the clock: a thread of
//! the default policy waits behind other runnable threads, spinning or not.
//! Only a real-time policy (`SCHED_FIFO`) removes that tail: each hub thread
//! asks for it as it starts, as [`LinkConfig::realtime`](crate::LinkConfig::realtime)
//! says ([`crate::realtime`]; by default where the host grants it), and
//! [`current_thread_policy`] says which policy a thread has. Under
//! `SCHED_FIFO` keep the spin margin well below the period: a thread that
//! never sleeps is throttled by the kernel (by default it may use 95 % of
//! each second), which costs tens of milliseconds at once.

use core::fmt;
use std::io;
use std::path::PathBuf;

use ndr_core::time::Duration;

/// The longest spin margin a hub uses (at most half the period): how long
/// before a deadline the native sleep ends and the spin begins. A hub
/// learns a shorter one from its sleeps' overshoots
/// ([`crate::spin::SpinMargin`]). A native sleep with a 1 µs timer slack
/// overshoots by tens of microseconds; under the default policy on a loaded
/// machine the tail of the lateness is the scheduler's and no margin
/// shortens it, a longer one only burns CPU (docs/benchmarks.md, "Release
/// clock").
pub const DEFAULT_SPIN_MARGIN: Duration = Duration::from_micros(200);

/// The timer slack the hub's thread asks for (see the module docs).
pub const DEFAULT_TIMER_SLACK: Duration = Duration::from_micros(1);

/// A Linux scheduling policy, as `/proc/<tid>/stat` reports it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SchedPolicy {
    /// `SCHED_OTHER`, the default time-sharing policy.
    Other,
    /// `SCHED_FIFO` at a real-time priority (1–99).
    Fifo(u32),
    /// `SCHED_RR` at a real-time priority (1–99).
    RoundRobin(u32),
    /// `SCHED_BATCH`.
    Batch,
    /// `SCHED_IDLE`.
    Idle,
    /// `SCHED_DEADLINE`.
    Deadline,
    /// A policy number this crate does not know.
    Unknown(u32),
}

impl SchedPolicy {
    /// Whether the policy is a real-time one (`SCHED_FIFO`, `SCHED_RR`,
    /// `SCHED_DEADLINE`), which preempts every thread of the default policy.
    #[must_use]
    pub fn is_realtime(self) -> bool {
        matches!(
            self,
            SchedPolicy::Fifo(_) | SchedPolicy::RoundRobin(_) | SchedPolicy::Deadline
        )
    }
}

impl fmt::Display for SchedPolicy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SchedPolicy::Other => write!(f, "SCHED_OTHER"),
            SchedPolicy::Fifo(p) => write!(f, "SCHED_FIFO {p}"),
            SchedPolicy::RoundRobin(p) => write!(f, "SCHED_RR {p}"),
            SchedPolicy::Batch => write!(f, "SCHED_BATCH"),
            SchedPolicy::Idle => write!(f, "SCHED_IDLE"),
            SchedPolicy::Deadline => write!(f, "SCHED_DEADLINE"),
            SchedPolicy::Unknown(n) => write!(f, "policy {n}"),
        }
    }
}

/// The scheduling policy of the calling thread, read from
/// `/proc/thread-self/stat` (Linux only).
///
/// # Errors
///
/// The file cannot be read (not Linux, no `/proc`) or does not parse.
pub fn current_thread_policy() -> io::Result<SchedPolicy> {
    let stat = std::fs::read_to_string("/proc/thread-self/stat")?;
    parse_policy(&stat).ok_or_else(|| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            "no scheduling policy in /proc/thread-self/stat",
        )
    })
}

/// Fields 40 (`rt_priority`) and 41 (`policy`) of a `stat` line; the command
/// name (field 2) may hold spaces and parentheses, so count after its last `)`.
pub(crate) fn parse_policy(stat: &str) -> Option<SchedPolicy> {
    let (_, rest) = stat.rsplit_once(')')?;
    let mut fields = rest.split_whitespace().skip(40 - 3);
    let priority: u32 = fields.next()?.parse().ok()?;
    let policy: u32 = fields.next()?.parse().ok()?;
    Some(match policy {
        0 => SchedPolicy::Other,
        1 => SchedPolicy::Fifo(priority),
        2 => SchedPolicy::RoundRobin(priority),
        3 => SchedPolicy::Batch,
        5 => SchedPolicy::Idle,
        6 => SchedPolicy::Deadline,
        n => SchedPolicy::Unknown(n),
    })
}

/// `/proc/<tid>/timerslack_ns` of the calling thread (the file exists only
/// under the thread's own id, not under `/proc/thread-self`).
fn timer_slack_path() -> io::Result<PathBuf> {
    let link = std::fs::read_link("/proc/thread-self")?;
    let tid = link.file_name().ok_or_else(|| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            "/proc/thread-self names no thread",
        )
    })?;
    Ok(PathBuf::from("/proc").join(tid).join("timerslack_ns"))
}

/// The calling thread's timer slack: how much later than asked the kernel may
/// end its sleeps, to group wake-ups (Linux only).
///
/// # Errors
///
/// The `/proc` file cannot be read or does not parse.
pub fn current_thread_timer_slack() -> io::Result<Duration> {
    let text = std::fs::read_to_string(timer_slack_path()?)?;
    let nanos = text
        .trim()
        .parse()
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidData, e))?;
    Ok(Duration::from_nanos(nanos))
}

/// Sets the calling thread's timer slack (Linux only; a thread may set its
/// own without privilege). Zero is taken as 1 ns, the kernel reading 0 as
/// "back to the default".
///
/// # Errors
///
/// The `/proc` file cannot be written.
pub fn set_current_thread_timer_slack(slack: Duration) -> io::Result<()> {
    let nanos = slack.as_nanos().max(1);
    std::fs::write(timer_slack_path()?, nanos.to_string())
}

/// A fixed histogram of tick lateness: 1 µs buckets from 0 to
/// [`LatenessHistogram::RANGE_MICROS`] µs, plus an overflow count, with the
/// exact count, minimum, maximum and mean.
///
/// It allocates its buckets once, in [`new`](Self::new); recording never
/// allocates. Percentiles are exact to the bucket: at most 1 µs above the
/// true value, never above the maximum.
#[derive(Clone, PartialEq, Eq)]
pub struct LatenessHistogram {
    buckets: Box<[u64]>,
    overflow: u64,
    count: u64,
    missed: u64,
    sum_nanos: u128,
    min: Duration,
    max: Duration,
    period: Duration,
}

impl fmt::Debug for LatenessHistogram {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LatenessHistogram")
            .field("period", &self.period)
            .field("stats", &self.stats())
            .field("overflow", &self.overflow)
            .finish_non_exhaustive()
    }
}

impl LatenessHistogram {
    /// The top of the linear range, in microseconds (10 ms).
    pub const RANGE_MICROS: u64 = 10_000;

    /// An empty histogram for a clock of period `period`: a tick at least a
    /// period late counts as missed (a zero period counts none).
    #[must_use]
    pub fn new(period: Duration) -> Self {
        let len = usize::try_from(Self::RANGE_MICROS + 1).unwrap_or(usize::MAX);
        LatenessHistogram {
            buckets: vec![0; len].into_boxed_slice(),
            overflow: 0,
            count: 0,
            missed: 0,
            sum_nanos: 0,
            min: Duration::MAX,
            max: Duration::ZERO,
            period,
        }
    }

    /// Records one tick's lateness.
    pub fn record(&mut self, lateness: Duration) {
        let micros = lateness.as_micros();
        let slot = usize::try_from(micros)
            .ok()
            .and_then(|i| self.buckets.get_mut(i));
        match slot {
            Some(n) => *n += 1,
            None => self.overflow += 1,
        }
        self.count += 1;
        if !self.period.is_zero() && lateness >= self.period {
            self.missed += 1;
        }
        self.sum_nanos += u128::from(lateness.as_nanos());
        self.min = self.min.min(lateness);
        self.max = self.max.max(lateness);
    }

    /// Forgets every record (keeps the period and the buckets' memory).
    pub fn clear(&mut self) {
        self.buckets.fill(0);
        self.overflow = 0;
        self.count = 0;
        self.missed = 0;
        self.sum_nanos = 0;
        self.min = Duration::MAX;
        self.max = Duration::ZERO;
    }

    /// The period given to [`new`](Self::new).
    #[must_use]
    pub fn period(&self) -> Duration {
        self.period
    }

    /// How many ticks were recorded.
    #[must_use]
    pub fn count(&self) -> u64 {
        self.count
    }

    /// How many ticks were a whole period late or more.
    #[must_use]
    pub fn missed(&self) -> u64 {
        self.missed
    }

    /// How many ticks were later than the linear range
    /// ([`RANGE_MICROS`](Self::RANGE_MICROS)).
    #[must_use]
    pub fn overflow(&self) -> u64 {
        self.overflow
    }

    /// The smallest lateness recorded.
    #[must_use]
    pub fn min(&self) -> Option<Duration> {
        (self.count > 0).then_some(self.min)
    }

    /// The largest lateness recorded.
    #[must_use]
    pub fn max(&self) -> Option<Duration> {
        (self.count > 0).then_some(self.max)
    }

    /// The mean lateness, exact to the nanosecond (truncated).
    #[must_use]
    pub fn mean(&self) -> Option<Duration> {
        let mean = self.sum_nanos.checked_div(u128::from(self.count))?;
        Some(Duration::from_nanos(
            u64::try_from(mean).unwrap_or(u64::MAX),
        ))
    }

    /// How many records were under `micros` µs late. Records past the linear
    /// range are counted only when the maximum is under `micros` too (the
    /// histogram does not know them apart).
    #[must_use]
    pub fn count_under_micros(&self, micros: u64) -> u64 {
        let n = usize::try_from(micros).unwrap_or(usize::MAX);
        let under: u64 = self.buckets.iter().take(n).sum();
        if micros > Self::RANGE_MICROS && self.max < Duration::from_micros(micros) {
            under + self.overflow
        } else {
            under
        }
    }

    /// The `p`-th percentile (`p` in percent, 0–100, clamped; nearest rank):
    /// the upper edge of the 1 µs bucket that holds it, capped by the maximum;
    /// the maximum itself past the linear range. `None` with no record or a
    /// NaN `p`.
    #[must_use]
    pub fn percentile(&self, p: f64) -> Option<Duration> {
        if self.count == 0 || p.is_nan() {
            return None;
        }
        // Nearest rank: the smallest value with at least ⌈p·n/100⌉ records at
        // or below it (at least the first). Counts fit a f64 exactly up to 2⁵³.
        let rank =
            ((p.clamp(0.0, 100.0) / 100.0 * self.count as f64).ceil() as u64).clamp(1, self.count);
        let mut seen = 0u64;
        for (micros, &n) in (0u64..).zip(self.buckets.iter()) {
            seen += n;
            if seen >= rank {
                return Some(Duration::from_micros(micros + 1).min(self.max));
            }
        }
        Some(self.max)
    }

    /// Records under each of [`LATENESS_BOUNDS_MICROS`], in one pass over
    /// the linear range that ends at its last record (on the hub's thread,
    /// with the percentiles, as they do). Past it, as
    /// [`count_under_micros`](Self::count_under_micros).
    fn below_bounds(&self) -> [u64; LATENESS_BOUNDS_MICROS.len()] {
        let mut below = [0; LATENESS_BOUNDS_MICROS.len()];
        let in_range = self.count - self.overflow;
        let mut seen = 0u64;
        let mut next = 0;
        for (micros, &n) in (0u64..).zip(self.buckets.iter()) {
            if seen == in_range {
                break;
            }
            while next < below.len() && LATENESS_BOUNDS_MICROS[next] <= micros {
                below[next] = seen;
                next += 1;
            }
            seen += n;
        }
        for (slot, &bound) in below.iter_mut().zip(&LATENESS_BOUNDS_MICROS).skip(next) {
            *slot = if bound <= Self::RANGE_MICROS {
                seen
            } else {
                self.count_under_micros(bound)
            };
        }
        below
    }

    /// The summary: count, missed, min, p50, p99, p99.9, max and mean (all
    /// zero with no record), the sum and the counts under fixed bounds.
    #[must_use]
    pub fn stats(&self) -> LatenessStats {
        let q = |p| self.percentile(p).unwrap_or(Duration::ZERO);
        LatenessStats {
            sum: Duration::from_nanos(u64::try_from(self.sum_nanos).unwrap_or(u64::MAX)),
            below: self.below_bounds(),
            count: self.count,
            missed: self.missed,
            min: self.min().unwrap_or(Duration::ZERO),
            p50: q(50.0),
            p99: q(99.0),
            p999: q(99.9),
            max: self.max().unwrap_or(Duration::ZERO),
            mean: self.mean().unwrap_or(Duration::ZERO),
        }
    }
}

/// The bounds, in microseconds, under which [`LatenessStats::below`] counts
/// ticks: the buckets of a Prometheus histogram of the lateness.
pub const LATENESS_BOUNDS_MICROS: [u64; 21] = [
    1, 2, 3, 5, 7, 10, 15, 20, 30, 50, 75, 100, 150, 200, 300, 500, 750, 1_000, 2_000, 5_000,
    10_000,
];

/// A summary of tick lateness (see [`LatenessHistogram::stats`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct LatenessStats {
    /// Ticks served.
    pub count: u64,
    /// Ticks served a whole period late or more.
    pub missed: u64,
    /// The smallest lateness.
    pub min: Duration,
    /// The median lateness.
    pub p50: Duration,
    /// The 99th percentile.
    pub p99: Duration,
    /// The 99.9th percentile.
    pub p999: Duration,
    /// The largest lateness.
    pub max: Duration,
    /// The mean lateness.
    pub mean: Duration,
    /// The lateness of every tick added up (a histogram's sum).
    #[cfg_attr(feature = "serde", serde(skip))]
    pub sum: Duration,
    /// Ticks served under each bound of [`LATENESS_BOUNDS_MICROS`]
    /// (cumulative, to the histogram's 1 µs resolution).
    #[cfg_attr(feature = "serde", serde(skip))]
    pub below: [u64; LATENESS_BOUNDS_MICROS.len()],
}

impl fmt::Display for LatenessStats {
    /// One line, e.g. `5000 ticks, 0 missed: p50 1.000µs, p99 4.000µs, …`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} ticks, {} missed: p50 {}, p99 {}, p99.9 {}, max {}, mean {}",
            self.count, self.missed, self.p50, self.p99, self.p999, self.max, self.mean
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_under_the_bounds_and_the_sum_match_the_records() {
        let mut h = LatenessHistogram::new(Duration::from_millis(1));
        // 0.5 µs, 1 µs, 7 µs, 700 µs, 3 ms, 20 ms (past the linear range).
        for nanos in [500, 1_000, 7_000, 700_000, 3_000_000, 20_000_000] {
            h.record(Duration::from_nanos(nanos));
        }
        let s = h.stats();
        assert_eq!(s.sum, Duration::from_nanos(23_708_500));
        let expect = |bound: u64| h.count_under_micros(bound);
        let want: Vec<u64> = LATENESS_BOUNDS_MICROS.iter().map(|&b| expect(b)).collect();
        assert_eq!(s.below.to_vec(), want);
        // Under 1, 2, 3, 5, 7 and 10 µs.
        assert_eq!(&s.below[..6], &[1, 2, 2, 2, 2, 3]);
        // Under 10 ms: all but the 20 ms tick.
        assert_eq!(s.below[LATENESS_BOUNDS_MICROS.len() - 1], 5);
        assert!(s.below.windows(2).all(|w| w[0] <= w[1]));
        // On the bounds themselves, at the ends of the range, and empty.
        let cases: [&[u64]; 4] = [
            &[],
            &[0],
            &[9_999_999, 10_000_000, 10_000_999, 10_001_000],
            &[1_000, 2_000, 2_999, 3_000, 150_000, 150_001, 999_999],
        ];
        for case in cases {
            let mut h = LatenessHistogram::new(Duration::from_millis(1));
            for &nanos in case {
                h.record(Duration::from_nanos(nanos));
            }
            let want: Vec<u64> = LATENESS_BOUNDS_MICROS
                .iter()
                .map(|&b| h.count_under_micros(b))
                .collect();
            assert_eq!(h.stats().below.to_vec(), want, "{case:?}");
        }
    }

    #[test]
    fn policy_fields_are_counted_after_the_command_name() {
        // A real line of /proc/<tid>/stat, its command name holding `) (`.
        let line = "4242 (a) (b c) S 1 4242 4242 0 -1 4194560 120 0 0 0 1 0 0 0 -51 0 1 0 \
                    100 1000 200 18446744073709551615 1 1 0 0 0 0 0 0 0 0 0 0 17 1 50 1 0 0 0";
        assert_eq!(parse_policy(line), Some(SchedPolicy::Fifo(50)));
        let other = line.replace(" 17 1 50 1 ", " 17 1 0 0 ");
        assert_eq!(parse_policy(&other), Some(SchedPolicy::Other));
        assert_eq!(parse_policy("12 (x) S 1"), None);
    }

    #[test]
    fn the_calling_thread_reads_its_own_policy_and_slack() {
        if !std::path::Path::new("/proc/thread-self").exists() {
            return;
        }
        let policy = current_thread_policy().expect("readable on Linux");
        std::thread::spawn(move || {
            set_current_thread_timer_slack(Duration::from_nanos(1_500)).expect("own slack");
            let slack = current_thread_timer_slack().expect("readable");
            // The kernel gives real-time threads no slack whatever they ask.
            if !policy.is_realtime() {
                assert_eq!(slack, Duration::from_nanos(1_500));
            }
        })
        .join()
        .expect("no panic");
    }
}
