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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tls::TlsError;

    /// One error of each variant of the driver's errors (the link's are
    /// ndr-core's), and of each cause a variant words apart.
    fn every_message() -> Vec<String> {
        use rustls::{AlertDescription, CertificateError};
        let handshakes = vec![
            HandshakeError::from_rustls(&rustls::Error::InvalidCertificate(
                CertificateError::ApplicationVerificationFailure,
            )),
            HandshakeError::from_rustls(&rustls::Error::InvalidCertificate(
                CertificateError::UnknownIssuer,
            )),
            HandshakeError::from_rustls(&rustls::Error::AlertReceived(
                AlertDescription::AccessDenied,
            )),
            HandshakeError::NoCertificate,
            HandshakeError::Version("ProtocolVersion".into()),
            HandshakeError::Timeout(std::time::Duration::from_secs(3)),
            HandshakeError::Other("reset".into()),
        ];
        let transports = vec![
            TransportError::Unknown("sctp".into()),
            TransportError::QuicWithoutTls,
            TransportError::UdpWithTls,
            TransportError::ZenohWithTls,
            TransportError::ZenohNotBuilt,
            TransportError::ZenohByName,
            TransportError::Mismatch {
                link: crate::Transport::UDP,
                endpoint: ndr_core::endpoint::Transport::Stream,
            },
        ];
        let tls = vec![
            TlsError::Read {
                path: "a.crt".into(),
                error: "No such file".into(),
            },
            TlsError::NoCertificate("a.key".into()),
            TlsError::Rustls("key mismatch".into()),
            TlsError::Fingerprint("12".into()),
            TlsError::NoTrust,
        ];
        let nets = vec![
            NetError::Io(io::ErrorKind::ConnectionRefused.into()),
            NetError::Config(ConfigError::Width {
                which: "command",
                width: 0,
            }),
            NetError::Timeout,
            NetError::Insecure(([192, 0, 2, 7], 7300).into()),
            NetError::Realtime(RealtimeError::BadPriority(0)),
        ];
        // No wildcard: a new variant fails to compile here until it has
        // its sample above (and its entry in the page).
        for e in &handshakes {
            match e {
                HandshakeError::UnknownCertificate(_)
                | HandshakeError::NoCertificate
                | HandshakeError::Version(_)
                | HandshakeError::Timeout(_)
                | HandshakeError::Other(_) => {}
            }
        }
        for e in &transports {
            match e {
                TransportError::Unknown(_)
                | TransportError::QuicWithoutTls
                | TransportError::UdpWithTls
                | TransportError::ZenohWithTls
                | TransportError::ZenohNotBuilt
                | TransportError::ZenohByName
                | TransportError::Mismatch { .. } => {}
            }
        }
        for e in &tls {
            match e {
                TlsError::Read { .. }
                | TlsError::NoCertificate(_)
                | TlsError::Rustls(_)
                | TlsError::Fingerprint(_)
                | TlsError::NoTrust => {}
            }
        }
        for e in &nets {
            match e {
                // The link's and these three wrap the errors above.
                NetError::Link(_) | NetError::Handshake(_) | NetError::Transport(_) => {}
                NetError::Io(_)
                | NetError::Config(_)
                | NetError::Timeout
                | NetError::Insecure(_)
                | NetError::Realtime(_) => {}
            }
        }
        let mut all: Vec<String> = handshakes
            .into_iter()
            .map(NetError::Handshake)
            .chain(transports.into_iter().map(NetError::Transport))
            .chain(nets)
            .map(|e| e.to_string())
            .collect();
        all.extend(tls.iter().map(ToString::to_string));
        all
    }

    include!(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/support/troubleshooting_page.rs"
    ));

    #[test]
    fn every_message_is_in_the_troubleshooting_page() {
        troubleshooting_page::assert_listed(
            concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../../docs/guide/troubleshooting.md"
            ),
            every_message(),
        );
    }
}
