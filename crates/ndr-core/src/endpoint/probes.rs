//! The probes' arrivals, kept for a driver that asks for them (a recorder):
//! the initialization pattern's frames size the queue, and a replay of a
//! recorded link needs their delays to size it as the link did.

use heapless::Deque;

use super::Endpoint;
use crate::storage::Storage;
use crate::time::Instant;

/// Probe arrivals that may wait for the driver: a burst of a congested
/// start-up's probes handed over in one batch of datagrams.
pub(super) const PROBE_LOG: usize = 64;

/// A probe (a Data frame without values: the initialization pattern's, or
/// a remote's before its first state) as this side saw it arrive.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct ProbeArrival {
    /// Its sequence number, in the peer's count of Data frames.
    pub seq: u64,
    /// When the peer's tick that sent it was scheduled, on the peer's clock.
    pub sent_at: Instant,
    /// When it arrived, on this side's clock.
    pub arrived_at: Instant,
}

/// The arrivals kept since the driver last took them; nothing unless on.
#[derive(Clone, Debug, Default)]
pub(super) struct ProbeLog {
    on: bool,
    queue: Deque<ProbeArrival, PROBE_LOG>,
}

impl<S: Storage> Endpoint<S> {
    /// Keeps each probe's arrival from now on (or no longer) for
    /// [`poll_probe_arrival`](Self::poll_probe_arrival). Off by default;
    /// past 64 waiting, arrivals are dropped and counted in
    /// [`Stats::probe_arrivals_dropped`](super::Stats::probe_arrivals_dropped).
    pub fn keep_probe_arrivals(&mut self, on: bool) {
        self.probes.on = on;
        if !on {
            self.probes.queue.clear();
        }
    }

    /// The oldest probe arrival kept and not yet taken.
    #[must_use]
    pub fn poll_probe_arrival(&mut self) -> Option<ProbeArrival> {
        self.probes.queue.pop_front()
    }

    pub(super) fn log_probe(&mut self, seq: u64, sent_at: Instant, arrived_at: Instant) {
        if !self.probes.on {
            return;
        }
        let arrival = ProbeArrival {
            seq,
            sent_at,
            arrived_at,
        };
        if self.probes.queue.push_back(arrival).is_err() {
            self.stats.probe_arrivals_dropped += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use std::boxed::Box;
    use std::vec::Vec;

    use super::ProbeArrival;
    use crate::endpoint::{Config, Endpoint, Event, LinkError};
    use crate::pair::{Pair, World};
    use crate::storage::Heap;
    use crate::time::{Duration, Instant};
    use crate::wire::Role;

    /// 3 to 9 ms each way by the send time; the base's driver takes its
    /// probe arrivals after each turn.
    struct Wire {
        taken: Vec<ProbeArrival>,
    }

    fn delay(sent: Instant) -> Duration {
        Duration::from_millis(3 + sent.as_nanos() / 10_000_000 % 7)
    }

    impl World<Heap> for Wire {
        type Error = LinkError;
        fn arrival(&mut self, _: Role, sent: Instant, _: &[u8]) -> Option<Instant> {
            Some(sent + delay(sent))
        }
        fn event(
            &mut self,
            _: Role,
            ep: &mut Endpoint<Heap>,
            _: Instant,
            event: Event<Box<[f64]>>,
        ) -> Result<(), LinkError> {
            if let Event::Released(_) = event {
                ep.set_sample(&[1.0])?;
            }
            Ok(())
        }
        fn sample(
            &mut self,
            side: Role,
            ep: &mut Endpoint<Heap>,
            _: Instant,
        ) -> Result<(), LinkError> {
            if side == Role::Base {
                self.taken
                    .extend(core::iter::from_fn(|| ep.poll_probe_arrival()));
            }
            Ok(())
        }
        fn failed(&mut self, _: Role, _: Instant, error: LinkError) -> Result<(), LinkError> {
            Err(error)
        }
    }

    #[test]
    fn a_driver_that_asks_gets_each_probes_arrival_and_one_that_does_not_none() {
        let config = |role| {
            let mut c = Config::paper(role).with_widths(1, 1);
            c.period = Duration::from_millis(10);
            c
        };
        let mut base = Endpoint::new(config(Role::Base), Instant::ZERO).unwrap();
        base.keep_probe_arrivals(true);
        let remote = Endpoint::new(config(Role::Remote), Instant::ZERO).unwrap();
        let mut pair = Pair::new(base, remote, Wire { taken: Vec::new() });
        pair.run_until(Instant::from_millis(2000)).unwrap();
        let (base, mut remote, wire) = pair.into_parts();
        let taken = wire.taken;
        let stats = base.stats();
        assert!(stats.probes_received > 10, "{stats:?}");
        assert_eq!(taken.len() as u64, stats.probes_received);
        assert_eq!(stats.probe_arrivals_dropped, 0);
        assert!(taken.windows(2).all(|w| w[0].seq < w[1].seq), "{taken:?}");
        for p in &taken {
            assert_eq!(p.arrived_at - p.sent_at, delay(p.sent_at), "{p:?}");
        }
        assert!(remote.stats().probes_received > 10);
        assert_eq!(remote.poll_probe_arrival(), None);
    }
}
