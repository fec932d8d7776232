//! A link's endpoint, with its regulator sized when the link starts.
//!
//! The endpoint holds its regulator inline (no heap, a const capacity): at
//! 8 channels a capacity of 256 is 38 KiB per endpoint, most of a link's
//! memory. A link that never needs more than a few dozen samples in its
//! regulator can take a smaller one ([`LinkConfig::queue_capacity`]); the
//! capacity is rounded up to one of [`QUEUE_CAPACITIES`]. Only a link whose
//! playout is [`Playout::Adaptive`] carries that policy's histogram (6.5 KiB).
//!
//! [`LinkConfig::queue_capacity`]: crate::LinkConfig::queue_capacity

use ndr_core::endpoint::{Config, ConfigError, Endpoint, Event, LinkError, Phase, Stats};
use ndr_core::playout::{NoAdaptive, Playout};
use ndr_core::regulator::Occupancy;
use ndr_core::time::{Duration, Instant};

use crate::link::{MAX_AXES, QUEUE};

/// The regulator capacities a link may have: `ns` is at most the capacity − 1.
pub const QUEUE_CAPACITIES: [usize; 3] = [16, 64, QUEUE];

/// An endpoint of one of the [`QUEUE_CAPACITIES`], with the adaptive
/// playout's state only when it runs that policy.
pub(crate) enum SizedEndpoint {
    Small(Box<Endpoint<MAX_AXES, 16, NoAdaptive>>),
    Medium(Box<Endpoint<MAX_AXES, 64, NoAdaptive>>),
    Full(Box<Endpoint<MAX_AXES, QUEUE, NoAdaptive>>),
    SmallAdaptive(Box<Endpoint<MAX_AXES, 16>>),
    MediumAdaptive(Box<Endpoint<MAX_AXES, 64>>),
    FullAdaptive(Box<Endpoint<MAX_AXES, QUEUE>>),
}

/// Runs `$body` with `$ep` bound to the endpoint, whatever its type.
macro_rules! each {
    ($self:expr, $ep:ident => $body:expr) => {
        match $self {
            SizedEndpoint::Small($ep) => $body,
            SizedEndpoint::Medium($ep) => $body,
            SizedEndpoint::Full($ep) => $body,
            SizedEndpoint::SmallAdaptive($ep) => $body,
            SizedEndpoint::MediumAdaptive($ep) => $body,
            SizedEndpoint::FullAdaptive($ep) => $body,
        }
    };
}

impl SizedEndpoint {
    /// The smallest of the [`QUEUE_CAPACITIES`] that holds `capacity`
    /// samples (the largest one for more).
    pub(crate) fn new(config: Config, now: Instant, capacity: usize) -> Result<Self, ConfigError> {
        use SizedEndpoint as S;
        let adaptive = matches!(config.playout, Playout::Adaptive { .. });
        Ok(match (capacity, adaptive) {
            (0..=16, false) => S::Small(Box::new(Endpoint::new(config, now)?)),
            (17..=64, false) => S::Medium(Box::new(Endpoint::new(config, now)?)),
            (_, false) => S::Full(Box::new(Endpoint::new(config, now)?)),
            (0..=16, true) => S::SmallAdaptive(Box::new(Endpoint::new(config, now)?)),
            (17..=64, true) => S::MediumAdaptive(Box::new(Endpoint::new(config, now)?)),
            (_, true) => S::FullAdaptive(Box::new(Endpoint::new(config, now)?)),
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

    pub(crate) fn axes(&self) -> u16 {
        each!(self, ep => ep.config().axes)
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

    /// The regulator's capacity, whether it holds the adaptive state, and
    /// the endpoint's size.
    fn built(playout: Playout, asked: usize) -> (usize, bool, usize) {
        let mut config = Config::new(Role::Base);
        config.playout = playout;
        let ep = SizedEndpoint::new(config, Instant::ZERO, asked)
            .unwrap_or_else(|e| panic!("{playout} refused: {e}"));
        let size = each!(&ep, e => std::mem::size_of_val(&**e));
        match ep {
            SizedEndpoint::Small(_) => (16, false, size),
            SizedEndpoint::Medium(_) => (64, false, size),
            SizedEndpoint::Full(_) => (QUEUE, false, size),
            SizedEndpoint::SmallAdaptive(_) => (16, true, size),
            SizedEndpoint::MediumAdaptive(_) => (64, true, size),
            SizedEndpoint::FullAdaptive(_) => (QUEUE, true, size),
        }
    }

    #[test]
    fn a_capacity_is_rounded_up_to_the_next_one_built() {
        for playout in [Playout::Fifo, Playout::ADAPTIVE] {
            let capacity = |asked| built(playout, asked).0;
            assert_eq!(capacity(0), 16);
            assert_eq!(capacity(16), 16);
            assert_eq!(capacity(17), 64);
            assert_eq!(capacity(64), 64);
            assert_eq!(capacity(65), QUEUE);
            assert_eq!(capacity(usize::MAX), QUEUE);
        }
    }

    #[test]
    fn only_the_adaptive_playout_carries_its_histogram() {
        for playout in [Playout::Fifo, Playout::NetEq, Playout::Ramjee4] {
            assert!(!built(playout, 64).1, "{playout}");
        }
        assert!(built(Playout::ADAPTIVE, 64).1);
        let lean = built(Playout::Fifo, 64).2;
        let adaptive = built(Playout::ADAPTIVE, 64).2;
        // The histogram's 6.5 KiB and the window's counters, less NetEQ's
        // 2 KiB that the target's room holds anyway.
        assert!(adaptive >= lean + 4 * 1024, "{lean} {adaptive}");
    }

    #[test]
    fn a_smaller_capacity_is_a_smaller_endpoint() {
        for playout in [Playout::Fifo, Playout::ADAPTIVE] {
            let size = |asked| built(playout, asked).2;
            assert!(size(16) < size(64) && size(64) < size(QUEUE));
        }
        // At 8 channels: about 112 bytes per queued sample, plus the clock
        // estimate (4 KiB) and NetEQ's histogram (2 KiB) inline: 20.4 KiB
        // at 64 without the adaptive policy's histogram, 25.1 KiB with it.
        assert!(built(Playout::Fifo, 64).2 < 21 * 1024);
        assert!(built(Playout::ADAPTIVE, 64).2 < 25 * 1024 + 512);
    }
}
