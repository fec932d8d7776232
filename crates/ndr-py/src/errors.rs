//! The link's exceptions: `ConnectionError` subclasses, one per way a link
//! fails, so a controller can catch exactly what it can handle.
//!
//! ```text
//! ConnectionError
//! └── LinkError
//!     ├── HandshakeError     the peers disagree (version, role, axes, period,
//!     │                      mode) or the handshake timed out
//!     ├── ProtocolError      the peer sent bytes that are not the protocol
//!     ├── PeerClosedError    the peer ended the link (`reason`, `reason_name`)
//!     ├── DisconnectedError  the connection dropped without a goodbye
//!     └── LinkClosedError    this side closed the link
//! ```
//!
//! A socket error is Python's own `OSError` subclass for its errno, with
//! `errno` and `strerror` set (a refused connection is
//! `ConnectionRefusedError`, also a `ConnectionError`; an address in use is
//! `OSError` with `errno.EADDRINUSE`); a receive timeout is `TimeoutError`;
//! a sample of the wrong shape or a bad configuration is `ValueError`.

use std::io;

use ndr_core::endpoint::LinkError as CoreError;
use ndr_core::wire::CloseReason;
use ndr_net::tls::HandshakeError as TlsHandshakeError;
use ndr_net::{NetError, TransportError};
use pyo3::create_exception;
use pyo3::exceptions::{
    PyConnectionError, PyOSError, PyPermissionError, PyRuntimeError, PyTimeoutError, PyValueError,
};
use pyo3::prelude::*;

create_exception!(
    ndr,
    LinkError,
    PyConnectionError,
    "The link failed or ended. Every link failure is a subclass of this \
     (itself a ConnectionError)."
);
create_exception!(
    ndr,
    HandshakeError,
    LinkError,
    "The peers could not agree: another wire version, both claiming the same \
     role, different axes, period or mode, or a handshake that did not finish \
     in time. Check that both sides use the same settings."
);
create_exception!(
    ndr,
    ProtocolError,
    LinkError,
    "The peer sent bytes that are not a valid ndr frame, or a frame that \
     makes no sense at that point: it is not an ndr peer, or a broken one."
);
create_exception!(
    ndr,
    PeerClosedError,
    LinkError,
    "The peer ended the link. `reason` is the Close frame's code (0 for a \
     normal end) and `reason_name` its name."
);
create_exception!(
    ndr,
    DisconnectedError,
    LinkError,
    "The connection dropped without a Close frame: the peer process died, \
     the relay was killed, or the network cut the connection."
);
create_exception!(
    ndr,
    LinkClosedError,
    LinkError,
    "This side closed the link: nothing more can be sent or received on it."
);

/// The exception for a core link error.
pub fn link_error(py: Python<'_>, e: CoreError) -> PyErr {
    let msg = e.to_string();
    match e {
        CoreError::VersionMismatch { .. }
        | CoreError::RoleMismatch { .. }
        | CoreError::WidthMismatch { .. }
        | CoreError::LayoutMismatch { .. }
        | CoreError::TransportMismatch { .. }
        | CoreError::PeriodMismatch { .. }
        | CoreError::ModeMismatch { .. }
        | CoreError::BadParameters { .. }
        | CoreError::Timeout
        // The peer's TLS refused our certificate after our side's handshake
        // was over (TLS 1.3 checks the client's last): a TLS handshake failure.
        | CoreError::CertificateRefused
        | CoreError::PeerCertificateRefused => HandshakeError::new_err(msg),
        CoreError::Wire(_)
        | CoreError::Unexpected { .. }
        | CoreError::ChannelCount { .. }
        | CoreError::OutOfSequence { .. }
        | CoreError::StampBehind { .. }
        | CoreError::StampAhead { .. }
        | CoreError::StampOutOfRange { .. } => ProtocolError::new_err(msg),
        CoreError::PeerClosed { reason } => peer_closed(py, msg, reason),
        // A peer silent past the liveness time: hung, or the connection
        // half-open; for the application, the connection is gone.
        CoreError::Disconnected | CoreError::PeerSilent { .. } => DisconnectedError::new_err(msg),
        CoreError::Closed => LinkClosedError::new_err(msg),
        CoreError::SampleShape { .. }
        | CoreError::NonFinite { .. }
        | CoreError::BufferTooSmall { .. } => PyValueError::new_err(msg),
        _ => LinkError::new_err(msg),
    }
}

fn peer_closed(py: Python<'_>, msg: String, reason: CloseReason) -> PyErr {
    // A peer that refused our handshake closes with the mismatch's code.
    let err = match reason {
        CloseReason::VersionMismatch
        | CloseReason::RoleMismatch
        | CloseReason::WidthMismatch
        | CloseReason::LayoutMismatch
        | CloseReason::PeriodMismatch
        | CloseReason::ModeMismatch
        | CloseReason::TransportMismatch => HandshakeError::new_err(msg),
        // Refused for now (busy, or its slot taken for a newer
        // connection): `reason` says which; trying again may succeed.
        _ => PeerClosedError::new_err(msg),
    };
    let value = err.value(py);
    // Setting attributes on a fresh exception object cannot fail in practice;
    // if it did, the exception would still carry its message.
    let _ = value.setattr("reason", u16::from(reason));
    let _ = value.setattr("reason_name", reason.name());
    err
}

/// The exception for a network driver error.
pub fn net_error(py: Python<'_>, e: NetError) -> PyErr {
    match e {
        NetError::Io(io) => os_error(py, &io, None),
        NetError::Config(c) => PyValueError::new_err(format!("link configuration: {c}")),
        NetError::Link(l) => link_error(py, l),
        NetError::Timeout => {
            PyTimeoutError::new_err("no sample within the timeout (the link is still up)")
        }
        NetError::Handshake(h) => HandshakeError::new_err(tls_handshake_message(&h)),
        NetError::Insecure(addr) => PyValueError::new_err(format!(
            "refusing a plain link with {addr}: it is not loopback; pass \
             tls=ndr.TlsConfig(...) (mutual TLS), or insecure=True to send plain TCP \
             (anyone on the path can read and forge the samples)"
        )),
        NetError::Transport(t) => transport_error(&t),
        NetError::Realtime(rt) => realtime_error(&rt),
        other => PyRuntimeError::new_err(other.to_string()),
    }
}

/// Real-time scheduling refused under `realtime="enforce"` (a
/// `PermissionError` naming what to grant), or a setting that cannot be
/// asked for (`ValueError`).
pub fn realtime_error(e: &ndr_net::RealtimeError) -> PyErr {
    match e {
        ndr_net::RealtimeError::BadMode(_) | ndr_net::RealtimeError::BadPriority(_) => {
            PyValueError::new_err(format!("realtime: {e}"))
        }
        _ => PyPermissionError::new_err(format!(
            "real-time scheduling refused under realtime=\"enforce\": {e}; \
             realtime=\"try\" runs without it (with a warning)"
        )),
    }
}

/// A transport that does not fit the link's security, in the words of
/// the Python API.
pub fn transport_error(e: &TransportError) -> PyErr {
    match e {
        TransportError::QuicWithoutTls => PyValueError::new_err(
            "transport=\"quic\" runs mutual TLS 1.3: pass tls=ndr.TlsConfig(...) on both sides",
        ),
        TransportError::UdpWithTls => PyValueError::new_err(
            "transport=\"udp\" is plain UDP: with tls=, use transport=\"quic\" \
             (datagrams over QUIC) or \"tcp\"",
        ),
        other => PyValueError::new_err(format!("transport: {other}")),
    }
}

/// A TLS handshake failure in the words of the Python API (the Rust
/// message names the command line's flags).
fn tls_handshake_message(h: &TlsHandshakeError) -> String {
    match h {
        TlsHandshakeError::UnknownCertificate(why) => format!(
            "TLS handshake refused: unknown certificate: {why}; give each side's TlsConfig \
             the other's certificate (peer_cert=) or its fingerprint (pins=[...])"
        ),
        TlsHandshakeError::NoCertificate => "TLS handshake refused: no client certificate; \
             both sides need a TlsConfig (cert and key)"
            .to_owned(),
        TlsHandshakeError::Version(why) => format!(
            "TLS handshake refused: the peer does not speak TLS 1.3 ({why}); give both \
             sides a TlsConfig (tls=), or neither on loopback"
        ),
        other => other.to_string(),
    }
}

/// The `OSError` for a socket error: the subclass its errno selects
/// (`ConnectionRefusedError`, `PermissionError`, …, plain `OSError` for an
/// address in use), with `errno` and `strerror` set, as Python's own socket
/// functions raise. `context` (e.g. `"cannot connect to 127.0.0.1:7300"`)
/// goes before the system's message in `strerror`, as asyncio does.
///
/// The errno is the system's when `e` carries it, else the one of its kind
/// (an error re-wrapped with a message keeps only its kind); an error with
/// neither is an `OSError` (or the subclass of its kind) with the message.
pub fn os_error(py: Python<'_>, e: &io::Error, context: Option<&str>) -> PyErr {
    let errno = e.raw_os_error().or_else(|| errno_of(py, e.kind()));
    // An OS error displays as "Address already in use (os error 98)":
    // strerror is the part before the code.
    let text = e.to_string();
    let text = match text.rfind(" (os error ") {
        Some(i) if text.ends_with(')') => text[..i].to_owned(),
        _ => text,
    };
    let strerror = match context {
        Some(c) => format!("{c}: {text}"),
        None => text,
    };
    match errno {
        // `OSError(errno, strerror)` is created as the subclass for errno.
        Some(code) => PyOSError::new_err((code, strerror)),
        None => PyErr::from(io::Error::new(e.kind(), strerror)),
    }
}

/// The errno of an I/O error kind, from Python's `errno` module (so the
/// platform's value), for the kinds a socket gives.
fn errno_of(py: Python<'_>, kind: io::ErrorKind) -> Option<i32> {
    use io::ErrorKind as K;
    let name = match kind {
        K::ConnectionRefused => "ECONNREFUSED",
        K::ConnectionReset => "ECONNRESET",
        K::ConnectionAborted => "ECONNABORTED",
        K::NotConnected => "ENOTCONN",
        K::AddrInUse => "EADDRINUSE",
        K::AddrNotAvailable => "EADDRNOTAVAIL",
        K::BrokenPipe => "EPIPE",
        K::TimedOut => "ETIMEDOUT",
        K::PermissionDenied => "EACCES",
        K::HostUnreachable => "EHOSTUNREACH",
        K::NetworkUnreachable => "ENETUNREACH",
        K::NetworkDown => "ENETDOWN",
        _ => return None,
    };
    py.import("errno")
        .and_then(|m| m.getattr(name))
        .and_then(|v| v.extract::<i32>())
        .ok()
}

/// Registers the exception types on the module.
pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("LinkError", py.get_type::<LinkError>())?;
    m.add("HandshakeError", py.get_type::<HandshakeError>())?;
    m.add("ProtocolError", py.get_type::<ProtocolError>())?;
    m.add("PeerClosedError", py.get_type::<PeerClosedError>())?;
    m.add("DisconnectedError", py.get_type::<DisconnectedError>())?;
    m.add("LinkClosedError", py.get_type::<LinkClosedError>())?;
    Ok(())
}
