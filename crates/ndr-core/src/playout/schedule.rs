//! When the adaptive playout releases each sample: its release schedule
//! ([`Schedule`]).

use heapless::Deque;

use super::AdaptiveSlot;
use crate::sync::ClockSync;
use crate::time::{Duration, Instant};
use crate::wire::Role;

/// The adaptive delay's dead band, in bands ([`dead_band`]): it rises past
/// its delay only when the measured need does, or when the need passes it
/// by this many bands; it falls only when the need is a band and this many
/// under it, and then to this many bands over the need, so that a quantile
/// that wobbles does not move the delay back and forth (each rise repeats
/// a sample or brings a release later).
pub(crate) const HYSTERESIS: f64 = 0.5;

/// The adaptive delay falls only when its need is this share of it under
/// it (see `Schedule::fall_band`).
pub(crate) const FALL_SHARE: f64 = 0.05;

/// The adaptive delay falls by bringing its releases forward by
/// `T / RELEASE_SLEW_STEPS` per release (releases every 0.9·T while it
/// falls): no sample is skipped.
pub(crate) const RELEASE_SLEW_STEPS: u64 = 10;

/// The share of its late budget the adaptive window must have used before
/// a silence is held for being cheap (see [`Schedule::before_release`]):
/// below it, the late rate is under its target anyway.
pub(crate) const BINDING: f64 = 0.5;

/// The release schedule follows the clock estimate by at most
/// `T / MAPPING_SLEW` per release: an update of the offset estimate moves
/// the releases over several periods, not in one.
pub(crate) const MAPPING_SLEW: u64 = 20;

/// Over [`DEAD_BAND`] periods the adaptive delay is a whole number of
/// quanta `q = T/⌈T/1 ms⌉`, the period cut in parts of a millisecond at
/// most: the releases are at the samples' slots, apart from the ticks, so
/// the delay need not be a whole number of periods, and a coarser step
/// wastes up to a step each way (a 20 ms step over a two-level route flap
/// was up to a fifth of the delay). What keeps a wobbling quantile from
/// moving the delay is then the dead band, not the step. Up to 20 ms the
/// quantum is the period, and the dead band too.
pub(super) const DELAY_QUANTUM: Duration = Duration::from_millis(1);

/// The dead band of the default quantum, `T/⌈T/20 ms⌉`: whole periods up
/// to 20 ms, a fraction of the period beyond (15 ms at `T = 30 ms`, 20 ms
/// at the paper's 200 ms). A quantile wobbles by a few milliseconds as its
/// window's blocks rotate.
pub(super) const DEAD_BAND: Duration = Duration::from_millis(20);

/// The quantum of the adaptive delay at period `T` when `asked` is asked
/// for ([`Playout::Adaptive`](super::Playout::Adaptive)'s `quantum`):
/// `T/⌈T/asked⌉`, the period cut in the fewest equal parts no longer than
/// `asked` (the period itself when `asked` is longer), so that the
/// releases keep to a lattice of the ticks. `None` asks for the default:
/// the period up to 20 ms, `T/⌈T/1 ms⌉` beyond.
#[must_use]
pub fn delay_quantum(period: Duration, asked: Option<Duration>) -> Duration {
    let asked = asked.unwrap_or(if period > DEAD_BAND {
        DELAY_QUANTUM
    } else {
        DEAD_BAND
    });
    let per = period.as_nanos().max(1);
    let parts = per.div_ceil(asked.as_nanos().max(1)).max(1);
    Duration::from_nanos(per / parts)
}

/// The dead band of the adaptive delay at period `T` ([`HYSTERESIS`]): the
/// quantum asked for, if any (a delay held in whole steps), else
/// [`DEAD_BAND`]'s `T/⌈T/20 ms⌉`.
#[must_use]
pub(super) fn dead_band(period: Duration, asked: Option<Duration>) -> Duration {
    delay_quantum(period, Some(asked.unwrap_or(DEAD_BAND)))
}

fn ns_i64(t: Instant) -> i64 {
    i64::try_from(t.as_nanos()).unwrap_or(i64::MAX)
}

fn dur_i64(d: Duration) -> i64 {
    i64::try_from(d.as_nanos()).unwrap_or(i64::MAX)
}

/// The floor of the received frames' raw delays at `t` (ns): what the
/// adaptive policy's delays are measured above.
#[must_use]
pub(crate) fn floor_ns(sync: &ClockSync, t: Instant) -> Option<i64> {
    Some((sync.floor_at(t)? * 1e9) as i64)
}

/// `local − peer` at `t` (ns), which maps send stamps to the local clock;
/// until the offset is known, the floor (as if the fastest frame took no
/// time).
#[must_use]
pub(crate) fn mapping_ns(sync: &ClockSync, t: Instant) -> Option<i64> {
    let floor = floor_ns(sync, t)?;
    Some(
        sync.offset_at(t)
            .map_or(floor, |theta| (theta * 1e9) as i64),
    )
}

/// The samples waiting for their slots, as the schedule sees them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Queued {
    /// The oldest one's send stamp (peer clock).
    pub(crate) front: Option<Instant>,
    /// The second oldest one's.
    pub(crate) second: Option<Instant>,
    /// How many wait.
    pub(crate) len: usize,
}

/// What the schedule decides on, as its owner knows it at one instant.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Context<'a, A> {
    /// The quantile policy: the delay above the floor it asks for, its late
    /// budget, its warm-up margin.
    pub(crate) policy: &'a A,
    /// The estimate of the peer's clock.
    pub(crate) sync: &'a ClockSync,
    /// The samples queued.
    pub(crate) queued: Queued,
    /// The newest Data frame received: its send stamp (peer clock) and its
    /// arrival.
    pub(crate) newest: Option<(Instant, Instant)>,
    /// The frames now arriving drain an outage's backlog.
    pub(crate) outage: bool,
    /// How far ahead of the measured need the network's forecast steers
    /// the delay (s): half the rise of the mean round trip it forecasts.
    pub(crate) lead: f64,
}

/// What [`Schedule::before_release`] decided.
#[derive(Clone, Copy, Debug, PartialEq)]
#[must_use]
pub(crate) enum Plan {
    /// The delay rose by up to half a period: the release moves later, to
    /// the slot given, and nothing is released now.
    Later(Instant),
    /// Release now; pass this to [`Schedule::after_release`].
    Now(Pending),
}

/// A release decided by [`Schedule::before_release`], for
/// [`Schedule::after_release`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Pending {
    need: Option<f64>,
    silence: Option<f64>,
    expected: Option<Instant>,
}

/// Delay changes not yet taken by the owner: a release may settle on a
/// delay at the end of a silence and rise at once after it.
const CHANGES: usize = 2;

/// The adaptive playout's release schedule.
///
/// [`Playout::Adaptive`](crate::playout::Playout::Adaptive) keeps the end-to-end
/// delay constant at a whole number of quanta ([`delay_quantum`]) over
/// the delay its quantile policy ([`Adaptive`](crate::playout::Adaptive)) asks
/// for, within a dead band ([`dead_band`]).
/// A sample sent at stamp `s` (peer clock) has its **slot** at
/// `s + θ + D` on the local clock (`θ` the clock mapping, `D` the delay),
/// and is released there, apart from the ticks that send.
///
/// [`Schedule`] holds that decision and nothing else: it reads no clock,
/// holds no sample and touches no counter. Its owner
/// ([`AdaptivePlayout`](crate::playout::AdaptivePlayout)) tells it what
/// happened — a tick, a sample queued, a release due, stamps bunched — with
/// what the endpoint knows then (the quantile policy, the clock estimate,
/// the queue's front, the newest frame). It answers when the next release
/// is ([`next_release`](Schedule::next_release)), which samples are due
/// ([`release_cutoff`](Schedule::release_cutoff)), the delay now
/// ([`delay`](Schedule::delay)), and each delay it settles on
/// ([`poll_delay_changed`](Schedule::poll_delay_changed)).
///
/// Its decisions:
///
/// - **Rise** at once to the quantum over the need (the quantile's delay
///   above the floor of the clock estimate, plus the floor's one-way delay),
///   once the measured need passes the delay, or the need passes it by
///   `HYSTERESIS` (½) bands. A rise repeats a sample, or brings the release
///   later when it is small.
/// - **Hold a silence**: a stall of the path past a slot, while it is cheap
///   or the late budget is spent, holds the delay ahead of it, so that its
///   burst is released in order rather than dropped as late; the delay then
///   falls back to where it was.
/// - **Fall** by `T / RELEASE_SLEW_STEPS` per release, once the need is
///   1 + `HYSTERESIS` bands under the delay, to `HYSTERESIS` bands over
///   the need (never under it: a fall that went past the need would rise
///   again): the releases come that much earlier, and no sample is
///   skipped.
/// - **Outage**: a silence past the watchdog is not a delay to cover; the
///   delay goes back at once to where it was before it.
#[derive(Clone, Debug)]
pub(crate) struct Schedule {
    role: Role,
    period: Duration,
    /// The step of the delay.
    quantum: Duration,
    /// The dead band ([`dead_band`]).
    band: Duration,
    watchdog: Option<Duration>,
    /// The end-to-end delay now (while it falls, the step it is at).
    delay: Option<Duration>,
    /// The delay a fall under way ends at.
    falling_to: Option<Duration>,
    /// The delay last announced.
    announced: Option<Duration>,
    /// The delay before the silence being followed, to go back to if the
    /// silence turns into an outage.
    before_silence: Option<Duration>,
    /// The next release, apart from the ticks.
    next_release: Option<Instant>,
    /// The last release's scheduled time, and the peer's send stamp its
    /// slot was for (the next slot's is a period later).
    last_slot: Option<(Instant, Instant)>,
    /// The clock mapping the schedule uses (ns): the estimate's, followed
    /// by [`MAPPING_SLEW`] at most per release.
    mapping: Option<i64>,
    changes: Deque<Duration, CHANGES>,
}

impl Schedule {
    /// The schedule of one side (`role`) at `period`, the delay in quanta of
    /// `quantum` within a dead band `band`, outages from `watchdog` of
    /// silence.
    #[must_use]
    pub(crate) fn new(
        role: Role,
        period: Duration,
        (quantum, band): (Duration, Duration),
        watchdog: Option<Duration>,
    ) -> Self {
        Schedule {
            role,
            period,
            quantum,
            band,
            watchdog,
            delay: None,
            falling_to: None,
            announced: None,
            before_silence: None,
            next_release: None,
            last_slot: None,
            mapping: None,
            changes: Deque::new(),
        }
    }

    /// The period changed (a pause resizes the link); so did the quantum
    /// and the dead band.
    pub(crate) fn set_period(&mut self, period: Duration, (quantum, band): (Duration, Duration)) {
        self.period = period;
        self.quantum = quantum;
        self.band = band;
    }

    /// A new regime starts: the schedule of the last one is dropped, the
    /// delay kept.
    pub(crate) fn restart(&mut self) {
        self.falling_to = None;
        self.next_release = None;
        self.last_slot = None;
        self.mapping = None;
    }

    /// The link ended: nothing more is released.
    pub(crate) fn stop(&mut self) {
        self.next_release = None;
    }

    /// The end-to-end delay now; `None` until the policy has a target.
    #[must_use]
    pub(crate) fn delay(&self) -> Option<Duration> {
        self.delay
    }

    /// When the next release is due.
    #[must_use]
    pub(crate) fn next_release(&self) -> Option<Instant> {
        self.next_release
    }

    /// The next delay settled on (at rest, not a step of a fall), and its
    /// ticks, in order.
    #[must_use]
    pub(crate) fn poll_delay_changed(&mut self) -> Option<(Duration, u64)> {
        self.changes.pop_front().map(|d| (d, self.ticks(d)))
    }

    /// The tick scheduled at `at` ran at `t`, the next tick being
    /// `next_tick`: until a release is scheduled, the delay is set as soon
    /// as it can be (so that the first release is at its sample's slot
    /// rather than at a tick past it, two due there: a rise), and the next
    /// release is at the next slot, or the next tick.
    pub(crate) fn on_tick<A: AdaptiveSlot>(
        &mut self,
        at: Instant,
        t: Instant,
        next_tick: Option<Instant>,
        cx: &Context<'_, A>,
    ) {
        if self.next_release.is_some() {
            return;
        }
        if self.delay.is_none()
            && let Some(need) = self.need(t, cx)
        {
            self.rise_to(need, None, cx);
        }
        self.next_release = self.next_slot(at, cx).or(next_tick);
    }

    /// The tick scheduled at `at` falls on the release just run, and the
    /// next release is about a period after it: a remote's grid has moved
    /// to its releases.
    #[must_use]
    pub(crate) fn on_release_grid(&self, at: Instant) -> bool {
        let close = |a: Instant, b: Instant| {
            a.signed_nanos_since(b).unsigned_abs() <= (self.band / 4).as_nanos()
        };
        self.last_slot.is_some_and(|(r, _)| r == at)
            && self
                .next_release
                .is_some_and(|n| close(n, at + self.period))
    }

    /// A remote's tick after `plain − T`, were it on its own grid at
    /// `plain`: the release point nearest to `plain`, so half a period to
    /// one and a half after the last. A remote ticks with its releases,
    /// which are the base's send stamps mapped to the local clock plus the
    /// delay, so that the state answering a command leaves as the command
    /// is released, and the two grids do not slide under skew.
    #[must_use]
    pub(crate) fn following_tick(&self, plain: Instant) -> Instant {
        let (Role::Remote, Some(release)) = (self.role, self.next_release) else {
            return plain;
        };
        let per = dur_i64(self.period).max(1);
        let apart = release.signed_nanos_since(plain);
        let shift = (apart + per / 2).rem_euclid(per) - per / 2;
        u64::try_from(ns_i64(plain).saturating_add(shift)).map_or(plain, Instant::from_nanos)
    }

    /// A sample was queued. On the base, one that arrives first in the
    /// queue moves the next release to its slot, if that is within half a
    /// period of the slot expected: the remote's ticks move with its
    /// delay, and a release at the expected slot would take its sample a
    /// little early or late.
    pub(crate) fn on_queued<A: AdaptiveSlot>(&mut self, cx: &Context<'_, A>) {
        let (Role::Base, 1, Some(next), Some((at, _))) =
            (self.role, cx.queued.len, self.next_release, self.last_slot)
        else {
            return;
        };
        if let Some(slot) = self.next_slot(at, cx)
            && slot.signed_nanos_since(next).unsigned_abs() < self.period.as_nanos() / 2
        {
            self.next_release = Some(slot);
        }
    }

    /// The slot of the sample sent at `stamp` (peer clock), the mapping
    /// taken at `at` until the schedule has its own.
    #[must_use]
    pub(crate) fn slot_at(&self, stamp: Instant, at: Instant, sync: &ClockSync) -> Option<Instant> {
        let d = self.delay?;
        let map = self.mapping.or_else(|| mapping_ns(sync, at))?;
        let slot = ns_i64(stamp).saturating_add(map).saturating_add(dur_i64(d));
        Some(Instant::from_nanos(u64::try_from(slot).unwrap_or(0)))
    }

    /// Frames sent (peer clock) at or before this are due at `t`: their
    /// send stamp mapped to the local clock plus the delay, less half a
    /// band (so that the estimate's noise cannot move a sample across a
    /// release), is past. Half a period at a sub-tick delay would run ahead
    /// of the arrivals: a release would pass, and so drop as late, samples
    /// still on their way to slots after it. Until the delay and the
    /// mapping are known, `t − target`.
    #[must_use]
    pub(crate) fn release_cutoff(&self, t: Instant, target: Duration, sync: &ClockSync) -> Instant {
        match (self.mapping.or_else(|| mapping_ns(sync, t)), self.delay) {
            (Some(map), Some(d)) => {
                let d = dur_i64(d) - dur_i64(self.band / 2);
                let c = ns_i64(t).saturating_sub(map).saturating_sub(d);
                Instant::from_nanos(u64::try_from(c).unwrap_or(0))
            }
            _ => t - target,
        }
    }

    /// More than one sample due at a release (stamps bunched: a send that
    /// left late, or the clock estimate moved the slots earlier), the
    /// second sent at `second`: the delay rises by just enough quanta that
    /// the second is not due, instead of skipping samples; the release then
    /// takes the oldest, so that each later release has one due. Were it to
    /// take none, the same samples would be due again at the next release,
    /// and the delay would rise without end. Returns whether it rose.
    pub(crate) fn rise_past(&mut self, cutoff: Instant, second: Instant) -> bool {
        let Some(cur) = self.delay else {
            return false;
        };
        let q = self.quantum;
        let short = (cutoff - second) + Duration::from_nanos(1);
        let quanta = (cur + short).as_nanos().div_ceil(q.as_nanos().max(1));
        self.falling_to = None;
        self.set_delay(q * quanta);
        self.announce();
        true
    }

    /// The release scheduled at `at` is run at `t`: the delay rises at once
    /// before it (the release comes later, or for a rise of more than half
    /// a period repeats the last sample), a silence is followed or let go.
    /// Nothing scheduled stays: [`after_release`](Self::after_release)
    /// schedules the next.
    pub(crate) fn before_release<A: AdaptiveSlot>(
        &mut self,
        at: Instant,
        t: Instant,
        cx: &Context<'_, A>,
    ) -> Plan {
        self.next_release = None;
        let silence = self.silence_need(t, cx);
        let resumed = self.end_silence(t, silence.is_some(), cx);
        let need = self.need(t, cx).map(|n| silence.map_or(n, |s| s.max(n)));
        let before = self.delay;
        if let Some(need) = need {
            self.rise_to(need, silence, cx);
        }
        if let (Some(was), Some(need)) = (resumed, need) {
            self.fall_back(was, need);
        }
        // A rise of up to half a period just brings the release later (a
        // remote's tick with it, so that its state still answers the
        // command); a larger one repeats the last sample now.
        if let (Some(b), Some(a)) = (before, self.delay)
            && a > b
            && let Some(slot) = self.front_slot(at, cx)
            && slot > t
            && slot <= at + self.period / 2
        {
            self.next_release = Some(slot);
            return Plan::Later(slot);
        }
        Plan::Now(Pending {
            need,
            silence,
            expected: self.expected_stamp(),
        })
    }

    /// The release planned by [`before_release`](Self::before_release) ran;
    /// `fresh` is the send stamp of the sample it released, if any. The
    /// delay falls a step, and the next release is scheduled at the next
    /// sample's slot (`cx` as after the release).
    pub(crate) fn after_release<A: AdaptiveSlot>(
        &mut self,
        at: Instant,
        t: Instant,
        pending: Pending,
        fresh: Option<Instant>,
        cx: &Context<'_, A>,
    ) {
        if let Some(need) = pending.need {
            self.fall_from(need);
        }
        // The slot was that of the sample released, or of the one expected.
        let stamp = match fresh {
            Some(stamp) => Some(stamp),
            // Following a silence, the next slot stays the missing
            // sample's: the burst's first is released at its slot, not at a
            // release scheduled for a later stamp (a period late, and the
            // next one a period early).
            None if pending.silence.is_some() => cx.newest.map(|(sent, _)| sent),
            // A silence followed, then let go: the rise may have put the
            // missing sample's slot after this release, which then passes
            // nothing.
            None if self.before_silence.is_some()
                && pending
                    .expected
                    .and_then(|s| self.slot_at(s, at, cx.sync))
                    .is_some_and(|slot| slot > t) =>
            {
                self.last_slot.map(|(_, stamp)| stamp)
            }
            None => pending.expected,
        };
        if self.delay.is_some()
            && let Some(stamp) = stamp
        {
            self.last_slot = Some((at, stamp));
        }
        if let Some(map) = mapping_ns(cx.sync, t) {
            let most = dur_i64(self.period / MAPPING_SLEW);
            self.mapping = Some(match self.mapping {
                Some(m) => m.saturating_add(map.saturating_sub(m).clamp(-most, most)),
                None => map,
            });
        }
        self.next_release = self.next_slot(at, cx);
    }

    fn ticks(&self, d: Duration) -> u64 {
        d.as_nanos().div_ceil(self.period.as_nanos().max(1))
    }

    /// The end-to-end delay the target needs (s): the floor's one-way
    /// delay plus the policy's target above it, steered ahead by the
    /// forecast (at most a quantum: a forecast may move the delay a step
    /// early, the measured delays decide the rest; a step more, held by
    /// the dead band, was an overshoot after each rise of a route flap).
    fn need<A: AdaptiveSlot>(&self, t: Instant, cx: &Context<'_, A>) -> Option<f64> {
        let d = cx.policy.target()?;
        let min_one_way = (floor_ns(cx.sync, t)? - mapping_ns(cx.sync, t)?) as f64 * 1e-9;
        Some(min_one_way + d.as_secs_f64() + cx.lead.min(self.quantum.as_secs_f64()))
    }

    /// Nothing received for as long as the watchdog allows.
    fn past_watchdog<A>(&self, t: Instant, cx: &Context<'_, A>) -> bool {
        match (self.watchdog, cx.newest) {
            (Some(w), Some((_, arrived))) => t - arrived >= w,
            _ => false,
        }
    }

    /// The delay that holds the next sample's slot a period ahead (s),
    /// while nothing is queued, its slot has passed, and either the rise is
    /// cheaper per sample saved than the quantile's way of saving one
    /// ([`Adaptive::sample_cost`](super::Adaptive::sample_cost)) with half
    /// the late budget used, or the window's late samples have used up its
    /// late rate; `None` otherwise.
    ///
    /// A silence past the slot is a stall of the path (a retransmission, a
    /// congestion episode): its frames come later, in a burst. Dropped as
    /// late, each would be lost; with the delay held ahead of the silence
    /// (the ticks repeat the last sample, as they would anyway), they are
    /// released in order, and the delay falls back to where it was. A
    /// short rise costs little (the cost grows with its square), so it is
    /// held once half the late budget is used; a longer one only once `ε`
    /// of the samples have been let go: the window's quantile sits under
    /// that many on purpose, and stretching for them would only hold the
    /// delay higher. A silence longer than the watchdog is an outage, not a
    /// delay, and is not followed.
    fn silence_need<A: AdaptiveSlot>(&self, t: Instant, cx: &Context<'_, A>) -> Option<f64> {
        // An outage's backlog still draining is no silence to follow.
        if cx.queued.len != 0 || cx.outage {
            return None;
        }
        let (sent, _) = cx.newest?;
        if self.past_watchdog(t, cx) {
            return None;
        }
        let d = self.delay?;
        // The samples after the newest that this release would pass: lost
        // if the delay stays.
        let passed = self
            .release_cutoff(t, d, cx.sync)
            .checked_duration_since(sent)?;
        let missed = passed.as_nanos() / self.period.as_nanos().max(1);
        // The delay at which the newest sample's slot would be now (the
        // cutoff is half a band past the slots): the next one's is then a
        // period ahead.
        let need = (passed + d).saturating_sub(self.band / 2);
        // Holding a rise `h` saves `h/T` samples and, as the delay falls
        // back by `T/RELEASE_SLEW_STEPS` per release, costs
        // `h²·RELEASE_SLEW_STEPS/(2T)` of delay summed over the releases:
        // the last sample saved, `h·RELEASE_SLEW_STEPS`. Worth it while
        // that is below what the quantile pays for one. A lost sample costs
        // that only while the budget binds: with most of it unspent, the
        // quantile is already above what the late rate asks, and a hold
        // would only make the delay vary. (The cost's two scans of the
        // histogram only when it can decide.)
        let rise = need.saturating_sub(self.before_silence.unwrap_or(d));
        let used = cx.policy.budget_used(missed);
        let cheap = || rise.saturating_mul(RELEASE_SLEW_STEPS) <= cx.policy.sample_cost();
        (missed >= 1 && (used > 1.0 || (used >= BINDING && cheap())))
            .then_some(need.as_nanos() as f64 * 1e-9)
    }

    /// Notes where a followed silence started, and ends it: when a sample
    /// is queued again (the delay then falls as after any rise), or when
    /// the silence outlasts the watchdog. An outage is not a delay to
    /// cover: the delay goes back at once to where it was (nothing is
    /// queued, so no sample is skipped), instead of falling for as long as
    /// it rose.
    ///
    /// Returns the delay before the silence when its burst has come.
    fn end_silence<A: AdaptiveSlot>(
        &mut self,
        t: Instant,
        following: bool,
        cx: &Context<'_, A>,
    ) -> Option<Duration> {
        if following {
            if self.before_silence.is_none() {
                self.before_silence = self.delay;
            }
            return None;
        }
        let before = self.before_silence?;
        if cx.queued.len != 0 {
            self.before_silence = None;
            return Some(before);
        }
        if self.past_watchdog(t, cx) {
            self.before_silence = None;
            if self.delay.is_some_and(|d| d > before) {
                self.falling_to = None;
                self.set_delay(before);
                self.announce();
            }
            // The next slot was held on the missing sample's: back to the
            // stamp due now, or the releases would repeat the last sample
            // twice a period until the expected stamps caught up.
            let map = self.mapping.or_else(|| mapping_ns(cx.sync, t));
            if let (Some((at, stamp)), Some(map)) = (self.last_slot, map) {
                let due = ns_i64(t)
                    .saturating_sub(map)
                    .saturating_sub(dur_i64(before));
                let per = self.period.as_nanos().max(1);
                let behind = u64::try_from(due.saturating_sub(ns_i64(stamp))).unwrap_or(0);
                self.last_slot = Some((at, stamp + self.period * (behind / per)));
            }
        }
        None
    }

    /// A held silence's burst has come. The delay falls back to where it
    /// was before the silence (or to the quantum over the need, if that is
    /// higher), by `T / RELEASE_SLEW_STEPS` per release: the rise was for
    /// the silence's samples only, and the hysteresis would keep a rise of
    /// a quantum for good.
    fn fall_back(&mut self, was: Duration, need: f64) {
        let Some(d) = self.delay else {
            return;
        };
        let to = was.max(self.quanta_over(need));
        if to < d {
            self.falling_to = Some(to);
        }
    }

    /// The peer's send stamp the next slot is for, when no sample is
    /// queued: a period after the last slot's.
    fn expected_stamp(&self) -> Option<Instant> {
        self.last_slot.map(|(_, stamp)| stamp + self.period)
    }

    /// When the next release is due, after the one scheduled at `at`: the
    /// slot of the oldest sample queued, or of the one expected a period
    /// after the last; at least half a period after `at`. A slot further
    /// than one and a half periods away (the delay rose by more than half a
    /// period) gets a release a period after `at` first, which repeats the
    /// last sample: one release per period or so.
    fn next_slot<A>(&self, at: Instant, cx: &Context<'_, A>) -> Option<Instant> {
        let slot = self.front_slot(at, cx)?;
        if slot > at + self.period + self.period / 2 {
            return Some(at + self.period);
        }
        Some(slot.max(at + self.period / 2))
    }

    /// The slot of the oldest sample queued, or of the one expected a
    /// period after the last.
    fn front_slot<A>(&self, at: Instant, cx: &Context<'_, A>) -> Option<Instant> {
        let stamp = match cx.queued.front {
            Some(s) => s,
            None => self.expected_stamp()?,
        };
        self.slot_at(stamp, at, cx.sync)
    }

    /// Rises to the quantum at or above `need` (s) at once (a fall under
    /// way is given up): once a delay is set, when what the delays measured
    /// ask for passes it — `need` less the policy's warm-up margin, or the
    /// `silence` followed — or when `need` passes it by [`HYSTERESIS`]
    /// bands. A rise repeats a sample, and the margin is a guess: with the
    /// need a hair under a quantum boundary, the first estimates of the
    /// clocks must not cross it and repeat a sample no late one called for.
    fn rise_to<A: AdaptiveSlot>(&mut self, need: f64, silence: Option<f64>, cx: &Context<'_, A>) {
        if let Some(d) = self.delay.map(Duration::as_secs_f64) {
            if need <= d {
                return;
            }
            let margin = cx.policy.margin().as_secs_f64();
            let measured = silence.map_or(need - margin, |s| s.max(need - margin));
            let band = HYSTERESIS * self.band.as_secs_f64();
            if measured <= d && need <= d + band {
                return;
            }
        }
        self.falling_to = None;
        self.set_delay(self.quanta_over(need));
        self.announce();
    }

    /// The delay in whole quanta at or over `need` (s), one at least.
    fn quanta_over(&self, need: f64) -> Duration {
        let q = self.quantum;
        q * (libm::ceil(need / q.as_secs_f64()).max(1.0) as u64)
    }

    /// The delay falls by `T / RELEASE_SLEW_STEPS` per release (the
    /// releases come that much earlier), from where
    /// [`fall_start`](Self::fall_start) says.
    fn fall_from(&mut self, need: f64) {
        let Some(d) = self.delay else {
            return;
        };
        let to = match self.falling_to {
            Some(to) => to,
            None => {
                let Some(to) = self.fall_start(d, need) else {
                    return;
                };
                self.falling_to = Some(to);
                to
            }
        };
        let step = (self.period / RELEASE_SLEW_STEPS).min(d - to);
        self.set_delay(d - step);
        if d - step <= to {
            self.falling_to = None;
            self.announce();
        }
    }

    /// Where a fall from `d` ends, if the need calls for one. In quanta
    /// finer than the dead band: once the need is a fall band
    /// ([`fall_band`](Self::fall_band)) and [`HYSTERESIS`] of one under
    /// the delay, to [`HYSTERESIS`] of a fall band over the need, at once
    /// where the level now is and never under the need (a fall past it
    /// would rise again). In whole steps of the band (up to 20 ms, or a
    /// quantum asked for): a quantum at a time, once the need is
    /// [`HYSTERESIS`] quanta under the quantum below the delay.
    fn fall_start(&self, d: Duration, need: f64) -> Option<Duration> {
        let q = self.quantum;
        if q >= self.band {
            // The quantum strictly below the delay, at least one.
            let to = q * (d.as_nanos().saturating_sub(1) / q.as_nanos().max(1));
            return (to >= q && need <= to.as_secs_f64() - HYSTERESIS * q.as_secs_f64())
                .then_some(to);
        }
        let band = self.fall_band(d);
        let to = self.quanta_over(need + HYSTERESIS * band.as_secs_f64());
        (to + band <= d).then_some(to)
    }

    /// How far under the delay `d` the need must be for it to fall:
    /// [`FALL_SHARE`] of it, two quanta at least and a band and a half at
    /// most. A quantile's wobble grows with the delay it measures.
    fn fall_band(&self, d: Duration) -> Duration {
        let share = Duration::from_secs_f64(d.as_secs_f64() * FALL_SHARE);
        let most = self.band + self.band / 2;
        share.max(self.quantum * 2).min(most.max(self.quantum * 2))
    }

    fn set_delay(&mut self, d: Duration) {
        self.delay = Some(d);
    }

    /// A delay at rest that is not the last one announced is a change.
    fn announce(&mut self) {
        let Some(delay) = self.delay else {
            return;
        };
        if self.announced != Some(delay) {
            self.announced = Some(delay);
            if self.changes.is_full() {
                // Taken after every call: only an owner that never polls
                // gets here, and the newest delay is what it needs.
                let _ = self.changes.pop_front();
            }
            let _ = self.changes.push_back(delay);
        }
    }
}

#[cfg(test)]
mod tests;
