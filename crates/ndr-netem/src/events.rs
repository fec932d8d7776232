//! Delay scenarios with known events, for comparing playout policies: a
//! step in the base delay, delay spikes, TCP head-of-line stalls, and a
//! route that flaps between two levels, each on top of i.i.d. per-frame
//! jitter. Both directions see the same events.

use std::vec::Vec;

use ndr_core::time::{Duration, Instant};
use rand_chacha::ChaCha8Rng;

use super::Direction;
use super::profiles::{Jitter, JitterParams};

/// A delay scenario: per-frame jitter plus events at known times.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EventParams {
    /// Per-frame jitter of each direction, independent between directions.
    pub jitter: JitterParams,
    /// What happens, and when.
    pub kind: EventKind,
}

/// The events of an [`EventParams`] scenario. Times in seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EventKind {
    /// From `at_s` on, every delay is `by_s` longer.
    Step {
        /// When.
        at_s: f64,
        /// By how much (may be negative; delays stay ≥ 0).
        by_s: f64,
    },
    /// At `first_s`, then every `every_s`, the delay jumps up by `height_s`
    /// and falls back at `fall_rate` s per s (Ramjee et al.'s spikes).
    Spikes {
        /// The first onset.
        first_s: f64,
        /// Time between onsets.
        every_s: f64,
        /// The jump.
        height_s: f64,
        /// The fall, in seconds of delay per second.
        fall_rate: f64,
    },
    /// At `first_s`, then every `every_s`, the first frame sent is held
    /// `stall_s` longer: in-order delivery holds the frames behind it, which
    /// then arrive in one burst (a TCP retransmission stall).
    Stalls {
        /// The first onset.
        first_s: f64,
        /// Time between onsets.
        every_s: f64,
        /// How long the stalled frame is held.
        stall_s: f64,
    },
    /// From `first_s` the path flips between two routes every `every_s`:
    /// `by_s` longer for `every_s`, then back for `every_s`, and so on (a
    /// route flap). Each flip, up or down, is an onset.
    Flaps {
        /// The first flip (up).
        first_s: f64,
        /// Time between flips.
        every_s: f64,
        /// How much longer the second route is.
        by_s: f64,
    },
}

impl EventParams {
    /// The onsets of the events before `until_s`, in seconds.
    #[must_use]
    pub fn onsets(&self, until_s: f64) -> Vec<f64> {
        let periodic = |first: f64, every: f64| {
            let every = if every.is_finite() && every > 0.0 {
                every
            } else {
                f64::INFINITY
            };
            (0..)
                .map(move |k| first + every * f64::from(k))
                .take_while(move |&t| t < until_s && t.is_finite())
                .take(1_000_000)
                .collect()
        };
        match self.kind {
            EventKind::Step { at_s, .. } => {
                if at_s < until_s {
                    std::vec![at_s]
                } else {
                    Vec::new()
                }
            }
            EventKind::Spikes {
                first_s, every_s, ..
            }
            | EventKind::Stalls {
                first_s, every_s, ..
            }
            | EventKind::Flaps {
                first_s, every_s, ..
            } => periodic(first_s, every_s),
        }
    }
}

/// The sampler's state: the jitter, and per direction the next stall.
#[derive(Clone, Debug)]
pub(super) struct Events {
    p: EventParams,
    jitter: Jitter,
    next_stall: [u64; 2],
}

impl Events {
    pub(super) fn new(p: EventParams) -> Self {
        Events {
            jitter: Jitter::new(p.jitter),
            p,
            next_stall: [0; 2],
        }
    }

    /// Index of the newest periodic onset at or before `t`, if any.
    fn newest(first: f64, every: f64, t: f64) -> Option<(u64, f64)> {
        if t.is_nan() || t < first {
            return None;
        }
        if !(every.is_finite() && every > 0.0) {
            return Some((0, first));
        }
        let k = ((t - first) / every).floor();
        Some((k as u64, first + k * every))
    }

    pub(super) fn delay(
        &mut self,
        rng: &mut ChaCha8Rng,
        dir: Direction,
        sent_at: Instant,
    ) -> Duration {
        let t = sent_at.as_secs_f64();
        let extra = match self.p.kind {
            EventKind::Step { at_s, by_s } => {
                if t >= at_s && by_s.is_finite() {
                    by_s
                } else {
                    0.0
                }
            }
            EventKind::Spikes {
                first_s,
                every_s,
                height_s,
                fall_rate,
            } => Self::newest(first_s, every_s, t).map_or(0.0, |(_, onset)| {
                let fall = if fall_rate > 0.0 {
                    fall_rate
                } else {
                    f64::INFINITY
                };
                (height_s - fall * (t - onset)).max(0.0)
            }),
            EventKind::Stalls {
                first_s,
                every_s,
                stall_s,
            } => match Self::newest(first_s, every_s, t) {
                // The first frame of this direction sent since the onset.
                Some((k, _)) if k >= self.next_stall[dir.index()] => {
                    self.next_stall[dir.index()] = k + 1;
                    stall_s
                }
                _ => 0.0,
            },
            EventKind::Flaps {
                first_s,
                every_s,
                by_s,
            } => match Self::newest(first_s, every_s, t) {
                // Up after an even number of flips.
                Some((k, _)) if k % 2 == 0 && by_s.is_finite() => by_s,
                _ => 0.0,
            },
        };
        let base = self.jitter.sample(rng).as_secs_f64();
        Duration::from_secs_f64(base + extra)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    const FLAT: JitterParams = JitterParams {
        base_s: 0.05,
        mean_s: 0.0,
        shape: 1.0,
        cap_s: 0.0,
    };

    fn delays(kind: EventKind, times_ms: &[u64]) -> Vec<u64> {
        let mut e = Events::new(EventParams { jitter: FLAT, kind });
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        times_ms
            .iter()
            .map(|&t| {
                e.delay(&mut rng, Direction::Forward, Instant::from_millis(t))
                    .as_millis()
            })
            .collect()
    }

    #[test]
    fn step_spike_and_stall_shapes() {
        let step = EventKind::Step {
            at_s: 1.0,
            by_s: 0.1,
        };
        assert_eq!(delays(step, &[0, 999, 1000, 5000]), [50, 50, 150, 150]);
        let spikes = EventKind::Spikes {
            first_s: 1.0,
            every_s: 10.0,
            height_s: 0.3,
            fall_rate: 0.5,
        };
        assert_eq!(
            delays(spikes, &[900, 1000, 1200, 1600, 2000, 11_000]),
            [50, 350, 250, 50, 50, 350]
        );
        let stalls = EventKind::Stalls {
            first_s: 1.0,
            every_s: 2.0,
            stall_s: 0.25,
        };
        // Only the first frame sent after each onset.
        assert_eq!(
            delays(stalls, &[980, 1020, 1040, 3010, 3030]),
            [50, 300, 50, 300, 50]
        );
        let p = EventParams {
            jitter: FLAT,
            kind: stalls,
        };
        assert_eq!(p.onsets(6.0), [1.0, 3.0, 5.0]);
        let flaps = EventKind::Flaps {
            first_s: 1.0,
            every_s: 2.0,
            by_s: 0.04,
        };
        assert_eq!(
            delays(flaps, &[999, 1000, 2999, 3000, 4999, 5000, 7000]),
            [50, 90, 90, 50, 50, 90, 50]
        );
        let p = EventParams {
            jitter: FLAT,
            kind: flaps,
        };
        assert_eq!(p.onsets(6.0), [1.0, 3.0, 5.0]);
    }
}
