//! A snapshot of a link's state and counters.

use ndr_core::endpoint::{Phase, Running, Stats};
use ndr_core::reconnect::ReconnectStats;
use ndr_core::time::Duration;

use crate::clock::LatenessStats;

/// A snapshot of a link's state and counters.
///
/// With the `serde` feature it serializes flat, the endpoint's counters
/// beside the link's, durations in seconds (the form the Python binding
/// hands out).
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct LinkStats {
    /// Where the protocol is.
    pub phase: Phase,
    /// The current period.
    pub period: Duration,
    /// The regulator's nominal size.
    pub ns: usize,
    /// Samples in the regulator.
    pub queue_len: usize,
    /// Occupancy before a release in the current regime: (min, max).
    pub queue_range: Option<(usize, usize)>,
    /// The latest NRTT measured.
    pub last_nrtt: Option<Duration>,
    /// Everything the endpoint counted.
    #[cfg_attr(feature = "serde", serde(flatten))]
    pub endpoint: Stats,
    /// How late the hub's thread woke for its deadlines (all its links).
    pub lateness: LatenessStats,
    /// How late the hub ran each link's deadline (the release's stamp, after
    /// the frames that arrived before it and the links served before it),
    /// over all its links.
    pub release_lateness: LatenessStats,
    /// How long before a deadline the hub stops sleeping and spins, as it
    /// has learned from how late its timer wakes (at most
    /// [`LinkConfig::spin_margin`](crate::LinkConfig::spin_margin)).
    pub spin_margin: Duration,
    /// Samples and events dropped because the application did not read them.
    pub app_dropped: u64,
    /// Events dropped, the oldest first, because more than
    /// [`EVENT_BACKLOG`](crate::EVENT_BACKLOG) waited for [`Link::drain_events`](crate::Link::drain_events).
    pub events_dropped: u64,
    /// Events the endpoint itself dropped
    /// ([`Endpoint::events_dropped`](ndr_core::endpoint::Endpoint::events_dropped)):
    /// none from the hub, which takes the events of a long catch-up as
    /// the endpoint's queue fills
    /// ([`Endpoint::catching_up`](ndr_core::endpoint::Endpoint::catching_up)).
    pub endpoint_events_dropped: u64,
    /// Receive path, in seconds: from a frame's arrival (the kernel's stamp
    /// where there is one) to the hub handing it to the endpoint.
    pub rx_lag: Running,
    /// Datagram transport: where this side sends its datagrams (the
    /// peer's address as its newest datagram gave it); `None` on a stream,
    /// and on a listener's side until the peer's first datagram.
    pub datagram_peer: Option<std::net::SocketAddr>,
    /// Datagram transport: datagrams not sent (no address for the peer
    /// yet, or the socket refused them; over QUIC also those quinn did not
    /// take); the peer sees them as lost.
    pub datagrams_unsent: u64,
    /// Datagram transport: times the peer's address changed (its first
    /// datagram to a listener's side, a NAT's new mapping, a peer that
    /// moved; over QUIC, the migrations the connection followed).
    pub datagram_path_changes: u64,
    /// Datagram transport: datagrams to this link's UDP socket that carried
    /// no token of a link on it (strays, spoofs, truncated or not Bundles),
    /// or over QUIC that no connection on it took (garbage, a stranger's
    /// packets, a closed connection's); shared by every link on the socket.
    pub datagrams_stray: u64,
    /// Zenoh transport: frames that reached the link while its inbox was
    /// full (its hub behind by hundreds of frames), dropped.
    pub zenoh_dropped: u64,
    /// How long connecting waited for the remote
    /// ([`LinkConfig::wait_for_remote`](crate::LinkConfig::wait_for_remote)):
    /// from the first attempt to the one that reached it.
    pub waited: Duration,
    /// A reconnecting link ([`LinkConfig::reconnect`](crate::LinkConfig::reconnect)):
    /// its sessions after the first and their outages. The other counters
    /// are the current session's.
    #[cfg_attr(feature = "serde", serde(flatten))]
    pub reconnect: ReconnectStats,
}
