//! The adaptive playout as a policy: its quantile ([`Adaptive`]) sets the
//! delay above the floor of the clock estimate, its [`Schedule`] releases
//! each sample at its slot apart from the ticks, and an outage's backlog is
//! no delay to cover.

use core::fmt;

use super::adaptive::{Adaptive, AdaptiveSlot};
use super::policy::{
    Admit, Announcement, Arrival, Due, NoRoom, Observed, Outcome, Policy, Setup, Stamps, View,
};
use super::registry::{Entry, UnknownPlayout, millis, write_decimal, write_millis};
use super::schedule::{self, Context, Pending, Plan, Queued, Schedule, dead_band, delay_quantum};
use super::target::Slots;
use crate::endpoint::Underflow;
use crate::time::{Duration, Instant};

/// The finest quantum [`Playout::Adaptive`](super::Playout::Adaptive) takes:
/// below it the delay would follow every wobble of its quantile.
pub(super) const MIN_QUANTUM: Duration = Duration::from_millis(1);
/// The coarsest quantum the command line takes (any beyond the period is
/// the period).
pub(super) const MAX_QUANTUM: Duration = Duration::from_secs(10);

/// The adaptive policy's default late rate, 0.1 % in parts per million.
pub(super) const DEFAULT_EPSILON_PPM: u32 = 1000;

fn ns_i64(t: Instant) -> i64 {
    i64::try_from(t.as_nanos()).unwrap_or(i64::MAX)
}

/// [`Playout::Adaptive`](super::Playout::Adaptive): releases each sample at
/// its send stamp mapped to the local clock plus a delay of whole quanta
/// over the quantile's target, on the [`Schedule`]. The quantile's state is
/// `A` ([`Adaptive`], or [`NoAdaptive`](super::NoAdaptive), which cannot be
/// made).
#[derive(Clone, Debug)]
pub(crate) struct AdaptivePlayout<A = Adaptive> {
    quantile: A,
    schedule: Schedule,
    underflow: Underflow,
    watchdog: Option<Duration>,
    /// The quantum asked for (`None`: the default).
    asked: Option<Duration>,
    slots: Slots,
    /// The frames now arriving drain an outage's backlog.
    outage: bool,
    /// What the schedule decided before the release under way.
    pending: Option<Pending>,
}

impl<A: AdaptiveSlot> AdaptivePlayout<A> {
    #[cfg(test)]
    /// The quantile policy.
    #[must_use]
    pub(crate) fn quantile(&self) -> &A {
        &self.quantile
    }

    /// Splits the schedule from what it decides on.
    fn parts<'a>(&'a mut self, view: &View<'a>) -> (&'a mut Schedule, Context<'a, A>) {
        let queued = Queued {
            front: view.queue.get(0).map(|s| s.sent_at),
            second: view.queue.get(1).map(|s| s.sent_at),
            len: view.queue.len(),
        };
        let lead = view
            .forecast()
            .map_or(0.0, |p| (p.nrtt_ahead - p.nrtt_mean).max(0.0) / 2.0);
        let cx = Context {
            policy: &self.quantile,
            sync: view.sync,
            queued,
            newest: view.newest,
            outage: self.outage,
            lead,
        };
        (&mut self.schedule, cx)
    }
}

impl<A: AdaptiveSlot> Policy for AdaptivePlayout<A> {
    fn start(&mut self, _ns: usize) -> usize {
        self.slots = Slots::default();
        self.schedule.restart();
        0
    }

    fn set_period(&mut self, period: Duration) {
        self.schedule.set_period(
            period,
            (
                delay_quantum(period, self.asked),
                dead_band(period, self.asked),
            ),
        );
    }

    fn stop(&mut self) {
        self.schedule.stop();
    }

    fn arrival(&mut self, arrival: &Arrival, view: &View<'_>) -> Observed {
        let &Arrival {
            sent_at, arrived, ..
        } = arrival;
        if arrival.copy && self.outage {
            return Observed::Ignored;
        }
        // Before any echo has bounded the clocks (a peer's first frames may
        // echo nothing) the raw delay is the clocks' offset, not a delay,
        // and would set the target to it.
        let Some(floor) = schedule::floor_ns(view.sync, arrived) else {
            return Observed::Ignored;
        };
        // The delay above the floor, whatever the clocks.
        let raw = ns_i64(arrived).saturating_sub(ns_i64(sent_at));
        let above = Duration::from_nanos(u64::try_from(raw.saturating_sub(floor)).unwrap_or(0));
        if !arrival.copy {
            // A frame after a silence longer than the watchdog allows ends
            // an outage, not a delay; so do the frames after it while they
            // are still held longer than the watchdog, or come in the burst
            // held behind them (faster than they were sent), and the frames
            // a stalled driver hands over late. Counted as delays, they would
            // fill the window's tail, and the target would cover the outage
            // for the window's length.
            let over = |d: Duration| self.watchdog.is_some_and(|w| d > w);
            self.outage = arrival.stalled
                || arrival.prev.is_some_and(|(ps, pa)| {
                    let silence = arrived - pa;
                    over(silence) || (self.outage && (over(above) || silence * 2 < sent_at - ps))
                });
            if self.outage {
                return Observed::Outage;
            }
        }
        // A copy recovered from a later datagram: the delay it really had is
        // one the playout must cover to keep its late rate.
        self.quantile.observe(sent_at, above);
        Observed::Delay
    }

    fn floor_moved(&mut self, from: f64, to: f64) {
        // The delays in the window since the shift were measured above the
        // old floor, and would count the shift twice on top of the new one.
        let (before, after) = ((from * 1e9) as i64, (to * 1e9) as i64);
        self.quantile.rebase(
            Duration::from_nanos(after.saturating_sub(before).unsigned_abs()),
            after > before,
        );
    }

    fn admit(&self, sample: &Stamps, now: Instant, view: &View<'_>) -> Admit {
        if self.underflow == Underflow::DropLate && self.slots.passed(sample, view.released) {
            return Admit::Late;
        }
        // Under hold, a sample held behind an outage, past its slot, is
        // stale; kept, it would stretch the delay to the outage's length and
        // replay the outage's commands.
        if self.outage
            && self
                .schedule
                .slot_at(sample.sent_at, now, view.sync)
                .is_some_and(|s| s < now)
        {
            return Admit::Stale;
        }
        Admit::Queue
    }

    fn queued(&mut self, view: &View<'_>) {
        let (s, cx) = self.parts(view);
        s.on_queued(&cx);
    }

    fn lost(&mut self) {
        self.quantile.note_late();
    }

    fn tick(
        &mut self,
        at: Instant,
        t: Instant,
        next_tick: Option<Instant>,
        view: &View<'_>,
    ) -> Option<Due> {
        // Its releases have their own schedule, each at its sample's slot;
        // until the delay is set, the ticks.
        let (s, cx) = self.parts(view);
        s.on_tick(at, t, next_tick, &cx);
        None
    }

    fn due(&mut self, at: Instant, t: Instant, view: &View<'_>) -> Due {
        let (s, cx) = self.parts(view);
        match s.before_release(at, t, &cx) {
            Plan::Later(slot) => return Due::Later(slot),
            Plan::Now(pending) => self.pending = Some(pending),
        }
        // Nothing is due before the delay is set.
        let (Some(_), Some(d)) = (self.schedule.delay(), self.quantile.target()) else {
            return Due::NotYet;
        };
        let mut cutoff = self.schedule.release_cutoff(at, d, view.sync);
        // More than one due: stamps bunched (a send that left late, or the
        // clock estimate moved the slots earlier). The delay rises by as many
        // ticks instead of skipping samples, and this release takes the
        // oldest of them, so that each later release has one due: were it to
        // take none, the same samples would be due again at the next
        // release, and the delay would rise without end.
        let mut oldest = false;
        let bunched = view.queue.get(1).is_some_and(|s| s.sent_at <= cutoff)
            && view.queue.get(0).is_some_and(|s| s.sent_at <= cutoff);
        if let (true, Some(second)) = (bunched, view.queue.get(1))
            && self.schedule.rise_past(cutoff, second.sent_at)
        {
            cutoff = self.schedule.release_cutoff(at, d, view.sync);
            oldest = true;
        }
        self.slots.take(view, cutoff, oldest, self.underflow)
    }

    fn released(&mut self, at: Instant, t: Instant, outcome: Outcome, view: &View<'_>) {
        let Some(pending) = self.pending.take() else {
            return;
        };
        let fresh = match outcome {
            Outcome::Released(s) => Some(s.sent_at),
            Outcome::Underflow | Outcome::Nothing => None,
        };
        let (s, cx) = self.parts(view);
        s.after_release(at, t, pending, fresh, &cx);
    }

    fn next_release(&self) -> Option<Instant> {
        self.schedule.next_release()
    }

    fn delay(&self) -> Option<Duration> {
        self.schedule.delay()
    }

    fn poll_announcement(&mut self) -> Option<Announcement> {
        self.schedule
            .poll_delay_changed()
            .map(|(delay, ticks)| Announcement::DelayChanged { delay, ticks })
    }

    fn following_tick(&self, plain: Instant) -> Instant {
        self.schedule.following_tick(plain)
    }

    fn grid_settled(&self, at: Instant) -> bool {
        self.schedule.on_release_grid(at)
    }
}

const PERCENT: &str = "adaptive:PERCENT takes the target late rate in percent, \
    0 < PERCENT < 100 (0.1 by default)";
const QUANTUM: &str = "adaptive:PERCENT:QUANTUM_MS takes the step of the delay in milliseconds, \
    1 to 10000 (e.g. 10)";

impl<A: AdaptiveSlot> Entry for AdaptivePlayout<A> {
    type Fields = (u32, Option<Duration>);
    const NAME: &'static str = "adaptive";
    const SYNTAX: &'static str = "adaptive[:PERCENT[:QUANTUM_MS]]";
    const VALUES: &'static str = "the target late rate, 0 < PERCENT < 100, default 0.1; \
        the delay's step, 1 to 10000 ms, default the period up to 20 ms, 1 ms beyond";

    fn parse(value: Option<&str>) -> Result<Self::Fields, UnknownPlayout> {
        let Some(v) = value else {
            return Ok((DEFAULT_EPSILON_PPM, None));
        };
        let (pc, quantum) = match v.split_once(':') {
            Some((pc, q)) => match millis(q) {
                Some(q) if (MIN_QUANTUM..=MAX_QUANTUM).contains(&q) => (pc, Some(q)),
                _ => return Err(UnknownPlayout::value(QUANTUM)),
            },
            None => (v, None),
        };
        match pc.trim().parse::<f64>() {
            Ok(pc) if pc > 0.0 && pc < 100.0 => {
                Ok((libm::round(pc * 1e4).max(1.0) as u32, quantum))
            }
            _ => Err(UnknownPlayout::value(PERCENT)),
        }
    }

    fn write_value(
        &(epsilon_ppm, quantum): &Self::Fields,
        f: &mut fmt::Formatter<'_>,
    ) -> fmt::Result {
        if (epsilon_ppm, quantum) == (DEFAULT_EPSILON_PPM, None) {
            return Ok(());
        }
        f.write_str(":")?;
        write_decimal(f, u64::from(epsilon_ppm), 4)?;
        match quantum {
            Some(q) => {
                f.write_str(":")?;
                write_millis(f, q)
            }
            None => Ok(()),
        }
    }

    fn check(&(_, quantum): &Self::Fields) -> Result<(), &'static str> {
        match quantum {
            Some(q) if !(MIN_QUANTUM..=MAX_QUANTUM).contains(&q) => Err(
                "the adaptive playout's quantum is outside 1.000ms to 10.000s; ask for a step \
                 in that range, or none for the default",
            ),
            _ => Ok(()),
        }
    }

    fn build((epsilon_ppm, asked): Self::Fields, setup: &Setup) -> Result<Self, NoRoom> {
        let quantum = delay_quantum(setup.period, asked);
        let band = dead_band(setup.period, asked);
        let quantile = A::build(setup.period, f64::from(epsilon_ppm) * 1e-6, quantum)
            .ok_or(NoRoom::Adaptive)?;
        Ok(AdaptivePlayout {
            quantile,
            schedule: Schedule::new(setup.role, setup.period, (quantum, band), setup.watchdog),
            underflow: setup.underflow,
            watchdog: setup.watchdog,
            asked,
            slots: Slots::default(),
            outage: false,
            pending: None,
        })
    }
}
