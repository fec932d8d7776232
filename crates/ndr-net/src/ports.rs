//! One port number over UDP and TCP for a listening address.
//!
//! A datagram listener takes its links' datagrams at its TCP port's number,
//! and the relay listens on one number over both. Given port 0, either needs
//! a number free over both protocols, and another program may take it over
//! one while the other is bound. UDP goes first (an ephemeral port), then
//! TCP at the same number; when that number is taken over TCP, another UDP
//! port is drawn, the ones tried held until the end so that the kernel does
//! not hand one out again.

use std::io;
use std::net::SocketAddr;

/// UDP ports drawn when given port 0 and TCP is taken at each.
pub(crate) const BIND_ATTEMPTS: usize = 8;

/// Binds `udp` at `listen`, then `tcp` at the address and port UDP got;
/// the sockets and that address. With port 0, a TCP bind refused because
/// the number is in use draws another UDP port, `attempts` times in all;
/// a port the caller gave that is taken is an error at once. `who` names
/// the listening side in the errors ("relay", "listener").
pub(crate) fn bind_pair<U, T>(
    listen: SocketAddr,
    attempts: usize,
    who: &str,
    mut udp: impl FnMut(SocketAddr) -> io::Result<(U, SocketAddr)>,
    mut tcp: impl FnMut(SocketAddr) -> io::Result<T>,
) -> io::Result<(U, T, SocketAddr)> {
    let attempts = if listen.port() == 0 {
        attempts.max(1)
    } else {
        1
    };
    // The UDP ports tried, closed only once a pair is found.
    let mut tried = Vec::new();
    loop {
        let (datagrams, local) = udp(listen).map_err(|e| {
            io::Error::new(
                e.kind(),
                format!("{who}: cannot listen on {listen} over UDP (the datagrams): {e}"),
            )
        })?;
        match tcp(local) {
            Ok(stream) => return Ok((datagrams, stream, local)),
            Err(e) if e.kind() == io::ErrorKind::AddrInUse && tried.len() + 1 < attempts => {
                tried.push(datagrams);
            }
            Err(e) => {
                let picked = if listen.port() == 0 {
                    format!(
                        " (UDP got port {}; tried {} ports)",
                        local.port(),
                        tried.len() + 1
                    )
                } else {
                    String::new()
                };
                return Err(io::Error::new(
                    e.kind(),
                    format!(
                        "{who}: cannot listen on {local} over TCP{picked}: {e}; the {who} \
                         listens on one port number over TCP and UDP: give a port free for \
                         both, or 0"
                    ),
                ));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn addr(port: u16) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], port))
    }

    /// A UDP bind that hands out ports 40000, 40001, … for port 0 and
    /// records the ports it gave.
    fn udp_from(given: &mut Vec<u16>) -> impl FnMut(SocketAddr) -> io::Result<(u16, SocketAddr)> {
        move |at: SocketAddr| {
            let port = if at.port() == 0 {
                40_000 + given.len() as u16
            } else {
                at.port()
            };
            given.push(port);
            Ok((port, addr(port)))
        }
    }

    fn in_use() -> io::Error {
        io::Error::from(io::ErrorKind::AddrInUse)
    }

    #[test]
    fn a_port_taken_over_tcp_draws_another_udp_port_holding_the_first() {
        let mut given = Vec::new();
        let mut tcp_tried = Vec::new();
        let (udp, tcp, at) =
            bind_pair(addr(0), BIND_ATTEMPTS, "relay", udp_from(&mut given), |a| {
                tcp_tried.push(a.port());
                if tcp_tried.len() < 3 {
                    Err(in_use())
                } else {
                    Ok(a.port())
                }
            })
            .unwrap();
        assert_eq!((udp, tcp, at), (40_002, 40_002, addr(40_002)));
        assert_eq!(tcp_tried, [40_000, 40_001, 40_002]);
        assert_eq!(given, [40_000, 40_001, 40_002]);
    }

    #[test]
    fn a_port_taken_at_every_attempt_is_a_clear_error_after_the_bound() {
        let mut given = Vec::new();
        let e = bind_pair(addr(0), 4, "relay", udp_from(&mut given), |_| {
            Err::<u16, _>(in_use())
        })
        .unwrap_err();
        assert_eq!(given.len(), 4);
        assert_eq!(e.kind(), io::ErrorKind::AddrInUse);
        let msg = e.to_string();
        assert!(
            msg.contains("over TCP") && msg.contains("tried 4 ports"),
            "{msg}"
        );
    }

    #[test]
    fn a_port_the_user_gave_is_not_traded_for_another() {
        let mut given = Vec::new();
        let e = bind_pair(
            addr(7000),
            BIND_ATTEMPTS,
            "relay",
            udp_from(&mut given),
            |_| Err::<u16, _>(in_use()),
        )
        .unwrap_err();
        assert_eq!(given, [7000]);
        assert!(e.to_string().contains("127.0.0.1:7000 over TCP"), "{e}");
    }

    #[test]
    fn other_errors_are_not_retried_and_udp_is_named() {
        let mut tcp_calls = 0;
        let e = bind_pair(
            addr(0),
            BIND_ATTEMPTS,
            "relay",
            |_| Err::<(u16, SocketAddr), _>(io::Error::from(io::ErrorKind::PermissionDenied)),
            |_| {
                tcp_calls += 1;
                Ok(0u16)
            },
        )
        .unwrap_err();
        assert_eq!(tcp_calls, 0);
        assert_eq!(e.kind(), io::ErrorKind::PermissionDenied);
        assert!(e.to_string().contains("over UDP"), "{e}");
        let e = bind_pair(
            addr(0),
            BIND_ATTEMPTS,
            "relay",
            |a| Ok((0u16, a)),
            |_| Err::<u16, _>(io::Error::from(io::ErrorKind::PermissionDenied)),
        )
        .unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::PermissionDenied);
    }

    #[test]
    fn real_sockets_share_one_number() {
        let (udp, tcp, at) = bind_pair(
            addr(0),
            BIND_ATTEMPTS,
            "relay",
            |a| {
                let s = std::net::UdpSocket::bind(a)?;
                let local = s.local_addr()?;
                Ok((s, local))
            },
            std::net::TcpListener::bind,
        )
        .unwrap();
        assert_ne!(at.port(), 0);
        assert_eq!(udp.local_addr().unwrap(), at);
        assert_eq!(tcp.local_addr().unwrap(), at);
    }
}
