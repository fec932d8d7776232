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
//! Time is counted in ticks of the link's period. The Smith predictor
//! needs the round trip in ticks — from the tick a command is sent to the
//! tick the state it produced is taken back — and each command applied
//! once: a base release's GRTT divided by the period, rounded up to the
//! tick that takes it, gives the round trip ([`round_trip_ticks`]), and
//! the link announces each change of it as a `RoundTripChanged` event
//! before the release that shows it — not only at `DelayChanged` (an
//! adaptive playout's release can fall on either side of a tick). The wave
//! channel needs every wave delivered at most once: a repeated sample (an
//! underflow, a rising delay) is energy the channel did not receive, so
//! the receiving side decodes a repeat as a zero wave, which the regulated
//! link can do because it says which releases are fresh.
//!
//! Either way the application sets a sample once a tick, every tick the
//! link sends: an endpoint sends the sample last set, and a peer takes a
//! sample sent twice as two fresh ones (a command applied twice, a wave
//! delivered twice).
//!
//! Nothing here allocates, reads a clock or panics.
//!
//! # Example
//!
//! A Smith-predicted PID on the remote's delayed state over the paper's
//! FIFO (3 ms each way, `T = 10 ms`): with the plant's true model the
//! predictor's correction stays exactly zero, so the controller sees the
//! delay-free loop's state.
//!
//! ```
//! use ndr_core::{Tf2, Tf2State};
//! use ndr_core::control::{Pid, PidConfig, SmithPredictor, round_trip_ticks};
//! use ndr_core::endpoint::{Config, Endpoint, Event, LinkError, Status};
//! use ndr_core::pair::{Pair, World};
//! use ndr_core::storage::Heap;
//! use ndr_core::time::{Duration, Instant};
//! use ndr_core::wire::Role;
//!
//! const T: Duration = Duration::from_millis(10);
//!
//! struct Loop {
//!     smith: SmithPredictor<64>,
//!     pid: Pid,
//!     plant: Tf2State,
//!     known: bool,
//!     corrections: Vec<f64>,
//! }
//!
//! impl World<Heap> for Loop {
//!     type Error = LinkError;
//!     fn arrival(&mut self, _: Role, sent: Instant, _: &[u8]) -> Option<Instant> {
//!         Some(sent + Duration::from_millis(3))
//!     }
//!     fn event(
//!         &mut self,
//!         side: Role,
//!         ep: &mut Endpoint<Heap>,
//!         _: Instant,
//!         event: Event<Box<[f64]>>,
//!     ) -> Result<(), LinkError> {
//!         // The paper's FIFO releases at the ticks: one release a tick.
//!         let Event::Released(r) = event else { return Ok(()) };
//!         if side == Role::Remote {
//!             // The plant steps on the command released; its state goes back.
//!             return ep.set_sample(&[self.plant.step(r.values()[0])]);
//!         }
//!         if let Some(d) = r.grtt.and_then(|g| round_trip_ticks(g, T)) {
//!             self.smith.set_round_trip(d).unwrap();
//!             self.known = true;
//!         }
//!         // A state is paired with the command one round trip back: none
//!         // before the round trip is known.
//!         let fresh = (self.known && r.status == Status::Fresh).then(|| r.values()[0]);
//!         let seen = self.smith.feedback(fresh).unwrap();
//!         if fresh.is_some() {
//!             self.corrections.push(self.smith.correction());
//!         }
//!         let u = self.pid.step(1.0, seen).unwrap();
//!         self.smith.command(u).unwrap();
//!         ep.set_sample(&[u])
//!     }
//!     fn failed(&mut self, _: Role, _: Instant, error: LinkError) -> Result<(), LinkError> {
//!         Err(error)
//!     }
//! }
//!
//! let model = Tf2::low_pass(std::f64::consts::TAU * 0.5, 0.7, 1.0, T.as_secs_f64())?;
//! let config = |role| {
//!     let mut c = Config::paper(role);
//!     c.period = T;
//!     c
//! };
//! let world = Loop {
//!     smith: SmithPredictor::with_model(model, 1)?,
//!     pid: Pid::new(PidConfig::new(4.0, 2.0, 0.3, T.as_secs_f64()))?,
//!     plant: Tf2State::new(model),
//!     known: false,
//!     corrections: Vec::new(),
//! };
//! let base = Endpoint::new(config(Role::Base), Instant::ZERO)?;
//! let remote = Endpoint::new(config(Role::Remote), Instant::ZERO)?;
//! let mut pair = Pair::new(base, remote, world);
//! pair.run_until(Instant::from_millis(5000))?;
//! let w = &pair.world;
//! // A constant round trip of 6 ticks (as in the crate's example), and a
//! // plant that is the model, command for command.
//! assert_eq!(w.smith.round_trip(), 6);
//! assert!(w.corrections.len() > 400, "{}", w.corrections.len());
//! assert!(w.corrections.iter().all(|&c| c == 0.0));
//! assert!(w.plant.output() > 0.5);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

mod pid;
mod smith;
mod wave;

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
