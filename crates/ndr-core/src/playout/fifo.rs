//! The paper's NDR as a policy: a FIFO pre-filled to `ns` samples, one
//! release per tick (the queue itself is the [`regulator`](crate::regulator)).

use super::policy::{
    Admit, Arrival, Due, Lost, NoRoom, Observed, Outcome, Policy, Setup, Stamps, View,
};
use super::registry::{Entry, UnknownPlayout, bare};
use crate::endpoint::Underflow;
use crate::time::{Duration, Instant};

/// The paper's FIFO: a stock of `ns` samples, the oldest released at each
/// tick. Its slots are one per tick, in sequence: under
/// [`Underflow::DropLate`] a sample whose slot a tick has passed (the tick
/// found it missing) is late.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Fifo {
    underflow: Underflow,
    /// The sequence number of the next slot, from the regime's first release.
    due: Option<u64>,
}

impl Fifo {
    /// A FIFO that treats a missing sample as `underflow` says.
    #[must_use]
    pub(crate) const fn new(underflow: Underflow) -> Self {
        Fifo {
            underflow,
            due: None,
        }
    }
}

impl Policy for Fifo {
    fn start(&mut self, ns: usize) -> usize {
        self.due = None;
        ns
    }

    fn set_period(&mut self, _period: Duration) {}

    fn arrival(&mut self, _arrival: &Arrival, _view: &View<'_>) -> Observed {
        Observed::Ignored
    }

    fn admit(&self, sample: &Stamps, _now: Instant, _view: &View<'_>) -> Admit {
        if self.underflow == Underflow::DropLate && self.due.is_some_and(|due| sample.seq < due) {
            Admit::Late
        } else {
            Admit::Queue
        }
    }

    fn tick(&mut self, _: Instant, _: Instant, _: Option<Instant>, view: &View<'_>) -> Option<Due> {
        Some(match (self.underflow, self.due) {
            (Underflow::DropLate, Some(due)) => {
                let mut late = 0;
                while view.queue.get(late).is_some_and(|s| s.seq < due) {
                    late += 1;
                }
                Due::Release {
                    passed: late,
                    lost_as: Lost::Late,
                    release: view.queue.get(late).is_some_and(|s| s.seq == due),
                }
            }
            _ => Due::FRONT,
        })
    }

    fn released(&mut self, _at: Instant, _t: Instant, outcome: Outcome, _view: &View<'_>) {
        match outcome {
            // A forged `seq` may be near the end of the count: the slot due
            // stays at its end.
            Outcome::Released(s) => self.due = Some(s.seq.saturating_add(1)),
            // This tick's slot is gone.
            Outcome::Underflow => self.due = self.due.map(|d| d.saturating_add(1)),
            Outcome::Nothing => {}
        }
    }

    fn delay(&self) -> Option<Duration> {
        None
    }
}

impl Entry for Fifo {
    type Fields = ();
    const NAME: &'static str = "fifo";
    const SYNTAX: &'static str = "fifo";

    fn parse(value: Option<&str>) -> Result<(), UnknownPlayout> {
        bare(value)
    }

    fn build((): (), setup: &Setup) -> Result<Self, NoRoom> {
        Ok(Fifo::new(setup.underflow))
    }
}
