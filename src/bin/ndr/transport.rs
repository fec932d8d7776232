//! `--transport`: how a link's samples cross — the endpoint's transport,
//! and whether its datagrams go over QUIC.

use std::fmt;
use std::str::FromStr;

use ndr::core::endpoint::Transport;
use ndr::netem::LossModel;

/// `tcp`, `udp[:K[:R]]` or `quic[:K[:R]]`: a datagram transport over
/// plain UDP or over QUIC (mutual TLS 1.3, which then needs the TLS
/// options).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LinkTransport {
    /// What the endpoint does with its samples.
    pub transport: Transport,
    /// The datagrams go over QUIC.
    pub quic: bool,
}

impl FromStr for LinkTransport {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if let Some(rest) = s.strip_prefix("quic") {
            let name = format!("datagram{rest}");
            let transport = name.parse::<Transport>().map_err(|_| {
                format!(
                    "unknown transport {s:?}: quic, quic:K (K samples per datagram, 1 to 8) \
                     or quic:K:R (R repeats, 0 to 4)"
                )
            })?;
            return Ok(LinkTransport {
                transport,
                quic: true,
            });
        }
        let transport = s.parse::<Transport>().map_err(|e| {
            format!("{e}; or quic[:K[:R]] (datagrams over QUIC, with the TLS options)")
        })?;
        Ok(LinkTransport {
            transport,
            quic: false,
        })
    }
}

impl fmt::Display for LinkTransport {
    /// `tcp`, `udp:K:R` or `quic:K:R`: the names the reports show.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.transport {
            Transport::Datagram {
                redundancy,
                repeats,
            } => {
                let name = if self.quic { "quic" } else { "udp" };
                write!(f, "{name}:{redundancy}:{repeats}")
            }
            _ => f.write_str("tcp"),
        }
    }
}

/// `--transport` of the simulator: as [`LinkTransport`], with QUIC
/// modelled as its datagrams (never retransmitted, as plain UDP's); its
/// handshake and encryption take no part in the samples' timing.
pub fn simulated(s: &str) -> Result<Transport, String> {
    s.parse::<LinkTransport>().map(|t| t.transport)
}

/// The paper's stream: what base and remote run unless told otherwise.
impl Default for LinkTransport {
    fn default() -> LinkTransport {
        LinkTransport {
            transport: Transport::Stream,
            quic: false,
        }
    }
}

impl LinkTransport {
    /// `ndr demo`'s: plain UDP datagrams with the endpoint's default
    /// copies and repeats.
    pub const DEMO: LinkTransport = LinkTransport {
        transport: Transport::DATAGRAM,
        quic: false,
    };

    /// Whether the link's security fits the transport: QUIC needs TLS, and
    /// plain UDP does not run beside it.
    pub fn check_security(&self, tls: bool) -> Result<(), String> {
        let datagrams = matches!(self.transport, Transport::Datagram { .. });
        match (self.quic, datagrams && !self.quic, tls) {
            (true, _, false) => Err(
                "--transport quic runs mutual TLS 1.3: give --cert and --key, \
                 and --peer-cert, --pin or --ca (`ndr keygen` makes a pair)"
                    .into(),
            ),
            (false, true, true) => Err("--transport udp is plain UDP: with the TLS options, \
                 use --transport quic (datagrams over QUIC) or tcp"
                .into()),
            _ => Ok(()),
        }
    }
}

/// Refuses a loss model over the stream, which has no datagrams to lose;
/// `instead` says what to give for datagrams.
pub fn check_loss(transport: Transport, loss: &LossModel, instead: &str) -> Result<(), String> {
    if transport == Transport::Stream && !loss.is_none() {
        return Err(format!(
            "--loss {loss} drops datagrams, and --transport tcp sends none (the relay never \
             drops TCP bytes): {instead}, or leave --loss out"
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quic_names_read_back_and_need_tls() {
        let q: LinkTransport = "quic:2:1".parse().unwrap();
        assert!(q.quic);
        assert_eq!(q.to_string(), "quic:2:1");
        assert_eq!(
            "quic".parse::<LinkTransport>().unwrap().to_string(),
            "quic:4:3"
        );
        assert!(q.check_security(false).is_err());
        assert!(q.check_security(true).is_ok());
        let u: LinkTransport = "udp".parse().unwrap();
        assert!(!u.quic);
        assert!(u.check_security(true).is_err());
        assert!("quic:9".parse::<LinkTransport>().is_err());
        assert_eq!("tcp".parse::<LinkTransport>().unwrap().to_string(), "tcp");
    }
}
