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
//! A refused connection is Python's own `ConnectionRefusedError` (also a
//! `ConnectionError`); a receive timeout is `TimeoutError`; a sample of the
//! wrong shape or a bad configuration is `ValueError`.

use ndr_core::endpoint::LinkError as CoreError;
use ndr_core::wire::close_reason;
use ndr_net::NetError;
use pyo3::create_exception;
use pyo3::exceptions::{PyConnectionError, PyTimeoutError, PyValueError};
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
        | CoreError::AxesMismatch { .. }
        | CoreError::PeriodMismatch { .. }
        | CoreError::ModeMismatch { .. }
        | CoreError::BadParameters { .. }
        | CoreError::Timeout => HandshakeError::new_err(msg),
        CoreError::Wire(_) | CoreError::Unexpected { .. } | CoreError::ChannelCount { .. } => {
            ProtocolError::new_err(msg)
        }
        CoreError::PeerClosed { reason } => peer_closed(py, msg, reason),
        CoreError::Disconnected => DisconnectedError::new_err(msg),
        CoreError::Closed => LinkClosedError::new_err(msg),
        CoreError::SampleShape { .. }
        | CoreError::NonFinite { .. }
        | CoreError::BufferTooSmall { .. } => PyValueError::new_err(msg),
        _ => LinkError::new_err(msg),
    }
}

fn peer_closed(py: Python<'_>, msg: String, reason: u16) -> PyErr {
    // A peer that refused our handshake closes with the mismatch's code.
    let err = match reason {
        close_reason::VERSION_MISMATCH
        | close_reason::ROLE_MISMATCH
        | close_reason::AXES_MISMATCH
        | close_reason::PERIOD_MISMATCH
        | close_reason::MODE_MISMATCH => HandshakeError::new_err(msg),
        _ => PeerClosedError::new_err(msg),
    };
    let value = err.value(py);
    // Setting attributes on a fresh exception object cannot fail in practice;
    // if it did, the exception would still carry its message.
    let _ = value.setattr("reason", reason);
    let _ = value.setattr("reason_name", close_reason::name(reason));
    err
}

/// The exception for a network driver error.
pub fn net_error(py: Python<'_>, e: NetError) -> PyErr {
    match e {
        NetError::Io(io) => PyErr::from(io),
        NetError::Config(c) => PyValueError::new_err(format!("link configuration: {c}")),
        NetError::Link(l) => link_error(py, l),
        NetError::Timeout => {
            PyTimeoutError::new_err("no sample within the timeout (the link is still up)")
        }
        NetError::Handshake(h) => HandshakeError::new_err(h.to_string()),
        other @ NetError::Insecure(_) => PyValueError::new_err(other.to_string()),
    }
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
