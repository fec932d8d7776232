//! Releasing: which sample each tick or release hands the application, and the round trips and watchdog that follow from it.

use super::{Endpoint, Event, Phase, Release, Slot, Status, Underflow};
use crate::control::round_trip_ticks;
use crate::playout::{Announcement, Due, Lost, Outcome, Policy, Queued, Stamps, View};
use crate::regulator::{self, RegulatorIn, Tick};
use crate::storage::{Queue, Storage};
use crate::time::{Duration, Instant};
use crate::wire::Role;

impl<S: Storage> Endpoint<S> {
    /// The policy, and what it is told things with.
    #[inline]
    pub(super) fn policy_view(&mut self) -> (&mut S::Policy, View<'_>) {
        let view = View::new(&self.sync, &self.regulator).with(
            self.heard.prev_data,
            self.rel.released_seq,
            &self.predictor,
        );
        (&mut self.policy, view)
    }

    /// What the policy announced, as events.
    #[inline]
    pub(super) fn heed(&mut self) {
        while let Some(announcement) = self.policy.poll_announcement() {
            match announcement {
                Announcement::DelayChanged { delay, ticks } => {
                    self.stats.delay_changes += 1;
                    self.emit(Event::DelayChanged { delay, ticks });
                }
            }
        }
    }

    /// A release of the policy's own schedule ([`Policy::next_release`]),
    /// scheduled at `at`, run (and stamped) at `t`.
    pub(super) fn release(&mut self, at: Instant, t: Instant) {
        if self.phase != Phase::Running {
            self.policy.stop();
            return;
        }
        let (policy, view) = self.policy_view();
        let due = policy.due(at, t, &view);
        self.heed();
        self.take(at, t, due);
    }

    /// The release scheduled at `at` and run at `t` takes what `due` says.
    pub(super) fn take(&mut self, at: Instant, t: Instant, due: Due) {
        let tick = match due {
            Due::Later(slot) => {
                // A remote's tick moves with its release, so that its state
                // still answers the command.
                if self.config.role == Role::Remote && self.next_tick == Some(at) {
                    self.next_tick = Some(slot);
                }
                return;
            }
            // Nothing released yet: not an underflow.
            Due::NotYet => Tick::Prefilling {
                have: self.regulator.len(),
                need: 1,
            },
            Due::Release {
                passed,
                lost_as,
                release,
            } => {
                for _ in 0..passed {
                    if self.regulator.discard_front().is_none() {
                        break;
                    }
                    match lost_as {
                        Lost::Late => self.stats.late += 1,
                        Lost::Skipped => self.stats.skipped += 1,
                    }
                    self.policy.lost();
                }
                self.regulator.tick_if(|_| release)
            }
        };
        let outcome = self.deliver(t, tick);
        self.watch(t);
        let (policy, view) = self.policy_view();
        policy.released(at, t, outcome, &view);
        self.heed();
    }

    pub(super) fn deliver(&mut self, t: Instant, outcome: Tick<Slot<S::Values>>) -> Outcome {
        match outcome {
            Tick::Released(slot) => {
                if !self.apply_command(slot.term) {
                    return Outcome::Released(slot.head);
                }
                self.stats.released_fresh += 1;
                self.rel.last_fresh = t;
                self.rel.released_seq = Some(slot.head.seq);
                self.rel.armed = true;
                let stamps = slot.head;
                let grtt = slot.peer_released.and_then(|k| self.measure_grtt(t, k));
                if let Some(g) = grtt {
                    self.round_trip_event(g);
                }
                let release = Release::fresh(slot.head, slot.term, slot.values, slot.len, t, grtt);
                match &mut self.rel.last {
                    Some(last) => last.copy_from(&release),
                    None => self.rel.last = Some(release.clone()),
                }
                self.emit(Event::Released(release));
                Outcome::Released(stamps)
            }
            Tick::Underflow => {
                self.stats.underflows += 1;
                if self.config.underflow == Underflow::Hold {
                    self.stats.late += 1;
                }
                if let Some(mut held) = self.rel.last.clone() {
                    held.status = Status::Held;
                    held.released_at = t;
                    held.grtt = None;
                    self.stats.released_held += 1;
                    self.emit(Event::Released(held));
                }
                Outcome::Underflow
            }
            Tick::Prefilling { .. } => Outcome::Nothing,
        }
    }

    /// Announces the round trip in ticks when a measured GRTT changes it.
    fn round_trip_event(&mut self, grtt: Duration) {
        let Some(ticks) = round_trip_ticks(grtt, self.period).map(|t| t as u64) else {
            return;
        };
        self.stats.round_trip_ticks = ticks;
        if self.rel.round_trip_ticks != Some(ticks) {
            self.rel.round_trip_ticks = Some(ticks);
            self.stats.round_trip_changes += 1;
            self.emit(Event::RoundTripChanged { grtt, ticks });
        }
    }

    /// The watchdog: an application must know when fresh samples stop.
    pub(super) fn watch(&mut self, t: Instant) {
        // Armed from the first release of a regime: pre-fill is silent by design.
        let (Some(limit), true) = (self.config.watchdog, self.rel.armed) else {
            return;
        };
        let silent_for = t - self.rel.last_fresh;
        if silent_for >= limit && self.rel.lost.is_none() {
            self.rel.lost = Some(self.rel.last_fresh);
            self.stats.link_lost += 1;
            self.emit(Event::LinkLost { silent_for });
        } else if silent_for.is_zero()
            && let Some(since) = self.rel.lost.take()
        {
            self.emit(Event::LinkRestored { outage: t - since });
        }
    }

    /// The peer had released our sample `k` when it sent what we release now.
    pub(super) fn measure_grtt(&mut self, t: Instant, k: u64) -> Option<Duration> {
        if self.rel.grtt_acked.is_some_and(|a| k <= a) {
            return None;
        }
        self.rel.grtt_acked = Some(k);
        match self.tick_of(k) {
            Some(sent) => {
                let grtt = t - sent;
                self.stats.grtt.push_duration(grtt);
                Some(grtt)
            }
            _ => {
                self.stats.grtt_unmeasured += 1;
                None
            }
        }
    }
}

/// What was released to the application: the sequence numbers the
/// releases and round trips go by, the last release, the watchdog.
#[derive(Clone, Debug)]
pub(super) struct Released<V> {
    pub(super) released_seq: Option<u64>,
    pub(super) grtt_acked: Option<u64>,
    /// A fresh sample was released in this regime: the watchdog is armed.
    pub(super) armed: bool,
    pub(super) last: Option<Release<V>>,
    /// Last fresh release, or the start of the running phase, for the watchdog.
    pub(super) last_fresh: Instant,
    /// While the watchdog holds: the last fresh release before the silence.
    pub(super) lost: Option<Instant>,
    /// The round trip in ticks last announced.
    pub(super) round_trip_ticks: Option<u64>,
}

impl<V> Released<V> {
    pub(super) fn new(now: Instant) -> Self {
        Released {
            released_seq: None,
            grtt_acked: None,
            armed: false,
            last: None,
            last_fresh: now,
            lost: None,
            round_trip_ticks: None,
        }
    }
}

/// The regulator's samples, as a policy sees them.
impl<V, Q: Queue<Slot<V>>> Queued for RegulatorIn<Slot<V>, Q> {
    fn len(&self) -> usize {
        RegulatorIn::len(self)
    }

    fn get(&self, i: usize) -> Option<Stamps> {
        RegulatorIn::get(self, i).map(|s| s.head)
    }

    fn prefilling(&self) -> bool {
        self.phase() == regulator::Phase::Prefilling
    }
}
