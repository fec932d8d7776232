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
//! [`SpinMargin`] therefore keeps the margin at the longest overshoot of
//! the last [`WINDOW`] blocks of [`BLOCK`] sleeps, with a cushion, between
//! [`MIN_SPIN_MARGIN`] and the margin configured (the longest it may be;
//! until a whole window is in, the margin: a few blocks miss the rarer long
//! wake-ups). Load makes it wider at once,
//! and a narrow margin must be earned again: a sleep that overshoots the
//! margin in use (its deadline served late) sets the margin configured and
//! holds it for a block; each such overshoot that comes before a narrow
//! margin has lasted as long as the hold before it doubles the hold (up to
//! [`MAX_HOLD_BLOCKS`]), and every [`MAX_HOLD_BLOCKS`] blocks served at a
//! narrow margin halve it. On a quiet machine the margin follows the
//! timer's overshoots; on a loaded one, where long wake-ups come every few
//! blocks, it stays at the configured one, so its tail is that of the
//! fixed margin, and a late deadline caused by a narrow margin is at most
//! one per hold. Memory is fixed and each
//! sleep costs a few comparisons.

use ndr_core::time::Duration;

/// The shortest margin an adaptive one takes: the spin also covers reading
/// the clock and the thread's return from the sleep.
pub const MIN_SPIN_MARGIN: Duration = Duration::from_micros(20);

/// Sleeps per block.
pub const BLOCK: u32 = 256;

/// Blocks whose longest overshoot the margin covers.
pub const WINDOW: usize = 16;

/// The longest hold at the configured margin after an overshoot beyond the
/// margin in use, in blocks.
pub const MAX_HOLD_BLOCKS: u32 = 64;

/// The cushion over the longest overshoot: a quarter of it, and at least
/// this.
const CUSHION: Duration = Duration::from_micros(10);

/// The spin margin of a precise wait: fixed, or learned from the sleeps'
/// overshoots up to the margin configured.
///
/// ```
/// use ndr_core::time::Duration;
/// use ndr_net::spin::{SpinMargin, BLOCK, WINDOW};
///
/// let mut margin = SpinMargin::adaptive(Duration::from_micros(200));
/// assert_eq!(margin.current(), Duration::from_micros(200));
/// for _ in 0..BLOCK * WINDOW as u32 {
///     margin.record(Duration::from_micros(30));
/// }
/// // 30 µs of overshoot, a quarter more and at least 10 µs of cushion.
/// assert_eq!(margin.current(), Duration::from_micros(40));
/// // An overshoot past it: the configured margin at once.
/// margin.record(Duration::from_micros(55));
/// assert_eq!(margin.current(), Duration::from_micros(200));
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SpinMargin {
    max: Duration,
    adaptive: bool,
    current: Duration,
    /// The longest overshoot of each of the last full blocks (zero for
    /// those not seen yet), the slot of the next, and whether all are in.
    window: [Duration; WINDOW],
    next: usize,
    learned: bool,
    /// The longest overshoot of the current block.
    longest: Duration,
    seen: u32,
    /// Sleeps left at the configured margin after an overshoot past the
    /// margin in use.
    hold: u32,
    /// The next hold, in blocks (1 to [`MAX_HOLD_BLOCKS`]).
    hold_blocks: u32,
    /// Sleeps at a margin under the configured one since the last hold.
    narrow_run: u32,
}

impl SpinMargin {
    /// Always `margin`.
    #[must_use]
    pub fn fixed(margin: Duration) -> Self {
        SpinMargin {
            max: margin,
            adaptive: false,
            current: margin,
            window: [Duration::ZERO; WINDOW],
            next: 0,
            learned: false,
            longest: Duration::ZERO,
            seen: 0,
            hold: 0,
            hold_blocks: 1,
            narrow_run: 0,
        }
    }

    /// Learned from the overshoots, between [`MIN_SPIN_MARGIN`] and `max`
    /// (a `max` at or under [`MIN_SPIN_MARGIN`] stays fixed); `max` until
    /// [`WINDOW`] blocks of sleeps are in.
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

    /// One native sleep, ended a margin of [`current`](Self::current)
    /// before its deadline, woke `overshoot` after the instant it was asked
    /// to end (zero if it woke early).
    pub fn record(&mut self, overshoot: Duration) {
        if !self.adaptive {
            return;
        }
        self.longest = self.longest.max(overshoot);
        self.seen += 1;
        if overshoot > self.current {
            // The spin did not cover the wake-up: widen at once, and hold
            // longer if the narrow margin did not last as long as the hold.
            if self.current < self.max && self.narrow_run < self.hold_blocks * BLOCK {
                self.hold_blocks = (self.hold_blocks * 2).min(MAX_HOLD_BLOCKS);
            }
            self.hold = self.hold_blocks * BLOCK;
            self.narrow_run = 0;
            self.current = self.max;
        } else if self.hold > 0 {
            self.hold -= 1;
        } else if self.current < self.max {
            self.narrow_run = self.narrow_run.saturating_add(1);
            if self.narrow_run.is_multiple_of(MAX_HOLD_BLOCKS * BLOCK) {
                self.hold_blocks = (self.hold_blocks / 2).max(1);
            }
        }
        if self.seen >= BLOCK {
            self.window[self.next] = self.longest;
            self.next = (self.next + 1) % WINDOW;
            self.learned |= self.next == 0;
            self.longest = Duration::ZERO;
            self.seen = 0;
        }
        if self.hold == 0 && self.learned {
            let q = self.window.iter().fold(self.longest, |a, &b| a.max(b));
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

    /// Simulated sleeps: each ends `margin.current()` before its deadline
    /// and wakes `overshoot` after that; the spin covers the margin, so the
    /// deadline is served `overshoot − margin` late, or on time. The
    /// lateness of each, in order.
    fn serve(m: &mut SpinMargin, overshoots: &[Duration]) -> Vec<Duration> {
        overshoots
            .iter()
            .map(|&o| {
                let late = o.saturating_sub(m.current());
                m.record(o);
                late
            })
            .collect()
    }

    /// A loaded machine's overshoots, reproducibly: 10 to 40 µs, and in
    /// each block two wake-ups of 120 µs at scattered places (under 1 %,
    /// so a 99th percentile never sees them).
    fn loaded(blocks: u32) -> Vec<Duration> {
        let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
        let mut next = move || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x
        };
        let mut all = Vec::new();
        for _ in 0..blocks {
            let long = [next() % u64::from(BLOCK), next() % u64::from(BLOCK)];
            for i in 0..u64::from(BLOCK) {
                all.push(if long.contains(&i) {
                    us(120)
                } else {
                    us(10 + next() % 31)
                });
            }
        }
        all
    }

    #[test]
    fn the_margin_is_the_configured_one_until_a_window_is_in() {
        let mut m = SpinMargin::adaptive(us(200));
        feed(&mut m, WINDOW as u32 * BLOCK - 1, |_| us(30));
        assert_eq!(m.current(), us(200));
        m.record(us(30));
        assert_eq!(m.current(), us(40));
    }

    #[test]
    fn the_margin_covers_the_longest_overshoot_of_a_block_with_a_cushion() {
        let mut m = SpinMargin::adaptive(us(200));
        feed(&mut m, (WINDOW as u32 - 1) * BLOCK, |_| Duration::ZERO);
        feed(&mut m, BLOCK, |i| {
            Duration::from_nanos(500 * u64::from(i + 1))
        });
        let q = Duration::from_nanos(500 * u64::from(BLOCK));
        assert_eq!(m.current(), q + q / 4);
    }

    #[test]
    fn an_overshoot_past_the_margin_widens_it_at_once_and_holds_it() {
        let mut m = SpinMargin::adaptive(us(200));
        feed(&mut m, WINDOW as u32 * BLOCK, |_| us(30));
        assert_eq!(m.current(), us(40));
        m.record(us(100));
        assert_eq!(m.current(), us(200));
        // The narrow margin failed within its first block: held for two.
        feed(&mut m, 2 * BLOCK - 1, |_| us(30));
        assert_eq!(m.current(), us(200));
        // Then covering the 100 µs while it is in the window.
        m.record(us(30));
        assert_eq!(m.current(), us(125));
        feed(&mut m, WINDOW as u32 * BLOCK, |_| us(30));
        assert_eq!(m.current(), us(40));
    }

    #[test]
    fn holds_grow_while_narrow_margins_fail_and_shrink_while_they_last() {
        let mut m = SpinMargin::adaptive(us(200));
        feed(&mut m, WINDOW as u32 * BLOCK, |_| us(30));
        // Each failure comes right after the hold before it: it doubles.
        for (held_blocks, overshoot, then) in [(2, 100, 125), (4, 150, 187), (8, 190, 200)] {
            m.record(us(overshoot));
            feed(&mut m, held_blocks * BLOCK - 1, |_| us(30));
            assert_eq!(m.current(), us(200), "held {held_blocks} blocks");
            m.record(us(30));
            assert_eq!(m.current().as_micros(), then);
        }
        // Narrow for the longest hold's length: the next hold is halved.
        feed(&mut m, (WINDOW as u32 + MAX_HOLD_BLOCKS) * BLOCK, |_| {
            us(30)
        });
        assert_eq!(m.current(), us(40));
        m.record(us(100));
        feed(&mut m, 4 * BLOCK - 1, |_| us(30));
        assert_eq!(m.current(), us(200));
        m.record(us(30));
        assert!(m.current() < us(200));
    }

    #[test]
    fn rare_long_wake_ups_keep_the_configured_margin() {
        // A 300 µs wake-up every three blocks, 20 µs otherwise.
        let overshoots: Vec<Duration> = (0..60 * BLOCK)
            .map(|i| {
                if i % (3 * BLOCK) == 100 {
                    us(300)
                } else {
                    us(20)
                }
            })
            .collect();
        let tail = |m: &mut SpinMargin| {
            let mut late = serve(m, &overshoots);
            late.sort_unstable_by(|a, b| b.cmp(a));
            late
        };
        let fixed = tail(&mut SpinMargin::fixed(us(200)));
        let learned = tail(&mut SpinMargin::adaptive(us(200)));
        // The first one may find the margin narrow; none after it.
        assert!(learned[1..].iter().zip(&fixed).all(|(l, f)| l <= f));
    }

    #[test]
    fn under_load_the_tail_is_no_worse_than_the_fixed_margins() {
        let overshoots = loaded(200);
        let late = |m: &mut SpinMargin| {
            serve(m, &overshoots)
                .into_iter()
                .filter(|l| !l.is_zero())
                .count()
        };
        assert_eq!(late(&mut SpinMargin::fixed(us(200))), 0);
        // Each narrow margin that fails holds the configured one twice as
        // long: a handful of late deadlines in 51 200, not two a block.
        let learned = late(&mut SpinMargin::adaptive(us(200)));
        assert!(learned <= overshoots.len() / 5_000, "{learned} late");
    }

    #[test]
    fn the_margin_narrows_again_once_the_load_is_gone() {
        let mut m = SpinMargin::adaptive(us(200));
        for o in loaded(100) {
            m.record(o);
        }
        // Covering the load's longest wake-ups.
        assert!(m.current() >= us(150), "{}", m.current());
        // At most the longest hold and the window, then the quiet timer's
        // margin.
        let most = (MAX_HOLD_BLOCKS + WINDOW as u32 + 1) * BLOCK;
        let mut narrowed = None;
        for i in 0..most + BLOCK {
            m.record(us(30));
            if narrowed.is_none() && m.current() == us(40) {
                narrowed = Some(i);
            }
        }
        assert!(narrowed.is_some_and(|i| i < most), "{narrowed:?}");
        assert_eq!(m.current(), us(40));
    }

    #[test]
    fn a_quiet_timer_keeps_the_floor() {
        let mut m = SpinMargin::adaptive(us(200));
        feed(&mut m, (WINDOW as u32 + 1) * BLOCK, |_| Duration::ZERO);
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
