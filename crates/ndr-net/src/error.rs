//! Why a link could not be set up or used.

use std::fmt;
use std::io;
use std::net::SocketAddr;

use ndr_core::endpoint::{ConfigError, LinkError};

use crate::realtime::RealtimeError;
use crate::tls::HandshakeError;
use crate::transport::TransportError;

/// Why a link could not be set up or used.
#[derive(Debug)]
#[non_exhaustive]
pub enum NetError {
    /// The socket failed (connection refused, address in use, …).
    Io(io::Error),
    /// The configuration cannot run.
    Config(ConfigError),
    /// The link ended, with the reason.
    Link(LinkError),
    /// No sample came within the timeout (the link is still up).
    Timeout,
    /// A plain (unencrypted, unauthenticated) link to or from a
    /// non-loopback address, without [`LinkConfig::insecure`](crate::LinkConfig::insecure).
    Insecure(SocketAddr),
    /// The TLS handshake failed: no link was set up.
    Handshake(HandshakeError),
    /// The transport does not fit the link's security (QUIC without TLS,
    /// plain UDP with it) or its endpoint's configuration.
    Transport(TransportError),
    /// The hub's thread was refused real-time scheduling under
    /// [`RealtimeMode::Enforce`](crate::RealtimeMode::Enforce) (the message
    /// says what to grant), or the setting cannot be asked for.
    Realtime(RealtimeError),
}

impl fmt::Display for NetError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NetError::Io(e) => write!(f, "network error: {e}"),
            NetError::Config(e) => write!(f, "link configuration: {e}"),
            NetError::Link(e) => write!(f, "{e}"),
            NetError::Timeout => f.write_str("no sample within the timeout (the link is still up)"),
            NetError::Insecure(addr) => write!(
                f,
                "refusing a plain link with {addr}: it is not loopback; configure TLS \
                 (--cert, --key, --peer-cert or --pin) or pass --insecure (Python: insecure=True)"
            ),
            NetError::Handshake(e) => write!(f, "{e}"),
            NetError::Transport(e) => write!(f, "{e}"),
            NetError::Realtime(e) => write!(f, "real-time scheduling: {e}"),
        }
    }
}

impl std::error::Error for NetError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            NetError::Io(e) => Some(e),
            NetError::Config(e) => Some(e),
            NetError::Link(e) => Some(e),
            NetError::Handshake(e) => Some(e),
            NetError::Transport(e) => Some(e),
            NetError::Realtime(e) => Some(e),
            NetError::Timeout | NetError::Insecure(_) => None,
        }
    }
}

impl From<io::Error> for NetError {
    /// [`NetError::Io`], or [`NetError::Realtime`] for the error a hub's
    /// start returns when refused real-time scheduling.
    fn from(e: io::Error) -> Self {
        match e.get_ref().and_then(|i| i.downcast_ref::<RealtimeError>()) {
            Some(rt) => NetError::Realtime(rt.clone()),
            None => NetError::Io(e),
        }
    }
}

impl From<RealtimeError> for NetError {
    fn from(e: RealtimeError) -> Self {
        NetError::Realtime(e)
    }
}

impl From<TransportError> for NetError {
    fn from(e: TransportError) -> Self {
        NetError::Transport(e)
    }
}
