//! `--transport`: how a link's samples cross. The names, their parsing
//! and the rule that ties QUIC to TLS are the library's
//! ([`ndr::net::Transport`]); this module words its refusals for the
//! command line.

use ndr::core::endpoint::Transport;
use ndr::net::TransportError;
use ndr::netem::LossModel;

/// `tcp`, `udp[:K[:R]]` or `quic[:K[:R]]`: a datagram transport over
/// plain UDP or over QUIC (mutual TLS 1.3, which then needs the TLS
/// options).
pub use ndr::net::Transport as LinkTransport;

/// `--transport` of the simulator: as [`LinkTransport`], with QUIC
/// modelled as its datagrams (never retransmitted, as plain UDP's); its
/// handshake and encryption take no part in the samples' timing.
pub fn simulated(s: &str) -> Result<Transport, String> {
    s.parse::<LinkTransport>()
        .map(LinkTransport::carriage)
        .map_err(|e| e.to_string())
}

/// Whether the link's security fits the transport: QUIC needs TLS, and
/// plain UDP does not run beside it.
pub fn check_security(transport: LinkTransport, tls: bool) -> Result<(), String> {
    transport.check_security(tls).map_err(|e| match e {
        TransportError::QuicWithoutTls => "--transport quic runs mutual TLS 1.3: give --cert \
             and --key, and --peer-cert, --pin or --ca (`ndr keygen` makes a pair)"
            .to_string(),
        TransportError::UdpWithTls => "--transport udp is plain UDP: with the TLS options, \
             use --transport quic (datagrams over QUIC) or tcp"
            .to_string(),
        other => other.to_string(),
    })
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
    fn the_refusals_name_the_options() {
        let quic: LinkTransport = "quic:2:1".parse().unwrap();
        assert!(check_security(quic, false).unwrap_err().contains("--cert"));
        assert!(check_security(quic, true).is_ok());
        let udp = LinkTransport::UDP;
        assert!(
            check_security(udp, true)
                .unwrap_err()
                .contains("--transport quic")
        );
        assert_eq!(simulated("quic:2").unwrap(), "datagram:2".parse().unwrap());
        assert_eq!(simulated("stream").unwrap(), Transport::Stream);
    }
}
