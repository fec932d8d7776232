//! Waiting from Python: without the GIL, in slices, with Ctrl-C.
//!
//! A wait (receive, accept, connect) runs in slices of at most [`SLICE`]
//! with the GIL released; between slices the thread takes the GIL back
//! and lets Python run its signal handlers, so Ctrl-C raises
//! `KeyboardInterrupt` within a slice. A slice ends as soon as its result
//! is there, so slicing adds no latency to a sample that comes.
//!
//! The process shares one small tokio runtime (`ndr-io`, for connecting,
//! accepting and the relay) and one hub (`ndr-hub`, the thread that drives
//! the links this process connects; a listener's links get a hub of their
//! own).

use std::net::{SocketAddr, ToSocketAddrs};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use ndr_net::Hub;
use pyo3::exceptions::{PyOSError, PyTimeoutError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyTuple;
use tokio::runtime::Runtime;

use crate::convert::int_in;

/// Longest stretch without checking for Ctrl-C.
pub const SLICE: Duration = Duration::from_millis(50);

/// The process's I/O runtime.
pub fn runtime() -> PyResult<&'static Runtime> {
    static RT: OnceLock<Result<Runtime, String>> = OnceLock::new();
    RT.get_or_init(|| {
        tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .thread_name("ndr-io")
            .enable_all()
            .build()
            .map_err(|e| e.to_string())
    })
    .as_ref()
    .map_err(|e| PyOSError::new_err(format!("cannot start ndr's I/O thread: {e}")))
}

/// The hub that drives the links this process connects.
pub fn hub() -> PyResult<&'static Hub> {
    static HUB: OnceLock<Result<Hub, String>> = OnceLock::new();
    HUB.get_or_init(|| Hub::with_defaults().map_err(|e| e.to_string()))
        .as_ref()
        .map_err(|e| PyOSError::new_err(format!("cannot start ndr's hub thread: {e}")))
}

/// A timeout argument: `None` waits forever; otherwise finite seconds ≥ 0.
pub fn timeout(name: &str, value: Option<f64>) -> PyResult<Option<Duration>> {
    match value {
        None => Ok(None),
        Some(t) if (0.0..1e9).contains(&t) => Ok(Some(Duration::from_secs_f64(t))),
        Some(t) => Err(PyValueError::new_err(format!(
            "{name} must be None (wait forever) or a finite number of seconds ≥ 0, got {t}"
        ))),
    }
}

/// Calls `attempt(slice)` without the GIL until it gives a value or an
/// error, checking for signals between calls (a signal handler's exception,
/// e.g. `KeyboardInterrupt`, is the outer error); `Ok(Ok(None))` when
/// `limit` passed first. `attempt` waits at most `slice` (zero: it polls).
pub fn wait<T, E, F>(
    py: Python<'_>,
    limit: Option<Duration>,
    mut attempt: F,
) -> PyResult<Result<Option<T>, E>>
where
    T: Send,
    E: Send,
    F: FnMut(Duration) -> Result<Option<T>, E> + Send,
{
    let end = limit.map(|l| Instant::now() + l);
    loop {
        let slice = match end {
            None => SLICE,
            Some(end) => end.saturating_duration_since(Instant::now()).min(SLICE),
        };
        match py.detach(|| attempt(slice)) {
            Ok(None) => {}
            done => return Ok(done),
        }
        if end.is_some_and(|end| Instant::now() >= end) {
            return Ok(Ok(None));
        }
        py.check_signals()?;
    }
}

/// An address: `"host:port"` or a `(host, port)` tuple; resolved, first
/// address taken. An empty host (`("", 0)`, `":7300"`) is every interface,
/// `0.0.0.0`, as Python's `socket.bind` takes it.
pub fn address(py: Python<'_>, obj: &Bound<'_, PyAny>) -> PyResult<SocketAddr> {
    const EXPECTED: &str = "address: expected \"host:port\" or a (host, port) tuple";
    let text = if let Ok(s) = obj.extract::<String>() {
        match s.strip_prefix(':') {
            Some(port) => format!("0.0.0.0:{port}"),
            None => s,
        }
    } else if let Ok(t) = obj.cast::<PyTuple>() {
        if t.len() != 2 {
            return Err(PyTypeError::new_err(format!(
                "{EXPECTED}, got a tuple of {} items",
                t.len()
            )));
        }
        let host_item = t.get_item(0)?;
        let host: String = host_item.extract().map_err(|_| {
            let ty = host_item.get_type().name();
            PyTypeError::new_err(match ty {
                Ok(ty) => format!("{EXPECTED}: the host must be a str, got {ty}"),
                Err(_) => format!("{EXPECTED}: the host must be a str"),
            })
        })?;
        let port: u16 = int_in("port", &t.get_item(1)?, 0, u16::MAX)?;
        if host.is_empty() {
            format!("0.0.0.0:{port}")
        } else if host.contains(':') {
            format!("[{host}]:{port}")
        } else {
            format!("{host}:{port}")
        }
    } else {
        return Err(PyTypeError::new_err(format!(
            "{EXPECTED}, got {}",
            obj.get_type().name()?
        )));
    };
    let resolved = py.detach(|| text.to_socket_addrs().map(|mut a| a.next()));
    match resolved {
        Ok(Some(a)) => Ok(a),
        Ok(None) => Err(PyOSError::new_err(format!(
            "address {text:?} resolves to no address"
        ))),
        Err(e) => Err(PyOSError::new_err(format!(
            "address {text:?}: {e} (expected \"host:port\", e.g. \"127.0.0.1:7300\")"
        ))),
    }
}

/// A timeout error naming what was waited for.
pub fn timed_out(what: &str, limit: Option<Duration>) -> PyErr {
    let secs = limit.map_or(0.0, |l| l.as_secs_f64());
    PyTimeoutError::new_err(format!("{what} within {secs} s"))
}
