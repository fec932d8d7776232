//! The oracle: on a known trace, the smallest constant delay `D*(ε)` whose
//! late rate is at most `ε`, computed on the receiver's tick grid.
//!
//! # Quantization
//!
//! A target-delay playout releases a sample sent at `s` (sender's stamp) at
//! the first receiver tick at or after `s + D`; the sample is on time when it
//! arrived (`a`, receiver's clock) by that tick. So a sample is on time for
//! every `D > θ`, with `θ = (last tick strictly before a) − s`: its
//! *threshold*. `D*(ε)` is the `⌈(1−ε)N⌉`-th smallest threshold plus one
//! nanosecond, and the oracle's end-to-end delay for a sample is that tick
//! minus `s`. When sender and receiver share the tick grid (no skew), every
//! on-time sample then has the same end-to-end delay, a whole number of
//! periods: `D*` rounded up to the grid. The policies' delays are measured
//! the same way (receiver's release tick − sender's stamp), so the oracle
//! and the policies are compared on the same grid. The comparison harness
//! builds it on the grid of the adaptive delay's quantum
//! ([`delay_quantum`](ndr_core::playout::delay_quantum): the period up to
//! 20 ms, a fraction of it beyond), where the adaptive playout releases
//! between ticks.

use std::vec::Vec;

use ndr_core::time::{Duration, Instant};

/// Most targets each window of the piecewise oracle chooses among.
pub const PIECEWISE_OPTIONS: usize = 64;
/// Most targets each side of the split oracle chooses among.
pub const SPLIT_OPTIONS: usize = 512;

/// A window's target and what it gives: late samples, and the sum (ns) and
/// count of the on-time samples' delays; or the sum of several windows',
/// with the largest target.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Choice {
    late: usize,
    sum: i128,
    on_time: usize,
    target: i128,
}

impl Choice {
    fn and(self, other: &Choice) -> Choice {
        Choice {
            late: self.late + other.late,
            sum: self.sum + other.sum,
            on_time: self.on_time + other.on_time,
            target: self.target.max(other.target),
        }
    }
}

/// One sample of a trace as a receiver sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Arrival {
    /// The sender's stamp.
    pub sent_at: Instant,
    /// The arrival, on the receiver's clock.
    pub arrived_at: Instant,
}

/// What a constant delay (or a schedule of them) gives on a trace.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OraclePoint {
    /// The constant target `D*` (the largest of a piecewise schedule), s.
    pub target_s: f64,
    /// Mean end-to-end delay of the samples on time, s.
    pub mean_delay_s: f64,
    /// Samples late / samples.
    pub late_rate: f64,
}

/// The oracle of one trace: every sample's threshold, on a tick grid
/// `origin + k·period` of the receiver's clock.
#[derive(Clone, Debug)]
pub struct Oracle {
    period: u64,
    origin: u64,
    samples: Vec<(Instant, i128)>,
    sorted: Vec<i128>,
    /// Samples that never arrived (an arrival [`NEVER`](crate::engine::NEVER)
    /// after the send): late whatever the delay, so always in the budget.
    lost: usize,
}

impl Oracle {
    /// The oracle of `arrivals` for a receiver ticking at `origin + k·period`.
    #[must_use]
    pub fn new(arrivals: &[Arrival], origin: Instant, period: Duration) -> Self {
        let period = period.as_nanos().max(1);
        let origin = origin.as_nanos();
        let samples: Vec<(Instant, i128)> = arrivals
            .iter()
            .map(|a| {
                let at = i128::from(a.arrived_at.as_nanos());
                let (o, t) = (i128::from(origin), i128::from(period));
                // The last tick strictly before the arrival.
                let before = o + (at - 1 - o).div_euclid(t) * t;
                (a.sent_at, before - i128::from(a.sent_at.as_nanos()))
            })
            .collect();
        let mut sorted: Vec<i128> = samples.iter().map(|&(_, th)| th).collect();
        sorted.sort_unstable();
        let never = i128::from(crate::engine::NEVER.as_nanos()) - i128::from(period);
        let lost = sorted.iter().filter(|&&th| th >= never).count();
        Oracle {
            period,
            origin,
            samples,
            sorted,
            lost,
        }
    }

    /// Samples in the trace.
    #[must_use]
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// Whether the trace is empty.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// The end-to-end delay of a sample sent at `s` for a target `d` (ns):
    /// first tick at or after `s + d`, minus `s`.
    fn e2e(&self, s: Instant, d: i128) -> i128 {
        let (o, t) = (i128::from(self.origin), i128::from(self.period));
        let x = i128::from(s.as_nanos()) + d;
        let k = (x - o + t - 1).div_euclid(t);
        o + k * t - i128::from(s.as_nanos())
    }

    /// The smallest target (ns) with at most `allowed` of `sorted` late.
    fn smallest_target(sorted: &[i128], allowed: usize) -> i128 {
        let n = sorted.len();
        let on_time = n.saturating_sub(allowed);
        match on_time.checked_sub(1).and_then(|i| sorted.get(i)) {
            Some(&th) => (th + 1).max(0),
            None => 0,
        }
    }

    /// `(late, sum of on-time delays, on time)` of samples `range` for target `d`.
    fn tally(&self, range: core::ops::Range<usize>, d: i128) -> (usize, i128, usize) {
        let mut late = 0;
        let mut sum = 0;
        let mut on_time = 0;
        for &(s, th) in self.samples.get(range).unwrap_or(&[]) {
            if th >= d {
                late += 1;
            } else {
                sum += self.e2e(s, d);
                on_time += 1;
            }
        }
        (late, sum, on_time)
    }

    fn point(&self, target: i128, late: usize, sum: i128, on_time: usize) -> OraclePoint {
        let n = self.samples.len().max(1) as f64;
        OraclePoint {
            target_s: target as f64 * 1e-9,
            mean_delay_s: if on_time == 0 {
                0.0
            } else {
                sum as f64 / on_time as f64 * 1e-9
            },
            late_rate: late as f64 / n,
        }
    }

    /// `D*(ε)`: the smallest constant target with late rate ≤ `ε`.
    #[must_use]
    pub fn constant(&self, epsilon: f64) -> OraclePoint {
        let d = Self::smallest_target(&self.sorted, self.budget(epsilon));
        let (late, sum, on_time) = self.tally(0..self.samples.len(), d);
        self.point(d, late, sum, on_time)
    }

    /// The piecewise oracle: the samples are cut by send time into windows
    /// of `window`, each window gets its own constant target, and the late
    /// samples allowed (`floor(ε·N)`) are shared between the windows where
    /// they shorten the delays most (a Lagrangian split of the budget, each
    /// window choosing among at most [`PIECEWISE_OPTIONS`] targets): a delay
    /// that may change once per window, with late rate ≤ `ε`.
    #[must_use]
    pub fn piecewise(&self, epsilon: f64, window: Duration) -> OraclePoint {
        let budget = self.budget(epsilon);
        let w = window.as_nanos().max(1);
        let windows = self.windows(|s| s.as_nanos() / w, budget, PIECEWISE_OPTIONS);
        let choose = |lambda: f64| -> Choice {
            let mut total = Choice::default();
            for options in &windows {
                let best = options.iter().min_by(|a, b| {
                    let cost = |o: &Choice| o.sum as f64 + lambda * o.late as f64;
                    cost(a).total_cmp(&cost(b)).then(a.late.cmp(&b.late))
                });
                if let Some(best) = best {
                    total = total.and(best);
                }
            }
            total
        };
        // The smallest price of a late sample that keeps within the budget.
        let (mut lo, mut hi) = (0.0f64, 1e18f64);
        for _ in 0..100 {
            let mid = 0.5 * (lo + hi);
            if choose(mid).late <= budget {
                hi = mid;
            } else {
                lo = mid;
            }
        }
        let c = choose(hi);
        let split = self.point(c.target, c.late, c.sum, c.on_time);
        // The same target in every window is a choice too, which the
        // Lagrangian split (convex in the price) can miss between two
        // prices: never worse than the constant oracle.
        let constant = self.constant(epsilon);
        if constant.mean_delay_s < split.mean_delay_s {
            constant
        } else {
            split
        }
    }

    /// The split oracle: one constant target for the samples sent before
    /// `at`, another for the rest, the pair with the least mean delay whose
    /// late rate is at most `ε` (an exhaustive search over up to
    /// [`SPLIT_OPTIONS`] targets each side). At the onset of a trace's first
    /// event, no delay that learns of the events only when the first one
    /// comes, and holds a constant afterwards, does better: one that does
    /// changes in step with the later events, which takes foreseeing them.
    #[must_use]
    pub fn split(&self, epsilon: f64, at: Instant) -> OraclePoint {
        let budget = self.budget(epsilon);
        let windows = self.windows(|s| u64::from(s >= at), budget, SPLIT_OPTIONS);
        let none = [Choice::default()];
        let (before, after) = match windows.as_slice() {
            [only] => (only.as_slice(), none.as_slice()),
            [before, after] => (before.as_slice(), after.as_slice()),
            _ => return self.point(0, 0, 0, 0),
        };
        let mean = |c: &Choice| {
            if c.on_time == 0 {
                f64::INFINITY
            } else {
                c.sum as f64 / c.on_time as f64
            }
        };
        let best = before
            .iter()
            .flat_map(|x| after.iter().map(move |y| x.and(y)))
            .filter(|c| c.late <= budget)
            .min_by(|a, b| mean(a).total_cmp(&mean(b)));
        match best {
            Some(c) => self.point(c.target, c.late, c.sum, c.on_time),
            None => self.point(0, 0, 0, 0),
        }
    }

    /// The late samples allowed at `ε`: `floor(ε·N)`.
    /// Late samples allowed at `epsilon`: the lost ones at least, which no
    /// delay brings in time.
    fn budget(&self, epsilon: f64) -> usize {
        let allowed =
            ((epsilon.clamp(0.0, 1.0) * self.samples.len() as f64) + 1e-9).floor() as usize;
        allowed.max(self.lost)
    }

    /// The runs of consecutive samples with the same `key` of their send
    /// stamps (non-decreasing along the trace), each with its options: a
    /// target for each number of late samples up to `budget` (at most `cap`
    /// of them, evenly spaced).
    fn windows(&self, key: impl Fn(Instant) -> u64, budget: usize, cap: usize) -> Vec<Vec<Choice>> {
        let n = self.samples.len();
        let mut windows = Vec::new();
        let mut start = 0;
        while start < n {
            let key = |i: usize| self.samples.get(i).map(|&(s, _)| key(s));
            let k = key(start);
            let mut end = start;
            while end < n && key(end) == k {
                end += 1;
            }
            let mut sorted: Vec<i128> = self
                .samples
                .get(start..end)
                .unwrap_or(&[])
                .iter()
                .map(|&(_, th)| th)
                .collect();
            sorted.sort_unstable();
            let len = sorted.len();
            // Allowing `l` lates: the target just above the (len − l)-th threshold.
            let mut lates: Vec<usize> = (0..=len.min(budget))
                .filter(|&l| l == 0 || l == len || sorted.get(len - l - 1) != sorted.get(len - l))
                .collect();
            if lates.len() > cap {
                let step = lates.len().div_ceil(cap);
                lates = lates.into_iter().step_by(step).collect();
            }
            let options = lates
                .into_iter()
                .map(|l| {
                    let d = match (len - l).checked_sub(1).and_then(|i| sorted.get(i)) {
                        Some(&th) => (th + 1).max(0),
                        None => 0,
                    };
                    let (late, sum, on_time) = self.tally(start..end, d);
                    Choice {
                        late,
                        sum,
                        on_time,
                        target: d,
                    }
                })
                .collect();
            windows.push(options);
            start = end;
        }
        windows
    }

    /// The lower convex envelope of the constant oracle's (late rate, mean
    /// delay) points at `ε`: the best a policy can do by time-sharing
    /// between two constant targets. O(K·N) for K distinct thresholds; past
    /// [`PIECEWISE_OPTIONS`]·4 distinct ones (a skewed grid) the envelope is
    /// taken over an evenly spaced subset of them, which can only raise it.
    #[must_use]
    pub fn hull(&self, epsilon: f64) -> f64 {
        let mut targets: Vec<i128> = self.sorted.iter().map(|&th| (th + 1).max(0)).collect();
        targets.push(0);
        targets.sort_unstable();
        targets.dedup();
        let most = 4 * PIECEWISE_OPTIONS;
        if targets.len() > most {
            let step = targets.len().div_ceil(most);
            targets = targets.into_iter().step_by(step).collect();
        }
        let points: Vec<OraclePoint> = targets
            .iter()
            .map(|&d| {
                let (late, sum, on_time) = self.tally(0..self.samples.len(), d);
                self.point(d, late, sum, on_time)
            })
            .collect();
        // Best mix of two points whose late rates bracket ε: a share μ of
        // the samples under `a`'s target, the rest under `b`'s. The mean
        // delay is over the samples on time, so each side weighs by its own.
        let mut best = f64::INFINITY;
        for a in points.iter().filter(|p| p.late_rate <= epsilon) {
            best = best.min(a.mean_delay_s);
            for b in points.iter().filter(|p| p.late_rate > epsilon) {
                let mu = (b.late_rate - epsilon) / (b.late_rate - a.late_rate);
                let (wa, wb) = (mu * (1.0 - a.late_rate), (1.0 - mu) * (1.0 - b.late_rate));
                if wa + wb > 0.0 {
                    best = best.min((wa * a.mean_delay_s + wb * b.mean_delay_s) / (wa + wb));
                }
            }
        }
        if best.is_finite() { best } else { 0.0 }
    }

    /// The mean of the `released` smallest *slot delays* (first tick at or
    /// after arrival, minus send): no playout that releases `released`
    /// samples of this trace fresh can have a smaller mean delay, since each
    /// sample it releases waits at least its slot delay.
    #[must_use]
    pub fn lower_bound(&self, released: usize) -> f64 {
        let mut slot: Vec<i128> = self
            .sorted
            .iter()
            .map(|&th| th + self.period as i128)
            .collect();
        slot.truncate(released);
        if slot.is_empty() {
            return 0.0;
        }
        slot.iter().sum::<i128>() as f64 / slot.len() as f64 * 1e-9
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trace(delays_ms: &[u64], period_ms: u64) -> Vec<Arrival> {
        delays_ms
            .iter()
            .enumerate()
            .map(|(k, &d)| {
                let s = Instant::from_millis(k as u64 * period_ms);
                Arrival {
                    sent_at: s,
                    arrived_at: s + Duration::from_millis(d),
                }
            })
            .collect()
    }

    #[test]
    fn a_lost_sample_is_late_whatever_the_delay_and_spends_no_budget_twice() {
        // Five samples, the 81 ms one lost (arriving NEVER after its send).
        let mut t = trace(&[15, 25, 40, 55, 81], 20);
        t[4].arrived_at = t[4].sent_at + crate::engine::NEVER;
        let o = Oracle::new(&t, Instant::ZERO, Duration::from_millis(20));
        // Asked for no late sample, it does the best it can: the lost one.
        for p in [o.constant(0.0), o.piecewise(0.0, Duration::from_secs(1))] {
            assert!((p.mean_delay_s - 0.060).abs() < 1e-12, "{p:?}");
            assert!((p.late_rate - 0.2).abs() < 1e-12);
        }
        // One more late allowed beyond it: 40 ms.
        assert!((o.constant(0.4).mean_delay_s - 0.040).abs() < 1e-12);
    }

    #[test]
    fn constant_oracle_on_a_tiny_trace() {
        // T = 20 ms; slot delays (rounded up to the grid): 20, 40, 40, 60, 100.
        let o = Oracle::new(
            &trace(&[15, 25, 40, 55, 81], 20),
            Instant::ZERO,
            Duration::from_millis(20),
        );
        let p = o.constant(0.0);
        assert!((p.mean_delay_s - 0.100).abs() < 1e-12 && p.late_rate == 0.0);
        // ε = 0.2: one late allowed (the 81 ms one): 60 ms.
        let p = o.constant(0.2);
        assert!((p.mean_delay_s - 0.060).abs() < 1e-12);
        assert!((p.late_rate - 0.2).abs() < 1e-12);
        // ε = 0.4: 40 ms (an arrival exactly on the tick is on time).
        assert!((o.constant(0.4).mean_delay_s - 0.040).abs() < 1e-12);
        // ε = 0.39 allows only one late.
        assert!((o.constant(0.39).mean_delay_s - 0.060).abs() < 1e-12);
        // Time-sharing 60 ms (late 0.2) and 40 ms (late 0.4) half and half
        // at ε = 0.3: on time 0.4 at 60 ms and 0.3 at 40 ms, 36/0.7 ms.
        assert!((o.hull(0.3) - 0.036 / 0.7).abs() < 1e-12);
        // Past every late rate of a point, at least as good as that point.
        assert!((o.hull(0.9) - 0.020).abs() < 1e-12);
        // Releasing 3 samples costs at least (20 + 40 + 40)/3.
        assert!((o.lower_bound(3) - 0.100 / 3.0).abs() < 1e-12);
    }

    #[test]
    fn piecewise_oracle_follows_a_step() {
        // 10 samples at 15 ms, then 10 at 95 ms; windows of 200 ms.
        let mut d = std::vec![15u64; 10];
        d.extend([95u64; 10]);
        let o = Oracle::new(&trace(&d, 20), Instant::ZERO, Duration::from_millis(20));
        assert!((o.constant(0.0).mean_delay_s - 0.100).abs() < 1e-12);
        let p = o.piecewise(0.0, Duration::from_millis(200));
        assert!((p.mean_delay_s - 0.060).abs() < 1e-12 && p.late_rate == 0.0);
        assert!((p.target_s - 0.080_000_001).abs() < 1e-12);
        // Cut at the step, the split oracle is the same schedule; cut
        // anywhere else, one side must cover both levels.
        let at = Instant::from_millis(200);
        let split = o.split(0.0, at);
        assert!((split.mean_delay_s - 0.060).abs() < 1e-12 && split.late_rate == 0.0);
        let late_cut = o.split(0.0, Instant::from_millis(300));
        assert!(late_cut.mean_delay_s > split.mean_delay_s + 0.01);
        // A cut outside the trace leaves one constant.
        let p = o.split(0.0, Instant::from_millis(10_000));
        assert!((p.mean_delay_s - 0.100).abs() < 1e-12);
    }

    #[test]
    fn split_oracle_shares_the_late_budget_between_its_sides() {
        // Before the cut at 200 ms: 10 samples at 15 ms but one at 95; after
        // it: 10 at 15 ms. One late allowed (ε = 0.05 of 20): spent before
        // the cut, both sides hold 20 ms, the best; a constant holds 20 ms
        // too, but one late there is all it can afford.
        let mut d = std::vec![15u64; 20];
        if let Some(x) = d.get_mut(3) {
            *x = 95;
        }
        let o = Oracle::new(&trace(&d, 20), Instant::ZERO, Duration::from_millis(20));
        let at = Instant::from_millis(200);
        let p = o.split(0.05, at);
        assert!((p.mean_delay_s - 0.020).abs() < 1e-12);
        assert!((p.late_rate - 0.05).abs() < 1e-12);
        // No late allowed: the side with the 95 ms sample holds 100 ms, the
        // other 20 ms: (10·100 + 10·20)/20 = 60 ms, below a constant's 100.
        let p = o.split(0.0, at);
        assert!((p.mean_delay_s - 0.060).abs() < 1e-12 && p.late_rate == 0.0);
        assert!((o.constant(0.0).mean_delay_s - 0.100).abs() < 1e-12);
        // Never above the constant oracle, at any ε.
        for eps in [0.0, 0.05, 0.1, 0.5] {
            assert!(o.split(eps, at).mean_delay_s <= o.constant(eps).mean_delay_s + 1e-12);
        }
    }
}
