//! The QUIC transport of a link: what its connections are configured with.
//!
//! A link over QUIC ([`Transport::Quic`](crate::Transport::Quic)) needs a
//! [`TlsConfig`]: the samples go as QUIC DATAGRAM frames (RFC 9221),
//! encrypted and authenticated by the TLS 1.3 handshake QUIC runs with the
//! same identities, pins or CA, and verifiers as a TLS link over TCP; the
//! endpoint's reliable frames go on one bidirectional stream. The hub
//! drives quinn-proto's sans-IO state machine (`hub/quic.rs`).
//!
//! # Congestion control
//!
//! A link sends one Bundle per period, whatever the network does: its rate
//! is fixed by its period, and a congestion controller that shrank its
//! window after a loss would hold back the very samples that matter (a
//! held datagram is a late sample). The connection's controller is
//! [`FixedWindow`]: a window that never shrinks, as large as the bytes a
//! link has in flight at any sane period and delay, so quinn never holds
//! a datagram back for congestion. Datagrams quinn does not take anyway
//! are counted in [`LinkStats::datagrams_unsent`](crate::LinkStats::datagrams_unsent).
//!
//! # Idle timeout and keep-alive
//!
//! The endpoint's own liveness watchdog decides when a silent link is lost;
//! QUIC's idle timeout is twice that (at least the TLS handshake timeout),
//! so it only cleans up a connection whose endpoint is gone, and QUIC
//! pings a third of the liveness apart keep a paused link's path open.
//!
//! [`Transport::Datagram`]: ndr_core::endpoint::Transport::Datagram

use std::any::Any;
use std::sync::Arc;
use std::time::Duration as StdDuration;

use ndr_core::endpoint::{Config, DEFAULT_LIVENESS};
use quinn_proto::congestion::{Controller, ControllerFactory};
use quinn_proto::{IdleTimeout, RttEstimator, TransportConfig, VarInt};

use crate::tls::{TlsConfig, TlsError};

/// The ALPN token of an ndr link over QUIC: a peer that speaks another
/// protocol on the port is refused in the handshake.
pub const ALPN: &[u8] = b"ndr/1";

/// The congestion window of a QUIC link, in bytes: a Bundle of the widest
/// samples is a QUIC datagram (at most about 1.2 kB), and this covers
/// some 800 of them in flight (8 s at 100 Hz), with the acknowledgements
/// of a path that has stopped answering.
pub const WINDOW: u64 = 1 << 20;

/// A congestion controller whose window never changes: a link's sending
/// rate is fixed by its period, and must not drop when datagrams are lost.
#[derive(Clone, Copy, Debug)]
pub struct FixedWindow {
    window: u64,
}

impl FixedWindow {
    /// A controller with a window of `window` bytes.
    #[must_use]
    pub fn new(window: u64) -> FixedWindow {
        FixedWindow { window }
    }
}

impl Controller for FixedWindow {
    fn on_congestion_event(
        &mut self,
        _: std::time::Instant,
        _: std::time::Instant,
        _: bool,
        _: u64,
    ) {
        // Loss does not change the rate: the period sets it.
    }

    fn on_mtu_update(&mut self, _: u16) {}

    fn window(&self) -> u64 {
        self.window
    }

    fn clone_box(&self) -> Box<dyn Controller> {
        Box::new(*self)
    }

    fn initial_window(&self) -> u64 {
        self.window
    }

    fn into_any(self: Box<Self>) -> Box<dyn Any> {
        self
    }

    fn on_ack(
        &mut self,
        _: std::time::Instant,
        _: std::time::Instant,
        _: u64,
        _: bool,
        _: &RttEstimator,
    ) {
    }
}

/// Makes [`FixedWindow`]s for quinn.
#[derive(Clone, Copy, Debug)]
pub struct FixedWindowFactory(pub u64);

impl ControllerFactory for FixedWindowFactory {
    fn build(self: Arc<Self>, _: std::time::Instant, _: u16) -> Box<dyn Controller> {
        Box::new(FixedWindow::new(self.0))
    }
}

/// What every QUIC connection of a link runs with.
fn transport(endpoint: &Config, tls: &TlsConfig) -> TransportConfig {
    let liveness: StdDuration = endpoint.liveness.unwrap_or(DEFAULT_LIVENESS).into();
    let idle = (liveness * 2).max(tls.handshake_timeout);
    let mut t = TransportConfig::default();
    t.max_idle_timeout(IdleTimeout::try_from(idle).ok())
        .keep_alive_interval(Some(liveness / 3))
        // One stream, the endpoint's frames: Hello, Control, Close.
        .max_concurrent_bidi_streams(VarInt::from_u32(1))
        .max_concurrent_uni_streams(VarInt::from_u32(0))
        .stream_receive_window(VarInt::from_u32(64 * 1024))
        .receive_window(VarInt::from_u32(64 * 1024))
        .send_window(64 * 1024)
        // A few periods of Bundles: a newer one matters more than an old
        // one that waits.
        .datagram_receive_buffer_size(Some(64 * 1024))
        .datagram_send_buffer_size(64 * 1024)
        .congestion_controller_factory(Arc::new(FixedWindowFactory(WINDOW)))
        .enable_segmentation_offload(false);
    t
}

/// The client side of a link's connection.
pub(crate) fn client(
    endpoint: &Config,
    tls: &TlsConfig,
) -> Result<quinn_proto::ClientConfig, TlsError> {
    let crypto = tls.quic_client(ALPN)?;
    let mut config = quinn_proto::ClientConfig::new(Arc::new(crypto));
    config.transport_config(Arc::new(transport(endpoint, tls)));
    Ok(config)
}

/// The server side: a listener's.
pub(crate) fn server(
    endpoint: &Config,
    tls: &TlsConfig,
) -> Result<quinn_proto::ServerConfig, TlsError> {
    let crypto = tls.quic_server(ALPN)?;
    let mut config = quinn_proto::ServerConfig::with_crypto(Arc::new(crypto));
    config
        .transport_config(Arc::new(transport(endpoint, tls)))
        // A peer that moves (another Wi-Fi access point, a NAT's new
        // mapping) keeps its link.
        .migration(true)
        .max_incoming(tls.max_pending_handshakes.max(1));
    Ok(config)
}

/// A QUIC endpoint with quinn's defaults (no path MTU discovery: a
/// link's datagrams fit the minimum), its stateless resets and connection
/// IDs keyed by the side's identity ([`TlsConfig::quic_keys`]): random
/// keys would make a restarted peer drop the old connection's packets
/// unanswered, its successor's reset unrecognisable.
pub(crate) fn endpoint(
    server: Option<Arc<quinn_proto::ServerConfig>>,
    tls: &TlsConfig,
) -> quinn_proto::Endpoint {
    let (reset, cid) = tls.quic_keys();
    let mut config = quinn_proto::EndpointConfig::new(Arc::new(reset));
    config.cid_generator(move || Box::new(quinn_proto::HashedConnectionIdGenerator::from_key(cid)));
    quinn_proto::Endpoint::new(Arc::new(config), server, false, None)
}
