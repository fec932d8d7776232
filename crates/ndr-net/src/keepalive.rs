//! Liveness at the transport, on every link's socket (connected or
//! accepted).
//!
//! The endpoint ends a link whose peer stays silent
//! ([`Config::liveness`](ndr_core::endpoint::Config::liveness)); the
//! kernel must give up too, or a half-open connection (the peer's host or
//! network gone, nothing to say so) keeps its socket and its unacknowledged
//! bytes. TCP keepalive probes an idle connection; `TCP_USER_TIMEOUT` bounds
//! how long sent data may stay unacknowledged, probes included, before the
//! kernel resets the connection and the hub reads the error.
//!
//! The kernel's bound is the liveness time and half as much again: a hung
//! peer (its process stopped) whose kernel drops what this side keeps
//! sending leaves data unacknowledged from the moment it stopped, and a
//! bound equal to the liveness raced the endpoint's own, whose message
//! names the silence ("nothing came from the peer for …"), with a reset
//! that says only that the connection was lost.

use std::io;
use std::os::fd::AsFd;
use std::time::Duration as StdDuration;

/// Idle time before the first keepalive probe.
pub(crate) const KEEPALIVE_IDLE: StdDuration = StdDuration::from_secs(2);
/// Time between keepalive probes.
pub(crate) const KEEPALIVE_INTERVAL: StdDuration = StdDuration::from_secs(1);
/// Probes unanswered before the connection is dropped.
pub(crate) const KEEPALIVE_PROBES: u32 = 3;

/// How long sent data may stay unacknowledged on a link whose endpoint
/// ends a silent peer after `liveness`: longer, so that the endpoint, not
/// the kernel, says why a hung peer was dropped.
pub(crate) fn user_timeout(liveness: StdDuration) -> StdDuration {
    liveness.saturating_add(liveness / 2)
}

/// Turns keepalive on and bounds unacknowledged data to
/// [`user_timeout`] of `liveness` (at least a second: the kernel counts in
/// milliseconds, and shorter would drop a sound connection in one
/// retransmission).
#[cfg(target_os = "linux")]
pub(crate) fn enable(socket: &impl AsFd, liveness: StdDuration) -> io::Result<()> {
    use nix::sys::socket::{setsockopt, sockopt};

    let secs = |d: StdDuration| u32::try_from(d.as_secs()).unwrap_or(u32::MAX).max(1);
    let millis = u32::try_from(user_timeout(liveness).as_millis())
        .unwrap_or(u32::MAX)
        .max(1000);
    setsockopt(socket, sockopt::KeepAlive, &true)?;
    setsockopt(socket, sockopt::TcpKeepIdle, &secs(KEEPALIVE_IDLE))?;
    setsockopt(socket, sockopt::TcpKeepInterval, &secs(KEEPALIVE_INTERVAL))?;
    setsockopt(socket, sockopt::TcpKeepCount, &KEEPALIVE_PROBES)?;
    setsockopt(socket, sockopt::TcpUserTimeout, &millis)?;
    Ok(())
}

/// Elsewhere the endpoint's liveness alone ends a silent link.
#[cfg(not(target_os = "linux"))]
pub(crate) fn enable(_: &impl AsFd, _: StdDuration) -> io::Result<()> {
    Ok(())
}

#[cfg(all(test, target_os = "linux"))]
mod tests {
    use super::*;
    use nix::sys::socket::{getsockopt, sockopt};

    #[test]
    fn a_link_socket_gets_keepalive_and_a_user_timeout() {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind");
        let socket =
            std::net::TcpStream::connect(listener.local_addr().expect("address")).expect("connect");
        enable(&socket, StdDuration::from_secs(10)).expect("options");
        assert!(getsockopt(&socket, sockopt::KeepAlive).expect("keepalive"));
        assert_eq!(getsockopt(&socket, sockopt::TcpKeepIdle).expect("idle"), 2);
        assert_eq!(
            getsockopt(&socket, sockopt::TcpKeepInterval).expect("interval"),
            1
        );
        assert_eq!(
            getsockopt(&socket, sockopt::TcpKeepCount).expect("count"),
            3
        );
        // Past the endpoint's liveness, whose message names a hung peer.
        assert_eq!(
            getsockopt(&socket, sockopt::TcpUserTimeout).expect("user timeout"),
            15_000
        );
        // Too short a bound would cut a sound link at its first retransmission.
        enable(&socket, StdDuration::from_millis(10)).expect("options");
        assert_eq!(
            getsockopt(&socket, sockopt::TcpUserTimeout).expect("user timeout"),
            1000
        );
    }
}
