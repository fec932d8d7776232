//! How long before a deadline to stop sleeping and start spinning, learned
//! from how late the native sleeps actually wake.
//!
//! A precise release sleeps natively until a *spin margin* before its
//! deadline, then spins. The margin must cover the sleep's overshoot (the
//! timer slack plus the wake-up latency), or the release is late; anything
//! beyond that is a spin that burns CPU for nothing. The overshoot depends
//! on the machine and its load: tens of microseconds on a quiet machine
//! with a 1 µs timer slack, milliseconds on a loaded one (the scheduler's
//! tail, which no margin shortens); what a fixed margin and a learned one
//! cost and give is in docs/benchmarks.md, "Release clock".
//!
//! [`SpinMargin`] therefore keeps the margin at a high quantile of the
//! overshoots it has seen, with a cushion, between [`MIN_SPIN_MARGIN`] and
//! the margin configured (the longest it may be). The quantile is the
//! [`KEPT`]-th largest overshoot of a block of [`BLOCK`] sleeps (about its
//! p99); the margin covers the larger of the last full block's and the
//! current block's, so it rises within [`KEPT`] long overshoots and falls
//! only after a whole block without them. Until the first block is full it
//! is the configured one. Memory is fixed and each sleep costs a few
//! comparisons.

use ndr_core::time::Duration;

/// The shortest margin an adaptive one takes: the spin also covers reading
/// the clock and the thread's return from the sleep.
pub const MIN_SPIN_MARGIN: Duration = Duration::from_micros(20);

/// Sleeps per block.
pub const BLOCK: u32 = 256;

/// The rank, from the largest, of the overshoot a block keeps as its
/// quantile: the 3rd largest of 256 is about the 99th percentile.
pub const KEPT: usize = 3;

/// The cushion over the quantile: a quarter of it, and at least this.
const CUSHION: Duration = Duration::from_micros(10);

/// The spin margin of a precise wait: fixed, or learned from the sleeps'
/// overshoots up to the margin configured.
///
/// ```
/// use ndr_core::time::Duration;
/// use ndr_net::spin::{SpinMargin, BLOCK};
///
/// let mut margin = SpinMargin::adaptive(Duration::from_micros(200));
/// assert_eq!(margin.current(), Duration::from_micros(200));
/// for _ in 0..BLOCK {
///     margin.record(Duration::from_micros(30));
/// }
/// // 30 µs of overshoot, a quarter more and at least 10 µs of cushion.
/// assert_eq!(margin.current(), Duration::from_micros(40));
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SpinMargin {
    max: Duration,
    adaptive: bool,
    current: Duration,
    /// The quantile of the last full block, once there is one.
    previous: Option<Duration>,
    /// The largest overshoots of the current block, largest first.
    top: [Duration; KEPT],
    seen: u32,
}

impl SpinMargin {
    /// Always `margin`.
    #[must_use]
    pub fn fixed(margin: Duration) -> Self {
        SpinMargin {
            max: margin,
            adaptive: false,
            current: margin,
            previous: None,
            top: [Duration::ZERO; KEPT],
            seen: 0,
        }
    }

    /// Learned from the overshoots, between [`MIN_SPIN_MARGIN`] and `max`
    /// (a `max` at or under [`MIN_SPIN_MARGIN`] stays fixed); `max` until
    /// the first block of sleeps is in.
    #[must_use]
    pub fn adaptive(max: Duration) -> Self {
        SpinMargin {
            adaptive: max > MIN_SPIN_MARGIN,
            ..SpinMargin::fixed(max)
        }
    }

    /// The margin to use now.
    #[must_use]
    pub fn current(&self) -> Duration {
        self.current
    }

    /// The longest margin (the one configured).
    #[must_use]
    pub fn max(&self) -> Duration {
        self.max
    }

    /// Whether the margin follows the overshoots.
    #[must_use]
    pub fn is_adaptive(&self) -> bool {
        self.adaptive
    }

    /// One native sleep woke `overshoot` after the instant it was asked to
    /// end (zero if it woke early).
    pub fn record(&mut self, overshoot: Duration) {
        if !self.adaptive {
            return;
        }
        // Insert into the kept largest, in order.
        if overshoot > self.top[KEPT - 1] {
            let at = self
                .top
                .iter()
                .position(|&t| overshoot > t)
                .unwrap_or(KEPT - 1);
            self.top.copy_within(at..KEPT - 1, at + 1);
            self.top[at] = overshoot;
        }
        self.seen += 1;
        let block = self.top[KEPT - 1];
        if self.seen >= BLOCK {
            self.previous = Some(block);
            self.top = [Duration::ZERO; KEPT];
            self.seen = 0;
        }
        if let Some(previous) = self.previous {
            let q = previous.max(self.top[KEPT - 1]);
            let cushion = (q / 4).max(CUSHION);
            self.current = (q + cushion).clamp(MIN_SPIN_MARGIN, self.max);
        }
    }
}

/// A margin given as a duration is the longest of an adaptive one.
impl From<Duration> for SpinMargin {
    fn from(max: Duration) -> Self {
        SpinMargin::adaptive(max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn us(n: u64) -> Duration {
        Duration::from_micros(n)
    }

    fn feed(m: &mut SpinMargin, n: u32, overshoot: impl Fn(u32) -> Duration) {
        for i in 0..n {
            m.record(overshoot(i));
        }
    }

    #[test]
    fn the_margin_is_the_configured_one_until_a_block_is_in() {
        let mut m = SpinMargin::adaptive(us(200));
        feed(&mut m, BLOCK - 1, |_| us(30));
        assert_eq!(m.current(), us(200));
        m.record(us(30));
        assert_eq!(m.current(), us(40));
    }

    #[test]
    fn the_margin_covers_the_blocks_99th_percentile_with_a_cushion() {
        let mut m = SpinMargin::adaptive(us(200));
        // 1..=256 µs scaled down: the 3rd largest of a block is 254 · 0.5.
        feed(&mut m, BLOCK, |i| {
            Duration::from_nanos(500 * u64::from(i + 1))
        });
        let q = Duration::from_nanos(500 * 254);
        assert_eq!(m.current(), (q + q / 4).min(us(200)));
        assert!(m.current() > q);
    }

    #[test]
    fn rare_long_overshoots_are_not_chased_but_a_few_in_a_block_are() {
        let mut m = SpinMargin::adaptive(us(200));
        feed(&mut m, BLOCK, |_| us(30));
        // Two preemptions of a millisecond in a block: the 3rd largest is
        // still 30 µs, the margin stays.
        feed(&mut m, BLOCK, |i| {
            if i == 7 || i == 107 { us(1000) } else { us(30) }
        });
        assert_eq!(m.current(), us(40));
        // Three: it rises to the configured margin at once, within the block.
        let mut at = None;
        for i in 0..BLOCK {
            m.record(if i < 3 { us(1000) } else { us(30) });
            if at.is_none() && m.current() == us(200) {
                at = Some(i);
            }
        }
        assert_eq!(at, Some(2));
    }

    #[test]
    fn the_margin_falls_back_a_block_after_the_load_is_gone() {
        let mut m = SpinMargin::adaptive(us(200));
        feed(&mut m, BLOCK, |_| us(150));
        assert_eq!(m.current(), us(187) + Duration::from_nanos(500));
        // The last full block holds 150 µs until this one is full.
        feed(&mut m, BLOCK - 1, |_| us(20));
        assert_eq!(m.current(), us(187) + Duration::from_nanos(500));
        m.record(us(20));
        assert_eq!(m.current(), us(30));
        feed(&mut m, BLOCK, |_| us(20));
        assert_eq!(m.current(), us(30));
    }

    #[test]
    fn a_quiet_timer_keeps_the_floor() {
        let mut m = SpinMargin::adaptive(us(200));
        feed(&mut m, 3 * BLOCK, |_| Duration::ZERO);
        assert_eq!(m.current(), MIN_SPIN_MARGIN);
    }

    #[test]
    fn a_fixed_margin_and_a_short_one_do_not_move() {
        for mut m in [SpinMargin::fixed(us(200)), SpinMargin::adaptive(us(15))] {
            let before = m.current();
            feed(&mut m, 4 * BLOCK, |i| us(u64::from(i % 500)));
            assert_eq!(m.current(), before);
            assert!(!m.is_adaptive());
        }
    }
}
