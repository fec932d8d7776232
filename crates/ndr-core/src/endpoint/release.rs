//! Releasing: which sample each tick or release hands the application, and the round trips and watchdog that follow from it.

use super::{Endpoint, Event, Phase, Release, Slot, Status, Underflow, delay_quantum};
use crate::control::round_trip_ticks;
use crate::playout::schedule::{self, Context, Plan, Queued, Schedule};
use crate::playout::{AdaptiveSlot, Target, TargetDelay};
use crate::regulator::{self, Tick};
use crate::storage::Storage;
use crate::time::{Duration, Instant};
use crate::wire::Role;

impl<S: Storage> Endpoint<S> {
    /// The adaptive schedule and what it decides on now, `None` under
    /// another playout.
    pub(super) fn adaptive(&mut self) -> Option<(&mut Schedule, Context<'_, S::Adaptive>)> {
        let (Some(schedule), Some(Target::Adaptive(policy))) = (&mut self.schedule, &self.target)
        else {
            return None;
        };
        let mut queue = self.regulator.iter().map(|s| s.head.sent_at);
        let queued = Queued {
            front: queue.next(),
            second: queue.next(),
            len: self.regulator.len(),
        };
        // The paper's predictor steers the delay ahead: half the rise of the
        // mean round trip it forecasts over its horizon.
        let lead = self
            .predictor
            .last()
            .map_or(0.0, |p| (p.nrtt_ahead - p.nrtt_mean).max(0.0) / 2.0);
        let cx = Context {
            policy,
            sync: &self.sync,
            queued,
            newest: self.heard.prev_data,
            outage: self.heard.outage_burst,
            lead,
        };
        Some((schedule, cx))
    }

    /// Each delay the adaptive schedule settled on, as an event.
    pub(super) fn delay_events(&mut self) {
        while let Some((delay, ticks)) = self
            .schedule
            .as_mut()
            .and_then(Schedule::poll_delay_changed)
        {
            self.stats.delay_changes += 1;
            self.emit(Event::DelayChanged { delay, ticks });
        }
    }

    /// The adaptive delay's quantum at `period`.
    pub(super) fn quantum_at(&self, period: Duration) -> Duration {
        self.config
            .playout
            .quantum(period)
            .unwrap_or_else(|| delay_quantum(period))
    }

    /// Adaptive playout: one release, at its sample's slot, the schedule
    /// deciding when and at what delay (see [`Schedule`]).
    pub(super) fn release_apart(&mut self, at: Instant, t: Instant) {
        let running = self.phase == Phase::Running;
        let Some((s, cx)) = self.adaptive() else {
            return;
        };
        let plan = if running {
            s.before_release(at, t, &cx)
        } else {
            s.stop();
            return;
        };
        self.delay_events();
        let pending = match plan {
            Plan::Later(slot) => {
                // A remote's tick moves with its release, so that its state
                // still answers the command.
                if self.config.role == Role::Remote && self.next_tick == Some(at) {
                    self.next_tick = Some(slot);
                }
                return;
            }
            Plan::Now(pending) => pending,
        };
        let fresh = self.stats.released_fresh;
        self.release(at, t);
        self.watch(t);
        let stamp = match &self.rel.last {
            Some(r) if self.stats.released_fresh > fresh => Some(r.sent_at),
            _ => None,
        };
        if let Some((s, cx)) = self.adaptive() {
            s.after_release(at, t, pending, stamp, &cx);
        }
        self.delay_events();
    }

    /// Adaptive: a sample lost (late or skipped) spends the late rate.
    pub(super) fn note_lost(&mut self) {
        if let Some(Target::Adaptive(a)) = &mut self.target {
            a.note_late();
        }
    }

    /// The release scheduled at `at`, run (and stamped) at `t`.
    pub(super) fn release(&mut self, at: Instant, t: Instant) {
        let unset = self.schedule.as_ref().map(Schedule::delay) == Some(None);
        let outcome = match self.target.as_ref().map(TargetDelay::target) {
            // Adaptive: nothing is due before the delay is set.
            Some(_) if unset => self.not_started(),
            Some(target) => self.release_target(at, target),
            None => self.release_fifo(),
        };
        self.deliver(t, outcome);
    }

    pub(super) fn release_fifo(&mut self) -> Tick<Slot<S::Values>> {
        match (self.config.underflow, self.rel.due_seq) {
            (Underflow::DropLate, Some(due)) => {
                while self.regulator.front().is_some_and(|s| s.head.seq < due) {
                    let _ = self.regulator.discard_front();
                    self.stats.late += 1;
                }
                self.regulator.tick_if(|s| s.head.seq == due)
            }
            _ => self.regulator.tick(),
        }
    }

    /// One tick of a target-delay playout: the sample whose slot (the first
    /// tick at or after `sent_at + D`) is this tick is released. Until the
    /// policy has a target and the first sample is due, ticks release
    /// nothing and count nothing (like the FIFO's pre-fill).
    pub(super) fn release_target(
        &mut self,
        t: Instant,
        target: Option<Duration>,
    ) -> Tick<Slot<S::Values>> {
        let Some(d) = target else {
            return self.not_started();
        };
        let mut cutoff = self.release_cutoff(t, d);
        // Adaptive, more than one due: stamps bunched (a send that left late,
        // or the clock estimate moved the slots earlier). The delay rises by
        // as many ticks instead of skipping samples, and this release takes
        // the oldest of them, so that each later release has one due: were
        // it to take none, the same samples would be due again at the next
        // release, and the delay would rise without end.
        let mut oldest = false;
        let bunched = self.schedule.is_some()
            && self
                .regulator
                .iter()
                .take_while(|s| s.head.sent_at <= cutoff)
                .count()
                > 1;
        let second = self.regulator.iter().nth(1).map(|s| s.head.sent_at);
        if let (Some(s), true, Some(second)) = (&mut self.schedule, bunched, second)
            && s.rise_past(cutoff, second)
        {
            self.delay_events();
            cutoff = self.release_cutoff(t, d);
            oldest = true;
        }
        let due = |s: &Slot<S::Values>| s.head.sent_at <= cutoff;
        if self.config.underflow == Underflow::DropLate {
            // The target fell: older samples share this tick's slot with a
            // newer one. The newest due is released, the others skipped.
            while self.regulator.iter().nth(1).is_some_and(due) {
                let _ = self.regulator.discard_front();
                self.stats.skipped += 1;
                self.note_lost();
            }
            self.rel.passed = Some(self.rel.passed.map_or(cutoff, |p| p.max(cutoff)));
        }
        let release = |s: &Slot<S::Values>| oldest || due(s);
        if self.regulator.phase() == regulator::Phase::Prefilling
            && !self.regulator.front().is_some_and(release)
        {
            return self.not_started();
        }
        self.regulator.tick_if(release)
    }

    /// Nothing released yet: not an underflow.
    pub(super) fn not_started(&self) -> Tick<Slot<S::Values>> {
        Tick::Prefilling {
            have: self.regulator.len(),
            need: 1,
        }
    }

    /// The end-to-end delay a sample released at `t` gets: for the adaptive
    /// policy the delay it keeps, for the others their target.
    pub(super) fn current_delay(&self, _t: Instant) -> Option<Duration> {
        match &self.schedule {
            Some(s) => s.delay(),
            None => self.target.as_ref()?.target(),
        }
    }

    /// Frames sent (peer clock) at or before this have their slot at or
    /// before the tick `t` for a target delay `d` (the adaptive schedule's
    /// own delay and clock mapping once it has them; the other policies
    /// take the two clocks as one).
    pub(super) fn release_cutoff(&self, t: Instant, d: Duration) -> Instant {
        match &self.schedule {
            Some(s) => s.release_cutoff(t, d, &self.sync),
            None => t - d,
        }
    }

    /// Adaptive: the floor of the raw delays at `t` (ns), to which its
    /// target is relative; `None` under another playout.
    pub(super) fn floor_ns(&self, t: Instant) -> Option<i64> {
        self.schedule.as_ref()?;
        schedule::floor_ns(&self.sync, t)
    }

    /// A target playout other than the adaptive one: sets the delay and
    /// emits [`Event::DelayChanged`] when the delay in ticks changes.
    pub(super) fn track_delay(&mut self, t: Instant) {
        let Some(d) = self.current_delay(t) else {
            return;
        };
        let ticks = d.as_nanos().div_ceil(self.period.as_nanos().max(1));
        self.announce(d, ticks);
    }

    pub(super) fn announce(&mut self, d: Duration, ticks: u64) {
        self.stats.playout_delay_s = d.as_secs_f64();
        self.stats.playout_delay_ticks = ticks;
        if self.rel.delay_ticks != Some(ticks) {
            self.rel.delay_ticks = Some(ticks);
            self.stats.delay_changes += 1;
            self.emit(Event::DelayChanged { delay: d, ticks });
        }
    }

    pub(super) fn deliver(&mut self, t: Instant, outcome: Tick<Slot<S::Values>>) {
        match outcome {
            Tick::Released(slot) => {
                self.stats.released_fresh += 1;
                self.rel.last_fresh = t;
                self.rel.released_seq = Some(slot.head.seq);
                // A forged `seq` may be near the end of the count: the slot
                // due stays at its end.
                self.rel.due_seq = Some(slot.head.seq.saturating_add(1));
                let grtt = slot.peer_released.and_then(|k| self.measure_grtt(t, k));
                if let Some(g) = grtt {
                    self.round_trip_event(g);
                }
                let release = Release::fresh(slot.head, slot.values, slot.len, t, grtt);
                match &mut self.rel.last {
                    Some(last) => last.copy_from(&release),
                    None => self.rel.last = Some(release.clone()),
                }
                self.emit(Event::Released(release));
            }
            Tick::Underflow => {
                self.stats.underflows += 1;
                if self.config.underflow == Underflow::Hold {
                    self.stats.late += 1;
                }
                if self.target.is_none() {
                    // FIFO slots are one per tick: this tick's slot is gone.
                    self.rel.due_seq = self.rel.due_seq.map(|d| d.saturating_add(1));
                }
                if let Some(mut held) = self.rel.last.clone() {
                    held.status = Status::Held;
                    held.released_at = t;
                    held.grtt = None;
                    self.stats.released_held += 1;
                    self.emit(Event::Released(held));
                }
            }
            Tick::Prefilling { .. } => {}
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
        let (Some(limit), Some(_)) = (self.config.watchdog, self.rel.due_seq) else {
            return;
        };
        let silent_for = t - self.rel.last_fresh;
        if silent_for >= limit && !self.rel.lost {
            self.rel.lost = true;
            self.stats.link_lost += 1;
            self.emit(Event::LinkLost { silent_for });
        } else if silent_for.is_zero() && self.rel.lost {
            self.rel.lost = false;
            self.emit(Event::LinkRestored);
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
    /// Target-delay playout: frames sent at or before this (peer clock) had
    /// their slot at a tick already run.
    pub(super) passed: Option<Instant>,
    pub(super) released_seq: Option<u64>,
    pub(super) grtt_acked: Option<u64>,
    pub(super) due_seq: Option<u64>,
    pub(super) last: Option<Release<V>>,
    /// Last fresh release, or the start of the running phase, for the watchdog.
    pub(super) last_fresh: Instant,
    pub(super) lost: bool,
    /// A target playout other than the adaptive one: the constant
    /// end-to-end delay now, in ticks (rounded up).
    pub(super) delay_ticks: Option<u64>,
    /// The round trip in ticks last announced.
    pub(super) round_trip_ticks: Option<u64>,
}

impl<V> Released<V> {
    pub(super) fn new(now: Instant) -> Self {
        Released {
            passed: None,
            released_seq: None,
            grtt_acked: None,
            due_seq: None,
            last: None,
            last_fresh: now,
            lost: false,
            delay_ticks: None,
            round_trip_ticks: None,
        }
    }
}
