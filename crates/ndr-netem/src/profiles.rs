//! The built-in models: congestion episodes (Paris–New York), a jittery
//! LAN, and the paper's Fig. 6 generator.

use core::f64::consts::TAU;

use ndr_core::time::{Duration, Instant};
use rand::{Rng, RngExt};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Gamma};

use super::Direction;

/// Per-frame jitter: `base + min(cap, X)` with `X` gamma-distributed, the
/// waiting time of a few Poisson events ("Poisson-like", paper §3.1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JitterParams {
    /// Fixed part (propagation, transmission), s.
    pub base_s: f64,
    /// Mean of the random part before capping, s.
    pub mean_s: f64,
    /// Gamma shape `k` (1 = exponential; larger is more regular).
    pub shape: f64,
    /// Largest random part, s: keeps the jitter bounded.
    pub cap_s: f64,
}

/// `lan-75km`: 7 ms fixed plus an Erlang-3 of mean 4.5 ms capped at 15 ms:
/// one-way 11.5 ms mean, 2.6 ms standard deviation.
pub const LAN_75KM: JitterParams = JitterParams {
    base_s: 0.007,
    mean_s: 0.0045,
    shape: 3.0,
    cap_s: 0.015,
};

/// Parameters of the congestion-episode model behind `paris-newyork` (see the
/// module docs for the picture). Times in seconds. Values out of range are
/// clamped when a sampler is made (negative or NaN to zero, ranges put in
/// order, the slot to at least 1 ms), never a panic.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpisodeParams {
    /// Per-frame jitter of each direction, independent between directions.
    pub jitter: JitterParams,
    /// Mean time between episode onsets: one episode per slot of this length.
    pub slot_s: f64,
    /// The onset falls uniformly within the first `onset_spread_s` of its
    /// slot (0 = strictly periodic, `slot_s` = anywhere in the slot).
    pub onset_spread_s: f64,
    /// Probability that a slot has an episode at all.
    pub occurrence: f64,
    /// Extra delay during an episode, drawn uniformly in this range,
    /// independently for each direction.
    pub height_s: (f64, f64),
    /// How long each direction holds the full height, drawn uniformly.
    pub hold_s: (f64, f64),
    /// After the hold the extra delay falls at this rate (s per s); infinite
    /// for a sudden end. In-order delivery turns any fall faster than 1 into
    /// a burst of frames.
    pub fall_rate: f64,
    /// The backward episode starts `base + forward height + lag` after the
    /// forward one: when the frames caught in the forward episode reach the
    /// remote, so the replies to them are caught too.
    pub backward_lag_s: f64,
}

/// `paris-newyork`: calibrated so that the simulator measures the paper's
/// NRTT (610 ms mean, 500 ms standard deviation); see the module docs.
pub const PARIS_NEW_YORK: EpisodeParams = EpisodeParams {
    jitter: JitterParams {
        base_s: 0.11,
        mean_s: 0.025,
        shape: 4.0,
        cap_s: 0.3,
    },
    slot_s: 3.75,
    onset_spread_s: 0.35,
    occurrence: 1.0,
    height_s: (0.90, 0.90),
    hold_s: (0.36, 0.36),
    fall_rate: 1.0,
    backward_lag_s: 0.16,
};

/// Jitter sampler: the gamma is built once.
#[derive(Clone, Debug)]
pub(super) struct Jitter {
    base_s: f64,
    cap_s: f64,
    gamma: Option<Gamma<f64>>,
}

impl Jitter {
    pub(super) fn new(p: JitterParams) -> Self {
        let base_s = finite_non_negative(p.base_s);
        let mean_s = finite_non_negative(p.mean_s);
        let cap_s = finite_non_negative(p.cap_s);
        let shape = finite_non_negative(p.shape);
        // No random part when the mean or shape is zero (Gamma refuses them).
        let gamma = if mean_s > 0.0 && shape > 0.0 {
            Gamma::new(shape, mean_s / shape).ok()
        } else {
            None
        };
        Jitter {
            base_s,
            cap_s,
            gamma,
        }
    }

    fn sample_s<R: Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        let x = self.gamma.as_ref().map_or(0.0, |g| g.sample(rng));
        self.base_s + x.min(self.cap_s)
    }

    pub(super) fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> Duration {
        Duration::from_secs_f64(self.sample_s(rng))
    }
}

fn finite_non_negative(x: f64) -> f64 {
    if x.is_finite() && x > 0.0 { x } else { 0.0 }
}

fn ordered(r: (f64, f64)) -> (f64, f64) {
    let (a, b) = (finite_non_negative(r.0), finite_non_negative(r.1));
    if a <= b { (a, b) } else { (b, a) }
}

/// One episode, as drawn for its slot.
#[derive(Clone, Copy, Debug, Default)]
struct Episode {
    slot: u64,
    present: bool,
    onset_s: f64,
    height: [f64; 2],
    hold: [f64; 2],
}

/// Episodes remembered, so that consecutive calls do not redraw them.
const CACHE: usize = 8;
/// Most slots looked back at per call, whatever the parameters.
const MAX_LOOKBACK: u64 = 64;
/// ChaCha words reserved per slot (one block).
const WORDS_PER_SLOT: u128 = 16;

/// The congestion-episode model: shared episodes, drawn by random access in
/// the shared stream so that they are a function of (seed, time) only.
#[derive(Clone, Debug)]
pub(super) struct Episodes {
    p: EpisodeParams,
    jitter: Jitter,
    shared: ChaCha8Rng,
    slot_ns: u64,
    phase_ns: u64,
    lookback: u64,
    cache: [Option<Episode>; CACHE],
}

impl Episodes {
    pub(super) fn new(params: EpisodeParams, mut shared: ChaCha8Rng) -> Self {
        let mut p = params;
        p.jitter.base_s = finite_non_negative(p.jitter.base_s);
        p.slot_s = finite_non_negative(p.slot_s).max(1e-3);
        p.onset_spread_s = finite_non_negative(p.onset_spread_s).min(p.slot_s);
        p.occurrence = finite_non_negative(p.occurrence).min(1.0);
        p.height_s = ordered(p.height_s);
        p.hold_s = ordered(p.hold_s);
        if p.fall_rate.is_nan() || p.fall_rate <= 0.0 {
            // NaN, zero or negative: a sudden end is the safe reading.
            p.fall_rate = f64::INFINITY;
        }
        if !p.backward_lag_s.is_finite() {
            p.backward_lag_s = 0.0;
        }
        let slot_ns = Duration::from_secs_f64(p.slot_s).as_nanos().max(1);
        // Block 0 of the shared stream: the grid's phase, so that t = 0 is
        // not special (the process is stationary from the first frame).
        shared.set_word_pos(0);
        let phase_ns = (shared.random::<f64>() * slot_ns as f64) as u64 % slot_ns;
        // How long an episode can act after its slot starts, backward
        // direction included.
        let (h_max, hold_max) = (p.height_s.1, p.hold_s.1);
        let fall = if p.fall_rate.is_finite() {
            h_max / p.fall_rate
        } else {
            0.0
        };
        let reach = p.onset_spread_s
            + p.jitter.base_s
            + h_max
            + p.backward_lag_s.max(0.0)
            + hold_max
            + fall;
        let lookback = ((reach / p.slot_s).ceil().max(0.0) as u64)
            .saturating_add(1)
            .min(MAX_LOOKBACK);
        Episodes {
            jitter: Jitter::new(p.jitter),
            p,
            shared,
            slot_ns,
            phase_ns,
            lookback,
            cache: [None; CACHE],
        }
    }

    /// Slot `n` starts at `phase − slot + n·slot` (slot 0 starts before the
    /// origin, so every `t ≥ 0` is in a slot `n ≥ 0`).
    fn episode(&mut self, n: u64) -> Episode {
        let entry = (n % CACHE as u64) as usize;
        if let Some(Some(e)) = self.cache.get(entry)
            && e.slot == n
        {
            return *e;
        }
        let rng = &mut self.shared;
        rng.set_word_pos(u128::from(n).saturating_add(1) * WORDS_PER_SLOT);
        let mut u = || rng.random::<f64>();
        let start_s = n as f64 * self.p.slot_s - (self.slot_ns - self.phase_ns) as f64 * 1e-9;
        let (h, hold) = (self.p.height_s, self.p.hold_s);
        let onset_s = start_s + self.p.onset_spread_s * u();
        let height = [h.0 + (h.1 - h.0) * u(), h.0 + (h.1 - h.0) * u()];
        let hold = [
            hold.0 + (hold.1 - hold.0) * u(),
            hold.0 + (hold.1 - hold.0) * u(),
        ];
        let present = u() < self.p.occurrence;
        let e = Episode {
            slot: n,
            present,
            onset_s,
            height,
            hold,
        };
        if let Some(c) = self.cache.get_mut(entry) {
            *c = Some(e);
        }
        e
    }

    /// Extra delay of the episodes for a frame sent at `t_s` in `dir`.
    fn extra_s(&mut self, dir: Direction, sent_at: Instant) -> f64 {
        let t_ns = sent_at.as_nanos();
        let n = t_ns
            .saturating_add(self.slot_ns - self.phase_ns)
            .checked_div(self.slot_ns)
            .unwrap_or(0);
        let t_s = sent_at.as_secs_f64();
        let d = dir.index();
        let mut extra: f64 = 0.0;
        for m in n.saturating_sub(self.lookback)..=n {
            let e = self.episode(m);
            if !e.present {
                continue;
            }
            let start = match dir {
                Direction::Forward => e.onset_s,
                Direction::Backward => {
                    e.onset_s + self.p.jitter.base_s + e.height[0] + self.p.backward_lag_s
                }
            };
            let dt = t_s - start;
            let (h, hold) = (e.height[d], e.hold[d]);
            let v = if dt < 0.0 {
                0.0
            } else if dt < hold {
                h
            } else {
                (h - self.p.fall_rate * (dt - hold)).max(0.0)
            };
            extra = extra.max(v);
        }
        extra
    }

    pub(super) fn delay(
        &mut self,
        rng: &mut ChaCha8Rng,
        dir: Direction,
        sent_at: Instant,
    ) -> Duration {
        let extra = self.extra_s(dir, sent_at);
        Duration::from_secs_f64(self.jitter.sample_s(rng) + extra)
    }
}

/// Length of the `paper-fig6` scenario: 20 minutes, as in the paper.
pub const FIG6_DURATION: Duration = Duration::from_secs(20 * 60);
/// When `paper-fig6`'s mean steps up, s.
pub const FIG6_STEP_AT_S: f64 = 720.0;

/// The generating one-way mean and standard deviation of `paper-fig6` at
/// time `t_s`, in seconds:
///
/// ```text
/// mean(t) = 0.300 + 0.100·sin(2π t / 420 s) + (0.150 if t ≥ 720 s)
/// std(t)  = 0.110 + 0.060·sin(2π t / 300 s + 1)
/// ```
///
/// so the mean wanders between 200 and 400 ms, then 350 and 550 ms after the
/// step at 12 minutes, and the standard deviation between 50 and 170 ms.
/// Negative or NaN times count as 0; the sines go on past 20 minutes.
#[must_use]
pub fn fig6_truth(t_s: f64) -> (f64, f64) {
    let t = if t_s.is_finite() { t_s.max(0.0) } else { 0.0 };
    let step = if t >= FIG6_STEP_AT_S { 0.150 } else { 0.0 };
    // Phases in turns, reduced before the sine for precision at large t.
    let mean = 0.300 + 0.100 * libm::sin(TAU * (t / 420.0).fract()) + step;
    let std = 0.110 + 0.060 * libm::sin(TAU * (t / 300.0).fract() + 1.0);
    (mean, std)
}

/// A `paper-fig6` delay: gamma with the mean and standard deviation of
/// [`fig6_truth`] at the send time.
pub(super) fn fig6_sample<R: Rng + ?Sized>(rng: &mut R, sent_at: Instant) -> Duration {
    let (mean, std) = fig6_truth(sent_at.as_secs_f64());
    // Gamma with shape (m/s)² and scale s²/m has mean m and deviation s.
    let x = Gamma::new((mean / std).powi(2), std * std / mean).map_or(mean, |g| g.sample(rng));
    Duration::from_secs_f64(x)
}
