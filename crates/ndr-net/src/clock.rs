//! The release clock: absolute deadlines `t0 + k·T` kept to the microsecond.
//!
//! The NDR releases one sample per period `T`. tokio's timers round up to
//! whole milliseconds (1.0–1.5 ms late on this project's machine), too coarse
//! for that, so the clock runs on a dedicated OS thread instead:
//!
//! - deadlines are absolute and computed from integers, `origin + k·T`
//!   ([`ReleaseClock::deadline`]), so they never drift however long the link
//!   runs and a late tick does not delay the next one;
//! - [`ReleaseClock::wait_until`] sleeps natively until a *spin margin*
//!   before the deadline, then spins on [`std::time::Instant::now`] (about
//!   30 ns a call here) until the deadline has passed, and returns how late
//!   it woke; the clock's thread learns the margin from how late its sleeps
//!   wake ([`crate::spin`]), up to the one configured;
//! - [`ReleaseClock::spawn`] runs a closure on every tick on a thread named
//!   `ndr-clock` and records each tick's lateness in a fixed
//!   [`LatenessHistogram`], allocated once when the thread starts.
//!
//! Ticks are never skipped: when the thread was descheduled past a deadline
//! (or the closure ran longer than a period) the late ticks are served at once,
//! in order, each with its lateness, and the caller decides what to do. A tick
//! served a whole period or more late is counted as *missed*
//! ([`LatenessStats::missed`]): the next deadline had passed too.
//!
//! # Scheduling
//!
//! Native sleeps overshoot by the thread's *timer slack* (50 µs by default on
//! Linux) plus the wake-up latency; the spawned thread therefore lowers its own
//! timer slack to [`DEFAULT_TIMER_SLACK`] by writing
//! `/proc/<tid>/timerslack_ns` (allowed for a thread's own entry, no privilege
//! needed), which lets the spin margin stay short. On a loaded machine the
//! tail of the lateness is set by the scheduler, not by the clock: a thread of
//! the default policy waits behind other runnable threads, spinning or not.
//! Only a real-time policy (`SCHED_FIFO`) removes that tail. Setting it needs a
//! system call that std does not wrap and this workspace forbids `unsafe`
//! code, so the clock does not try; a thread inherits its creator's policy, so
//! running the process under `chrt -f 50` gives the clock `SCHED_FIFO`. The
//! report says which policy the thread actually ran with
//! ([`ThreadSetup::policy`]). Under `SCHED_FIFO` keep the spin margin well
//! below the period: a thread that never sleeps is throttled by the kernel
//! (by default it may use 95 % of each second), which costs tens of
//! milliseconds at once.

use core::fmt;
use core::ops::ControlFlow;
use std::io;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::Instant as StdInstant;

use ndr_core::time::{Duration, Instant};

use crate::spin::SpinMargin;

/// The spin margin of a new clock (clamped to half the period): how long
/// before a deadline the native sleep ends and the spin begins. A clock
/// thread or a hub takes it as the longest margin and learns a shorter one
/// from its sleeps' overshoots ([`crate::spin::SpinMargin`]).
///
/// Chosen by measurement on the project's 2-core VM at T = 1 ms (5000 ticks,
/// `benches/release_clock.rs`): a native sleep with a 1 µs timer slack
/// overshoots by about 25 µs at the median (75 µs with the default 50 µs
/// slack). Under `SCHED_FIFO`, margins of 100, 200 and 500 µs gave a p99
/// lateness of 12, 1–11 and 35 µs for 9, 19 and 50 % of a core. Under the
/// default policy on a loaded machine the tail (p99 1.5–2.4 ms) is the
/// scheduler's and no margin shortens it; a longer one only burns CPU.
pub const DEFAULT_SPIN_MARGIN: Duration = Duration::from_micros(200);

/// The timer slack the clock thread asks for (see the module docs).
pub const DEFAULT_TIMER_SLACK: Duration = Duration::from_micros(1);

/// The name of the thread [`ReleaseClock::spawn`] starts.
pub const THREAD_NAME: &str = "ndr-clock";

/// Why a clock could not be made or its thread did not end well.
#[derive(Debug)]
pub enum ClockError {
    /// A period of zero: every deadline would be the origin.
    ZeroPeriod,
    /// The spin margin is not shorter than the period: the thread would spin
    /// forever (and, under `SCHED_FIFO`, be throttled by the kernel).
    SpinMarginTooLong {
        /// The margin asked for.
        margin: Duration,
        /// The clock's period.
        period: Duration,
    },
    /// The operating system refused to start the clock thread.
    Spawn(io::Error),
    /// The tick closure panicked; the thread ended there.
    Panicked,
}

impl fmt::Display for ClockError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ClockError::ZeroPeriod => write!(f, "the release clock needs a period above zero"),
            ClockError::SpinMarginTooLong { margin, period } => write!(
                f,
                "spin margin {margin} is not shorter than the period {period}: \
                 the clock thread would never sleep"
            ),
            ClockError::Spawn(e) => write!(f, "could not start the `{THREAD_NAME}` thread: {e}"),
            ClockError::Panicked => {
                write!(f, "the tick closure of the `{THREAD_NAME}` thread panicked")
            }
        }
    }
}

impl std::error::Error for ClockError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            ClockError::Spawn(e) => Some(e),
            _ => None,
        }
    }
}

/// Absolute periodic deadlines `origin + k·T`, and a precise wait for them.
///
/// ```
/// use ndr_core::time::Duration;
/// use ndr_net::clock::ReleaseClock;
///
/// let clock = ReleaseClock::new(std::time::Instant::now(), Duration::from_millis(1))?;
/// for k in 1..=3 {
///     let deadline = clock.deadline(k).expect("within the range of Instant");
///     let lateness = clock.wait_until(deadline);
///     // release the sample of tick k; `lateness` is how late that was
///     # let _ = lateness;
/// }
/// # Ok::<(), ndr_net::clock::ClockError>(())
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ReleaseClock {
    origin: StdInstant,
    period: Duration,
    spin_margin: Duration,
    adaptive_spin: bool,
    timer_slack: Option<Duration>,
}

impl ReleaseClock {
    /// A clock of period `period` whose tick `k` falls at `origin + k·period`,
    /// with the [`DEFAULT_SPIN_MARGIN`] (at most half the period) and the
    /// [`DEFAULT_TIMER_SLACK`] for its thread.
    ///
    /// # Errors
    ///
    /// [`ClockError::ZeroPeriod`] for a zero period.
    pub fn new(origin: StdInstant, period: Duration) -> Result<Self, ClockError> {
        if period.is_zero() {
            return Err(ClockError::ZeroPeriod);
        }
        Ok(ReleaseClock {
            origin,
            period,
            spin_margin: DEFAULT_SPIN_MARGIN.min(period / 2),
            adaptive_spin: true,
            timer_slack: Some(DEFAULT_TIMER_SLACK),
        })
    }

    /// The same clock with another spin margin (zero: sleep only, no spin):
    /// the longest its thread uses, learning a shorter one from its sleeps
    /// unless [`with_adaptive_spin(false)`](Self::with_adaptive_spin).
    ///
    /// # Errors
    ///
    /// [`ClockError::SpinMarginTooLong`] unless `margin` is shorter than the
    /// period.
    pub fn with_spin_margin(mut self, margin: Duration) -> Result<Self, ClockError> {
        if margin >= self.period {
            return Err(ClockError::SpinMarginTooLong {
                margin,
                period: self.period,
            });
        }
        self.spin_margin = margin;
        Ok(self)
    }

    /// The same clock whose thread ([`spawn`](Self::spawn)) learns its spin
    /// margin from its sleeps' overshoots, up to [`spin_margin`]
    /// (`true`, the default), or always spins the whole of it (`false`).
    /// [`wait_until`](Self::wait_until) always spins the whole margin.
    ///
    /// [`spin_margin`]: Self::spin_margin
    #[must_use]
    pub fn with_adaptive_spin(mut self, adaptive: bool) -> Self {
        self.adaptive_spin = adaptive;
        self
    }

    /// The same clock whose thread ([`spawn`](Self::spawn)) sets its timer
    /// slack to `slack`, or leaves it alone with `None`. [`wait_until`]
    /// does not change the slack of the calling thread: use
    /// [`set_current_thread_timer_slack`] there.
    ///
    /// [`wait_until`]: Self::wait_until
    #[must_use]
    pub fn with_timer_slack(mut self, slack: Option<Duration>) -> Self {
        self.timer_slack = slack;
        self
    }

    /// The instant of tick 0.
    #[must_use]
    pub fn origin(&self) -> StdInstant {
        self.origin
    }

    /// The period `T`.
    #[must_use]
    pub fn period(&self) -> Duration {
        self.period
    }

    /// How long before a deadline the sleep ends and the spin begins: the
    /// longest margin, when the thread learns a shorter one.
    #[must_use]
    pub fn spin_margin(&self) -> Duration {
        self.spin_margin
    }

    /// Whether the thread learns its spin margin from its sleeps.
    #[must_use]
    pub fn adaptive_spin(&self) -> bool {
        self.adaptive_spin
    }

    /// The timer slack the clock thread asks for, if any.
    #[must_use]
    pub fn timer_slack(&self) -> Option<Duration> {
        self.timer_slack
    }

    /// The deadline of tick `k`, `origin + k·T`, computed exactly from integer
    /// nanoseconds; `None` past the range of [`std::time::Instant`].
    #[must_use]
    pub fn deadline(&self, k: u64) -> Option<StdInstant> {
        let nanos = self.period.as_nanos().checked_mul(k)?;
        self.origin
            .checked_add(std::time::Duration::from_nanos(nanos))
    }

    /// The deadline of tick `k` on the link's own time scale (nanoseconds
    /// since the origin): exactly `k·T`, saturating at the end of time.
    #[must_use]
    pub fn deadline_since_origin(&self, k: u64) -> Instant {
        Instant::ZERO + self.period * k
    }

    /// The first tick whose deadline is at or after `t` (0 for any `t` before
    /// the origin): where to start a clock whose origin is in the past
    /// without serving the ticks already gone.
    #[must_use]
    pub fn first_tick_at_or_after(&self, t: StdInstant) -> u64 {
        let since = t.saturating_duration_since(self.origin).as_nanos();
        let k = since.div_ceil(u128::from(self.period.as_nanos()));
        u64::try_from(k).unwrap_or(u64::MAX)
    }

    /// Blocks the calling thread until `deadline` has passed and returns how
    /// late it woke (zero or more): a native sleep until the spin margin
    /// before the deadline, then a spin.
    ///
    /// A deadline already past returns at once with its lateness.
    pub fn wait_until(&self, deadline: StdInstant) -> Duration {
        let mut margin = SpinMargin::fixed(self.spin_margin);
        wait(deadline, &mut margin, None, std::thread::sleep).unwrap_or(Duration::ZERO)
    }

    /// Starts a thread named [`THREAD_NAME`] that waits for the deadline of
    /// each tick from `first` on, in order, and calls `on_tick` with it; the
    /// thread ends when `on_tick` returns [`ControlFlow::Break`], when
    /// [`ClockThread::stop`] is called (or the handle dropped), or past the
    /// range of [`std::time::Instant`].
    ///
    /// Each tick's lateness is recorded before `on_tick` runs; the time
    /// `on_tick` takes delays the next tick only if it overruns its deadline.
    ///
    /// # Errors
    ///
    /// [`ClockError::Spawn`] if the operating system refuses the thread.
    pub fn spawn<F>(self, first: u64, on_tick: F) -> Result<ClockThread, ClockError>
    where
        F: FnMut(Tick) -> ControlFlow<()> + Send + 'static,
    {
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            ticks: AtomicU64::new(0),
        });
        let thread_shared = Arc::clone(&shared);
        let handle = std::thread::Builder::new()
            .name(THREAD_NAME.into())
            .spawn(move || run(self, first, on_tick, &thread_shared))
            .map_err(ClockError::Spawn)?;
        Ok(ClockThread {
            handle: Some(handle),
            shared,
        })
    }
}

/// Waits for `deadline`: `sleep` until the margin before it, then spins;
/// each sleep's overshoot goes to `margin`. `None` if `stop` was raised
/// first.
fn wait(
    deadline: StdInstant,
    margin: &mut SpinMargin,
    stop: Option<&AtomicBool>,
    mut sleep: impl FnMut(std::time::Duration),
) -> Option<Duration> {
    let spin = std::time::Duration::from(margin.current());
    loop {
        let now = StdInstant::now();
        if now >= deadline {
            return Some(Duration::from(now.duration_since(deadline)));
        }
        if stop.is_some_and(|s| s.load(Ordering::Acquire)) {
            return None;
        }
        let remaining = deadline.duration_since(now);
        if remaining > spin {
            let until = deadline - spin;
            sleep(until - now);
            // A park can end early (a stop, or spuriously): only a sleep that
            // ran its course says how late it wakes.
            let woke = StdInstant::now();
            if woke >= until {
                margin.record((woke - until).into());
            }
        } else {
            std::hint::spin_loop();
        }
    }
}

/// One tick of a [`ClockThread`], as its closure receives it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tick {
    /// The tick's index `k`.
    pub index: u64,
    /// Its deadline, `k·T` since the clock's origin.
    pub deadline: Instant,
    /// How late the thread woke for it (zero or more).
    pub lateness: Duration,
}

impl Tick {
    /// When the thread woke for this tick, since the clock's origin.
    #[must_use]
    pub fn woke_at(&self) -> Instant {
        self.deadline + self.lateness
    }
}

struct Shared {
    stop: AtomicBool,
    ticks: AtomicU64,
}

/// The handle of a running clock thread (see [`ReleaseClock::spawn`]).
///
/// Dropping it stops the thread and waits for it.
#[derive(Debug)]
#[must_use = "dropping a ClockThread stops the clock"]
pub struct ClockThread {
    handle: Option<JoinHandle<ClockReport>>,
    shared: Arc<Shared>,
}

impl fmt::Debug for Shared {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Shared")
            .field("stop", &self.stop.load(Ordering::Relaxed))
            .field("ticks", &self.ticks.load(Ordering::Relaxed))
            .finish()
    }
}

impl ClockThread {
    /// Asks the thread to end: it wakes from its sleep at once and serves no
    /// further tick (a tick whose closure is running completes). Follow with
    /// [`join`](Self::join) to wait for it.
    pub fn stop(&self) {
        self.shared.stop.store(true, Ordering::Release);
        if let Some(handle) = &self.handle {
            handle.thread().unpark();
        }
    }

    /// How many ticks the thread has served so far.
    #[must_use]
    pub fn ticks(&self) -> u64 {
        self.shared.ticks.load(Ordering::Relaxed)
    }

    /// Whether the thread has ended.
    #[must_use]
    pub fn is_finished(&self) -> bool {
        self.handle.as_ref().is_none_or(JoinHandle::is_finished)
    }

    /// Waits for the thread to end (by [`stop`](Self::stop), by its closure or
    /// at the end of time) and returns its report.
    ///
    /// # Errors
    ///
    /// [`ClockError::Panicked`] if the closure panicked.
    pub fn join(mut self) -> Result<ClockReport, ClockError> {
        match self.handle.take() {
            Some(handle) => handle.join().map_err(|_| ClockError::Panicked),
            None => Err(ClockError::Panicked),
        }
    }
}

impl Drop for ClockThread {
    fn drop(&mut self) {
        if let Some(handle) = self.handle.take() {
            self.shared.stop.store(true, Ordering::Release);
            handle.thread().unpark();
            // A panic of the closure has nowhere to go from a drop.
            let _ = handle.join();
        }
    }
}

/// Why a clock thread ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ClockEnd {
    /// [`ClockThread::stop`] was called or the handle dropped.
    Stopped,
    /// The closure returned [`ControlFlow::Break`].
    Finished,
    /// The next deadline is past the range of [`std::time::Instant`].
    EndOfTime,
}

/// What a clock thread did, returned by [`ClockThread::join`].
#[derive(Clone, Debug)]
pub struct ClockReport {
    /// The lateness of every tick served.
    pub histogram: LatenessHistogram,
    /// Why the thread ended.
    pub end: ClockEnd,
    /// The first tick not served: where a new clock thread would resume.
    pub next_tick: u64,
    /// The scheduling the thread ran with.
    pub setup: ThreadSetup,
    /// The spin margin the thread was using at its end (learned from its
    /// sleeps, or the one configured).
    pub spin_margin: Duration,
}

impl ClockReport {
    /// The summary of [`histogram`](Self::histogram).
    #[must_use]
    pub fn stats(&self) -> LatenessStats {
        self.histogram.stats()
    }
}

/// The scheduling a clock thread had (Linux; `None` where unknown).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ThreadSetup {
    /// The scheduling policy the thread ran under.
    pub policy: Option<SchedPolicy>,
    /// The thread's timer slack, read back after setting it.
    pub timer_slack: Option<Duration>,
    /// Whether setting the timer slack failed (it was asked for and refused).
    pub timer_slack_refused: bool,
}

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
fn parse_policy(stat: &str) -> Option<SchedPolicy> {
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

fn run<F>(clock: ReleaseClock, first: u64, mut on_tick: F, shared: &Shared) -> ClockReport
where
    F: FnMut(Tick) -> ControlFlow<()>,
{
    let timer_slack_refused = clock
        .timer_slack
        .is_some_and(|slack| set_current_thread_timer_slack(slack).is_err());
    let setup = ThreadSetup {
        policy: current_thread_policy().ok(),
        timer_slack: current_thread_timer_slack().ok(),
        timer_slack_refused,
    };
    let mut histogram = LatenessHistogram::new(clock.period);
    let mut margin = if clock.adaptive_spin {
        SpinMargin::adaptive(clock.spin_margin)
    } else {
        SpinMargin::fixed(clock.spin_margin)
    };
    let mut k = first;
    let end = loop {
        if shared.stop.load(Ordering::Acquire) {
            break ClockEnd::Stopped;
        }
        let Some(deadline) = clock.deadline(k) else {
            break ClockEnd::EndOfTime;
        };
        let Some(lateness) = wait(
            deadline,
            &mut margin,
            Some(&shared.stop),
            std::thread::park_timeout,
        ) else {
            break ClockEnd::Stopped;
        };
        histogram.record(lateness);
        shared.ticks.fetch_add(1, Ordering::Relaxed);
        let tick = Tick {
            index: k,
            deadline: clock.deadline_since_origin(k),
            lateness,
        };
        let flow = on_tick(tick);
        k = k.saturating_add(1);
        if flow.is_break() {
            break ClockEnd::Finished;
        }
    };
    ClockReport {
        histogram,
        end,
        next_tick: k,
        setup,
        spin_margin: margin.current(),
    }
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

    /// The summary: count, missed, min, p50, p99, p99.9, max and mean (all
    /// zero with no record).
    #[must_use]
    pub fn stats(&self) -> LatenessStats {
        let q = |p| self.percentile(p).unwrap_or(Duration::ZERO);
        LatenessStats {
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

/// A summary of tick lateness (see [`LatenessHistogram::stats`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
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
