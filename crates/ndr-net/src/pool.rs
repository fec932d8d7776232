//! Several hubs, one per core: the [`HubPool`].
//!
//! One hub thread serves its links one after the other: at each tick it runs
//! every due endpoint and writes its frame, a few microseconds each, so with
//! a thousand links the last release of a tick comes milliseconds after the
//! first. A pool spreads the links over several hubs that share one tick
//! grid (one origin), so their links tick at the same instants and are
//! served in parallel, one hub per core.

use std::io;
use std::sync::Arc;
use std::time::Instant as StdInstant;

use crate::clock::DEFAULT_SPIN_MARGIN;
use crate::hub::Hub;
use crate::realtime::Realtime;
use crate::spin::SpinMargin;

/// Which hub drives a link, or the links a listener accepts
/// ([`LinkConfig::hub`](crate::LinkConfig::hub)).
#[derive(Clone, Debug, Default)]
#[non_exhaustive]
pub enum HubChoice {
    /// A hub of its own (a listener: one for all the links it accepts).
    #[default]
    Own,
    /// This hub, shared with other links and listeners.
    Shared(Hub),
    /// The least loaded hub of this pool, at each link.
    Pool(HubPool),
}

impl HubChoice {
    /// The hub for a link starting now; [`HubChoice::Own`] starts one.
    pub(crate) fn pick(
        &self,
        spin_margin: impl Into<SpinMargin>,
        realtime: Realtime,
    ) -> io::Result<Hub> {
        match self {
            HubChoice::Own => Hub::with_realtime(spin_margin, realtime),
            HubChoice::Shared(hub) => Ok(hub.clone()),
            HubChoice::Pool(pool) => Ok(pool.least_loaded().clone()),
        }
    }
}

/// Hubs that share a tick grid; a new link goes to the one with the fewest
/// links. Cheap to clone.
#[derive(Clone, Debug)]
pub struct HubPool {
    /// Never empty.
    hubs: Arc<[Hub]>,
    /// The first of them, a handle that needs no index.
    first: Hub,
}

impl HubPool {
    /// `hubs` hubs (at least one), spinning at most the last `spin_margin`
    /// before each deadline (see [`Hub::new`]).
    pub fn new(hubs: usize, spin_margin: impl Into<SpinMargin>) -> io::Result<HubPool> {
        HubPool::with_realtime(hubs, spin_margin, Realtime::default())
    }

    /// [`new`](Self::new), each hub's thread asking for `realtime` as it
    /// starts (see [`Hub::with_realtime`]); pinned, the `i`-th hub goes to
    /// the `i`-th CPU from [`Realtime::cpu`].
    pub fn with_realtime(
        hubs: usize,
        spin_margin: impl Into<SpinMargin>,
        realtime: Realtime,
    ) -> io::Result<HubPool> {
        let spin_margin = spin_margin.into();
        let origin = StdInstant::now();
        let first = Hub::with_origin(spin_margin, origin, realtime)?;
        let mut all = vec![first.clone()];
        for i in 1..hubs {
            all.push(Hub::with_origin(spin_margin, origin, realtime.shifted(i))?);
        }
        Ok(HubPool {
            hubs: all.into(),
            first,
        })
    }

    /// One hub per core the process may run on, with the default spin margin.
    pub fn per_core() -> io::Result<HubPool> {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        HubPool::new(cores, DEFAULT_SPIN_MARGIN)
    }

    /// The pool's hubs.
    #[must_use]
    pub fn hubs(&self) -> &[Hub] {
        &self.hubs
    }

    /// Links the pool drives now, over all its hubs.
    #[must_use]
    pub fn links(&self) -> usize {
        self.hubs.iter().map(Hub::links).sum()
    }

    /// The hub with the fewest links (the first of those on a tie).
    #[must_use]
    pub fn least_loaded(&self) -> &Hub {
        self.hubs
            .iter()
            .min_by_key(|h| h.links())
            .unwrap_or(&self.first)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pool_has_at_least_one_hub_on_one_grid() {
        let pool = HubPool::new(0, DEFAULT_SPIN_MARGIN).expect("a hub");
        assert_eq!(pool.hubs().len(), 1);
        let pool = HubPool::new(3, DEFAULT_SPIN_MARGIN).expect("hubs");
        assert_eq!(pool.hubs().len(), 3);
        let origin = pool.hubs()[0].origin();
        assert!(pool.hubs().iter().all(|h| h.origin() == origin));
        assert_eq!(pool.links(), 0);
    }
}
