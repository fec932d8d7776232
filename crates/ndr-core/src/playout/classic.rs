//! The classic target-delay policies the adaptive one is compared with:
//! Ramjee et al.'s algorithms 1 and 4, a NetEQ-like quantile of relative
//! delays, and a fixed latency above the smallest delay seen.

use core::fmt;

use super::policy::{NoRoom, Setup};
use super::registry::{Entry, UnknownPlayout, bare, millis, write_millis};
use super::target::{OnTicks, TargetDelay};
use crate::time::{Duration, Instant};

fn mean_plus_4dev(d: f64, v: f64) -> Duration {
    Duration::from_secs_f64(d + 4.0 * v)
}

/// Ramjee et al. (1994) algorithm 1's weight.
pub(super) const RAMJEE_ALPHA: f64 = 0.998002;

/// Ramjee et al. (1994), algorithm 1:
/// `d̂ ← α·d̂ + (1−α)·n`, `v̂ ← α·v̂ + (1−α)·|d̂ − n|`, `D = d̂ + 4·v̂`.
///
/// Until `1/(1−α)` ≈ 500 samples are seen, the weight is `1 − 1/i` at the
/// `i`-th sample (the running mean), so that the first samples do not start
/// the averages from zero.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct Ramjee1 {
    d: f64,
    v: f64,
    seen: u64,
}

impl Ramjee1 {
    /// No sample seen yet.
    #[must_use]
    pub(crate) const fn new() -> Self {
        Ramjee1 {
            d: 0.0,
            v: 0.0,
            seen: 0,
        }
    }

    #[cfg(test)]
    /// `(d̂, v̂)` in seconds.
    #[must_use]
    pub(crate) fn estimates(&self) -> (f64, f64) {
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
pub(super) const SPIKE_ENTER: f64 = 0.100;
/// Algorithm 4 leaves a spike when `var ≤ 63` units (7.875 ms at 8 kHz).
pub(super) const SPIKE_EXIT: f64 = 63.0 / 8000.0;

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
pub(crate) struct Ramjee4 {
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
    pub(crate) const fn new() -> Self {
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

    #[cfg(test)]
    /// Whether the policy is in spike mode.
    #[must_use]
    pub(crate) fn in_spike(&self) -> bool {
        self.spike
    }

    #[cfg(test)]
    /// `(d̂, v̂)` in seconds.
    #[must_use]
    pub(crate) fn estimates(&self) -> (f64, f64) {
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
pub(super) const NETEQ_BUCKETS: usize = 256;
/// The histogram's forget factor (WebRTC NetEQ's 0.983).
pub(super) const NETEQ_FORGET: f64 = 0.983;
/// The quantile of relative delays the target covers.
pub(super) const NETEQ_QUANTILE: f64 = 0.95;
/// The smallest delay is taken over the current and the previous block of
/// this length (a window of 2 to 4 s, NetEQ's 2 s history).
pub(super) const NETEQ_MIN_BLOCK: Duration = Duration::from_secs(2);

/// A NetEQ-like target: relative delay = delay − smallest delay of the last
/// 2–4 s; a histogram of relative delays with bucket width `T`, where each
/// sample multiplies every bucket by 0.983 and adds 0.017 to its own; the
/// target is that smallest delay plus the upper edge of the bucket holding
/// the 0.95 quantile.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct NetEq {
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
    pub(crate) fn new(width: Duration) -> Self {
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
    pub(crate) fn base(&self) -> Option<Duration> {
        self.block_start?;
        Some(
            self.prev_min
                .map_or(self.block_min, |p| p.min(self.block_min)),
        )
    }

    #[cfg(test)]
    /// The bucket holding the 0.95 quantile.
    #[must_use]
    pub(crate) fn quantile_bucket(&self) -> usize {
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
pub(crate) struct FixedAboveMin {
    latency: Duration,
    min: Option<Duration>,
}

impl FixedAboveMin {
    /// `latency` above the smallest delay to come.
    #[must_use]
    pub(crate) const fn new(latency: Duration) -> Self {
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

/// A constant target delay.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Constant(pub Duration);

impl TargetDelay for Constant {
    fn observe(&mut self, _sent_at: Instant, _delay: Duration) {}

    fn target(&self) -> Option<Duration> {
        Some(self.0)
    }
}

/// GStreamer rtpjitterbuffer's default latency.
pub(super) const DEFAULT_FIXED_LATENCY: Duration = Duration::from_millis(200);

const MILLIS: &str = "fixed:MS and constant:MS take milliseconds, finite and not negative";

impl Entry for OnTicks<Ramjee1> {
    type Fields = ();
    const NAME: &'static str = "ramjee-1";
    const SYNTAX: &'static str = "ramjee-1";

    fn parse(value: Option<&str>) -> Result<(), UnknownPlayout> {
        bare(value)
    }

    fn build((): (), setup: &Setup) -> Result<Self, NoRoom> {
        Ok(OnTicks::new(Ramjee1::new(), setup))
    }
}

impl Entry for OnTicks<Ramjee4> {
    type Fields = ();
    const NAME: &'static str = "ramjee-4";
    const SYNTAX: &'static str = "ramjee-4";

    fn parse(value: Option<&str>) -> Result<(), UnknownPlayout> {
        bare(value)
    }

    fn build((): (), setup: &Setup) -> Result<Self, NoRoom> {
        Ok(OnTicks::new(Ramjee4::new(), setup))
    }
}

impl Entry for OnTicks<NetEq> {
    type Fields = ();
    const NAME: &'static str = "neteq";
    const SYNTAX: &'static str = "neteq";

    fn parse(value: Option<&str>) -> Result<(), UnknownPlayout> {
        bare(value)
    }

    fn build((): (), setup: &Setup) -> Result<Self, NoRoom> {
        Ok(OnTicks::new(NetEq::new(setup.period), setup))
    }
}

impl Entry for OnTicks<FixedAboveMin> {
    type Fields = (Duration,);
    const NAME: &'static str = "fixed";
    const SYNTAX: &'static str = "fixed[:MS]";

    fn parse(value: Option<&str>) -> Result<(Duration,), UnknownPlayout> {
        match value {
            None => Ok((DEFAULT_FIXED_LATENCY,)),
            Some(v) => millis(v).map(|d| (d,)).ok_or(UnknownPlayout::value(MILLIS)),
        }
    }

    fn write_value(&(latency,): &(Duration,), f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(":")?;
        write_millis(f, latency)
    }

    fn build((latency,): (Duration,), setup: &Setup) -> Result<Self, NoRoom> {
        Ok(OnTicks::new(FixedAboveMin::new(latency), setup))
    }
}

impl Entry for OnTicks<Constant> {
    type Fields = (Duration,);
    const NAME: &'static str = "constant";
    const SYNTAX: &'static str = "constant:MS";
    const VALUES: &'static str = "milliseconds, finite, not negative";

    fn parse(value: Option<&str>) -> Result<(Duration,), UnknownPlayout> {
        match value {
            None => Err(UnknownPlayout::NAME),
            Some(v) => millis(v).map(|d| (d,)).ok_or(UnknownPlayout::value(MILLIS)),
        }
    }

    fn write_value(&(delay,): &(Duration,), f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(":")?;
        write_millis(f, delay)
    }

    fn build((delay,): (Duration,), setup: &Setup) -> Result<Self, NoRoom> {
        Ok(OnTicks::new(Constant(delay), setup))
    }
}
