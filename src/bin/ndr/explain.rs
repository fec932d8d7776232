//! `ndr base`'s messages where the command line knows more than the
//! library: which transport and port to check, and what a refused
//! connection may mean for a remote on another transport.

use std::net::SocketAddr;

use ndr::net::{LinkStats, NetError};

use crate::report::End;
use crate::transport::LinkTransport;

/// Why the connection to `to` failed: a refused TCP connection names the
/// remote's other transport (a QUIC remote listens on UDP only).
pub fn cannot_connect(e: &NetError, to: SocketAddr, transport: LinkTransport) -> String {
    match e {
        NetError::Io(io)
            if io.kind() == std::io::ErrorKind::ConnectionRefused && !transport.is_quic() =>
        {
            format!(
                "cannot connect to {to}: nothing accepts TCP connections there ({io}): start \
                 the remote first, or check the address and port; a remote run with \
                 --transport quic listens on UDP only: give this side --transport quic and \
                 the TLS options too"
            )
        }
        // A zenoh link has no address: its error names the robot.
        e if transport.is_zenoh() => e.to_string(),
        e => format!("cannot connect to {to}: {e}"),
    }
}

/// A udp link whose handshake (over TCP) completed but over which no
/// datagram came back: the end names the UDP port to open. Other ends are
/// returned as they are.
pub fn udp_silence(
    end: End,
    transport: LinkTransport,
    to: SocketAddr,
    stats: Option<&LinkStats>,
) -> End {
    let heard = stats.is_some_and(|s| s.endpoint.datagrams_received > 0);
    if !transport.datagrams() || transport.is_quic() || transport.is_zenoh() || heard {
        return end;
    }
    let hint = format!(
        "the handshake over TCP to {to} completed, but no datagram came back over UDP: a \
         firewall on the path or at the remote may let TCP through and drop UDP; open UDP \
         port {port} both ways (to the remote, and back from it), or use --transport tcp",
        port = to.port()
    );
    match end {
        // The general advice (the peer's settings, a longer run) points
        // the wrong way here: the hint replaces it.
        End::NeverConnected(_) => End::NeverConnected(hint),
        other => other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refused_tcp_connection_names_quic() {
        let to: SocketAddr = "127.0.0.1:7300".parse().unwrap();
        let refused = NetError::Io(std::io::ErrorKind::ConnectionRefused.into());
        let msg = cannot_connect(&refused, to, LinkTransport::Tcp);
        assert!(
            msg.contains("nothing accepts TCP connections there"),
            "{msg}"
        );
        assert!(
            msg.contains("--transport quic listens on UDP only"),
            "{msg}"
        );
        let other = NetError::Io(std::io::ErrorKind::TimedOut.into());
        assert!(!cannot_connect(&other, to, LinkTransport::Tcp).contains("quic"));
    }

    #[test]
    fn a_silent_udp_link_names_the_port() {
        let to: SocketAddr = "192.0.2.7:7300".parse().unwrap();
        let never = End::NeverConnected("no sample was released".into());
        let end = udp_silence(never.clone(), LinkTransport::UDP, to, None);
        let msg = end.to_string();
        assert!(
            msg.contains("no datagram came back over UDP") && msg.contains("UDP port 7300"),
            "{msg}"
        );
        // Over TCP, or with datagrams heard, the end stays as it was.
        assert_eq!(
            udp_silence(never.clone(), LinkTransport::Tcp, to, None),
            never
        );
    }
}
