//! Why a link could not be set up or used.

use std::fmt;
use std::io;
use std::net::SocketAddr;

use ndr_core::endpoint::{ConfigError, LinkError};

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
            NetError::Timeout | NetError::Insecure(_) => None,
        }
    }
}

impl From<io::Error> for NetError {
    fn from(e: io::Error) -> Self {
        NetError::Io(e)
    }
}

impl From<TransportError> for NetError {
    fn from(e: TransportError) -> Self {
        NetError::Transport(e)
    }
}
