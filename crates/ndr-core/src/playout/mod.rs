//! Playout policies: when a regulator releases each sample.
//!
//! [`Playout::Fifo`] is the paper's NDR: a FIFO pre-filled to `ns` samples
//! and released one per tick (its size set by the [`Mode`](crate::Mode)).
//! Every other policy is a **target delay** on the one-way delay: a sample
//! sent at `sent_at` is released at the first tick at or after
//! `sent_at + D`, `D` the policy's current target; under
//! [`Underflow::DropLate`](crate::Underflow::DropLate) one that arrives after
//! its slot is late (counted, discarded, the tick repeats the last sample).
//!
//! A target policy sees one sample per received frame through
//! [`TargetDelay::observe`]: the frame's send stamp and its one-way delay
//! (arrival − send stamp). The endpoint computes that delay in one place, so
//! a correction for the peers' clock offset applies to every policy at once.
//! Until then the target policies assume synchronized clocks.
//!
//! The constants and references of each policy are in `docs/algorithms.md`.

use core::fmt;
use core::str::FromStr;

use crate::time::{Duration, Instant};

mod adaptive;
mod classic;
pub mod schedule;

pub use adaptive::{
    ADAPTIVE_BLOCK, ADAPTIVE_BLOCK_MAX, ADAPTIVE_BLOCKS, ADAPTIVE_BUCKETS, ADAPTIVE_WINDOW_DELAYS,
    Adaptive, AdaptiveSlot, NoAdaptive, NoAdaptiveRoom, SLEW_DOWN, SLEW_UP,
};
pub use classic::{
    FixedAboveMin, NETEQ_BUCKETS, NETEQ_FORGET, NETEQ_MIN_BLOCK, NETEQ_QUANTILE, NetEq,
    RAMJEE_ALPHA, Ramjee1, Ramjee4, SPIKE_ENTER, SPIKE_EXIT,
};
pub use schedule::{DELAY_QUANTUM, Schedule, delay_quantum, delay_quantum_for};

/// How a regulator decides when to release each sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Playout {
    /// The paper's FIFO, pre-filled to `ns`, one release per tick.
    #[default]
    Fifo,
    /// Ramjee, Kurose, Towsley, Schulzrinne (1994), algorithm 1: `D = d̂ + 4·v̂`
    /// with exponential averages (α = 0.998002) of the delay and its deviation.
    Ramjee1,
    /// Ramjee et al. (1994), algorithm 4: algorithm 1's target with fast
    /// averages (1/8) and spike detection.
    Ramjee4,
    /// A NetEQ-like target: the 0.95 quantile of a histogram of relative
    /// delays (bucket width = period, forget factor 0.983) above the
    /// smallest delay of the last 2–4 s.
    NetEq,
    /// A fixed latency above the smallest delay seen (GStreamer's
    /// rtpjitterbuffer).
    FixedAboveMin {
        /// The latency added to the smallest delay.
        latency: Duration,
    },
    /// A constant target delay (the oracle's, on a known trace).
    Constant {
        /// The target.
        delay: Duration,
    },
    /// Timestamp-based: each sample is released at its send time,
    /// mapped to the local clock by the offset and skew estimate
    /// ([`ClockSync`](crate::sync::ClockSync)), plus the `1 − ε` quantile of
    /// the delays above the floor over the last 90–120 s; the target slews
    /// at a bounded rate. A silence past a slot (a stall, whose frames come
    /// in a burst) holds the delay ahead of it while the rise costs less
    /// per sample kept than the quantile would ([`Adaptive::sample_cost`])
    /// once half the late budget is used, and whatever it costs once the
    /// window's lost samples reach `ε` of its delays.
    Adaptive {
        /// The target late rate ε, in parts per million (1000 = 0.1 %).
        epsilon_ppm: u32,
        /// The step of the delay asked for, `None` for the default
        /// [`DELAY_QUANTUM`] (see
        /// [`delay_quantum_for`]): a
        /// finer one holds a lower delay that changes more often.
        quantum: Option<Duration>,
    },
}

/// The finest quantum [`Playout::Adaptive`] takes: below it the delay would
/// follow every wobble of its quantile.
pub const MIN_QUANTUM: Duration = Duration::from_millis(1);
/// The coarsest quantum the command line takes (any beyond the period is
/// the period).
pub const MAX_QUANTUM: Duration = Duration::from_secs(10);

/// The adaptive policy's default late rate, 0.1 % in parts per million.
pub const DEFAULT_EPSILON_PPM: u32 = 1000;

/// GStreamer rtpjitterbuffer's default latency.
pub const DEFAULT_FIXED_LATENCY: Duration = Duration::from_millis(200);

impl Playout {
    /// The name used on the command line and in reports. [`Playout::Constant`]
    /// and [`Playout::FixedAboveMin`] carry their value: `constant:120`,
    /// `fixed:200` (milliseconds).
    #[must_use]
    pub fn name(self) -> PlayoutName {
        PlayoutName(self)
    }

    /// The target-delay state of this policy for `period`, `None` for the FIFO.
    #[must_use]
    pub fn target(self, period: Duration) -> Option<Target> {
        // `Adaptive` always has room for itself: never `Err`.
        self.target_in::<Adaptive>(period).unwrap_or(None)
    }

    /// [`Playout::target`] in a [`Target`] whose adaptive state is `A`.
    ///
    /// # Errors
    ///
    /// [`NoAdaptiveRoom`] for [`Playout::Adaptive`] when `A` holds no
    /// adaptive state ([`NoAdaptive`]).
    pub fn target_in<A: AdaptiveSlot>(
        self,
        period: Duration,
    ) -> Result<Option<Target<A>>, NoAdaptiveRoom> {
        Ok(Some(match self {
            Playout::Fifo => return Ok(None),
            Playout::Ramjee1 => Target::Ramjee1(Ramjee1::new()),
            Playout::Ramjee4 => Target::Ramjee4(Ramjee4::new()),
            Playout::NetEq => Target::NetEq(NetEq::new(period)),
            Playout::FixedAboveMin { latency } => {
                Target::FixedAboveMin(FixedAboveMin::new(latency))
            }
            Playout::Constant { delay } => Target::Constant(delay),
            Playout::Adaptive {
                epsilon_ppm,
                quantum,
            } => Target::Adaptive(
                A::build(
                    period,
                    f64::from(epsilon_ppm) * 1e-6,
                    delay_quantum_for(period, quantum),
                )
                .ok_or(NoAdaptiveRoom)?,
            ),
        }))
    }

    /// The quantum the adaptive delay is held in at `period`, `None` for the
    /// other policies.
    #[must_use]
    pub fn quantum(self, period: Duration) -> Option<Duration> {
        match self {
            Playout::Adaptive { quantum, .. } => Some(delay_quantum_for(period, quantum)),
            _ => None,
        }
    }

    /// The adaptive policy at its default late rate and quantum.
    pub const ADAPTIVE: Playout = Playout::Adaptive {
        epsilon_ppm: DEFAULT_EPSILON_PPM,
        quantum: None,
    };
}

/// Displays a [`Playout`] by its command-line name.
#[derive(Clone, Copy, Debug)]
pub struct PlayoutName(Playout);

/// `units / 10^digits` with the fraction's trailing zeros cut: names are
/// printed from integers, so that no float noise shows (7 000 ppm is
/// `0.7`, not `0.7000000000000001`; 124 ms is `124`).
fn write_decimal(f: &mut fmt::Formatter<'_>, units: u64, digits: u32) -> fmt::Result {
    let scale = 10u64.pow(digits);
    write!(f, "{}", units / scale)?;
    let (mut frac, mut width) = (units % scale, digits as usize);
    if frac > 0 {
        while frac % 10 == 0 {
            frac /= 10;
            width -= 1;
        }
        write!(f, ".{frac:0width$}")?;
    }
    Ok(())
}

impl fmt::Display for PlayoutName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ms = |f: &mut fmt::Formatter<'_>, d: Duration| write_decimal(f, d.as_nanos(), 6);
        match self.0 {
            Playout::Fifo => f.write_str("fifo"),
            Playout::Ramjee1 => f.write_str("ramjee-1"),
            Playout::Ramjee4 => f.write_str("ramjee-4"),
            Playout::NetEq => f.write_str("neteq"),
            Playout::FixedAboveMin { latency } => {
                f.write_str("fixed:")?;
                ms(f, latency)
            }
            Playout::Constant { delay } => {
                f.write_str("constant:")?;
                ms(f, delay)
            }
            Playout::Adaptive {
                epsilon_ppm: DEFAULT_EPSILON_PPM,
                quantum: None,
            } => f.write_str("adaptive"),
            Playout::Adaptive {
                epsilon_ppm,
                quantum,
            } => {
                f.write_str("adaptive:")?;
                write_decimal(f, u64::from(epsilon_ppm), 4)?;
                match quantum {
                    Some(q) => {
                        f.write_str(":")?;
                        ms(f, q)
                    }
                    None => Ok(()),
                }
            }
        }
    }
}

impl fmt::Display for Playout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.name().fmt(f)
    }
}

/// A name that is not a [`Playout`], or a known one with a value out of
/// its range (the message says which).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UnknownPlayout(Why);

/// What was wrong with a playout's name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Why {
    Name,
    Millis,
    Percent,
    Quantum,
}

const UNKNOWN: UnknownPlayout = UnknownPlayout(Why::Name);

impl UnknownPlayout {
    /// The name itself is unknown (not a value out of a known policy's range).
    #[must_use]
    pub fn is_unknown_name(self) -> bool {
        self.0 == Why::Name
    }
}

impl fmt::Display for UnknownPlayout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self.0 {
            Why::Name => "unknown playout policy",
            Why::Millis => "fixed:MS and constant:MS take milliseconds, finite and not negative",
            Why::Percent => {
                "adaptive:PERCENT takes the target late rate in percent, 0 < PERCENT < 100 \
                 (0.1 by default)"
            }
            Why::Quantum => {
                "adaptive:PERCENT:QUANTUM_MS takes the step of the delay in milliseconds, \
                 1 to 10000 (e.g. 10)"
            }
        })?;
        f.write_str(
            "; valid: fifo, ramjee-1, ramjee-4, neteq, fixed[:MS], \
             constant:MS (milliseconds, finite, not negative), \
             adaptive[:PERCENT[:QUANTUM_MS]] (the target late rate, 0 < PERCENT < 100, \
             default 0.1; the delay's step, 1 to 10000 ms, default 20 ms or the period)",
        )
    }
}

impl core::error::Error for UnknownPlayout {}

impl FromStr for Playout {
    type Err = UnknownPlayout;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let millis = |v: &str| -> Result<Duration, UnknownPlayout> {
            match v.trim().parse::<f64>() {
                // To the nanosecond, rounded: `124` is 124 ms exactly.
                Ok(ms) if ms.is_finite() && ms >= 0.0 => {
                    Ok(Duration::from_nanos(libm::round(ms * 1e6) as u64))
                }
                _ => Err(UnknownPlayout(Why::Millis)),
            }
        };
        match s.trim().split_once(':') {
            None => match s.trim() {
                "fifo" => Ok(Playout::Fifo),
                "ramjee-1" => Ok(Playout::Ramjee1),
                "ramjee-4" => Ok(Playout::Ramjee4),
                "neteq" => Ok(Playout::NetEq),
                "adaptive" => Ok(Playout::ADAPTIVE),
                "fixed" => Ok(Playout::FixedAboveMin {
                    latency: DEFAULT_FIXED_LATENCY,
                }),
                _ => Err(UNKNOWN),
            },
            Some(("fixed", v)) => Ok(Playout::FixedAboveMin {
                latency: millis(v)?,
            }),
            Some(("constant", v)) => Ok(Playout::Constant { delay: millis(v)? }),
            Some(("adaptive", v)) => {
                let (pc, quantum) = match v.split_once(':') {
                    Some((pc, q)) => match millis(q) {
                        Ok(q) if (MIN_QUANTUM..=MAX_QUANTUM).contains(&q) => (pc, Some(q)),
                        _ => return Err(UnknownPlayout(Why::Quantum)),
                    },
                    None => (v, None),
                };
                match pc.trim().parse::<f64>() {
                    Ok(pc) if pc > 0.0 && pc < 100.0 => Ok(Playout::Adaptive {
                        epsilon_ppm: libm::round(pc * 1e4).max(1.0) as u32,
                        quantum,
                    }),
                    _ => Err(UnknownPlayout(Why::Percent)),
                }
            }
            Some(_) => Err(UNKNOWN),
        }
    }
}

/// A policy that sets a target one-way delay from the delays it observes.
pub trait TargetDelay {
    /// One received frame: its send stamp and its one-way delay.
    fn observe(&mut self, sent_at: Instant, delay: Duration);
    /// The current target, `None` before the policy can tell.
    fn target(&self) -> Option<Duration>;
}

/// The state of a target-delay [`Playout`], with the adaptive policy's state
/// in `A` (see [`AdaptiveSlot`]).
// No heap in the core: NetEQ's histogram (2 KiB) lives inline, and an
// endpoint holds one `Target`, so the size of the others does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq)]
pub enum Target<A = Adaptive> {
    /// See [`Playout::Ramjee1`].
    Ramjee1(Ramjee1),
    /// See [`Playout::Ramjee4`].
    Ramjee4(Ramjee4),
    /// See [`Playout::NetEq`].
    NetEq(NetEq),
    /// See [`Playout::FixedAboveMin`].
    FixedAboveMin(FixedAboveMin),
    /// See [`Playout::Constant`].
    Constant(Duration),
    /// See [`Playout::Adaptive`].
    Adaptive(A),
}

impl<A: TargetDelay> TargetDelay for Target<A> {
    fn observe(&mut self, sent_at: Instant, delay: Duration) {
        match self {
            Target::Ramjee1(p) => p.observe(sent_at, delay),
            Target::Ramjee4(p) => p.observe(sent_at, delay),
            Target::NetEq(p) => p.observe(sent_at, delay),
            Target::FixedAboveMin(p) => p.observe(sent_at, delay),
            Target::Constant(_) => {}
            Target::Adaptive(p) => p.observe(sent_at, delay),
        }
    }

    fn target(&self) -> Option<Duration> {
        match self {
            Target::Ramjee1(p) => p.target(),
            Target::Ramjee4(p) => p.target(),
            Target::NetEq(p) => p.target(),
            Target::FixedAboveMin(p) => p.target(),
            Target::Constant(d) => Some(*d),
            Target::Adaptive(p) => p.target(),
        }
    }
}

/// `d̂ + 4·v̂`, the playout delay of Ramjee et al.'s algorithms.
#[cfg(test)]
mod tests;
