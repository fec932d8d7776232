//! Target-delay policies released at the ticks: a [`TargetDelay`] sets the
//! delay from the one-way delays it observes, and [`OnTicks`] releases each
//! sample at the first tick at or after `sent_at + D`.

use super::policy::{
    Admit, Announcement, Arrival, Due, Lost, Observed, Policy, Setup, Stamps, View,
};
use crate::endpoint::Underflow;
use crate::time::{Duration, Instant};

/// A policy that sets a target one-way delay from the delays it observes.
pub trait TargetDelay {
    /// One received frame: its send stamp and its one-way delay.
    fn observe(&mut self, sent_at: Instant, delay: Duration);
    /// The current target, `None` before the policy can tell.
    fn target(&self) -> Option<Duration>;
}

/// A [`TargetDelay`] as a [`Policy`]: a sample sent at `sent_at` is released
/// at the first tick at or after `sent_at + D`, `D` the current target.
/// Under [`Underflow::DropLate`] one that arrives after its slot is late
/// (counted, discarded, the tick repeats the last sample), and when the
/// target falls the older samples that share a slot with a newer one are
/// skipped.
///
/// It takes the two clocks as one (a simulation, or hosts synchronized by
/// PTP or GPS): the delay it observes is the arrival time less the send
/// stamp.
#[derive(Clone, Debug, PartialEq)]
pub struct OnTicks<T> {
    target: T,
    underflow: Underflow,
    period: Duration,
    slots: Slots,
    /// The target at the last tick.
    held: Option<Duration>,
    /// The delay in ticks last announced.
    announced: Option<u64>,
    pending: Option<Announcement>,
}

impl<T: TargetDelay> OnTicks<T> {
    /// `target` released at the ticks of `setup`.
    #[must_use]
    pub fn new(target: T, setup: &Setup) -> Self {
        OnTicks {
            target,
            underflow: setup.underflow,
            period: setup.period,
            slots: Slots::default(),
            held: None,
            announced: None,
            pending: None,
        }
    }
}

impl<T: TargetDelay + Clone + core::fmt::Debug + Send + 'static> Policy for OnTicks<T> {
    fn start(&mut self, _ns: usize) -> usize {
        self.slots = Slots::default();
        0
    }

    fn set_period(&mut self, period: Duration) {
        self.period = period;
    }

    fn arrival(&mut self, arrival: &Arrival, _view: &View<'_>) -> Observed {
        if arrival.copy {
            return Observed::Ignored;
        }
        self.target
            .observe(arrival.sent_at, arrival.arrived - arrival.sent_at);
        Observed::Delay
    }

    fn admit(&self, sample: &Stamps, _now: Instant, view: &View<'_>) -> Admit {
        if self.underflow == Underflow::DropLate && self.slots.passed(sample, view.released) {
            Admit::Late
        } else {
            Admit::Queue
        }
    }

    fn tick(
        &mut self,
        at: Instant,
        _: Instant,
        _: Option<Instant>,
        view: &View<'_>,
    ) -> Option<Due> {
        let Some(d) = self.target.target() else {
            return Some(Due::NotYet);
        };
        self.held = Some(d);
        let ticks = d.as_nanos().div_ceil(self.period.as_nanos().max(1));
        if self.announced != Some(ticks) {
            self.announced = Some(ticks);
            self.pending = Some(Announcement::DelayChanged { delay: d, ticks });
        }
        Some(self.slots.take(view, at - d, false, self.underflow))
    }

    fn delay(&self) -> Option<Duration> {
        self.held
    }

    fn poll_announcement(&mut self) -> Option<Announcement> {
        self.pending.take()
    }
}

/// Which samples the releases of a target delay have passed: each sample
/// has its slot at the first release at or after its send stamp plus the
/// delay.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Slots {
    /// Frames sent (peer clock) at or before this had their slot at a
    /// release already run (under drop-late).
    passed: Option<Instant>,
}

impl Slots {
    /// Whether `sample`'s slot has passed: a newer one was released, or a
    /// release's cutoff was after its stamp.
    pub(crate) fn passed(&self, sample: &Stamps, released: Option<u64>) -> bool {
        released.is_some_and(|r| sample.seq <= r)
            || self.passed.is_some_and(|p| sample.sent_at <= p)
    }

    /// A release that takes the samples sent at or before `cutoff`, the
    /// oldest whatever its stamp if `oldest`. Under drop-late the older
    /// samples that share the slot with a newer one are passed over: the
    /// newest due is released. Until the first sample is due, nothing is
    /// (like the FIFO's pre-fill).
    pub(crate) fn take(
        &mut self,
        view: &View<'_>,
        cutoff: Instant,
        oldest: bool,
        underflow: Underflow,
    ) -> Due {
        let due = |s: Stamps| s.sent_at <= cutoff;
        let mut passed = 0;
        if underflow == Underflow::DropLate {
            while view.queue.get(passed + 1).is_some_and(due) {
                passed += 1;
            }
            self.passed = Some(self.passed.map_or(cutoff, |p| p.max(cutoff)));
        }
        let release = view.queue.get(passed).is_some_and(|s| oldest || due(s));
        if view.queue.prefilling() && !release {
            return Due::NotYet;
        }
        Due::Release {
            passed,
            lost_as: Lost::Skipped,
            release,
        }
    }
}
