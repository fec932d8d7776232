//! What a link is configured with: the endpoint, its transport's security,
//! the hub that drives it, and how a listener admits connections.

use std::fmt;
use std::sync::{Arc, Mutex, PoisonError};

use ndr_core::endpoint::Config;
use ndr_core::reconnect::Backoff;
use ndr_core::time::Duration;

use crate::hub::Hub;
use crate::pool::{HubChoice, HubPool};
use crate::realtime::Realtime;
use crate::tls::TlsConfig;
use crate::transport::{Transport, TransportError};

/// Default capacity of a link's regulator: `ns` up to 255.
pub const QUEUE: usize = 256;

/// What a link is configured with: the endpoint, the transport's security,
/// which hub drives it, and the bounds on what it holds.
///
/// ```
/// use ndr_core::endpoint::Config;
/// use ndr_core::wire::Role;
/// use ndr_net::{Hub, LinkConfig};
///
/// let hub = Hub::new(ndr_net::clock::DEFAULT_SPIN_MARGIN)?;
/// // Plain TCP (loopback only, unless `insecure`), on a hub shared with
/// // other links; `with_tls` for mutual TLS.
/// let config = LinkConfig::new(Config::new(Role::Base)).on_hub(hub);
/// # Ok::<(), std::io::Error>(())
/// ```
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct LinkConfig {
    /// The endpoint's configuration; its `role` is set by
    /// [`Link::connect`](crate::Link::connect) (base) and [`Listener::accept`](crate::Listener::accept) (remote).
    pub endpoint: Config,
    /// How long before a deadline the link's hub stops sleeping and spins,
    /// at most: it learns a shorter margin from how late its timer wakes
    /// ([`crate::spin`]; [`LinkStats::spin_margin`](crate::LinkStats::spin_margin) shows it).
    pub spin_margin: Duration,
    /// Released samples and events that may wait for the application; when
    /// it does not read, the newest are dropped and counted. Memory follows
    /// what waits, not this bound.
    pub app_queue: usize,
    /// Samples the regulator can hold (`ns` ≤ capacity − 1, capacity 1 to
    /// [`MAX_CAPACITY`](ndr_core::storage::MAX_CAPACITY)); default [`QUEUE`].
    /// Its memory is taken when the link starts: 16 bytes per sample for its
    /// send times, and the queued samples' values as they arrive. Both ends
    /// need room for the `ns` the base decides (a base clamps it and counts
    /// [`Stats::clamped`](ndr_core::endpoint::Stats::clamped); a remote that
    /// cannot hold it ends the link with [`LinkError::BadParameters`](ndr_core::endpoint::LinkError::BadParameters)).
    pub queue_capacity: usize,
    /// How the samples cross: `tcp` (the default), `udp` or `quic`. Set it
    /// with [`with_transport`](Self::with_transport), which also tells the
    /// endpoint ([`Config::transport`]) whether it sends a stream or
    /// datagrams; [`new`](Self::new) takes `tcp` or `udp` from the
    /// endpoint's. QUIC needs [`tls`](Self::tls), plain UDP refuses it
    /// ([`Transport::check_security`]).
    pub transport: Transport,
    /// Mutual TLS 1.3 with these identities and pins; `None` (the default):
    /// a plain link, which only a loopback address or
    /// [`insecure`](Self::insecure) allows.
    pub tls: Option<TlsConfig>,
    /// Which hub drives the link (a listener: the links it accepts); a hub
    /// of its own by default.
    pub hub: HubChoice,
    /// Allows a link without TLS to or from a non-loopback address (the
    /// `--insecure` switch). Off by default: such a link is refused with
    /// [`NetError::Insecure`](crate::NetError::Insecure); loopback links may always be plain.
    pub insecure: bool,
    /// How a [`Listener`](crate::Listener) admits connections before they authenticate, so
    /// that peers who never will cannot starve one who does (unused by
    /// [`Link::connect`](crate::Link::connect)).
    pub admission: Admission,
    /// The real-time scheduling the link's hub thread asks for as it starts
    /// (`SCHED_FIFO`, memory locked, a CPU): by default it tries and warns
    /// once if refused ([`crate::realtime`]). A hub given with
    /// [`on_hub`](Self::on_hub) or [`on_pool`](Self::on_pool) keeps what it
    /// was started with.
    pub realtime: Realtime,
    /// A base: how long [`Link::connect`](crate::Link::connect) keeps
    /// trying a remote that is not there yet (the connection refused, the
    /// host or network unreachable, no answer), its attempts spaced by
    /// [`backoff`](Self::backoff); past it, the last attempt's error. Zero
    /// (the default): one attempt. [`LinkStats::waited`](crate::LinkStats::waited)
    /// says how long the link waited.
    pub wait_for_remote: Duration,
    /// A base: a link that loses its peer (the connection dropped or reset,
    /// the peer silent past its liveness, a remote that ended the link in
    /// order) connects again by itself, at once and then spaced by
    /// [`backoff`](Self::backoff), until it is back or the application
    /// closes it. Meanwhile receiving waits and sends are kept for the new
    /// session; the application sees [`Event::LinkLost`](ndr_core::endpoint::Event::LinkLost),
    /// then, once the new session passed its initialization pattern,
    /// [`Event::LinkRestored`](ndr_core::endpoint::Event::LinkRestored) with
    /// the outage; the new session announces its round trip
    /// ([`Event::RoundTripChanged`](ndr_core::endpoint::Event::RoundTripChanged))
    /// and its releases' sequence numbers carry on from the last one given,
    /// nothing of the old session after them
    /// ([`ndr_core::reconnect::Sessions`]). A peer that refuses the link
    /// (other settings, a certificate) ends it as without this. Off by
    /// default. A listener ignores it: it serves the next base that comes.
    pub reconnect: bool,
    /// The waits between attempts to reach the remote
    /// ([`wait_for_remote`](Self::wait_for_remote), [`reconnect`](Self::reconnect)):
    /// 100 ms doubling to 1 s by default.
    pub backoff: Backoff,
    /// A reconnecting link's new session: the application's handle it
    /// takes over.
    pub(crate) rejoin: Rejoin,
}

/// What a reconnecting link's new session takes over from the old: the
/// state its handle shares with the hub (so that the handle and its
/// senders go on), its release handler and its tap.
#[derive(Clone, Default)]
pub(crate) struct Rejoin {
    pub(crate) shared: Option<Arc<crate::hub::Shared>>,
    pub(crate) handler: Option<Arc<Mutex<crate::hub::Handler>>>,
    pub(crate) tap: Option<Arc<Mutex<crate::hub::Tap>>>,
}

impl Rejoin {
    /// The handler for a session's hub entry: the link's one, shared by
    /// its sessions.
    pub(crate) fn handler(&self) -> Option<crate::hub::Handler> {
        let h = Arc::clone(self.handler.as_ref()?);
        Some(Box::new(move |s| {
            (h.lock().unwrap_or_else(PoisonError::into_inner))(s);
        }))
    }

    /// The tap for a session's hub entry, shared likewise.
    pub(crate) fn tap(&self) -> Option<crate::hub::Tap> {
        let t = Arc::clone(self.tap.as_ref()?);
        Some(Box::new(move |e| {
            (t.lock().unwrap_or_else(PoisonError::into_inner))(e);
        }))
    }
}

impl fmt::Debug for Rejoin {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(if self.shared.is_some() {
            "Rejoin"
        } else {
            "None"
        })
    }
}

impl LinkConfig {
    /// Defaults around an endpoint configuration, over `tcp` or `udp` as
    /// its `transport` says.
    #[must_use]
    pub fn new(endpoint: Config) -> Self {
        LinkConfig {
            transport: Transport::plain(endpoint.transport),
            endpoint,
            spin_margin: crate::clock::DEFAULT_SPIN_MARGIN,
            app_queue: 1024,
            queue_capacity: QUEUE,
            tls: None,
            hub: HubChoice::Own,
            insecure: false,
            admission: Admission::default(),
            realtime: Realtime::default(),
            wait_for_remote: Duration::ZERO,
            reconnect: false,
            backoff: Backoff::default(),
            rejoin: Rejoin::default(),
        }
    }

    /// The same, over `transport` (its endpoint told whether it sends a
    /// stream or datagrams).
    #[must_use]
    pub fn with_transport(mut self, transport: Transport) -> Self {
        self.transport = transport;
        self.endpoint.transport = transport.carriage();
        self
    }

    /// The link's transport, checked against its security (`tls`: whether
    /// the link runs TLS): QUIC needs TLS, plain UDP refuses it, and the
    /// endpoint must carry what the transport does.
    pub(crate) fn checked_transport(&self, tls: bool) -> Result<Transport, TransportError> {
        if self.endpoint.transport != self.transport.carriage() {
            return Err(TransportError::Mismatch {
                link: self.transport,
                endpoint: self.endpoint.transport,
            });
        }
        self.transport.check_security(tls)?;
        Ok(self.transport)
    }

    /// The same, over mutual TLS 1.3 ([`tls`](Self::tls)).
    #[must_use]
    pub fn with_tls(mut self, tls: TlsConfig) -> Self {
        self.tls = Some(tls);
        self
    }

    /// The same, driven by `hub`, shared with other links.
    #[must_use]
    pub fn on_hub(mut self, hub: Hub) -> Self {
        self.hub = HubChoice::Shared(hub);
        self
    }

    /// The same, driven by the least loaded hub of `pool` at each link.
    #[must_use]
    pub fn on_pool(mut self, pool: HubPool) -> Self {
        self.hub = HubChoice::Pool(pool);
        self
    }
}

/// How a [`Listener`](crate::Listener) admits connections before they authenticate
/// ([`LinkConfig::admission`]). Start from the defaults and change fields:
///
/// ```
/// # use ndr_core::endpoint::Config;
/// # use ndr_core::wire::Role;
/// # use ndr_net::LinkConfig;
/// let mut config = LinkConfig::new(Config::new(Role::Remote));
/// config.admission.preauth_timeout = ndr_core::time::Duration::from_secs(1);
/// config.admission.max_pending_per_source = 4;
/// ```
#[non_exhaustive]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Admission {
    /// The pre-authentication budget: a connection must finish TLS (if the
    /// listener has it) and ndr's Hello within this time, counted from its
    /// accept, or it is closed and counted in [`ListenerStats::timeouts`](crate::ListenerStats::timeouts).
    /// Default 3 s; raise it for a peer behind a slow, lossy path. Zero
    /// leaves only each step's own timeout
    /// ([`TlsConfig::handshake_timeout`](crate::TlsConfig::handshake_timeout), the endpoint's
    /// `handshake_timeout`).
    pub preauth_timeout: Duration,
    /// Most handshakes pending at once from one source (an IPv4 address,
    /// or an IPv6 /64). A new connection from a source that has as many
    /// takes the slot of one that has said less than it (silent, before a
    /// whole first message), or as much and not moved for a while; one that
    /// finds none
    /// waits a moment for its first message, or is turned away. Whoever
    /// loses is closed, its peer told why (Close `EVICTED_SOURCE`), and
    /// counted in
    /// [`ListenerStats::refused_per_source`](crate::ListenerStats::refused_per_source).
    /// So a base that completes its handshake promptly gets in however
    /// fast stale connections from its address come (over QUIC, a
    /// connection beyond the cap is closed at once instead). Default 8 (at
    /// least 1). Peers behind one NAT, or the clients of one relay, share a
    /// source: raise it for many operators behind one address.
    pub max_pending_per_source: usize,
    /// The kernel's queue of connections not yet accepted (`listen`'s
    /// backlog; the kernel caps it at `net.core.somaxconn`). Default 1024.
    pub backlog: u32,
    /// Links that completed their handshake and wait for
    /// [`Listener::accept`](crate::Listener::accept); one that finds the queue full is closed (its
    /// peer told the listener is busy) and counted in
    /// [`ListenerStats::unclaimed`](crate::ListenerStats::unclaimed). Default 16 (at least 1).
    pub accept_queue: usize,
    /// A remote's listener that shares one robot: `Some(n)` serves one
    /// controlling base and up to `n` observers (at most
    /// [`MAX_OBSERVERS`](ndr_core::floor::MAX_OBSERVERS); bases waiting for
    /// control count among them), control changing hands by the core's
    /// [`Floor`](ndr_core::floor::Floor): a base that asks for control
    /// while another holds it is refused (Close `busy`) or, asking to wait,
    /// observes until it is granted control; one that asks to observe past
    /// `n` is refused (Close `observers full`). Observers take none of
    /// [`Listener::with_max_links`](crate::Listener::with_max_links)'s
    /// links. `None` (the default): every link is the application's own,
    /// each base commanding on its link (a server of many robots).
    /// [`DEFAULT_OBSERVERS`](ndr_core::floor::DEFAULT_OBSERVERS) is 4.
    pub observers: Option<usize>,
}

impl Default for Admission {
    fn default() -> Self {
        Admission {
            preauth_timeout: Duration::from_secs(3),
            max_pending_per_source: 8,
            backlog: 1024,
            accept_queue: 16,
            observers: None,
        }
    }
}
