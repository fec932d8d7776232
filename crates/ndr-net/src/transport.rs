//! How a link's samples cross the network: [`Transport`], named the same
//! in Rust, on the command line and in Python, and checked against the
//! link's security in one place.

use std::fmt;
use std::str::FromStr;

use ndr_core::endpoint::Transport as Carriage;

/// A link's transport: `tcp`, `udp[:K[:R]]`, `quic[:K[:R]]` or
/// `zenoh[:K[:R]]`.
///
/// `K` is the samples each datagram carries (1 to 8, default 4) and `R`
/// the times each is sent again while the path loses datagrams (0 to 4,
/// default 3); see [`ndr_core::endpoint::Transport::Datagram`].
///
/// ```
/// use ndr_net::Transport;
///
/// let t: Transport = "quic:2".parse()?;
/// assert_eq!(t.to_string(), "quic:2:3");
/// // QUIC runs mutual TLS 1.3; plain UDP does not run beside TLS.
/// assert!(t.check_security(false).is_err());
/// assert!(Transport::UDP.check_security(true).is_err());
/// # Ok::<(), ndr_net::TransportError>(())
/// ```
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Transport {
    /// A TCP stream (plain, or mutual TLS 1.3): the paper's transport.
    #[default]
    Tcp,
    /// The samples as plain UDP datagrams; the handshake, Control and
    /// Close over a TCP stream beside them. Carries no TLS.
    Udp {
        /// Samples per datagram, 1 to 8.
        redundancy: u8,
        /// Times each sample's datagram is sent again, 0 to 4.
        repeats: u8,
    },
    /// The samples as QUIC datagrams, the rest on a QUIC stream: one UDP
    /// port, mutual TLS 1.3 (which it needs).
    Quic {
        /// Samples per datagram, 1 to 8.
        redundancy: u8,
        /// Times each sample's datagram is sent again, 0 to 4.
        repeats: u8,
    },
    /// Every frame as a zenoh publication (through a zenoh router or
    /// between zenoh peers, feature `zenoh`): the samples' datagrams
    /// best-effort and express, the rest reliable. Carries no ndr TLS.
    Zenoh {
        /// Samples per datagram, 1 to 8.
        redundancy: u8,
        /// Times each sample's datagram is sent again, 0 to 4.
        repeats: u8,
    },
}

impl Transport {
    /// `udp`: plain UDP with the endpoint's default copies and repeats
    /// ([`Transport::DATAGRAM`](ndr_core::endpoint::Transport::DATAGRAM)).
    pub const UDP: Transport = Transport::Udp {
        redundancy: 4,
        repeats: 3,
    };
    /// `quic`: QUIC datagrams with the default copies and repeats.
    pub const QUIC: Transport = Transport::Quic {
        redundancy: 4,
        repeats: 3,
    };

    /// `zenoh`: zenoh publications with the default copies and repeats.
    pub const ZENOH: Transport = Transport::Zenoh {
        redundancy: 4,
        repeats: 3,
    };

    /// What the endpoint does with its samples: a stream, or datagrams
    /// (UDP, QUIC and zenoh alike).
    #[must_use]
    pub fn carriage(self) -> Carriage {
        match self {
            Transport::Tcp => Carriage::Stream,
            Transport::Udp {
                redundancy,
                repeats,
            }
            | Transport::Quic {
                redundancy,
                repeats,
            }
            | Transport::Zenoh {
                redundancy,
                repeats,
            } => Carriage::Datagram {
                redundancy,
                repeats,
            },
        }
    }

    /// The plain transport that carries as `carriage` says: `tcp` or `udp`.
    #[must_use]
    pub fn plain(carriage: Carriage) -> Transport {
        match carriage {
            Carriage::Datagram {
                redundancy,
                repeats,
            } => Transport::Udp {
                redundancy,
                repeats,
            },
            _ => Transport::Tcp,
        }
    }

    /// Whether the samples go as datagrams (UDP, QUIC or zenoh).
    #[must_use]
    pub fn datagrams(self) -> bool {
        !matches!(self, Transport::Tcp)
    }

    /// Whether the link runs over QUIC.
    #[must_use]
    pub fn is_quic(self) -> bool {
        matches!(self, Transport::Quic { .. })
    }

    /// Whether the link runs over zenoh.
    #[must_use]
    pub fn is_zenoh(self) -> bool {
        matches!(self, Transport::Zenoh { .. })
    }

    /// Whether a link with (`tls`) or without TLS can run this transport:
    /// QUIC needs TLS, and plain UDP and zenoh cannot carry it.
    pub fn check_security(self, tls: bool) -> Result<(), TransportError> {
        match (self, tls) {
            (Transport::Quic { .. }, false) => Err(TransportError::QuicWithoutTls),
            (Transport::Udp { .. }, true) => Err(TransportError::UdpWithTls),
            (Transport::Zenoh { .. }, _) if !cfg!(feature = "zenoh") => {
                Err(TransportError::ZenohNotBuilt)
            }
            (Transport::Zenoh { .. }, true) => Err(TransportError::ZenohWithTls),
            _ => Ok(()),
        }
    }
}

impl FromStr for Transport {
    type Err = TransportError;

    /// `tcp`, `udp`, `udp:K`, `udp:K:R`, `quic`, `quic:K`, `quic:K:R`,
    /// `zenoh`, `zenoh:K`, `zenoh:K:R`; the endpoint's names `stream` and
    /// `datagram[:K[:R]]` read as `tcp` and `udp[:K[:R]]`.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let unknown = || TransportError::Unknown(s.to_owned());
        // `quic` and `zenoh` take the datagram transport's `:K:R`.
        let datagrams = |rest: &str| match format!("datagram{rest}").parse::<Carriage>() {
            Ok(Carriage::Datagram {
                redundancy,
                repeats,
            }) if rest.is_empty() || rest.starts_with(':') => Ok((redundancy, repeats)),
            _ => Err(unknown()),
        };
        if let Some(rest) = s.strip_prefix("quic") {
            return datagrams(rest).map(|(redundancy, repeats)| Transport::Quic {
                redundancy,
                repeats,
            });
        }
        if let Some(rest) = s.strip_prefix("zenoh") {
            return datagrams(rest).map(|(redundancy, repeats)| Transport::Zenoh {
                redundancy,
                repeats,
            });
        }
        s.parse::<Carriage>()
            .map(Transport::plain)
            .map_err(|_| unknown())
    }
}

impl fmt::Display for Transport {
    /// `tcp`, `udp:K:R` or `quic:K:R`: the name [`Transport::from_str`]
    /// reads back, as reports show it.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Transport::Tcp => f.write_str("tcp"),
            Transport::Udp {
                redundancy,
                repeats,
            } => write!(f, "udp:{redundancy}:{repeats}"),
            Transport::Quic {
                redundancy,
                repeats,
            } => write!(f, "quic:{redundancy}:{repeats}"),
            Transport::Zenoh {
                redundancy,
                repeats,
            } => write!(f, "zenoh:{redundancy}:{repeats}"),
        }
    }
}

/// Why a transport was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum TransportError {
    /// Not a transport's name.
    Unknown(String),
    /// QUIC without TLS identities: QUIC always runs mutual TLS 1.3.
    QuicWithoutTls,
    /// Plain UDP with TLS identities: its datagrams would go unencrypted.
    UdpWithTls,
    /// Zenoh with TLS identities: ndr's TLS does not run over zenoh.
    ZenohWithTls,
    /// Zenoh without the `zenoh` feature built in.
    ZenohNotBuilt,
    /// A zenoh link asked of a call that takes a socket address: zenoh
    /// links find their peer by the robot's name.
    ZenohByName,
    /// [`LinkConfig::transport`](crate::LinkConfig::transport) and its
    /// endpoint's `transport` disagree (one was changed without the other).
    Mismatch {
        /// The link's transport.
        link: Transport,
        /// What its endpoint was configured to carry.
        endpoint: Carriage,
    },
}

impl fmt::Display for TransportError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TransportError::Unknown(name) => write!(
                f,
                "unknown transport {name:?}: tcp; udp, udp:K or udp:K:R (K samples per \
                 datagram, 1 to 8; R repeats, 0 to 4); quic, quic:K or quic:K:R (the same \
                 over QUIC, with TLS); zenoh, zenoh:K or zenoh:K:R (the same as zenoh \
                 publications)"
            ),
            TransportError::QuicWithoutTls => {
                f.write_str("the quic transport runs mutual TLS 1.3: give the link TLS identities")
            }
            TransportError::UdpWithTls => f.write_str(
                "the udp transport is plain UDP and carries no TLS: with TLS, use quic \
                 (datagrams over QUIC) or tcp",
            ),
            TransportError::ZenohWithTls => f.write_str(
                "the zenoh transport carries no ndr TLS: run it on a network you trust \
                 (zenoh's access control in its configuration, --zenoh-config), or use quic \
                 or tcp with TLS",
            ),
            TransportError::ZenohNotBuilt => f.write_str(
                "this build has no zenoh transport: build ndr-net (or ndr-link) with the \
                 `zenoh` feature",
            ),
            TransportError::ZenohByName => f.write_str(
                "a zenoh link finds its robot by name, not by address: use \
                 Link::connect_zenoh or Listener::listen_zenoh",
            ),
            TransportError::Mismatch { link, endpoint } => write!(
                f,
                "the link's transport is {link} but its endpoint's is {endpoint}: set both \
                 with LinkConfig::with_transport"
            ),
        }
    }
}

impl std::error::Error for TransportError {}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_read_back() {
        for (name, shown) in [
            ("tcp", "tcp"),
            ("stream", "tcp"),
            ("udp", "udp:4:3"),
            ("datagram:2", "udp:2:3"),
            ("udp:2:0", "udp:2:0"),
            ("quic", "quic:4:3"),
            ("quic:2:1", "quic:2:1"),
            ("zenoh", "zenoh:4:3"),
            ("zenoh:2", "zenoh:2:3"),
        ] {
            let t: Transport = name.parse().unwrap();
            assert_eq!(t.to_string(), shown, "{name}");
            assert_eq!(shown.parse::<Transport>().unwrap(), t);
        }
        for bad in [
            "quic:9", "quicx", "quic:", "udp:0", "udp:2:5", "sctp", "", "zenohx", "zenoh:9",
        ] {
            assert_eq!(
                bad.parse::<Transport>(),
                Err(TransportError::Unknown(bad.into())),
                "{bad}"
            );
        }
    }

    #[test]
    fn quic_needs_tls_and_udp_refuses_it() {
        let q: Transport = "quic:2:1".parse().unwrap();
        assert_eq!(q.check_security(false), Err(TransportError::QuicWithoutTls));
        assert_eq!(q.check_security(true), Ok(()));
        assert_eq!(
            Transport::UDP.check_security(true),
            Err(TransportError::UdpWithTls)
        );
        assert_eq!(Transport::UDP.check_security(false), Ok(()));
        assert_eq!(Transport::Tcp.check_security(true), Ok(()));
        assert_eq!(Transport::Tcp.check_security(false), Ok(()));
        #[cfg(feature = "zenoh")]
        assert_eq!(
            Transport::ZENOH.check_security(true),
            Err(TransportError::ZenohWithTls)
        );
        let plain = if cfg!(feature = "zenoh") {
            Ok(())
        } else {
            Err(TransportError::ZenohNotBuilt)
        };
        assert_eq!(Transport::ZENOH.check_security(false), plain);
    }

    #[test]
    fn udp_and_quic_carry_datagrams_alike() {
        assert_eq!(Transport::QUIC.carriage(), Carriage::DATAGRAM);
        assert_eq!(Transport::UDP.carriage(), Carriage::DATAGRAM);
        assert_eq!(Transport::Tcp.carriage(), Carriage::Stream);
        assert_eq!(Transport::plain(Carriage::DATAGRAM), Transport::UDP);
    }
}
