//! Why a link could not be set up or used.

use std::fmt;
use std::io;
use std::net::SocketAddr;

use ndr_core::endpoint::{ConfigError, LinkError};

use crate::tls::HandshakeError;

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
    /// The datagram transport asked of a TCP stream that already carries
    /// TLS (an internal path): its datagrams would travel unencrypted. A
    /// datagram link with TLS runs over QUIC ([`Link::connect`](crate::Link::connect),
    /// [`Listener::bind`](crate::Listener::bind)).
    DatagramsWithTls,
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
            NetError::DatagramsWithTls => f.write_str(
                "a TLS stream does not take the datagram transport (its datagrams would be \
                 plain): a datagram link with TLS runs over QUIC (--transport quic, Python: \
                 transport=\"quic\")",
            ),
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
            NetError::Timeout | NetError::Insecure(_) | NetError::DatagramsWithTls => None,
        }
    }
}

impl From<io::Error> for NetError {
    fn from(e: io::Error) -> Self {
        NetError::Io(e)
    }
}
