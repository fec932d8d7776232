//! Classical teleoperation control closed across the regulated link: the
//! building blocks a loop needs once the link's delays are constant and
//! known in ticks (the paper's abstract: "one can use any high-level
//! teleoperation controls").
//!
//! - [`SmithPredictor`]: a position loop closed on the remote's delayed
//!   state. A local model of the remote axis (a given [`Tf2`](crate::Tf2) or one
//!   identified online by an [`Arx2`](crate::Arx2)) runs undelayed; the
//!   controller sees its output, corrected by the difference between the
//!   measured state and the model's output one round trip ago. With the
//!   true model and a constant round trip the loop behaves exactly like the
//!   delay-free loop, delayed by the round trip.
//! - [`WaveTransform`] and [`WaveEnergy`]: Niemeyer and Slotine's wave
//!   variables for a bilateral, force-reflecting loop, passive for any
//!   constant delay, and the energy bookkeeping of the channel so that
//!   passivity can be checked at every tick.
//! - [`Pid`]: a discrete PD/PID with output limits and anti-windup, the
//!   local controller.
//!
//! # What each needs from the link
//!
//! Time is counted in ticks of the link's period. The Smith predictor needs
//! the round trip in ticks — from the tick a command is sent to the tick the
//! state it produced is released back — and that it be constant between
//! announced changes: a base release's GRTT divided by the period, rounded up to the
//! tick that takes it, gives it ([`round_trip_ticks`]). The wave channel needs every wave delivered at
//! most once: a repeated sample (an underflow, a rising delay) is energy
//! the channel did not receive, so the receiving side decodes a repeat as a
//! zero wave, which the regulated link can do because it says which
//! releases are fresh.
//!
//! Nothing here allocates, reads a clock or panics.

pub mod pid;
pub mod smith;
pub mod wave;

use core::fmt;

pub use pid::{Pid, PidConfig};
pub use smith::SmithPredictor;
pub use wave::{MasterPort, SlavePort, WaveEnergy, WaveTransform};

use crate::time::Duration;

/// Why a controller could not be built or stepped.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum ControlError {
    /// A gain, limit or period is NaN or infinite, or negative where it
    /// must not be.
    InvalidParameter(&'static str),
    /// The output limits are empty (`min > max`).
    InvalidLimits {
        /// The lower limit.
        min: f64,
        /// The upper limit.
        max: f64,
    },
    /// The round trip in ticks is zero or beyond the predictor's history.
    RoundTrip {
        /// The round trip asked for (ticks).
        ticks: usize,
        /// The longest the history covers.
        max: usize,
    },
    /// The local model has a coefficient that is not finite.
    InvalidModel,
    /// An input (reference, measurement, command, velocity, force, wave) is
    /// NaN or infinite.
    NonFiniteInput,
}

impl fmt::Display for ControlError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            ControlError::InvalidParameter(what) => {
                write!(
                    f,
                    "{what} must be finite (and not negative): check the controller's configuration"
                )
            }
            ControlError::InvalidLimits { min, max } => {
                write!(f, "output limits [{min}, {max}] are empty: give min <= max")
            }
            ControlError::RoundTrip { ticks, max } => write!(
                f,
                "round trip of {ticks} ticks is outside 1..={max}: the loop needs at least one \
                 tick, and a longer one needs a SmithPredictor with a longer history"
            ),
            ControlError::InvalidModel => {
                write!(
                    f,
                    "the local model has a non-finite coefficient: give a finite Tf2"
                )
            }
            ControlError::NonFiniteInput => write!(
                f,
                "an input is NaN or infinite: check the sample before stepping the controller"
            ),
        }
    }
}

impl core::error::Error for ControlError {}

/// The round trip in whole ticks that a GRTT of `grtt` is at period
/// `period`, for an application that takes each release at its next tick
/// (at the release's own tick if it falls on one): `⌈grtt / period⌉`.
/// What a base release's [`grtt`](crate::endpoint::Release::grtt) tells a
/// [`SmithPredictor`]: a release between two ticks (the adaptive playout
/// releases on a schedule of its own) answers the command of `⌈…⌉` ticks
/// before the tick that uses it. `None` for a zero period.
#[must_use]
pub fn round_trip_ticks(grtt: Duration, period: Duration) -> Option<usize> {
    let t = period.as_nanos();
    if t == 0 {
        return None;
    }
    usize::try_from(grtt.as_nanos().div_ceil(t)).ok()
}

fn finite(v: f64) -> Result<f64, ControlError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(ControlError::NonFiniteInput)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_round_trip_counts_to_the_tick_that_takes_the_release() {
        let t = Duration::from_millis(20);
        assert_eq!(round_trip_ticks(Duration::from_millis(60), t), Some(3));
        assert_eq!(
            round_trip_ticks(Duration::from_nanos(60_000_001), t),
            Some(4)
        );
        assert_eq!(round_trip_ticks(Duration::from_millis(41), t), Some(3));
        assert_eq!(
            round_trip_ticks(Duration::from_millis(60), Duration::ZERO),
            None
        );
    }
}
