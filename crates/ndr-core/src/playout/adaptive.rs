//! The adaptive policy's target: the `1 − ε` quantile of the one-way
//! delays above the floor of the clock estimate, over a window of blocks
//! (its release schedule is [`schedule`](super::schedule)).

use core::fmt;

use super::target::TargetDelay;
use crate::time::{Duration, Instant};

/// Where a [`Builtin`](super::Builtin) keeps [`Playout::Adaptive`](super::Playout::Adaptive)'s state: [`Adaptive`]
/// itself (about 7 KiB, the default), or [`NoAdaptive`], nothing, for an
/// endpoint that never runs that policy and should not carry its histogram.
pub trait AdaptiveSlot: TargetDelay + Clone + fmt::Debug + Send + 'static {
    /// The state for `period`, late rate `epsilon` and the delay's
    /// `quantum`, the dead band of the delay; `None` if this slot holds none.
    fn build(period: Duration, epsilon: f64, quantum: Duration) -> Option<Self>;
    /// The floor the delays are measured above moved by `by` (up if
    /// `rose`): see `Adaptive::rebase`.
    fn rebase(&mut self, by: Duration, rose: bool);
    /// A sample was lost: see `Adaptive::note_late`.
    fn note_late(&mut self);
    /// See `Adaptive::budget_used`.
    fn budget_used(&self, more: u64) -> f64;
    /// See `Adaptive::sample_cost`.
    fn sample_cost(&self) -> Duration;
    /// See `Adaptive::margin`.
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

/// The state on the heap: what a [`Heap`](crate::storage::Heap) endpoint
/// holds, taken only by a link that runs the adaptive playout.
#[cfg(feature = "alloc")]
impl<A: AdaptiveSlot> AdaptiveSlot for alloc::boxed::Box<A> {
    fn build(period: Duration, epsilon: f64, quantum: Duration) -> Option<Self> {
        A::build(period, epsilon, quantum).map(alloc::boxed::Box::new)
    }

    fn rebase(&mut self, by: Duration, rose: bool) {
        (**self).rebase(by, rose);
    }

    fn note_late(&mut self) {
        (**self).note_late();
    }

    fn budget_used(&self, more: u64) -> f64 {
        (**self).budget_used(more)
    }

    fn sample_cost(&self) -> Duration {
        (**self).sample_cost()
    }

    fn margin(&self) -> Duration {
        (**self).margin()
    }
}

#[cfg(feature = "alloc")]
impl<A: TargetDelay> TargetDelay for alloc::boxed::Box<A> {
    fn observe(&mut self, sent_at: Instant, delay: Duration) {
        (**self).observe(sent_at, delay);
    }

    fn target(&self) -> Option<Duration> {
        (**self).target()
    }
}

/// An [`AdaptiveSlot`] with no room: a [`Builtin<NoAdaptive>`](super::Builtin) is the size of
/// the other policies' largest state (NetEQ's 2 KiB), and asking it for
/// [`Playout::Adaptive`](super::Playout::Adaptive) is a
/// [`NoRoom::Adaptive`](super::NoRoom::Adaptive) error.
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

/// Buckets of the adaptive policy's histogram (log-linear, module docs):
/// delays above the floor up to 13.1 s, the last bucket holding any
/// longer one (a path that slow is an outage to report, not a delay to
/// hold; 1 024 buckets, up to 105 s, were 1.5 KiB more per endpoint).
pub(super) const ADAPTIVE_BUCKETS: usize = 832;
/// The histogram's unit: 50 µs.
const UNIT_NS: u64 = 50_000;
/// Linear buckets below 128 units; then 64 per octave (1.6 % wide).
const LINEAR: u64 = 128;
const PER_OCTAVE: u64 = 64;
/// The histogram's window: `ADAPTIVE_BLOCKS` blocks of this (90–120 s),
/// or longer at long periods (see [`ADAPTIVE_BLOCK_MAX`]).
pub(super) const ADAPTIVE_BLOCK: Duration = Duration::from_secs(30);
/// The longest block. At a long period the blocks grow so that the
/// window's full blocks hold [`ADAPTIVE_WINDOW_DELAYS`] delays, up to this
/// (a window of 15–20 minutes).
pub(super) const ADAPTIVE_BLOCK_MAX: Duration = Duration::from_secs(300);
/// The delays the window's full blocks hold at least (below `1/ε` of them
/// the target keeps a warm-up margin of up to a period, which at the
/// paper's 200 ms would cost a whole tick of delay for good): `1/ε` at the
/// default ε = 0.1 %. 30 s blocks hold them at periods up to 90 ms.
pub(super) const ADAPTIVE_WINDOW_DELAYS: u64 = 1000;
/// Blocks in the window.
pub(super) const ADAPTIVE_BLOCKS: usize = 4;
/// The target may fall by this fraction of a period per sample (a skipped
/// sample at most every 10 ticks).
pub(super) const SLEW_DOWN: f64 = 0.1;
/// The target may rise by this fraction of a period per sample (a repeated
/// tick at most every tick: a late sample costs more than a repeat).
pub(super) const SLEW_UP: f64 = 1.0;

/// The bucket of a relative delay.
pub(super) fn bucket_of(d: Duration) -> usize {
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
pub(super) fn bucket_upper(b: usize) -> Duration {
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

/// The timestamp-based target of [`Playout::Adaptive`](super::Playout::Adaptive): the `1 − ε`
/// quantile of the delays above the floor (given by the endpoint, which
/// knows the clocks), over a sliding window of `ADAPTIVE_BLOCKS` ×
/// `ADAPTIVE_BLOCK`, in a log-linear histogram (50 µs linear up to 6.4 ms,
/// then 64 buckets per octave, up to 13 s), in bounded memory. The target
/// is the upper edge of the smallest bucket with at most `⌊ε·n⌋` of the `n`
/// delays above it (with fewer than 1/ε delays, the largest), and moves
/// towards it by at most `SLEW_UP` or `SLEW_DOWN` periods per sample.
#[derive(Clone, Debug, PartialEq)]
pub struct Adaptive {
    period: f64,
    /// The dead band of the delay the endpoint holds (s), the least
    /// margin of the warm-up.
    quantum: f64,
    pub(super) epsilon: f64,
    /// Counts per block in `u16` (6.5 KiB, not 13: the state is inline in
    /// every endpoint); a block ends early when it holds `u16::MAX` delays.
    /// The window's count of a bucket is summed over the blocks when the
    /// quantile's scan reaches it ([`Adaptive::held`]): a running total
    /// would be 4 KiB more in every endpoint, and put a link with both ends
    /// over 64 KiB now that this policy is the default.
    blocks: [[u16; ADAPTIVE_BUCKETS]; ADAPTIVE_BLOCKS],
    pub(super) count: u64,
    block_counts: [u64; ADAPTIVE_BLOCKS],
    /// Samples lost per block (late or skipped, as the endpoint reports
    /// them), and in the window: the late rate spent.
    block_late: [u64; ADAPTIVE_BLOCKS],
    pub(super) late: u64,
    /// Sum of the delays (s), per block and in the window.
    block_sums: [f64; ADAPTIVE_BLOCKS],
    sum: f64,
    current: usize,
    block_start: Option<Instant>,
    /// How long a block lasts (`ADAPTIVE_BLOCK` to [`ADAPTIVE_BLOCK_MAX`]).
    block: Duration,
    goal: Option<Duration>,
    applied: Option<f64>,
    /// One past the highest bucket holding a delay: the quantile's scan
    /// starts there, not at the histogram's top (the tail is short).
    pub(super) top: usize,
}

impl Adaptive {
    /// An empty window for `period` and late rate `epsilon` (clamped to
    /// 10⁻⁶..0.5), for the default dead band of the delay.
    #[must_use]
    pub fn new(period: Duration, epsilon: f64) -> Self {
        Self::with_quantum(period, epsilon, super::schedule::dead_band(period, None))
    }

    /// [`Adaptive::new`] for a delay held within a dead band of `quantum`
    /// (the warm-up's least margin).
    #[must_use]
    pub(crate) fn with_quantum(period: Duration, epsilon: f64, quantum: Duration) -> Self {
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

    #[cfg(test)]
    /// The quantile the target moves towards.
    #[must_use]
    pub(crate) fn goal(&self) -> Option<Duration> {
        self.goal
    }

    #[cfg(test)]
    /// Delays in the window.
    #[must_use]
    pub(crate) fn count(&self) -> u64 {
        self.count
    }

    /// A sample was lost: it came after its slot, or a fall of the delay
    /// skipped it. Counted in the current block, and leaves the window
    /// with it.
    pub(crate) fn note_late(&mut self) {
        if let Some(l) = self.block_late.get_mut(self.current) {
            *l += 1;
            self.late += 1;
        }
    }

    #[cfg(test)]
    /// Whether `more` lost samples would take the window's past `ε` of its
    /// delays: the late rate is spent, and the endpoint holds its delay
    /// ahead of a silence instead of letting more go (see
    /// [`Playout::Adaptive`](super::Playout::Adaptive)). A window younger than a block counts a
    /// block's delays: else the first seconds' budget is a handful of
    /// samples, and the first stall or episode, held whole, keeps the
    /// delay high while it falls back (about 10 s for paris-newyork's
    /// 0.9 s).
    #[must_use]
    pub(crate) fn over_budget(&self, more: u64) -> bool {
        self.budget_used(more) > 1.0
    }

    /// The share of the late budget that `more` lost samples would bring
    /// the window to: 1 is `ε` of its delays (see
    /// [`Adaptive::over_budget`]).
    #[must_use]
    pub(crate) fn budget_used(&self, more: u64) -> f64 {
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
    pub(super) fn held(&self, b: usize) -> u32 {
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
    /// dead band (the period up to 20 ms). Both vanish at `n = 1/ε`. (With a
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
    pub(crate) fn rebase(&mut self, by: Duration, rose: bool) {
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

    pub(super) fn quantile(&self) -> Option<Duration> {
        self.quantile_at(self.epsilon)
    }

    /// The part of the goal no delay measured asks for: the warm-up margin
    /// while the window holds fewer than `1/ε` delays, zero after. The
    /// endpoint raises its delay only when the measured part of the goal
    /// passes it: a margin that shrinks as the window fills must not make
    /// the delay rise by itself (each rise repeats a sample).
    #[must_use]
    pub(crate) fn margin(&self) -> Duration {
        self.quantile()
            .map_or(Duration::ZERO, |q| self.warmup_margin(q))
    }

    /// What one late sample fewer costs through the quantile: the delay
    /// added to every sample released (s, summed) for the quantile to let
    /// one fewer through, `(1 − ε)/f`, `f` the density of the delays at the
    /// quantile, taken over the window's quantiles at `ε` and `ε/2`. The
    /// endpoint holds a silence while holding it costs less per sample (see
    /// [`Playout::Adaptive`](super::Playout::Adaptive)); zero while the window is empty.
    #[must_use]
    pub(crate) fn sample_cost(&self) -> Duration {
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
