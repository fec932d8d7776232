//! Playout policies: when a regulator releases each sample.
//!
//! [`Playout::Fifo`] is the paper's NDR: a FIFO pre-filled to `ns` samples
//! and released one per tick (its size set by the [`Mode`](crate::Mode)).
//! Every other policy is a **target delay** on the one-way delay: a sample
//! sent at `sent_at` is released at the first tick at or after
//! `sent_at + D`, `D` the policy's current target; under
//! [`Underflow::DropLate`](crate::Underflow::DropLate) one that arrives after
//! its slot is late (counted, discarded, the tick repeats the last sample).
//!
//! A target policy sees one sample per received frame through
//! [`TargetDelay::observe`]: the frame's send stamp and its one-way delay
//! (arrival − send stamp). The endpoint computes that delay in one place, so
//! a correction for the peers' clock offset applies to every policy at once.
//! Until then the target policies assume synchronized clocks.
//!
//! The constants and references of each policy are in `docs/algorithms.md`.

use core::fmt;
use core::str::FromStr;

use crate::time::{Duration, Instant};

pub mod schedule;

pub use schedule::{DELAY_QUANTUM, Schedule, delay_quantum, delay_quantum_for};

/// How a regulator decides when to release each sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Playout {
    /// The paper's FIFO, pre-filled to `ns`, one release per tick.
    #[default]
    Fifo,
    /// Ramjee, Kurose, Towsley, Schulzrinne (1994), algorithm 1: `D = d̂ + 4·v̂`
    /// with exponential averages (α = 0.998002) of the delay and its deviation.
    Ramjee1,
    /// Ramjee et al. (1994), algorithm 4: algorithm 1's target with fast
    /// averages (1/8) and spike detection.
    Ramjee4,
    /// A NetEQ-like target: the 0.95 quantile of a histogram of relative
    /// delays (bucket width = period, forget factor 0.983) above the
    /// smallest delay of the last 2–4 s.
    NetEq,
    /// A fixed latency above the smallest delay seen (GStreamer's
    /// rtpjitterbuffer).
    FixedAboveMin {
        /// The latency added to the smallest delay.
        latency: Duration,
    },
    /// A constant target delay (the oracle's, on a known trace).
    Constant {
        /// The target.
        delay: Duration,
    },
    /// Timestamp-based (issue 7): each sample is released at its send time,
    /// mapped to the local clock by the offset and skew estimate
    /// ([`ClockSync`](crate::sync::ClockSync)), plus the `1 − ε` quantile of
    /// the delays above the floor over the last 90–120 s; the target slews
    /// at a bounded rate. A silence past a slot (a stall, whose frames come
    /// in a burst) holds the delay ahead of it while the rise costs less
    /// per sample kept than the quantile would ([`Adaptive::sample_cost`])
    /// once half the late budget is used, and whatever it costs once the
    /// window's lost samples reach `ε` of its delays.
    Adaptive {
        /// The target late rate ε, in parts per million (1000 = 0.1 %).
        epsilon_ppm: u32,
        /// The step of the delay asked for, `None` for the default
        /// [`DELAY_QUANTUM`] (see
        /// [`delay_quantum_for`]): a
        /// finer one holds a lower delay that changes more often.
        quantum: Option<Duration>,
    },
}

/// The finest quantum [`Playout::Adaptive`] takes: below it the delay would
/// follow every wobble of its quantile.
pub const MIN_QUANTUM: Duration = Duration::from_millis(1);
/// The coarsest quantum the command line takes (any beyond the period is
/// the period).
pub const MAX_QUANTUM: Duration = Duration::from_secs(10);

/// The adaptive policy's default late rate, 0.1 % in parts per million.
pub const DEFAULT_EPSILON_PPM: u32 = 1000;

/// GStreamer rtpjitterbuffer's default latency.
pub const DEFAULT_FIXED_LATENCY: Duration = Duration::from_millis(200);

impl Playout {
    /// The name used on the command line and in reports. [`Playout::Constant`]
    /// and [`Playout::FixedAboveMin`] carry their value: `constant:120`,
    /// `fixed:200` (milliseconds).
    #[must_use]
    pub fn name(self) -> PlayoutName {
        PlayoutName(self)
    }

    /// The target-delay state of this policy for `period`, `None` for the FIFO.
    #[must_use]
    pub fn target(self, period: Duration) -> Option<Target> {
        // `Adaptive` always has room for itself: never `Err`.
        self.target_in::<Adaptive>(period).unwrap_or(None)
    }

    /// [`Playout::target`] in a [`Target`] whose adaptive state is `A`.
    ///
    /// # Errors
    ///
    /// [`NoAdaptiveRoom`] for [`Playout::Adaptive`] when `A` holds no
    /// adaptive state ([`NoAdaptive`]).
    pub fn target_in<A: AdaptiveSlot>(
        self,
        period: Duration,
    ) -> Result<Option<Target<A>>, NoAdaptiveRoom> {
        Ok(Some(match self {
            Playout::Fifo => return Ok(None),
            Playout::Ramjee1 => Target::Ramjee1(Ramjee1::new()),
            Playout::Ramjee4 => Target::Ramjee4(Ramjee4::new()),
            Playout::NetEq => Target::NetEq(NetEq::new(period)),
            Playout::FixedAboveMin { latency } => {
                Target::FixedAboveMin(FixedAboveMin::new(latency))
            }
            Playout::Constant { delay } => Target::Constant(delay),
            Playout::Adaptive {
                epsilon_ppm,
                quantum,
            } => Target::Adaptive(
                A::build(
                    period,
                    f64::from(epsilon_ppm) * 1e-6,
                    delay_quantum_for(period, quantum),
                )
                .ok_or(NoAdaptiveRoom)?,
            ),
        }))
    }

    /// The quantum the adaptive delay is held in at `period`, `None` for the
    /// other policies.
    #[must_use]
    pub fn quantum(self, period: Duration) -> Option<Duration> {
        match self {
            Playout::Adaptive { quantum, .. } => Some(delay_quantum_for(period, quantum)),
            _ => None,
        }
    }

    /// The adaptive policy at its default late rate and quantum.
    pub const ADAPTIVE: Playout = Playout::Adaptive {
        epsilon_ppm: DEFAULT_EPSILON_PPM,
        quantum: None,
    };
}

/// Displays a [`Playout`] by its command-line name.
#[derive(Clone, Copy, Debug)]
pub struct PlayoutName(Playout);

/// `units / 10^digits` with the fraction's trailing zeros cut: names are
/// printed from integers, so that no float noise shows (7 000 ppm is
/// `0.7`, not `0.7000000000000001`; 124 ms is `124`).
fn write_decimal(f: &mut fmt::Formatter<'_>, units: u64, digits: u32) -> fmt::Result {
    let scale = 10u64.pow(digits);
    write!(f, "{}", units / scale)?;
    let (mut frac, mut width) = (units % scale, digits as usize);
    if frac > 0 {
        while frac % 10 == 0 {
            frac /= 10;
            width -= 1;
        }
        write!(f, ".{frac:0width$}")?;
    }
    Ok(())
}

impl fmt::Display for PlayoutName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ms = |f: &mut fmt::Formatter<'_>, d: Duration| write_decimal(f, d.as_nanos(), 6);
        match self.0 {
            Playout::Fifo => f.write_str("fifo"),
            Playout::Ramjee1 => f.write_str("ramjee-1"),
            Playout::Ramjee4 => f.write_str("ramjee-4"),
            Playout::NetEq => f.write_str("neteq"),
            Playout::FixedAboveMin { latency } => {
                f.write_str("fixed:")?;
                ms(f, latency)
            }
            Playout::Constant { delay } => {
                f.write_str("constant:")?;
                ms(f, delay)
            }
            Playout::Adaptive {
                epsilon_ppm: DEFAULT_EPSILON_PPM,
                quantum: None,
            } => f.write_str("adaptive"),
            Playout::Adaptive {
                epsilon_ppm,
                quantum,
            } => {
                f.write_str("adaptive:")?;
                write_decimal(f, u64::from(epsilon_ppm), 4)?;
                match quantum {
                    Some(q) => {
                        f.write_str(":")?;
                        ms(f, q)
                    }
                    None => Ok(()),
                }
            }
        }
    }
}

impl fmt::Display for Playout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.name().fmt(f)
    }
}

/// A name that is not a [`Playout`], or a known one with a value out of
/// its range (the message says which).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UnknownPlayout(Why);

/// What was wrong with a playout's name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Why {
    Name,
    Millis,
    Percent,
    Quantum,
}

const UNKNOWN: UnknownPlayout = UnknownPlayout(Why::Name);

impl UnknownPlayout {
    /// The name itself is unknown (not a value out of a known policy's range).
    #[must_use]
    pub fn is_unknown_name(self) -> bool {
        self.0 == Why::Name
    }
}

impl fmt::Display for UnknownPlayout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self.0 {
            Why::Name => "unknown playout policy",
            Why::Millis => "fixed:MS and constant:MS take milliseconds, finite and not negative",
            Why::Percent => {
                "adaptive:PERCENT takes the target late rate in percent, 0 < PERCENT < 100 \
                 (0.1 by default)"
            }
            Why::Quantum => {
                "adaptive:PERCENT:QUANTUM_MS takes the step of the delay in milliseconds, \
                 1 to 10000 (e.g. 10)"
            }
        })?;
        f.write_str(
            "; valid: fifo, ramjee-1, ramjee-4, neteq, fixed[:MS], \
             constant:MS (milliseconds, finite, not negative), \
             adaptive[:PERCENT[:QUANTUM_MS]] (the target late rate, 0 < PERCENT < 100, \
             default 0.1; the delay's step, 1 to 10000 ms, default 20 ms or the period)",
        )
    }
}

impl core::error::Error for UnknownPlayout {}

impl FromStr for Playout {
    type Err = UnknownPlayout;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let millis = |v: &str| -> Result<Duration, UnknownPlayout> {
            match v.trim().parse::<f64>() {
                // To the nanosecond, rounded: `124` is 124 ms exactly.
                Ok(ms) if ms.is_finite() && ms >= 0.0 => {
                    Ok(Duration::from_nanos(libm::round(ms * 1e6) as u64))
                }
                _ => Err(UnknownPlayout(Why::Millis)),
            }
        };
        match s.trim().split_once(':') {
            None => match s.trim() {
                "fifo" => Ok(Playout::Fifo),
                "ramjee-1" => Ok(Playout::Ramjee1),
                "ramjee-4" => Ok(Playout::Ramjee4),
                "neteq" => Ok(Playout::NetEq),
                "adaptive" => Ok(Playout::ADAPTIVE),
                "fixed" => Ok(Playout::FixedAboveMin {
                    latency: DEFAULT_FIXED_LATENCY,
                }),
                _ => Err(UNKNOWN),
            },
            Some(("fixed", v)) => Ok(Playout::FixedAboveMin {
                latency: millis(v)?,
            }),
            Some(("constant", v)) => Ok(Playout::Constant { delay: millis(v)? }),
            Some(("adaptive", v)) => {
                let (pc, quantum) = match v.split_once(':') {
                    Some((pc, q)) => match millis(q) {
                        Ok(q) if (MIN_QUANTUM..=MAX_QUANTUM).contains(&q) => (pc, Some(q)),
                        _ => return Err(UnknownPlayout(Why::Quantum)),
                    },
                    None => (v, None),
                };
                match pc.trim().parse::<f64>() {
                    Ok(pc) if pc > 0.0 && pc < 100.0 => Ok(Playout::Adaptive {
                        epsilon_ppm: libm::round(pc * 1e4).max(1.0) as u32,
                        quantum,
                    }),
                    _ => Err(UnknownPlayout(Why::Percent)),
                }
            }
            Some(_) => Err(UNKNOWN),
        }
    }
}

/// A policy that sets a target one-way delay from the delays it observes.
pub trait TargetDelay {
    /// One received frame: its send stamp and its one-way delay.
    fn observe(&mut self, sent_at: Instant, delay: Duration);
    /// The current target, `None` before the policy can tell.
    fn target(&self) -> Option<Duration>;
}

/// Where a [`Target`] keeps [`Playout::Adaptive`]'s state: [`Adaptive`]
/// itself (about 7 KiB, the default), or [`NoAdaptive`], nothing, for an
/// endpoint that never runs that policy and should not carry its histogram.
pub trait AdaptiveSlot: TargetDelay + Clone + fmt::Debug + PartialEq {
    /// The state for `period`, late rate `epsilon` and the delay's
    /// `quantum`; `None` if this slot holds none.
    fn build(period: Duration, epsilon: f64, quantum: Duration) -> Option<Self>;
    /// The floor the delays are measured above moved by `by` (up if
    /// `rose`): see [`Adaptive::rebase`].
    fn rebase(&mut self, by: Duration, rose: bool);
    /// A sample was lost: see [`Adaptive::note_late`].
    fn note_late(&mut self);
    /// See [`Adaptive::budget_used`].
    fn budget_used(&self, more: u64) -> f64;
    /// See [`Adaptive::sample_cost`].
    fn sample_cost(&self) -> Duration;
    /// See [`Adaptive::margin`].
    fn margin(&self) -> Duration;
}

impl AdaptiveSlot for Adaptive {
    fn build(period: Duration, epsilon: f64, quantum: Duration) -> Option<Self> {
        Some(Adaptive::with_quantum(period, epsilon, quantum))
    }

    fn rebase(&mut self, by: Duration, rose: bool) {
        Adaptive::rebase(self, by, rose);
    }

    fn note_late(&mut self) {
        Adaptive::note_late(self);
    }

    fn budget_used(&self, more: u64) -> f64 {
        Adaptive::budget_used(self, more)
    }

    fn sample_cost(&self) -> Duration {
        Adaptive::sample_cost(self)
    }

    fn margin(&self) -> Duration {
        Adaptive::margin(self)
    }
}

/// An [`AdaptiveSlot`] with no room: a [`Target<NoAdaptive>`] is the size of
/// the other policies' largest state (NetEQ's 2 KiB), and asking it for
/// [`Playout::Adaptive`] is a [`NoAdaptiveRoom`] error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NoAdaptive {}

impl TargetDelay for NoAdaptive {
    fn observe(&mut self, _: Instant, _: Duration) {
        match *self {}
    }

    fn target(&self) -> Option<Duration> {
        match *self {}
    }
}

impl AdaptiveSlot for NoAdaptive {
    fn build(_: Duration, _: f64, _: Duration) -> Option<Self> {
        None
    }

    fn rebase(&mut self, _: Duration, _: bool) {
        match *self {}
    }

    fn note_late(&mut self) {
        match *self {}
    }

    fn budget_used(&self, _: u64) -> f64 {
        match *self {}
    }

    fn sample_cost(&self) -> Duration {
        match *self {}
    }

    fn margin(&self) -> Duration {
        match *self {}
    }
}

/// [`Playout::Adaptive`] asked of a [`Target<NoAdaptive>`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NoAdaptiveRoom;

impl fmt::Display for NoAdaptiveRoom {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(
            "the adaptive playout needs room for its histogram: \
             build the endpoint with the default `Adaptive` slot, not `NoAdaptive`",
        )
    }
}

impl core::error::Error for NoAdaptiveRoom {}

/// The state of a target-delay [`Playout`], with the adaptive policy's state
/// in `A` (see [`AdaptiveSlot`]).
// No heap in the core: NetEQ's histogram (2 KiB) lives inline, and an
// endpoint holds one `Target`, so the size of the others does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq)]
pub enum Target<A = Adaptive> {
    /// See [`Playout::Ramjee1`].
    Ramjee1(Ramjee1),
    /// See [`Playout::Ramjee4`].
    Ramjee4(Ramjee4),
    /// See [`Playout::NetEq`].
    NetEq(NetEq),
    /// See [`Playout::FixedAboveMin`].
    FixedAboveMin(FixedAboveMin),
    /// See [`Playout::Constant`].
    Constant(Duration),
    /// See [`Playout::Adaptive`].
    Adaptive(A),
}

impl<A: TargetDelay> TargetDelay for Target<A> {
    fn observe(&mut self, sent_at: Instant, delay: Duration) {
        match self {
            Target::Ramjee1(p) => p.observe(sent_at, delay),
            Target::Ramjee4(p) => p.observe(sent_at, delay),
            Target::NetEq(p) => p.observe(sent_at, delay),
            Target::FixedAboveMin(p) => p.observe(sent_at, delay),
            Target::Constant(_) => {}
            Target::Adaptive(p) => p.observe(sent_at, delay),
        }
    }

    fn target(&self) -> Option<Duration> {
        match self {
            Target::Ramjee1(p) => p.target(),
            Target::Ramjee4(p) => p.target(),
            Target::NetEq(p) => p.target(),
            Target::FixedAboveMin(p) => p.target(),
            Target::Constant(d) => Some(*d),
            Target::Adaptive(p) => p.target(),
        }
    }
}

/// `d̂ + 4·v̂`, the playout delay of Ramjee et al.'s algorithms.
fn mean_plus_4dev(d: f64, v: f64) -> Duration {
    Duration::from_secs_f64(d + 4.0 * v)
}

/// Ramjee et al. (1994) algorithm 1's weight.
pub const RAMJEE_ALPHA: f64 = 0.998002;

/// Ramjee et al. (1994), algorithm 1:
/// `d̂ ← α·d̂ + (1−α)·n`, `v̂ ← α·v̂ + (1−α)·|d̂ − n|`, `D = d̂ + 4·v̂`.
///
/// Until `1/(1−α)` ≈ 500 samples are seen, the weight is `1 − 1/i` at the
/// `i`-th sample (the running mean), so that the first samples do not start
/// the averages from zero.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Ramjee1 {
    d: f64,
    v: f64,
    seen: u64,
}

impl Ramjee1 {
    /// No sample seen yet.
    #[must_use]
    pub const fn new() -> Self {
        Ramjee1 {
            d: 0.0,
            v: 0.0,
            seen: 0,
        }
    }

    /// `(d̂, v̂)` in seconds.
    #[must_use]
    pub fn estimates(&self) -> (f64, f64) {
        (self.d, self.v)
    }
}

impl TargetDelay for Ramjee1 {
    fn observe(&mut self, _sent_at: Instant, delay: Duration) {
        let n = delay.as_secs_f64();
        self.seen = self.seen.saturating_add(1);
        let alpha = RAMJEE_ALPHA.min(1.0 - 1.0 / self.seen as f64);
        self.d = alpha * self.d + (1.0 - alpha) * n;
        self.v = alpha * self.v + (1.0 - alpha) * libm::fabs(self.d - n);
    }

    fn target(&self) -> Option<Duration> {
        (self.seen > 0).then(|| mean_plus_4dev(self.d, self.v))
    }
}

/// Algorithm 4's spike threshold, `2·|v̂| + 800` in the paper's 8 kHz
/// timestamp units: 800 units = 100 ms.
pub const SPIKE_ENTER: f64 = 0.100;
/// Algorithm 4 leaves a spike when `var ≤ 63` units (7.875 ms at 8 kHz).
pub const SPIKE_EXIT: f64 = 63.0 / 8000.0;

/// Ramjee et al. (1994), algorithm 4: fast averages (weight 1/8) and a
/// spike mode in which `d̂` follows the delays one for one.
///
/// ```text
/// normal: if |n − n₁| > 2·|v̂| + 100 ms  → spike, var = 0
/// spike:  var = var/2 + |2n − n₁ − n₂|/8; if var ≤ 7.875 ms → normal (skip the update)
/// d̂ = d̂ + (n − d̂)/8 (normal) or d̂ + n − n₁ (spike);  v̂ = v̂ + (|n − d̂| − v̂)/8
/// ```
/// with `n₁`, `n₂` the two previous delays; `D = d̂ + 4·v̂`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Ramjee4 {
    d: f64,
    v: f64,
    var: f64,
    n1: f64,
    n2: f64,
    spike: bool,
    seen: u64,
}

impl Ramjee4 {
    /// No sample seen yet.
    #[must_use]
    pub const fn new() -> Self {
        Ramjee4 {
            d: 0.0,
            v: 0.0,
            var: 0.0,
            n1: 0.0,
            n2: 0.0,
            spike: false,
            seen: 0,
        }
    }

    /// Whether the policy is in spike mode.
    #[must_use]
    pub fn in_spike(&self) -> bool {
        self.spike
    }

    /// `(d̂, v̂)` in seconds.
    #[must_use]
    pub fn estimates(&self) -> (f64, f64) {
        (self.d, self.v)
    }
}

impl TargetDelay for Ramjee4 {
    fn observe(&mut self, _sent_at: Instant, delay: Duration) {
        let n = delay.as_secs_f64();
        if self.seen == 0 {
            // The first delay starts every average.
            *self = Ramjee4 {
                d: n,
                n1: n,
                n2: n,
                seen: 1,
                ..Ramjee4::new()
            };
            return;
        }
        self.seen = self.seen.saturating_add(1);
        if !self.spike {
            if libm::fabs(n - self.n1) > 2.0 * libm::fabs(self.v) + SPIKE_ENTER {
                self.var = 0.0;
                self.spike = true;
            }
        } else {
            self.var = self.var / 2.0 + libm::fabs((2.0 * n - self.n1 - self.n2) / 8.0);
            if self.var <= SPIKE_EXIT {
                self.spike = false;
                self.n2 = self.n1;
                self.n1 = n;
                return;
            }
        }
        if self.spike {
            self.d += n - self.n1;
        } else {
            self.d = 0.125 * n + 0.875 * self.d;
        }
        self.v = 0.125 * libm::fabs(n - self.d) + 0.875 * self.v;
        self.n2 = self.n1;
        self.n1 = n;
    }

    fn target(&self) -> Option<Duration> {
        (self.seen > 0).then(|| mean_plus_4dev(self.d, self.v))
    }
}

/// Buckets of the NetEQ-like histogram; relative delays beyond the last
/// bucket count in it.
pub const NETEQ_BUCKETS: usize = 256;
/// The histogram's forget factor (WebRTC NetEQ's 0.983).
pub const NETEQ_FORGET: f64 = 0.983;
/// The quantile of relative delays the target covers.
pub const NETEQ_QUANTILE: f64 = 0.95;
/// The smallest delay is taken over the current and the previous block of
/// this length (a window of 2 to 4 s, NetEQ's 2 s history).
pub const NETEQ_MIN_BLOCK: Duration = Duration::from_secs(2);

/// A NetEQ-like target: relative delay = delay − smallest delay of the last
/// 2–4 s; a histogram of relative delays with bucket width `T`, where each
/// sample multiplies every bucket by 0.983 and adds 0.017 to its own; the
/// target is that smallest delay plus the upper edge of the bucket holding
/// the 0.95 quantile.
#[derive(Clone, Debug, PartialEq)]
pub struct NetEq {
    width: Duration,
    buckets: [f64; NETEQ_BUCKETS],
    mass: f64,
    block_start: Option<Instant>,
    block_min: Duration,
    prev_min: Option<Duration>,
    quantile_bucket: usize,
}

impl NetEq {
    /// An empty histogram with buckets `width` wide (the period).
    #[must_use]
    pub fn new(width: Duration) -> Self {
        NetEq {
            width: Duration::from_nanos(width.as_nanos().max(1)),
            buckets: [0.0; NETEQ_BUCKETS],
            mass: 0.0,
            block_start: None,
            block_min: Duration::MAX,
            prev_min: None,
            quantile_bucket: 0,
        }
    }

    /// The smallest delay of the window, `None` before any sample.
    #[must_use]
    pub fn base(&self) -> Option<Duration> {
        self.block_start?;
        Some(
            self.prev_min
                .map_or(self.block_min, |p| p.min(self.block_min)),
        )
    }

    /// The bucket holding the 0.95 quantile.
    #[must_use]
    pub fn quantile_bucket(&self) -> usize {
        self.quantile_bucket
    }
}

impl TargetDelay for NetEq {
    fn observe(&mut self, sent_at: Instant, delay: Duration) {
        match self.block_start {
            Some(start) if sent_at < start + NETEQ_MIN_BLOCK => {
                self.block_min = self.block_min.min(delay);
            }
            Some(_) => {
                self.prev_min = Some(self.block_min);
                self.block_min = delay;
                self.block_start = Some(sent_at);
            }
            None => {
                self.block_min = delay;
                self.block_start = Some(sent_at);
            }
        }
        let base = self.base().unwrap_or(delay);
        let rel = (delay - base).as_nanos() / self.width.as_nanos();
        let bucket = usize::try_from(rel)
            .unwrap_or(usize::MAX)
            .min(NETEQ_BUCKETS - 1);
        for b in &mut self.buckets {
            *b *= NETEQ_FORGET;
        }
        if let Some(b) = self.buckets.get_mut(bucket) {
            *b += 1.0 - NETEQ_FORGET;
        }
        self.mass = self.mass * NETEQ_FORGET + (1.0 - NETEQ_FORGET);
        let goal = NETEQ_QUANTILE * self.mass;
        let mut sum = 0.0;
        self.quantile_bucket = NETEQ_BUCKETS - 1;
        for (i, b) in self.buckets.iter().enumerate() {
            sum += b;
            if sum >= goal {
                self.quantile_bucket = i;
                break;
            }
        }
    }

    fn target(&self) -> Option<Duration> {
        let upper = self.width * (self.quantile_bucket as u64 + 1);
        self.base().map(|b| b + upper)
    }
}

/// A fixed latency above the smallest one-way delay seen so far.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FixedAboveMin {
    latency: Duration,
    min: Option<Duration>,
}

impl FixedAboveMin {
    /// `latency` above the smallest delay to come.
    #[must_use]
    pub const fn new(latency: Duration) -> Self {
        FixedAboveMin { latency, min: None }
    }
}

impl TargetDelay for FixedAboveMin {
    fn observe(&mut self, _sent_at: Instant, delay: Duration) {
        self.min = Some(self.min.map_or(delay, |m| m.min(delay)));
    }

    fn target(&self) -> Option<Duration> {
        self.min.map(|m| m + self.latency)
    }
}

/// Buckets of the adaptive policy's histogram (log-linear, module docs):
/// delays above the floor up to 13.1 s, the last bucket holding any
/// longer one (a path that slow is an outage to report, not a delay to
/// hold; 1 024 buckets, up to 105 s, were 1.5 KiB more per endpoint).
pub const ADAPTIVE_BUCKETS: usize = 832;
/// The histogram's unit: 50 µs.
const UNIT_NS: u64 = 50_000;
/// Linear buckets below 128 units; then 64 per octave (1.6 % wide).
const LINEAR: u64 = 128;
const PER_OCTAVE: u64 = 64;
/// The histogram's window: [`ADAPTIVE_BLOCKS`] blocks of this (90–120 s),
/// or longer at long periods (see [`ADAPTIVE_BLOCK_MAX`]).
pub const ADAPTIVE_BLOCK: Duration = Duration::from_secs(30);
/// The longest block. At a long period the blocks grow so that the
/// window's full blocks hold [`ADAPTIVE_WINDOW_DELAYS`] delays, up to this
/// (a window of 15–20 minutes).
pub const ADAPTIVE_BLOCK_MAX: Duration = Duration::from_secs(300);
/// The delays the window's full blocks hold at least (below `1/ε` of them
/// the target keeps a warm-up margin of up to a period, which at the
/// paper's 200 ms would cost a whole tick of delay for good): `1/ε` at the
/// default ε = 0.1 %. 30 s blocks hold them at periods up to 90 ms.
pub const ADAPTIVE_WINDOW_DELAYS: u64 = 1000;
/// Blocks in the window.
pub const ADAPTIVE_BLOCKS: usize = 4;
/// The target may fall by this fraction of a period per sample (a skipped
/// sample at most every 10 ticks).
pub const SLEW_DOWN: f64 = 0.1;
/// The target may rise by this fraction of a period per sample (a repeated
/// tick at most every tick: a late sample costs more than a repeat).
pub const SLEW_UP: f64 = 1.0;

/// The bucket of a relative delay.
fn bucket_of(d: Duration) -> usize {
    let u = d.as_nanos() / UNIT_NS;
    let b = if u < LINEAR {
        u
    } else {
        let e = u64::from(63 - u.leading_zeros()); // ≥ 7
        let shift = e - 6;
        LINEAR + (shift - 1) * PER_OCTAVE + ((u >> shift) - PER_OCTAVE)
    };
    usize::try_from(b)
        .unwrap_or(usize::MAX)
        .min(ADAPTIVE_BUCKETS - 1)
}

/// The upper edge of bucket `b` (every delay in it is below).
fn bucket_upper(b: usize) -> Duration {
    let b = b as u64;
    let u = if b < LINEAR {
        b + 1
    } else {
        let shift = (b - LINEAR) / PER_OCTAVE + 1;
        let m = (b - LINEAR) % PER_OCTAVE + PER_OCTAVE;
        (m + 1) << shift
    };
    Duration::from_nanos(u.saturating_mul(UNIT_NS))
}

/// The timestamp-based target of [`Playout::Adaptive`]: the `1 − ε`
/// quantile of the delays above the floor (given by the endpoint, which
/// knows the clocks), over a sliding window of [`ADAPTIVE_BLOCKS`] ×
/// [`ADAPTIVE_BLOCK`], in a log-linear histogram (50 µs linear up to 6.4 ms,
/// then 64 buckets per octave, up to 13 s), in bounded memory. The target
/// is the upper edge of the smallest bucket with at most `⌊ε·n⌋` of the `n`
/// delays above it (with fewer than 1/ε delays, the largest), and moves
/// towards it by at most [`SLEW_UP`] or [`SLEW_DOWN`] periods per sample.
#[derive(Clone, Debug, PartialEq)]
pub struct Adaptive {
    period: f64,
    /// The quantum of the delay the endpoint holds (s), the least margin
    /// of the warm-up.
    quantum: f64,
    epsilon: f64,
    /// Counts per block in `u16` (6.5 KiB, not 13: the state is inline in
    /// every endpoint); a block ends early when it holds `u16::MAX` delays.
    /// The window's count of a bucket is summed over the blocks when the
    /// quantile's scan reaches it ([`Adaptive::held`]): a running total
    /// would be 4 KiB more in every endpoint, and put a link with both ends
    /// over 64 KiB now that this policy is the default.
    blocks: [[u16; ADAPTIVE_BUCKETS]; ADAPTIVE_BLOCKS],
    count: u64,
    block_counts: [u64; ADAPTIVE_BLOCKS],
    /// Samples lost per block (late or skipped, as the endpoint reports
    /// them), and in the window: the late rate spent.
    block_late: [u64; ADAPTIVE_BLOCKS],
    late: u64,
    /// Sum of the delays (s), per block and in the window.
    block_sums: [f64; ADAPTIVE_BLOCKS],
    sum: f64,
    current: usize,
    block_start: Option<Instant>,
    /// How long a block lasts ([`ADAPTIVE_BLOCK`] to [`ADAPTIVE_BLOCK_MAX`]).
    block: Duration,
    goal: Option<Duration>,
    applied: Option<f64>,
    /// One past the highest bucket holding a delay: the quantile's scan
    /// starts there, not at the histogram's top (the tail is short).
    top: usize,
}

impl Adaptive {
    /// An empty window for `period` and late rate `epsilon` (clamped to
    /// 10⁻⁶..0.5), for the default quantum of the delay.
    #[must_use]
    pub fn new(period: Duration, epsilon: f64) -> Self {
        Self::with_quantum(period, epsilon, crate::endpoint::delay_quantum(period))
    }

    /// [`Adaptive::new`] for a delay held in steps of `quantum` (the
    /// warm-up's least margin).
    #[must_use]
    pub fn with_quantum(period: Duration, epsilon: f64, quantum: Duration) -> Self {
        let epsilon = if epsilon.is_finite() { epsilon } else { 1e-3 };
        let epsilon = epsilon.clamp(1e-6, 0.5);
        // The full blocks: all but the current one.
        let block = (period * ADAPTIVE_WINDOW_DELAYS.div_ceil(ADAPTIVE_BLOCKS as u64 - 1))
            .clamp(ADAPTIVE_BLOCK, ADAPTIVE_BLOCK_MAX);
        Adaptive {
            period: period.as_secs_f64(),
            quantum: quantum.as_secs_f64(),
            epsilon,
            blocks: [[0; ADAPTIVE_BUCKETS]; ADAPTIVE_BLOCKS],
            count: 0,
            block_counts: [0; ADAPTIVE_BLOCKS],
            block_late: [0; ADAPTIVE_BLOCKS],
            late: 0,
            block_sums: [0.0; ADAPTIVE_BLOCKS],
            sum: 0.0,
            current: 0,
            block_start: None,
            block,
            goal: None,
            applied: None,
            top: 0,
        }
    }

    /// The target late rate.
    #[must_use]
    pub fn epsilon(&self) -> f64 {
        self.epsilon
    }

    /// The quantile the target moves towards.
    #[must_use]
    pub fn goal(&self) -> Option<Duration> {
        self.goal
    }

    /// Delays in the window.
    #[must_use]
    pub fn count(&self) -> u64 {
        self.count
    }

    /// A sample was lost: it came after its slot, or a fall of the delay
    /// skipped it. Counted in the current block, and leaves the window
    /// with it.
    pub fn note_late(&mut self) {
        if let Some(l) = self.block_late.get_mut(self.current) {
            *l += 1;
            self.late += 1;
        }
    }

    /// Whether `more` lost samples would take the window's past `ε` of its
    /// delays: the late rate is spent, and the endpoint holds its delay
    /// ahead of a silence instead of letting more go (see
    /// [`Playout::Adaptive`]). A window younger than a block counts a
    /// block's delays: else the first seconds' budget is a handful of
    /// samples, and the first stall or episode, held whole, keeps the
    /// delay high while it falls back (about 10 s for paris-newyork's
    /// 0.9 s).
    #[must_use]
    pub fn over_budget(&self, more: u64) -> bool {
        self.budget_used(more) > 1.0
    }

    /// The share of the late budget that `more` lost samples would bring
    /// the window to: 1 is `ε` of its delays (see
    /// [`Adaptive::over_budget`]).
    #[must_use]
    pub fn budget_used(&self, more: u64) -> f64 {
        let block = self.block.as_secs_f64() / self.period;
        (self.late + more) as f64 / (self.epsilon * (self.count as f64).max(block))
    }

    fn rotate(&mut self, sent_at: Instant) {
        let start = *self.block_start.get_or_insert(sent_at);
        let full = self
            .block_counts
            .get(self.current)
            .is_some_and(|&n| n >= u64::from(u16::MAX));
        if sent_at < start + self.block && !full {
            return;
        }
        self.block_start = Some(sent_at);
        self.current = (self.current + 1) % ADAPTIVE_BLOCKS;
        if let (Some(old), Some(n), Some(sum)) = (
            self.blocks.get_mut(self.current),
            self.block_counts.get_mut(self.current),
            self.block_sums.get_mut(self.current),
        ) {
            *old = [0; ADAPTIVE_BUCKETS];
            self.count = self.count.saturating_sub(*n);
            *n = 0;
            if let Some(l) = self.block_late.get_mut(self.current) {
                self.late = self.late.saturating_sub(*l);
                *l = 0;
            }
            self.sum = if self.count == 0 {
                0.0
            } else {
                self.sum - *sum
            };
            *sum = 0.0;
        }
        self.lower_top();
    }

    /// Brings [`Adaptive::top`] down past the buckets emptied.
    fn lower_top(&mut self) {
        while self.top > 0 && self.held(self.top - 1) == 0 {
            self.top -= 1;
        }
    }

    /// The window's delays in bucket `b`.
    fn held(&self, b: usize) -> u32 {
        self.blocks
            .iter()
            .map(|block| u32::from(block.get(b).copied().unwrap_or(0)))
            .sum()
    }

    /// While the window holds fewer than `1/ε` delays its quantile is only
    /// their maximum, which later delays pass (the next of `n` draws is the
    /// largest with odds `1/(n+1)`): the goal extrapolates the tail as an
    /// exponential one, `s·ln(1/(n·ε))` above the maximum with the scale
    /// `s = (max − mean)/ln n`, and at least `(1 − n·ε)·q`, `q` the delay's
    /// quantum (the period up to 20 ms). Both vanish at `n = 1/ε`. (With a
    /// whole period at `T = 200 ms` the warm-up cost up to 200 ms each way
    /// for its 200 s.)
    fn warmup_margin(&self, q: Duration) -> Duration {
        let n = self.count as f64;
        let filled = self.epsilon * n;
        if filled >= 1.0 || self.count == 0 {
            return Duration::ZERO;
        }
        let mean = self.sum / n;
        let scale = (q.as_secs_f64() - mean).max(0.0) / libm::log(n.max(2.0));
        let tail = scale * libm::log(1.0 / filled);
        Duration::from_secs_f64(tail.max((1.0 - filled) * self.quantum))
    }

    /// The floor the delays are measured above moved by `by`, up if
    /// `rose` (a level shift of the path, found some seconds after it
    /// happened): every delay in the window, and the target, move the other
    /// way, so that the delays seen since the shift, measured above the old
    /// floor, are not counted above the new one too. Those from before the
    /// shift that fall under the new floor count as no delay above it.
    pub fn rebase(&mut self, by: Duration, rose: bool) {
        let by_s = by.as_secs_f64();
        let moved = |d: f64| if rose { (d - by_s).max(0.0) } else { d + by_s };
        for (block, (n, sum)) in self
            .blocks
            .iter_mut()
            .zip(self.block_counts.iter().zip(self.block_sums.iter_mut()))
        {
            let mut next = [0u16; ADAPTIVE_BUCKETS];
            for (b, &c) in block.iter().enumerate() {
                if c == 0 {
                    continue;
                }
                let lower = b.checked_sub(1).map_or(Duration::ZERO, bucket_upper);
                let mid = (lower + bucket_upper(b)).as_secs_f64() / 2.0;
                if let Some(cell) = next.get_mut(bucket_of(Duration::from_secs_f64(moved(mid)))) {
                    *cell = cell.saturating_add(c);
                }
            }
            *block = next;
            let signed = if rose { -by_s } else { by_s };
            *sum = (*sum + signed * *n as f64).max(0.0);
        }
        self.sum = self.block_sums.iter().sum();
        self.top = ADAPTIVE_BUCKETS;
        self.lower_top();
        self.applied = self.applied.map(moved);
        self.goal = self.goal_now();
    }

    /// The quantile plus the warm-up's margin, moved by the drift of the
    /// level: how far the mean of the last block's length of delays is
    /// from the window's mean. The window lags a level that drifts (on the
    /// paper's slow sines the late samples came in clusters while a sine
    /// rose); the quantile of a window is that of its average level plus
    /// the noise's, so it moves by the level's drift.
    fn goal_now(&self) -> Option<Duration> {
        let q = self.quantile()?;
        let goal = (q + self.warmup_margin(q)).as_secs_f64() + self.drift();
        Some(Duration::from_secs_f64(goal.max(0.0)))
    }

    /// The mean of the last block's length of delays (the current block,
    /// and the share of the previous one a sliding block would still
    /// hold) less the window's mean (s).
    fn drift(&self) -> f64 {
        let prev = (self.current + ADAPTIVE_BLOCKS - 1) % ADAPTIVE_BLOCKS;
        let (Some(&n), Some(&sum), Some(&np), Some(&sp)) = (
            self.block_counts.get(self.current),
            self.block_sums.get(self.current),
            self.block_counts.get(prev),
            self.block_sums.get(prev),
        ) else {
            return 0.0;
        };
        if self.count == 0 || n == 0 {
            return 0.0;
        }
        let w = if np > n {
            1.0 - n as f64 / np as f64
        } else {
            0.0
        };
        let recent = (sum + sp * w) / (n as f64 + np as f64 * w);
        recent - self.sum / self.count as f64
    }

    fn quantile(&self) -> Option<Duration> {
        self.quantile_at(self.epsilon)
    }

    /// The part of the goal no delay measured asks for: the warm-up margin
    /// while the window holds fewer than `1/ε` delays, zero after. The
    /// endpoint raises its delay only when the measured part of the goal
    /// passes it: a margin that shrinks as the window fills must not make
    /// the delay rise by itself (each rise repeats a sample).
    #[must_use]
    pub fn margin(&self) -> Duration {
        self.quantile()
            .map_or(Duration::ZERO, |q| self.warmup_margin(q))
    }

    /// What one late sample fewer costs through the quantile: the delay
    /// added to every sample released (s, summed) for the quantile to let
    /// one fewer through, `(1 − ε)/f`, `f` the density of the delays at the
    /// quantile, taken over the window's quantiles at `ε` and `ε/2`. The
    /// endpoint holds a silence while holding it costs less per sample (see
    /// [`Playout::Adaptive`]); zero while the window is empty.
    #[must_use]
    pub fn sample_cost(&self) -> Duration {
        let half = self.epsilon / 2.0;
        let (Some(q), Some(q2)) = (self.quantile_at(self.epsilon), self.quantile_at(half)) else {
            return Duration::ZERO;
        };
        let cost = q2.saturating_sub(q).as_secs_f64() * (1.0 - self.epsilon) / half;
        Duration::from_secs_f64(cost)
    }

    fn quantile_at(&self, epsilon: f64) -> Option<Duration> {
        let allowed = (epsilon * self.count as f64) as u64;
        let mut above = 0u64;
        for b in (0..self.top.min(ADAPTIVE_BUCKETS)).rev() {
            above += u64::from(self.held(b));
            if above > allowed {
                return Some(bucket_upper(b));
            }
        }
        None
    }
}

impl TargetDelay for Adaptive {
    /// `delay` is the delay above the floor.
    fn observe(&mut self, sent_at: Instant, delay: Duration) {
        self.rotate(sent_at);
        let b = bucket_of(delay);
        if let (Some(block), Some(n), Some(sum)) = (
            self.blocks.get_mut(self.current),
            self.block_counts.get_mut(self.current),
            self.block_sums.get_mut(self.current),
        ) && let Some(c) = block.get_mut(b)
        {
            *c = c.saturating_add(1);
            self.top = self.top.max(b + 1);
            *n += 1;
            *sum += delay.as_secs_f64();
            self.count += 1;
            self.sum += delay.as_secs_f64();
        }
        self.goal = self.goal_now();
        let Some(goal) = self.goal.map(Duration::as_secs_f64) else {
            return;
        };
        let next = match self.applied {
            None => goal,
            Some(a) => goal.clamp(a - SLEW_DOWN * self.period, a + SLEW_UP * self.period),
        };
        self.applied = Some(next.max(0.0));
    }

    fn target(&self) -> Option<Duration> {
        self.applied.map(Duration::from_secs_f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(x: u64) -> Duration {
        Duration::from_millis(x)
    }

    fn feed(p: &mut impl TargetDelay, delays_ms: &[u64], period_ms: u64) {
        for (k, &d) in delays_ms.iter().enumerate() {
            p.observe(Instant::from_millis(k as u64 * period_ms), ms(d));
        }
    }

    fn close(a: Duration, b_s: f64) -> bool {
        (a.as_secs_f64() - b_s).abs() < 1e-9
    }

    #[test]
    fn ramjee1_starts_as_running_mean() {
        let mut p = Ramjee1::new();
        assert_eq!(p.target(), None);
        feed(&mut p, &[100, 200], 20);
        // i=1: d=0.1, v=0; i=2 (weight 1/2): d=0.15, v=0.5·0 + 0.5·|0.15−0.2| = 0.025.
        let (d, v) = p.estimates();
        assert!((d - 0.15).abs() < 1e-12 && (v - 0.025).abs() < 1e-12);
        assert!(close(p.target().unwrap(), 0.25));
    }

    #[test]
    fn ramjee1_uses_alpha_once_warm() {
        let mut p = Ramjee1::new();
        feed(&mut p, &[50; 600], 20);
        // Constant delays: d̂ = 50 ms, v̂ = 0 exactly.
        assert!(close(p.target().unwrap(), 0.05));
        p.observe(Instant::from_millis(100_000), ms(150));
        let a = RAMJEE_ALPHA;
        let d = a * 0.05 + (1.0 - a) * 0.15;
        let v = (1.0 - a) * (d - 0.15f64).abs();
        assert!(close(p.target().unwrap(), d + 4.0 * v));
    }

    #[test]
    fn ramjee4_detects_a_spike_and_follows_it() {
        let mut p = Ramjee4::new();
        feed(&mut p, &[50, 50, 50], 20);
        assert!(close(p.target().unwrap(), 0.05));
        // A jump of 300 ms > 2·0 + 100 ms: spike mode, d̂ follows one for one.
        p.observe(Instant::from_millis(60), ms(350));
        assert!(p.in_spike());
        let (d, v) = p.estimates();
        assert!((d - 0.35).abs() < 1e-12);
        assert!(v.abs() < 1e-12);
        // Falling at 20 ms per sample: var = 0/2 + |2·330 − 350 − 50|/8 = 32.5 ms.
        p.observe(Instant::from_millis(80), ms(330));
        assert!(p.in_spike());
        let (d, _) = p.estimates();
        assert!((d - 0.33).abs() < 1e-12);
        // Flat again: var = 16.25 + |2·330 − 330 − 350|/8 = 18.75 ms; then
        // 9.375 + 0 = 9.375 ms; then 4.6875 ≤ 7.875 → normal, no update.
        p.observe(Instant::from_millis(100), ms(330));
        p.observe(Instant::from_millis(120), ms(330));
        assert!(p.in_spike());
        p.observe(Instant::from_millis(140), ms(330));
        assert!(!p.in_spike());
        let (d, _) = p.estimates();
        assert!((d - 0.33).abs() < 1e-12);
    }

    #[test]
    fn ramjee4_small_changes_average_by_an_eighth() {
        let mut p = Ramjee4::new();
        feed(&mut p, &[80, 160], 20);
        // 80 ms jump < 100 ms: normal. d = 80 + 80/8 = 90, v = 70/8 = 8.75.
        assert!(!p.in_spike());
        assert!(close(p.target().unwrap(), 0.090 + 4.0 * 0.00875));
    }

    #[test]
    fn neteq_quantile_of_relative_delays() {
        let mut p = NetEq::new(ms(20));
        // 29 samples at the minimum, one 45 ms above (bucket 2) at k = 5:
        // after 24 more it weighs 0.017·0.983^24 ≈ 0.0113 of a mass
        // 1 − 0.983^30 ≈ 0.402, 2.8 % < 5 %: the quantile is bucket 0.
        let mut delays = [100u64; 30];
        delays[5] = 145;
        feed(&mut p, &delays, 20);
        assert_eq!(p.base(), Some(ms(100)));
        assert_eq!(p.quantile_bucket(), 0);
        assert_eq!(p.target(), Some(ms(120)));
        // A second one: (0.017 + 0.0111) / 0.412 ≈ 6.8 % above bucket 0.
        p.observe(Instant::from_millis(600), ms(145));
        assert_eq!(p.quantile_bucket(), 2);
        assert_eq!(p.target(), Some(ms(160)));
    }

    #[test]
    fn neteq_minimum_forgets_after_two_blocks() {
        let mut p = NetEq::new(ms(20));
        p.observe(Instant::from_millis(0_000), ms(50));
        p.observe(Instant::from_millis(1_000), ms(80));
        p.observe(Instant::from_millis(2_000), ms(80)); // new block, previous min 50
        assert_eq!(p.base(), Some(ms(50)));
        p.observe(Instant::from_millis(4_000), ms(80)); // the 50 ms block is gone
        assert_eq!(p.base(), Some(ms(80)));
    }

    #[test]
    fn fixed_above_min_tracks_the_minimum() {
        let mut p = FixedAboveMin::new(ms(200));
        assert_eq!(p.target(), None);
        feed(&mut p, &[70, 40, 90], 20);
        assert_eq!(p.target(), Some(ms(240)));
    }

    #[test]
    fn adaptive_buckets_cover_their_delays() {
        for us in [
            0u64, 49, 50, 6_399, 6_400, 6_450, 99_999, 1_234_567, 13_000_000,
        ] {
            let d = Duration::from_micros(us);
            let b = bucket_of(d);
            assert!(d < bucket_upper(b), "{us} µs in bucket {b}");
            if b > 0 {
                assert!(d >= bucket_upper(b - 1), "{us} µs above bucket {b}");
            }
        }
        // 64 buckets per octave: at most 1.6 % wide above 6.4 ms.
        let b = bucket_of(ms(500));
        let width = bucket_upper(b) - bucket_upper(b - 1);
        assert!(width.as_secs_f64() <= 0.016 * 0.5, "{width:?}");
        // The last bucket ends at 13.1 s and holds any longer delay.
        assert_eq!(
            bucket_upper(ADAPTIVE_BUCKETS - 1),
            Duration::from_micros(13_107_200)
        );
        assert_eq!(bucket_of(Duration::from_secs(14)), ADAPTIVE_BUCKETS - 1);
        assert_eq!(bucket_of(Duration::from_secs(1000)), ADAPTIVE_BUCKETS - 1);
    }

    #[test]
    fn adaptive_quantile_window_and_slew() {
        let mut p = Adaptive::new(ms(20), 0.01);
        assert_eq!(p.target(), None);
        // 1000 delays: 989 at 10 ms, 11 at 90 ms; ε·n = 10 may be above:
        // the quantile is 90 ms's bucket.
        for k in 0..1000u64 {
            let d = if k % 90 == 5 { 90 } else { 10 };
            p.observe(Instant::from_millis(k * 20), ms(d));
        }
        let q = p.goal().unwrap();
        assert!(q > ms(90) && q < ms(92), "{q:?}");
        // Only small delays for the next 2 minutes: the window forgets the
        // large ones, and the target falls at most 2 ms (0.1·T) per sample.
        let before = p.target().unwrap();
        p.observe(Instant::from_millis(20_000), ms(10));
        let after = p.target().unwrap();
        assert!(before - after <= ms(2) + Duration::from_nanos(1));
        for k in 1..7000u64 {
            p.observe(Instant::from_millis(20_000 + k * 20), ms(10));
        }
        let q = p.goal().unwrap();
        assert!(q > ms(10) && q <= ms(11), "{q:?}");
        assert_eq!(p.target(), Some(q));
        // A rise is followed by up to one period per sample.
        p.observe(Instant::from_millis(200_000), ms(500));
        p.observe(Instant::from_millis(200_020), ms(500));
        assert!(p.target().unwrap() <= q + ms(40) + Duration::from_nanos(2));
    }

    #[test]
    fn adaptive_quantile_scans_from_the_highest_delay_held() {
        // The scan starts at the highest bucket in the window: the same
        // quantile as a scan of the whole histogram, as blocks with the
        // largest delays leave the window and a level shift moves them.
        let full_scan = |a: &Adaptive| {
            let allowed = (a.epsilon * a.count as f64) as u64;
            let mut above = 0u64;
            for b in (0..ADAPTIVE_BUCKETS).rev() {
                above += u64::from(a.held(b));
                if above > allowed {
                    return Some(bucket_upper(b));
                }
            }
            None
        };
        let mut a = Adaptive::new(ms(20), 1e-2);
        let mut state = 7u64;
        for k in 0..40_000u64 {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1);
            // Large delays only in the first 3 minutes, then small ones.
            let scale = if k < 9_000 { 2_000 } else { 50 };
            let d = ms((state >> 33) % scale);
            a.observe(Instant::from_millis(20 * k), d);
            if k % 97 == 0 {
                assert_eq!(a.quantile(), full_scan(&a), "sample {k}");
            }
            if k == 20_000 {
                a.rebase(ms(30), true);
                assert_eq!(a.quantile(), full_scan(&a));
                a.rebase(ms(500), false);
                assert_eq!(a.quantile(), full_scan(&a));
            }
        }
        // The large delays have left the window: the scan starts low.
        assert!(a.top < bucket_of(ms(1_000)), "{}", a.top);
    }

    #[test]
    fn adaptive_late_budget_is_epsilon_of_the_window_and_leaves_with_it() {
        let mut a = Adaptive::new(ms(20), 1e-2);
        // 30 s blocks at 20 ms: 1 500 delays each.
        for k in 0..3_000u64 {
            a.observe(Instant::from_millis(20 * k), ms(5));
        }
        // ε·n = 30: 30 lost samples are within it, 31 are not.
        assert!(!a.over_budget(30) && a.over_budget(31));
        for _ in 0..25 {
            a.note_late();
        }
        assert!(!a.over_budget(5) && a.over_budget(6));
        // They were counted in the second block; when it is reused (4
        // blocks, three rotations on) they leave the window with its delays.
        for k in 3_000..6_000u64 {
            a.observe(Instant::from_millis(20 * k), ms(5));
        }
        assert!(!a.over_budget(35) && a.over_budget(36), "{}", a.late);
        for k in 6_000..7_501u64 {
            a.observe(Instant::from_millis(20 * k), ms(5));
        }
        assert_eq!(a.count(), 4_500 + 1);
        assert!(!a.over_budget(45) && a.over_budget(46), "{}", a.late);
    }

    #[test]
    fn adaptive_late_budget_counts_a_block_while_the_window_is_younger() {
        let mut a = Adaptive::new(ms(20), 1e-2);
        // No delay yet: a 30 s block's 1 500 at 20 ms, ε·1 500 = 15.
        assert!(!a.over_budget(15) && a.over_budget(16));
        for k in 0..100u64 {
            a.observe(Instant::from_millis(20 * k), ms(5));
        }
        assert!(!a.over_budget(15) && a.over_budget(16));
        a.note_late();
        assert!((a.budget_used(0) - 1.0 / 15.0).abs() < 1e-12);
        assert!((a.budget_used(14) - 1.0).abs() < 1e-12);
        // Past a block's delays, the window's own count.
        for k in 100..2_000u64 {
            a.observe(Instant::from_millis(20 * k), ms(5));
        }
        assert!(!a.over_budget(19) && a.over_budget(20));
    }

    #[test]
    fn adaptive_sample_cost_is_the_delay_the_quantile_adds_per_sample_kept() {
        let mut a = Adaptive::new(ms(20), 0.1);
        assert_eq!(a.sample_cost(), Duration::ZERO, "an empty window");
        // 2 000 delays spread evenly over 0–100 ms: a density of 10 per
        // second of delay. One sample fewer late takes the quantile up by
        // 1/(10·n) s, for the n·(1 − ε) released: 90 ms in all.
        for k in 0..2_000u64 {
            a.observe(Instant::from_millis(20 * k), Duration::from_micros(k * 50));
        }
        // Within the buckets' width (about 1 ms here) on the 5 ms between
        // the two quantiles.
        let c = a.sample_cost().as_secs_f64();
        assert!((c - 0.090).abs() < 0.009, "{c}");
        // Equal delays: the quantile saves no sample at any price short of
        // all of them (a zero difference), and a held silence is then worth
        // only what it costs nothing to hold.
        let mut b = Adaptive::new(ms(20), 0.1);
        for k in 0..2_000u64 {
            b.observe(Instant::from_millis(20 * k), ms(30));
        }
        assert_eq!(b.sample_cost(), Duration::ZERO);
    }

    #[test]
    fn adaptive_rebase_moves_the_window_and_the_target() {
        // 1000 delays: 989 at 10 ms, 11 at 160 ms (measured above a floor
        // 150 ms too low). The floor rises by 150 ms: they are 10 ms above
        // it, and the others fall under it.
        let mut p = Adaptive::new(ms(20), 0.01);
        for k in 0..1000u64 {
            let d = if (500..511).contains(&k) { 160 } else { 10 };
            p.observe(Instant::from_millis(k * 20), ms(d));
        }
        let (goal, target, count) = (p.goal().unwrap(), p.target().unwrap(), p.count());
        assert!(goal > ms(160) && goal < ms(163), "{goal:?}");
        p.rebase(ms(150), true);
        assert_eq!(p.count(), count, "no delay lost");
        let q = p.goal().unwrap();
        assert!(q > ms(10) && q < ms(12), "{q:?}");
        assert!(
            (target.as_secs_f64() - 0.150 - p.target().unwrap().as_secs_f64()).abs() < 1e-9,
            "the target moves with the floor: {target:?} then {:?}",
            p.target()
        );
        // And back down: every delay 150 ms higher above the lower floor.
        p.rebase(ms(150), false);
        let q = p.goal().unwrap();
        assert!(q > ms(159) && q < ms(163), "{q:?}");
    }

    #[test]
    fn adaptive_blocks_end_early_when_full() {
        // 200 000 delays in 20 s (a 100 µs period): more than a `u16` block
        // holds. Blocks end at 65 535 delays, the window keeps the last
        // three or four blocks, and the counts stay those of the window.
        let mut p = Adaptive::new(Duration::from_micros(100), 0.001);
        for k in 0..200_000u64 {
            let d = if k % 500 == 7 { ms(30) } else { ms(2) };
            p.observe(Instant::from_nanos(k * 100_000), d);
        }
        let total: u64 = (0..ADAPTIVE_BUCKETS).map(|b| u64::from(p.held(b))).sum();
        assert_eq!(total, p.count());
        assert!(p.count() > 3 * 65_535 - 1, "{}", p.count());
        // 0.2 % of the delays are 30 ms: the quantile is just above 30 ms.
        let q = p.goal().unwrap();
        assert!(q > ms(30) && q < ms(31), "{q:?}");
    }

    #[test]
    fn names_round_trip() {
        for p in [
            Playout::Fifo,
            Playout::Ramjee1,
            Playout::Ramjee4,
            Playout::NetEq,
            Playout::FixedAboveMin { latency: ms(200) },
            Playout::Constant { delay: ms(120) },
            Playout::ADAPTIVE,
            adaptive(5000, None),
            adaptive(7000, None),
            adaptive(1, None),
            adaptive(123_456, None),
            adaptive(1000, Some(ms(10))),
            adaptive(5000, Some(Duration::from_micros(2500))),
        ] {
            let name = std::format!("{p}");
            assert_eq!(name.parse::<Playout>(), Ok(p), "{name}");
        }
        for (ppm, name) in [
            (7000, "adaptive:0.7"),
            (1, "adaptive:0.0001"),
            (120_500, "adaptive:12.05"),
        ] {
            assert_eq!(std::format!("{}", adaptive(ppm, None)), name);
        }
        assert_eq!(
            std::format!("{}", adaptive(1000, Some(ms(10)))),
            "adaptive:0.1:10"
        );
        for (given, name) in [
            ("constant:124", "constant:124"),
            ("constant:0.1", "constant:0.1"),
            ("fixed:12.5", "fixed:12.5"),
            ("constant:0.000001", "constant:0.000001"),
        ] {
            let p: Playout = given.parse().unwrap();
            assert_eq!(std::format!("{p}"), name);
        }
        assert_eq!(
            "fixed".parse::<Playout>(),
            Ok(Playout::FixedAboveMin {
                latency: DEFAULT_FIXED_LATENCY
            })
        );
        assert!("constant:-1".parse::<Playout>().is_err());
        assert!("oracle".parse::<Playout>().is_err());
        assert_eq!("adaptive:0.5".parse::<Playout>(), Ok(adaptive(5000, None)));
        assert!("adaptive:0".parse::<Playout>().is_err());
        assert!("adaptive:100".parse::<Playout>().is_err());
        assert_eq!(
            "adaptive:0.5:7.5".parse::<Playout>(),
            Ok(adaptive(5000, Some(Duration::from_micros(7500))))
        );
        // The quantum: milliseconds from 1 to 10 000, and a late rate too.
        for bad in [
            "adaptive:0.1:0.5",
            "adaptive:0.1:0",
            "adaptive:0.1:-10",
            "adaptive:0.1:10001",
            "adaptive:0.1:nan",
            "adaptive:0.1:",
            "adaptive::10",
            "adaptive:0.1:10:1",
        ] {
            assert!(bad.parse::<Playout>().is_err(), "{bad}");
        }
        // Each error says what was wrong, then what is valid.
        let says = |name: &str| std::format!("{}", name.parse::<Playout>().unwrap_err());
        assert!(says("lifo").starts_with("unknown playout policy; valid: fifo"));
        assert!("lifo".parse::<Playout>().unwrap_err().is_unknown_name());
        assert!(
            !"adaptive:0"
                .parse::<Playout>()
                .unwrap_err()
                .is_unknown_name()
        );
        assert!(says("constant:-1").starts_with("fixed:MS and constant:MS take milliseconds"));
        assert!(says("adaptive:100").starts_with("adaptive:PERCENT takes the target late rate"));
        for bad in ["adaptive:0.1:0.5", "adaptive:0.1:x", "adaptive:0.1:10:1"] {
            let m = says(bad);
            assert!(
                m.starts_with("adaptive:PERCENT:QUANTUM_MS takes the step"),
                "{m}"
            );
            assert!(m.contains("; valid: fifo"), "{m}");
        }
    }

    fn adaptive(epsilon_ppm: u32, quantum: Option<Duration>) -> Playout {
        Playout::Adaptive {
            epsilon_ppm,
            quantum,
        }
    }

    #[test]
    fn the_quantum_asked_for_divides_the_period() {
        use crate::endpoint::delay_quantum_for;
        // Defaults: the period up to 20 ms, then T/⌈T/20 ms⌉.
        assert_eq!(Playout::ADAPTIVE.quantum(ms(20)), Some(ms(20)));
        assert_eq!(Playout::ADAPTIVE.quantum(ms(10)), Some(ms(10)));
        assert_eq!(Playout::ADAPTIVE.quantum(ms(200)), Some(ms(20)));
        assert_eq!(Playout::Fifo.quantum(ms(20)), None);
        // Asked: the period cut in the fewest equal parts no longer than that.
        assert_eq!(adaptive(1000, Some(ms(10))).quantum(ms(20)), Some(ms(10)));
        assert_eq!(
            adaptive(1000, Some(ms(8))).quantum(ms(20)),
            Some(Duration::from_nanos(6_666_666))
        );
        assert_eq!(adaptive(1000, Some(ms(50))).quantum(ms(20)), Some(ms(20)));
        assert_eq!(delay_quantum_for(ms(50), Some(ms(10))), ms(10));
        assert_eq!(
            delay_quantum_for(ms(50), None),
            Duration::from_nanos(16_666_666)
        );
        // The target's warm-up floor is a quantum, the one asked for.
        let Some(Target::Adaptive(a)) = adaptive(1000, Some(ms(5))).target(ms(20)) else {
            panic!("not adaptive");
        };
        assert_eq!(a, Adaptive::with_quantum(ms(20), 1e-3, ms(5)));
        assert_ne!(a, Adaptive::new(ms(20), 1e-3));
    }
}
