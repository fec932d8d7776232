//! A link's endpoint, with its regulator sized when the link starts.
//!
//! The endpoint holds its regulator inline (no heap, a const capacity): at
//! 8 channels a capacity of 256 is 38 KiB per endpoint, most of a link's
//! memory. A link that never needs more than a few dozen samples in its
//! regulator can take a smaller one ([`LinkConfig::queue_capacity`]); the
//! capacity is rounded up to one of [`QUEUE_CAPACITIES`].
//!
//! [`LinkConfig::queue_capacity`]: crate::LinkConfig::queue_capacity

use ndr_core::endpoint::{Config, ConfigError, Endpoint, Event, LinkError, Phase, Stats};
use ndr_core::regulator::Occupancy;
use ndr_core::time::{Duration, Instant};

use crate::link::{MAX_AXES, QUEUE};

/// The regulator capacities a link may have: `ns` is at most the capacity − 1.
pub const QUEUE_CAPACITIES: [usize; 3] = [16, 64, QUEUE];

/// An endpoint of one of the [`QUEUE_CAPACITIES`].
pub(crate) enum SizedEndpoint {
    Small(Box<Endpoint<MAX_AXES, 16>>),
    Medium(Box<Endpoint<MAX_AXES, 64>>),
    Full(Box<Endpoint<MAX_AXES, QUEUE>>),
}

/// Runs `$body` with `$ep` bound to the endpoint, whatever its capacity.
macro_rules! each {
    ($self:expr, $ep:ident => $body:expr) => {
        match $self {
            SizedEndpoint::Small($ep) => $body,
            SizedEndpoint::Medium($ep) => $body,
            SizedEndpoint::Full($ep) => $body,
        }
    };
}

impl SizedEndpoint {
    /// The smallest of the [`QUEUE_CAPACITIES`] that holds `capacity`
    /// samples (the largest one for more).
    pub(crate) fn new(config: Config, now: Instant, capacity: usize) -> Result<Self, ConfigError> {
        Ok(if capacity <= 16 {
            SizedEndpoint::Small(Box::new(Endpoint::new(config, now)?))
        } else if capacity <= 64 {
            SizedEndpoint::Medium(Box::new(Endpoint::new(config, now)?))
        } else {
            SizedEndpoint::Full(Box::new(Endpoint::new(config, now)?))
        })
    }

    pub(crate) fn handle_frame(&mut self, now: Instant, bytes: &[u8]) -> Result<(), LinkError> {
        each!(self, ep => ep.handle_frame(now, bytes))
    }

    pub(crate) fn handle_timeout(&mut self, now: Instant) {
        each!(self, ep => ep.handle_timeout(now));
    }

    pub(crate) fn poll_timeout(&self) -> Option<Instant> {
        each!(self, ep => ep.poll_timeout())
    }

    pub(crate) fn poll_transmit(
        &mut self,
        now: Instant,
        buf: &mut [u8],
    ) -> Result<Option<usize>, LinkError> {
        each!(self, ep => ep.poll_transmit(now, buf))
    }

    pub(crate) fn poll_event(&mut self) -> Option<Event<MAX_AXES>> {
        each!(self, ep => ep.poll_event())
    }

    pub(crate) fn set_sample(&mut self, values: &[f64]) -> Result<(), LinkError> {
        each!(self, ep => ep.set_sample(values))
    }

    pub(crate) fn abort(&mut self, error: LinkError) {
        each!(self, ep => ep.abort(error));
    }

    pub(crate) fn close(&mut self) {
        each!(self, ep => ep.close());
    }

    pub(crate) fn is_closed(&self) -> bool {
        each!(self, ep => ep.is_closed())
    }

    pub(crate) fn phase(&self) -> Phase {
        each!(self, ep => ep.phase())
    }

    pub(crate) fn period(&self) -> Duration {
        each!(self, ep => ep.period())
    }

    pub(crate) fn ns(&self) -> usize {
        each!(self, ep => ep.ns())
    }

    pub(crate) fn queue_len(&self) -> usize {
        each!(self, ep => ep.queue_len())
    }

    pub(crate) fn occupancy(&self) -> Option<Occupancy> {
        each!(self, ep => ep.occupancy())
    }

    pub(crate) fn last_nrtt(&self) -> Option<Duration> {
        each!(self, ep => ep.last_nrtt())
    }

    pub(crate) fn stats(&self) -> Stats {
        each!(self, ep => ep.stats())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndr_core::wire::Role;

    fn capacity_of(asked: usize) -> usize {
        match SizedEndpoint::new(Config::new(Role::Base), Instant::ZERO, asked) {
            Ok(SizedEndpoint::Small(_)) => 16,
            Ok(SizedEndpoint::Medium(_)) => 64,
            Ok(SizedEndpoint::Full(_)) => QUEUE,
            Err(e) => panic!("default config refused: {e}"),
        }
    }

    #[test]
    fn a_capacity_is_rounded_up_to_the_next_one_built() {
        assert_eq!(capacity_of(0), 16);
        assert_eq!(capacity_of(16), 16);
        assert_eq!(capacity_of(17), 64);
        assert_eq!(capacity_of(64), 64);
        assert_eq!(capacity_of(65), QUEUE);
        assert_eq!(capacity_of(usize::MAX), QUEUE);
    }

    #[test]
    fn a_smaller_capacity_is_a_smaller_endpoint() {
        let size = |c| match SizedEndpoint::new(Config::new(Role::Base), Instant::ZERO, c) {
            Ok(SizedEndpoint::Small(ep)) => std::mem::size_of_val(&*ep),
            Ok(SizedEndpoint::Medium(ep)) => std::mem::size_of_val(&*ep),
            Ok(SizedEndpoint::Full(ep)) => std::mem::size_of_val(&*ep),
            Err(e) => panic!("default config refused: {e}"),
        };
        assert!(size(16) < size(64) && size(64) < size(QUEUE));
        // At 8 channels: about 112 bytes per queued sample, plus about
        // 16 KiB of playout state held inline whatever the policy (the
        // adaptive policy's delay histogram, 12 KiB, and the clock
        // estimate, 4 KiB): 30.3 KiB at 64.
        assert!(size(64) < 32 * 1024, "{}", size(64));
    }
}
