//! Several hubs, one per core: the [`HubPool`].
//!
//! One hub thread serves its links one after the other: at each tick it runs
//! every due endpoint and writes its frame, a few microseconds each, so with
//! a thousand links the last release of a tick comes milliseconds after the
//! first. A pool spreads the links over several hubs that share one tick
//! grid (one origin), so their links tick at the same instants and are
//! served in parallel, one hub per core.

use std::io;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Instant as StdInstant;

use crate::clock::DEFAULT_SPIN_MARGIN;
use crate::hub::Hub;
use crate::link::{Link, LinkConfig, NetError};
use crate::spin::SpinMargin;
use crate::tls::TlsConfig;

/// Which hub drives a link, or the links a listener accepts
/// ([`LinkConfig::hub`]).
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
    pub(crate) fn pick(&self, spin_margin: impl Into<SpinMargin>) -> io::Result<Hub> {
        match self {
            HubChoice::Own => Hub::new(spin_margin),
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
        let spin_margin = spin_margin.into();
        let origin = StdInstant::now();
        let first = Hub::with_origin(spin_margin, origin)?;
        let mut all = vec![first.clone()];
        for _ in 1..hubs {
            all.push(Hub::with_origin(spin_margin, origin)?);
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

    /// Connects to a remote (this side is the base) and drives the link on
    /// the least loaded hub, on the current tokio runtime.
    #[deprecated(note = "use `Link::connect(addr, config.on_pool(pool.clone()))`")]
    pub async fn connect(&self, addr: SocketAddr, config: LinkConfig) -> Result<Link, NetError> {
        Link::connect(addr, config.on_pool(self.clone())).await
    }

    /// [`connect`](Self::connect) over mutual TLS 1.3.
    #[deprecated(
        note = "use `Link::connect(addr, config.on_pool(pool.clone()).with_tls(tls.clone()))`"
    )]
    pub async fn connect_tls(
        &self,
        addr: SocketAddr,
        config: LinkConfig,
        tls: &TlsConfig,
    ) -> Result<Link, NetError> {
        Link::connect(addr, config.on_pool(self.clone()).with_tls(tls.clone())).await
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

    #[test]
    fn links_are_spread_over_the_hubs_and_leave_them_when_closed() {
        use crate::link::Listener;
        use ndr_core::endpoint::Config;
        use ndr_core::wire::Role;

        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .expect("runtime");
        let mut c = Config::paper(Role::Base);
        c.axes = 1;
        let config = LinkConfig::new(c);
        let bases = HubPool::new(2, DEFAULT_SPIN_MARGIN).expect("hubs");
        let remotes = HubPool::new(2, DEFAULT_SPIN_MARGIN).expect("hubs");
        let links = rt.block_on(async {
            let any: SocketAddr = "127.0.0.1:0".parse().expect("address");
            let listener = Listener::bind(any, config.clone().on_pool(remotes.clone()))
                .await
                .expect("bind");
            let addr = listener.local_addr().expect("address");
            let mut links = Vec::new();
            for _ in 0..4 {
                let base = Link::connect(addr, config.clone().on_pool(bases.clone()));
                let (r, b) = tokio::join!(listener.accept(), base);
                links.push(r.expect("accepted"));
                links.push(b.expect("connected"));
            }
            links
        });
        for pool in [&bases, &remotes] {
            let per_hub: Vec<usize> = pool.hubs().iter().map(Hub::links).collect();
            assert_eq!(per_hub, [2, 2]);
        }
        for link in links {
            let _ = link.close();
        }
        assert_eq!(bases.links() + remotes.links(), 0);
    }
}
