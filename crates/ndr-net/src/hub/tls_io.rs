//! A TLS link's bytes in the hub: rustls's sans-IO calls on the hub's own
//! non-blocking socket.
//!
//! Records are read with the kernel's arrival stamp, like frames on a plain
//! link: a frame's arrival time is then that of the read that completed the
//! record holding it. Frames are sealed into records as they are sent and
//! the records go out by the plain link's path (written now, or queued
//! behind what is waiting, bounded the same way).

use std::io::{self, Read, Write as _};
use std::time::Instant as StdInstant;

use mio::net::TcpStream as MioStream;
use ndr_core::endpoint::LinkError;

use super::{Entry, handle_frames, write_or_queue};

/// The TLS state of one link, continued from its handshake.
pub(crate) struct Session {
    conn: rustls::Connection,
    /// Records sealed and not yet handed to the socket (reused).
    sealed: Vec<u8>,
}

impl Session {
    pub(crate) fn new(conn: rustls::Connection) -> Session {
        Session {
            conn,
            sealed: Vec::new(),
        }
    }
}

/// The socket as rustls reads it: each read stamped with its arrival.
struct Stamped<'a> {
    socket: &'a MioStream,
    kernel: bool,
    at: Option<StdInstant>,
    /// The last read took less than it was offered: the socket is empty.
    short: bool,
}

impl Read for Stamped<'_> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        let (n, at) = crate::arrival::read_now(self.socket, buf, self.kernel)?;
        self.at = Some(at);
        self.short = n < buf.len();
        Ok(n)
    }
}

/// Reads what the socket has (to `WouldBlock` or the end if `drain`),
/// opens the records and hands each whole frame to the endpoint.
pub(crate) fn read(e: &mut Entry, origin: StdInstant, drain: bool) {
    // Plaintext rustls already holds (read past the handshake's end).
    if !plaintext(e, origin, StdInstant::now()) {
        return;
    }
    loop {
        let Some((tls, stream)) = e.path.tls_mut() else {
            return;
        };
        let mut src = Stamped {
            socket: &stream.socket,
            kernel: stream.kernel_stamps,
            at: None,
            short: false,
        };
        let (eof, n) = match tls.conn.read_tls(&mut src) {
            Ok(0) => (true, 0),
            Ok(n) => (false, n),
            Err(err) if err.kind() == io::ErrorKind::WouldBlock => return,
            Err(err) if err.kind() == io::ErrorKind::Interrupted => continue,
            Err(_) => {
                e.endpoint.abort(LinkError::Disconnected);
                return;
            }
        };
        let (at, short) = (src.at.unwrap_or_else(StdInstant::now), src.short);
        if let Err(err) = tls.conn.process_new_packets() {
            tracing::warn!("TLS link: {err}; closing it");
            // The alert rustls queued, best effort.
            let _ = tls.conn.write_tls(&mut &stream.socket);
            e.endpoint.abort(ended_by(&err));
            return;
        }
        if !plaintext(e, origin, at) {
            return;
        }
        if eof {
            e.endpoint.abort(LinkError::Disconnected);
            return;
        }
        if e.endpoint.is_closed() || (short && !drain) {
            return;
        }
        // The rest waits for the link's next deadline (see
        // `READ_FRAMES_PER_DEADLINE`).
        if e.spend_read(n, drain) {
            return;
        }
    }
}

/// Frames from the plaintext rustls has opened; `false` once the link is
/// over (the peer's close, a corrupt stream).
fn plaintext(e: &mut Entry, origin: StdInstant, at: StdInstant) -> bool {
    loop {
        let Some((tls, _)) = e.path.tls_mut() else {
            return false;
        };
        let spare = e.deframer.spare();
        if spare.is_empty() {
            // Cannot happen: frames are taken out after every fill.
            e.endpoint.abort(LinkError::Disconnected);
            return false;
        }
        match tls.conn.reader().read(spare) {
            // The peer's close_notify: nothing more will come.
            Ok(0) => {
                e.endpoint.abort(LinkError::Disconnected);
                return false;
            }
            Ok(n) => {
                e.deframer.filled(n);
                if !handle_frames(e, origin, at) {
                    return false;
                }
            }
            Err(err) if err.kind() == io::ErrorKind::WouldBlock => return true,
            Err(_) => {
                e.endpoint.abort(LinkError::Disconnected);
                return false;
            }
        }
    }
}

/// Seals a frame and writes its records now, or queues them behind what is
/// waiting; `true` if bytes are left waiting for the socket.
pub(crate) fn send(e: &mut Entry, bytes: &[u8]) -> bool {
    let Some((tls, stream)) = e.path.tls_mut() else {
        return false;
    };
    if tls.conn.writer().write_all(bytes).is_err() {
        e.endpoint.abort(LinkError::Disconnected);
        return false;
    }
    seal(tls);
    write_or_queue(&mut stream.socket, &mut e.pending, &tls.sealed)
}

/// Moves every record rustls has ready into `sealed` (a `Vec` takes all).
fn seal(tls: &mut Session) {
    tls.sealed.clear();
    while tls.conn.wants_write() {
        if tls.conn.write_tls(&mut tls.sealed).is_err() {
            return;
        }
    }
}

/// Tells the peer the stream ends here (best effort, the link is closing).
pub(crate) fn close_notify(e: &mut Entry) {
    let Some((tls, stream)) = e.path.tls_mut() else {
        return;
    };
    tls.conn.send_close_notify();
    seal(tls);
    if e.pending.is_empty() {
        let _ = stream.socket.write(&tls.sealed);
    }
}

/// What a TLS error ends the link with: a peer that refused our certificate
/// says so in its alert (a TLS 1.3 server checks the client's certificate
/// after the client's handshake is over, so the client learns it here).
fn ended_by(err: &rustls::Error) -> LinkError {
    use rustls::AlertDescription as A;
    match err {
        rustls::Error::AlertReceived(
            A::BadCertificate
            | A::UnsupportedCertificate
            | A::CertificateRevoked
            | A::CertificateExpired
            | A::CertificateUnknown
            | A::UnknownCA
            | A::AccessDenied
            | A::CertificateRequired,
        ) => LinkError::CertificateRefused,
        _ => LinkError::Disconnected,
    }
}
