//! The schedule's decisions, driven by hand-made arrivals: a quantile
//! policy that answers what each test sets, a clock estimate fed the
//! arrivals, a queue of send stamps, and the release loop an endpoint runs
//! (release the front when it is due, else repeat the last).

use std::collections::VecDeque;
use std::vec::Vec;

use super::*;
use crate::playout::TargetDelay;

const T: Duration = Duration::from_millis(10);
/// The floor of the raw delays: a binary fraction of a second, so that the
/// estimate's seconds hold it exactly.
const FLOOR: Duration = Duration::from_nanos(3_906_250);
const ORIGIN: Instant = Instant::from_nanos(1_000_000_000);

fn stamp(k: u64) -> Instant {
    ORIGIN + T * k
}

fn ms(x: u64) -> Duration {
    Duration::from_millis(x)
}

/// What the quantile says, set by the test.
#[derive(Clone, Debug, PartialEq)]
struct Policy {
    target: Duration,
    budget_used: f64,
}

impl TargetDelay for Policy {
    fn observe(&mut self, _: Instant, _: Duration) {}
    fn target(&self) -> Option<Duration> {
        Some(self.target)
    }
}

impl AdaptiveSlot for Policy {
    fn build(_: Duration, _: f64, _: Duration) -> Option<Self> {
        None
    }
    fn rebase(&mut self, _: Duration, _: bool) {}
    fn note_late(&mut self) {}
    fn budget_used(&self, _: u64) -> f64 {
        self.budget_used
    }
    fn sample_cost(&self) -> Duration {
        Duration::ZERO
    }
    fn margin(&self) -> Duration {
        Duration::ZERO
    }
}

#[derive(Clone, Copy, Debug, PartialEq)]
struct Release {
    at: Instant,
    /// The stamp released, `None` for a repeat of the last.
    fresh: Option<Instant>,
    delay: Duration,
}

struct Bench {
    schedule: Schedule,
    policy: Policy,
    sync: ClockSync,
    queue: VecDeque<Instant>,
    newest: Option<(Instant, Instant)>,
    next_tick: Instant,
    releases: Vec<Release>,
    changes: Vec<(Duration, u64)>,
}

fn context<'a>(
    policy: &'a Policy,
    sync: &'a ClockSync,
    queue: &VecDeque<Instant>,
    newest: Option<(Instant, Instant)>,
) -> Context<'a, Policy> {
    Context {
        policy,
        sync,
        queued: Queued {
            front: queue.front().copied(),
            second: queue.get(1).copied(),
            len: queue.len(),
        },
        newest,
        outage: false,
        lead: 0.0,
    }
}

impl Bench {
    fn new(target: Duration, budget_used: f64, watchdog: Duration) -> Self {
        Self::with_steps(
            target,
            budget_used,
            watchdog,
            (delay_quantum(T, None), dead_band(T, None)),
        )
    }

    /// A delay held in whole quanta of `quantum`, as asked for.
    fn with_quantum(
        target: Duration,
        budget_used: f64,
        watchdog: Duration,
        quantum: Duration,
    ) -> Self {
        Self::with_steps(target, budget_used, watchdog, (quantum, quantum))
    }

    fn with_steps(
        target: Duration,
        budget_used: f64,
        watchdog: Duration,
        steps: (Duration, Duration),
    ) -> Self {
        Bench {
            schedule: Schedule::new(Role::Base, T, steps, Some(watchdog)),
            policy: Policy {
                target,
                budget_used,
            },
            sync: ClockSync::new(),
            queue: VecDeque::new(),
            newest: None,
            next_tick: ORIGIN,
            releases: Vec::new(),
            changes: Vec::new(),
        }
    }

    /// The frame sent at `stamp` arrives at `at`.
    fn arrive(&mut self, stamp: Instant, at: Instant) {
        self.run_until(at);
        self.sync.observe_arrival(stamp, at);
        self.queue.push_back(stamp);
        self.newest = Some((stamp, at));
        let cx = context(&self.policy, &self.sync, &self.queue, self.newest);
        self.schedule.on_queued(&cx);
    }

    /// Frames `ks` arrive, each `extra` over the floor.
    fn stream(&mut self, ks: core::ops::Range<u64>, extra: Duration) {
        for k in ks {
            self.arrive(stamp(k), stamp(k) + FLOOR + extra);
        }
    }

    /// Runs the ticks and releases due up to `end`, in time order.
    fn run_until(&mut self, end: Instant) {
        loop {
            let tick = self.next_tick;
            match self.schedule.next_release() {
                Some(r) if r <= end && r <= tick => self.release(r),
                _ if tick <= end => self.tick(tick),
                _ => break,
            }
        }
    }

    fn tick(&mut self, at: Instant) {
        self.next_tick = self.schedule.following_tick(at + T);
        let cx = context(&self.policy, &self.sync, &self.queue, self.newest);
        self.schedule.on_tick(at, at, Some(self.next_tick), &cx);
        self.drain();
    }

    fn release(&mut self, at: Instant) {
        let cx = context(&self.policy, &self.sync, &self.queue, self.newest);
        let pending = match self.schedule.before_release(at, at, &cx) {
            Plan::Later(slot) => {
                assert!(slot > at && slot <= at + T / 2, "{slot:?} after {at:?}");
                self.drain();
                return;
            }
            Plan::Now(p) => p,
        };
        let target = self.policy.target;
        let mut cutoff = self.schedule.release_cutoff(at, target, &self.sync);
        let due = self.queue.iter().take_while(|&&s| s <= cutoff).count();
        let mut oldest = false;
        if let (true, Some(&second)) = (due > 1, self.queue.get(1))
            && self.schedule.rise_past(cutoff, second)
        {
            cutoff = self.schedule.release_cutoff(at, target, &self.sync);
            oldest = true;
        }
        let fresh = match self.queue.front() {
            Some(&s) if oldest || s <= cutoff => self.queue.pop_front(),
            _ => None,
        };
        let cx = context(&self.policy, &self.sync, &self.queue, self.newest);
        self.schedule.after_release(at, at, pending, fresh, &cx);
        self.releases.push(Release {
            at,
            fresh,
            delay: self.schedule.delay().unwrap_or_default(),
        });
        self.drain();
    }

    fn drain(&mut self) {
        while let Some(c) = self.schedule.poll_delay_changed() {
            self.changes.push(c);
        }
    }

    /// The stamps released fresh, in the order released.
    fn fresh(&self) -> Vec<Instant> {
        self.releases.iter().filter_map(|r| r.fresh).collect()
    }

    /// The releases of stamps `ks`.
    fn released(&self, ks: core::ops::Range<u64>) -> Vec<Release> {
        self.releases
            .iter()
            .filter(|r| {
                r.fresh
                    .is_some_and(|s| ks.contains(&((s - ORIGIN).as_nanos() / T.as_nanos())))
            })
            .copied()
            .collect()
    }
}

/// The stamps of `ks` released once each, in order, then those of `more`
/// up to one at least `min`: none lost, none twice, none out of order.
fn assert_each_once(b: &Bench, ks: core::ops::Range<u64>, more: core::ops::Range<u64>, min: u64) {
    let fresh = b.fresh();
    let want: Vec<Instant> = ks.chain(more).map(stamp).take(fresh.len()).collect();
    assert_eq!(fresh, want, "released (left) vs sent");
    let last = fresh
        .last()
        .map_or(0, |&s| (s - ORIGIN).as_nanos() / T.as_nanos());
    assert!(last >= min, "released up to {last}, fewer than {min}");
}

/// Repeats of the last sample once the first was released.
fn repeats(b: &Bench) -> usize {
    b.releases
        .iter()
        .skip_while(|r| r.fresh.is_none())
        .filter(|r| r.fresh.is_none())
        .count()
}

/// Within a microsecond (the estimate's seconds round the floor).
fn assert_near(a: Instant, b: Instant) {
    assert!(
        a.signed_nanos_since(b).unsigned_abs() <= 1_000,
        "{a:?} vs {b:?}"
    );
}

#[test]
fn the_delay_is_set_at_the_quantum_over_the_need_and_each_release_is_at_its_slot() {
    // The quantile asks 12 ms over the floor: two quanta of 10 ms.
    let mut b = Bench::new(ms(12), 0.0, ms(1000));
    b.stream(0..50, Duration::ZERO);
    assert_eq!(b.changes, [(ms(20), 2)]);
    assert_each_once(&b, 0..50, 0..0, 47);
    assert_eq!(repeats(&b), 0);
    for r in b.released(0..48) {
        assert_near(r.at, r.fresh.unwrap() + FLOOR + ms(20));
    }
}

#[test]
fn a_rise_is_at_once_and_skips_no_sample() {
    let mut b = Bench::new(ms(12), 0.0, ms(1000));
    b.stream(0..50, Duration::ZERO);
    // Half a quantum past the delay: the quantum over it, at the next release.
    b.policy.target = ms(25);
    b.stream(50..100, Duration::ZERO);
    assert_eq!(b.changes, [(ms(20), 2), (ms(30), 3)]);
    assert_each_once(&b, 0..100, 0..0, 96);
    // A rise of a period repeats the last sample once.
    assert_eq!(repeats(&b), 1);
    for r in b.released(55..97) {
        assert_near(r.at, r.fresh.unwrap() + FLOOR + ms(30));
    }
}

#[test]
fn a_rise_of_less_than_half_a_period_brings_the_release_later_without_a_repeat() {
    // Quanta of 2 ms: 12 ms over the floor is six.
    let mut b = Bench::with_quantum(ms(12), 0.0, ms(1000), ms(2));
    b.stream(0..50, Duration::ZERO);
    assert_eq!(b.changes, [(ms(12), 2)]);
    b.policy.target = Duration::from_micros(13_500);
    b.stream(50..100, Duration::ZERO);
    assert_eq!(b.changes, [(ms(12), 2), (ms(14), 2)]);
    assert_each_once(&b, 0..100, 0..0, 97);
    assert_eq!(repeats(&b), 0);
    for r in b.released(55..97) {
        assert_near(r.at, r.fresh.unwrap() + FLOOR + ms(14));
    }
}

#[test]
fn a_need_within_the_hysteresis_holds_the_delay_and_a_fall_skips_nothing() {
    let mut b = Bench::new(ms(12), 0.0, ms(1000));
    b.stream(0..50, Duration::ZERO);
    // Under the quantum below (10 ms) but not by half a quantum: no fall.
    b.policy.target = ms(6);
    b.stream(50..100, Duration::ZERO);
    assert_eq!(b.changes, [(ms(20), 2)]);
    // Half a quantum under it: the delay falls to it, a millisecond
    // (T / RELEASE_SLEW_STEPS) per release, announced once at rest.
    b.policy.target = ms(4);
    b.stream(100..150, Duration::ZERO);
    assert_eq!(b.changes, [(ms(20), 2), (ms(10), 1)]);
    assert_each_once(&b, 0..150, 0..0, 147);
    assert_eq!(repeats(&b), 0);
    let falling: Vec<Duration> = b
        .releases
        .iter()
        .map(|r| r.delay)
        .filter(|&d| d > ms(10) && d < ms(20))
        .collect();
    assert_eq!(falling.len(), 9, "{falling:?}");
    assert!(
        falling
            .windows(2)
            .all(|w| w[0] - w[1] == T / RELEASE_SLEW_STEPS)
    );
    for r in b.released(120..148) {
        assert_near(r.at, r.fresh.unwrap() + FLOOR + ms(10));
    }
}

#[test]
fn a_silence_is_held_and_its_burst_released_in_order_then_the_delay_falls_back() {
    // The late budget is spent: a stall of the path is held.
    let mut b = Bench::new(ms(12), 2.0, ms(1000));
    b.stream(0..50, Duration::ZERO);
    // Frames 50..55 are held 40 ms on the path and come in a burst with 55.
    for k in 50..56 {
        b.arrive(stamp(k), stamp(55) + FLOOR);
    }
    // Held from the first release the silence passed, before its burst.
    let held: Vec<Duration> = b
        .releases
        .iter()
        .filter(|r| r.at < stamp(55) + FLOOR)
        .map(|r| r.delay)
        .collect();
    assert!(held.iter().any(|&d| d > ms(20)), "{held:?}");
    b.stream(56..120, Duration::ZERO);
    // None lost: each released once, in order.
    assert_each_once(&b, 0..120, 0..0, 116);
    let highest = b.releases.iter().map(|r| r.delay).max().unwrap();
    assert!(highest >= ms(50), "{highest:?}");
    // Back where it was, and the releases at their slots again.
    assert_eq!(b.changes.last(), Some(&(ms(20), 2)), "{:?}", b.changes);
    for r in b.released(100..117) {
        assert_near(r.at, r.fresh.unwrap() + FLOOR + ms(20));
    }
}

#[test]
fn a_silence_is_not_held_while_the_late_budget_is_unspent() {
    let mut b = Bench::new(ms(12), 0.0, ms(1000));
    b.stream(0..50, Duration::ZERO);
    for k in 50..56 {
        b.arrive(stamp(k), stamp(55) + FLOOR);
    }
    b.stream(56..60, Duration::ZERO);
    // The delay did not follow the silence: the burst came past its slots,
    // and the owner's stamps bunched (here the schedule rose past them).
    let before_burst: Vec<Duration> = b
        .releases
        .iter()
        .filter(|r| r.at < stamp(55) + FLOOR)
        .map(|r| r.delay)
        .collect();
    assert!(
        before_burst.iter().all(|&d| d == ms(20)),
        "{before_burst:?}"
    );
}

#[test]
fn an_outage_past_the_watchdog_takes_the_delay_back_at_once() {
    let mut b = Bench::new(ms(12), 2.0, ms(100));
    b.stream(0..50, Duration::ZERO);
    // Nothing for half a second, then the stream again (what was sent in
    // between is lost).
    b.run_until(stamp(100));
    let rose = b.releases.iter().map(|r| r.delay).max().unwrap();
    assert!(rose > ms(20), "the silence was followed first: {rose:?}");
    assert_eq!(b.schedule.delay(), Some(ms(20)));
    assert_eq!(b.changes.last(), Some(&(ms(20), 2)), "{:?}", b.changes);
    // Released once past the watchdog, the delay stays down: no fall of a
    // step per release.
    let after: Vec<Duration> = b
        .releases
        .iter()
        .filter(|r| r.at >= stamp(49) + FLOOR + ms(20) + ms(100) + T)
        .map(|r| r.delay)
        .collect();
    assert!(
        !after.is_empty() && after.iter().all(|&d| d == ms(20)),
        "{after:?}"
    );
    b.stream(100..150, Duration::ZERO);
    assert_each_once(&b, 0..50, 100..150, 146);
    for r in b.released(101..147) {
        assert_near(r.at, r.fresh.unwrap() + FLOOR + ms(20));
    }
}
