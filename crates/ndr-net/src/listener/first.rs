//! How much of its first message a connecting peer has sent: TLS's
//! ClientHello record, or ndr's Hello frame on a plain link.
//!
//! A real peer sends its first message whole, at once; a connection that
//! trickles it byte by byte is holding a slot, and is the first to lose it.
//! The bytes are only peeked at: TLS or the hub reads them afterwards.

use std::time::Duration as StdDuration;

use ndr_core::wire;
use tokio::net::TcpStream;

/// A TLS record's header: type, version, length.
const TLS_HEADER: usize = 5;
/// A TLS record of the handshake protocol (a ClientHello's).
const TLS_HANDSHAKE: u8 = 0x16;
/// The longest first message waited for whole: a TLS record's largest
/// plaintext. Longer claims are passed on as they are, to be refused.
const MAX_FIRST: usize = TLS_HEADER + (1 << 14);
/// The first wait for the rest of a message that came in part, doubled at
/// each look up to [`LAST_WAIT`]: a message split by the network is whole a
/// round trip later, a trickle is looked at rarely.
const FIRST_WAIT: StdDuration = StdDuration::from_millis(5);
const LAST_WAIT: StdDuration = StdDuration::from_millis(250);

/// How much of its first message a peer has sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Heard {
    /// Nothing yet.
    Nothing,
    /// Part of it; the whole is this long, where that is known yet.
    Part(Option<usize>),
    /// All of it, or bytes that are not such a message (for TLS or the hub
    /// to refuse).
    Whole,
}

/// What `bytes`, the start of what a peer sent, hold of its first message.
pub(super) fn heard(bytes: &[u8], tls: bool) -> Heard {
    if bytes.is_empty() {
        return Heard::Nothing;
    }
    let whole = if tls {
        if bytes.first() != Some(&TLS_HANDSHAKE) {
            return Heard::Whole;
        }
        match bytes.get(3..TLS_HEADER) {
            Some(&[hi, lo]) => TLS_HEADER + usize::from(u16::from_be_bytes([hi, lo])),
            _ => return Heard::Part(None),
        }
    } else {
        match wire::frame_len(bytes) {
            Ok(Some(len)) => len,
            Ok(None) => return Heard::Part(None),
            Err(_) => return Heard::Whole,
        }
    };
    if bytes.len() >= whole || whole > MAX_FIRST {
        Heard::Whole
    } else {
        Heard::Part(Some(whole))
    }
}

/// What a peer has said by the time it is accepted, without waiting.
pub(super) enum Said {
    /// So much of its first message.
    Heard(Heard),
    /// It closed or reset the connection.
    #[cfg_attr(not(target_os = "linux"), allow(dead_code))]
    Closed,
}

/// Peeks, without waiting, at what the peer has sent so far.
#[cfg(target_os = "linux")]
pub(super) fn said(stream: &TcpStream, tls: bool) -> Said {
    use nix::errno::Errno;
    use nix::sys::socket::{MsgFlags, recv};
    use std::os::fd::AsRawFd;

    // Enough for a whole ndr Hello or a usual ClientHello.
    let mut buf = [0; 512];
    let peek = MsgFlags::MSG_PEEK | MsgFlags::MSG_DONTWAIT;
    match recv(stream.as_raw_fd(), &mut buf, peek) {
        Ok(0) => Said::Closed,
        Ok(n) => Said::Heard(heard(buf.get(..n).unwrap_or_default(), tls)),
        Err(Errno::EAGAIN | Errno::EINTR) => Said::Heard(Heard::Nothing),
        Err(_) => Said::Closed,
    }
}

/// Elsewhere the peer's task finds out.
#[cfg(not(target_os = "linux"))]
pub(super) fn said(_: &TcpStream, _: bool) -> Said {
    Said::Heard(Heard::Nothing)
}

/// Waits until the peer has sent its whole first message, calling
/// `progress` with what it has heard and the bytes seen at each look;
/// `Ok(false)` if the peer closed first.
pub(super) async fn wait_whole(
    stream: &TcpStream,
    tls: bool,
    mut progress: impl FnMut(Heard, usize),
) -> std::io::Result<bool> {
    let mut buf = vec![0; 64];
    let mut wait = FIRST_WAIT;
    loop {
        let n = stream.peek(&mut buf).await?;
        if n == 0 {
            return Ok(false);
        }
        let now = heard(buf.get(..n).unwrap_or_default(), tls);
        progress(now, n);
        let want = match now {
            Heard::Whole => return Ok(true),
            Heard::Part(Some(whole)) => whole,
            Heard::Nothing | Heard::Part(None) => n + 1,
        };
        let cut = n == buf.len();
        if want > buf.len() {
            buf.resize(want.min(MAX_FIRST), 0);
        }
        if cut && buf.len() > n {
            // The peek was cut by the buffer: a longer one may find it whole.
            continue;
        }
        // Peeked bytes stay in the socket, which stays readable: wait by
        // the clock, not for readiness.
        tokio::time::sleep(wait).await;
        wait = (wait * 2).min(LAST_WAIT);
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use ndr_core::time::{Duration, Instant};
    use ndr_core::wire::{Header, Hello, Message, Role};

    /// A base's Hello, whole: what a real peer sends first.
    pub(in crate::listener) fn hello() -> Vec<u8> {
        let header = Header::new(0, Instant::ZERO);
        let hello = Hello {
            seat: ndr_core::wire::Seat::Control,
            role: Role::Base,
            mode: wire::ModeCode::PaperStatic,
            underflow: wire::UnderflowCode::Hold,
            command_width: 1,
            state_width: 1,
            period: Duration::from_millis(10),
            layout: 0,
            session: 0,
            regulation: ndr_core::wire::RegulationName::NONE,
        };
        let mut buf = vec![0; wire::MAX_FRAME_LEN];
        let n = wire::encode(&header, &Message::Hello(hello), &mut buf).expect("encode");
        buf.truncate(n);
        buf
    }

    #[test]
    fn an_ndr_hello_is_whole_only_with_all_its_bytes() {
        let h = hello();
        assert_eq!(heard(&[], false), Heard::Nothing);
        assert_eq!(heard(&h[..2], false), Heard::Part(None));
        assert_eq!(heard(&h[..h.len() - 1], false), Heard::Part(Some(h.len())));
        assert_eq!(heard(&h, false), Heard::Whole);
        // Not a frame at all: passed on, to be refused.
        assert_eq!(heard(b"GET / HTTP/1.1\r\n", false), Heard::Whole);
    }

    #[test]
    fn a_client_hello_is_whole_with_its_whole_record() {
        let record = [TLS_HANDSHAKE, 3, 1, 0, 3, 1, 2, 3];
        assert_eq!(heard(&record[..1], true), Heard::Part(None));
        assert_eq!(heard(&record[..6], true), Heard::Part(Some(8)));
        assert_eq!(heard(&record, true), Heard::Whole);
        // A plain peer on a TLS listener: TLS refuses it at once.
        assert_eq!(heard(&hello(), true), Heard::Whole);
    }

    #[test]
    fn a_message_split_in_two_is_waited_for_and_a_trickle_is_not_whole() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime");
        rt.block_on(async {
            let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
                .await
                .expect("bind");
            let addr = listener.local_addr().expect("address");
            let mut peer = tokio::net::TcpStream::connect(addr).await.expect("connect");
            let (accepted, _) = listener.accept().await.expect("accept");
            let h = hello();
            use tokio::io::AsyncWriteExt;
            peer.write_all(&h[..3]).await.expect("write");
            let mut seen = Vec::new();
            let waiting = wait_whole(&accepted, false, |heard, _| seen.push(heard));
            let partial = tokio::time::timeout(StdDuration::from_millis(100), waiting).await;
            assert!(partial.is_err(), "three bytes are not a Hello");
            assert!(seen.iter().all(|h| *h == Heard::Part(None)), "{seen:?}");
            peer.write_all(&h[3..]).await.expect("write");
            let whole = wait_whole(&accepted, false, |_, _| {}).await.expect("peek");
            assert!(whole);
        });
    }
}
