//! The peers' clock offset and skew, from the timestamps the link exchanges.

use crate::time::{Duration, Instant};

/// Length of a block of samples.
pub(crate) const SYNC_BLOCK: Duration = Duration::from_secs(5);
/// Block minima kept for the hull: 128 blocks of 5 s, 640 s.
pub(crate) const SYNC_BLOCKS: usize = 128;
/// The skew is estimated once the window spans this; before, it is 0.
pub(crate) const MIN_SKEW_SPAN: Duration = Duration::from_secs(60);
/// The largest skew believed, ±500 ppm.
pub(crate) const MAX_SKEW: f64 = 500e-6;
/// The smallest jump of a block minimum taken as a level shift.
pub(crate) const SHIFT_MIN: Duration = Duration::from_millis(5);

/// A point: local time and raw delay, in nanoseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Point {
    t: i64,
    v: i64,
}

/// A line `v = v0 + slope·(t − t0)`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Line {
    t0: i64,
    v0: f64,
    slope: f64,
}

impl Line {
    fn at(&self, t: i64) -> f64 {
        self.v0 + self.slope * (t - self.t0) as f64
    }
}

fn ns(t: Instant) -> i64 {
    i64::try_from(t.as_nanos()).unwrap_or(i64::MAX)
}

/// The floor of one direction's raw delays: the window of block minima,
/// its level shifts and the line under them.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Floor {
    minima: [Point; SYNC_BLOCKS],
    head: usize,
    len: usize,
    block_start: Option<i64>,
    block_min: Option<Point>,
    slope: f64,
    line: Option<Line>,
    shifts: u64,
}

impl Default for Floor {
    fn default() -> Self {
        Self::new()
    }
}

impl Floor {
    /// Nothing seen yet.
    #[must_use]
    pub(crate) const fn new() -> Self {
        Floor {
            minima: [Point { t: 0, v: 0 }; SYNC_BLOCKS],
            head: 0,
            len: 0,
            block_start: None,
            block_min: None,
            slope: 0.0,
            line: None,
            shifts: 0,
        }
    }

    /// A raw delay `v` (ns) observed at local time `t` (ns).
    fn observe(&mut self, t: i64, v: i64) {
        let p = Point { t, v };
        let start = *self.block_start.get_or_insert(t);
        if t.saturating_sub(start) >= ns(Instant::ZERO + SYNC_BLOCK) {
            self.close_block();
            self.block_start = Some(t);
        }
        if self.block_min.is_none_or(|m| v < m.v) {
            self.block_min = Some(p);
            self.fit();
        }
    }

    /// The line's slope (the skew of this direction's raw delays).
    #[must_use]
    pub(crate) fn slope(&self) -> f64 {
        self.slope
    }

    /// Level shifts seen (the window restarted).
    #[must_use]
    pub(crate) fn shifts(&self) -> u64 {
        self.shifts
    }

    /// The floor at local time `t`, in ns; `None` before any sample.
    fn at(&self, t: i64) -> Option<f64> {
        self.line.map(|l| l.at(t))
    }

    fn points(&self) -> impl Iterator<Item = Point> + '_ {
        (0..self.len)
            .filter_map(move |i| self.minima.get((self.head + i) % SYNC_BLOCKS))
            .copied()
            .chain(self.block_min)
    }

    fn close_block(&mut self) {
        let Some(m) = self.block_min.take() else {
            return;
        };
        if let Some(line) = self.line
            && self.len >= 2
        {
            let residual = |p: Point| p.v as f64 - line.at(p.t);
            let mean = self.points().map(residual).sum::<f64>() / self.len as f64;
            let limit = (4.0 * mean).max(ns(Instant::ZERO + SHIFT_MIN) as f64);
            if libm::fabs(residual(m)) > limit {
                self.shifts += 1;
                self.len = 0;
            }
        }
        if self.len == SYNC_BLOCKS {
            self.head = (self.head + 1) % SYNC_BLOCKS;
            self.len -= 1;
        }
        if let Some(cell) = self.minima.get_mut((self.head + self.len) % SYNC_BLOCKS) {
            *cell = m;
            self.len += 1;
        }
        self.fit();
    }

    /// Moon et al.'s line under the window's points.
    fn fit(&mut self) {
        let n = self.points().count();
        let Some(first) = self.points().next() else {
            return;
        };
        let last = self.points().last().unwrap_or(first);
        if last.t - first.t >= ns(Instant::ZERO + MIN_SKEW_SPAN) && n >= 3 {
            let mean_t = self.points().map(|p| (p.t - first.t) as f64).sum::<f64>() / n as f64;
            if let Some(slope) = self.hull_slope_at(first.t + mean_t as i64) {
                self.slope = slope.clamp(-MAX_SKEW, MAX_SKEW);
            }
        }
        // The line of the slope touching the lowest point from below.
        let slope = self.slope;
        let t0 = last.t;
        let v0 = self
            .points()
            .map(|p| p.v as f64 - slope * (p.t - t0) as f64)
            .fold(f64::INFINITY, f64::min);
        self.line = Some(Line { t0, v0, slope });
    }

    /// The slope of the lower convex hull's edge spanning `t` (Andrew's
    /// monotone chain over the time-ordered points, on a fixed-size stack).
    fn hull_slope_at(&self, t: i64) -> Option<f64> {
        let mut hull = [Point::default(); SYNC_BLOCKS + 1];
        let mut k = 0usize;
        let cross = |o: Point, a: Point, b: Point| {
            (a.t - o.t) as f64 * (b.v - o.v) as f64 - (a.v - o.v) as f64 * (b.t - o.t) as f64
        };
        for p in self.points() {
            while k >= 2 {
                let (Some(&o), Some(&a)) = (hull.get(k - 2), hull.get(k - 1)) else {
                    break;
                };
                if cross(o, a, p) <= 0.0 {
                    k -= 1;
                } else {
                    break;
                }
            }
            if let Some(cell) = hull.get_mut(k) {
                *cell = p;
                k += 1;
            }
        }
        let edges = hull.get(..k)?;
        edges
            .windows(2)
            .find(|w| w.get(1).is_some_and(|b| b.t >= t))
            .or_else(|| edges.windows(2).last())
            .and_then(|w| match w {
                [a, b] if b.t > a.t => Some((b.v - a.v) as f64 / (b.t - a.t) as f64),
                _ => None,
            })
    }
}

/// The peers' clock offset and skew, from the timestamps the link exchanges.
///
/// Each side reads its own clock: a frame's `sent_at` is on the peer's, its
/// arrival on ours. Their difference, the *raw delay*, is the one-way delay
/// plus `θ(t) = local − peer`, the offset, which drifts at the skew
/// `s = dθ/dt` (crystals: up to ±100 ppm). [`ClockSync`] estimates both:
///
/// - **Skew**, after Moon, Skelley and Towsley (1999): the raw delays of the
///   received frames lie above the line `d_min + θ(t)`. The skew is the
///   slope of the line under every point that minimizes the sum of the
///   distances to them: on the lower convex hull of the points, the edge
///   spanning their mean time. The points are the minima of
///   5 s blocks (a hull vertex is the lowest point around
///   it), the last 128 of them (a window of about 11 minutes, so
///   a drifting skew is followed). A block minimum more than
///   5 ms (or four mean residuals) off the line is a level shift
///   (a route change, not a clock): the window restarts there and keeps the
///   skew (switching). The slope is clamped to ±500 ppm.
/// - **Offset**, as NTP does (`θ = ((t4 − t3) − (t2 − t1))/2` for a frame
///   that echoes ours: `t1` our send, `t2 = t3 − hold` its arrival on the
///   peer's clock, `t3` the peer's send, `t4` our arrival), with the
///   minimum-delay filter taken per direction: the same floor is kept for
///   our frames (`t2 − t1 = d_forth − θ`, from the echoes) and `θ` is half
///   the difference of the two floors. Its error is half the asymmetry of
///   the two paths' fastest frames, plus the floors' spread (the gap between
///   the true minimum and the lowest of a block's samples). The skew is half
///   the difference of the two floors' slopes.
///
/// Everything is in integer nanoseconds on the local clock, in O(1) memory.
///
/// Offset and skew of the peer's clock, estimated online (module docs).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ClockSync {
    /// Received frames: `arrival − sent_at = d_back + θ`.
    rx: Floor,
    /// Our frames, from the echoes: `t2 − t1 = d_forth − θ`.
    tx: Floor,
}

impl ClockSync {
    /// Nothing seen yet.
    #[must_use]
    pub(crate) const fn new() -> Self {
        ClockSync {
            rx: Floor::new(),
            tx: Floor::new(),
        }
    }

    /// A frame stamped `sent_at` (peer clock) arrived at `arrived` (local).
    pub(crate) fn observe_arrival(&mut self, sent_at: Instant, arrived: Instant) {
        let t = ns(arrived);
        self.rx.observe(t, t.saturating_sub(ns(sent_at)));
    }

    /// A frame that echoes ours: `t1` our send (local), `hold` the peer's
    /// hold time, `t3` the peer's send (peer clock). Only the first echo
    /// of each of our frames should be given (later ones held longer).
    pub(crate) fn observe_echo(&mut self, t1: Instant, hold: Duration, t3: Instant) {
        let hold = i64::try_from(hold.as_nanos()).unwrap_or(i64::MAX);
        let t2 = ns(t3).saturating_sub(hold);
        self.tx.observe(ns(t1), t2.saturating_sub(ns(t1)));
    }

    /// The skew `d(local − peer)/dt` (dimensionless; 1e-6 is 1 ppm): half
    /// the difference of the two directions' slopes, or one of them until
    /// the other has one.
    #[must_use]
    pub fn skew(&self) -> f64 {
        (self.rx.slope() - self.tx.slope()) / 2.0
    }

    #[cfg(test)]
    /// Level shifts seen in either direction.
    #[must_use]
    pub(crate) fn shifts(&self) -> u64 {
        self.rx.shifts() + self.tx.shifts()
    }

    /// The received frames' floor.
    #[must_use]
    pub(crate) fn rx(&self) -> &Floor {
        &self.rx
    }

    /// `local − peer` at local time `t`, in seconds: half the difference of
    /// the two floors (NTP's formula on the fastest frames of each way).
    /// `None` until both directions have a floor.
    #[must_use]
    pub fn offset_at(&self, t: Instant) -> Option<f64> {
        let t = ns(t);
        Some((self.rx.at(t)? - self.tx.at(t)?) / 2.0 * 1e-9)
    }

    /// The floor of the received frames' raw delays (`d_min + θ(t)`) at
    /// local time `t`, in seconds; `None` before any frame.
    #[must_use]
    pub(crate) fn floor_at(&self, t: Instant) -> Option<f64> {
        self.rx.at(ns(t)).map(|v| v * 1e-9)
    }

    /// A received frame's one-way delay (raw delay − offset), in seconds.
    #[must_use]
    pub(crate) fn one_way_rx(&self, sent_at: Instant, arrived: Instant) -> Option<f64> {
        let raw = ns(arrived).saturating_sub(ns(sent_at)) as f64 * 1e-9;
        self.offset_at(arrived).map(|o| raw - o)
    }

    /// Our frame's one-way delay from its echo (`t2 − t1 + offset`), in seconds.
    #[must_use]
    pub(crate) fn one_way_tx(&self, t1: Instant, hold: Duration, t3: Instant) -> Option<f64> {
        let hold = i64::try_from(hold.as_nanos()).unwrap_or(i64::MAX);
        let raw = ns(t3).saturating_sub(hold).saturating_sub(ns(t1)) as f64 * 1e-9;
        self.offset_at(t1).map(|o| raw + o)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stream at 50 Hz over a path `base + jitter(k)` each way, the
    /// local clock `offset + (1 + skew)·t` of the peer's.
    fn run(
        secs: u64,
        skew_ppm: f64,
        offset_ms: f64,
        jitter: impl Fn(u64) -> f64,
    ) -> (ClockSync, Instant) {
        let mut s = ClockSync::new();
        let local = |t: f64| t * (1.0 + skew_ppm * 1e-6) + offset_ms * 1e-3 + 1000.0;
        let peer = |t: f64| t + 1000.0;
        let mut last = Instant::ZERO;
        for k in 0..secs * 50 {
            let t = k as f64 * 0.02;
            // Ours sent at t − 0.01, reached the peer after 30 ms + jitter;
            // the peer's frame leaves 5 ms later, arrives 30 ms + jitter after.
            let t1 = t - 0.01;
            let t2 = t1 + 0.030 + jitter(2 * k);
            let t3 = t2 + 0.005;
            let t4 = t3 + 0.030 + jitter(2 * k + 1);
            let i = |x: f64| Instant::from_nanos((x * 1e9) as u64);
            let arrived = i(local(t4));
            s.observe_arrival(i(peer(t3)), arrived);
            s.observe_echo(i(local(t1)), Duration::from_secs_f64(t3 - t2), i(peer(t3)));
            last = arrived;
        }
        (s, last)
    }

    fn jitter(k: u64) -> f64 {
        // Deterministic, in [0, 20 ms), zero now and then.
        let x = k.wrapping_mul(2_654_435_761) % 1000;
        if x < 20 { 0.0 } else { x as f64 * 2e-5 }
    }

    #[test]
    fn skew_within_5_ppm_after_10_minutes() {
        for ppm in [-100.0, 0.0, 100.0] {
            let (s, _) = run(600, ppm, 0.0, jitter);
            assert!(
                (s.skew() * 1e6 - ppm).abs() < 5.0,
                "{ppm}: {}",
                s.skew() * 1e6
            );
            assert_eq!(s.shifts(), 0);
        }
    }

    #[test]
    fn offset_within_the_spread_of_the_minimum() {
        for (ppm, off) in [(0.0, 250.0), (100.0, -4000.0), (-100.0, 12.5)] {
            let (s, t) = run(600, ppm, off, jitter);
            // True local − peer at the last arrival (peer time p: local = p + off + ppm·(p − 1000)).
            let p = t.as_secs_f64();
            let truth = off * 1e-3 + ppm * 1e-6 * (p - 1000.0);
            let got = s.offset_at(t).unwrap();
            assert!((got - truth).abs() < 1e-3, "{ppm} {off}: {got} vs {truth}");
            // The one-way delay of a fastest frame: 30 ms.
            let floor = s.floor_at(t).unwrap() - got;
            assert!((floor - 0.030).abs() < 1e-3, "{floor}");
        }
    }

    #[test]
    fn a_level_shift_restarts_the_window_and_keeps_the_skew() {
        let step = |k: u64| jitter(k) + if k > 2 * 50 * 400 { 0.150 } else { 0.0 };
        let (s, t) = run(600, 50.0, 0.0, step);
        assert_eq!(s.shifts(), 2);
        assert!((s.skew() * 1e6 - 50.0).abs() < 5.0, "{}", s.skew() * 1e6);
        let p = t.as_secs_f64();
        let floor = s.floor_at(t).unwrap() - 50e-6 * (p - 1000.0);
        assert!((floor - 0.180).abs() < 2e-3, "{floor}");
    }
}
