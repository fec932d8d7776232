//! `ndr.TlsConfig`: mutual TLS 1.3 for a link (certificates from PEM files,
//! the peer trusted by its pinned fingerprint or through a CA).

use ndr_net::TlsConfig;
use ndr_net::tls::{Fingerprint, TlsError};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyString;

/// This side's certificate and key, and whom it trusts. Give exactly one of
/// `peer_cert` (the peer's certificate file: its fingerprint is pinned, the
/// lab setup of `ndr keygen`), `pins` (SHA-256 fingerprints, hex) or `ca`
/// (a CA certificate file; the server's certificate must then name
/// `server_name`). A single fingerprint may be given as a str.
///
/// A robot's listener that shares its robot (`Link.listen(observers=N)`)
/// may also trust observers: `observer_pins` (fingerprints) and
/// `observer_certs` (certificate files, each pinned) name peers who may
/// only observe; one of them that asks for control is refused (Close
/// `observer only`, `listener.stats["refused_observer_only"]`). An
/// identity that `peer_cert`/`pins`/`ca` trusts as well may control.
#[pyclass(frozen, module = "ndr", name = "TlsConfig")]
pub struct PyTlsConfig {
    pub(crate) inner: TlsConfig,
}

#[pymethods]
impl PyTlsConfig {
    #[new]
    #[pyo3(signature = (cert, key, *, peer_cert = None, pins = None, ca = None, server_name = None, handshake_timeout = None, observer_pins = None, observer_certs = None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        cert: std::path::PathBuf,
        key: std::path::PathBuf,
        peer_cert: Option<std::path::PathBuf>,
        pins: Option<&Bound<'_, PyAny>>,
        ca: Option<std::path::PathBuf>,
        server_name: Option<&str>,
        handshake_timeout: Option<f64>,
        observer_pins: Option<&Bound<'_, PyAny>>,
        observer_certs: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let err = |e: TlsError| tls_error(&e);
        let pins = pins.map(pin_list).transpose()?;
        let mut inner = match (peer_cert, pins, ca) {
            (Some(peer), None, None) => TlsConfig::from_files(&cert, &key, peer).map_err(err)?,
            (None, Some(pins), None) => {
                let pins = pins
                    .iter()
                    .map(|p| {
                        p.parse::<Fingerprint>()
                            .map_err(|e| PyValueError::new_err(format!("pins: {}", words(&e))))
                    })
                    .collect::<PyResult<Vec<_>>>()?;
                TlsConfig::from_files_pinned(&cert, &key, pins).map_err(err)?
            }
            (None, None, Some(ca)) => TlsConfig::from_files_with_ca(
                &cert,
                &key,
                ca,
                server_name.unwrap_or(ndr_net::tls::DEFAULT_SERVER_NAME),
            )
            .map_err(err)?,
            _ => {
                return Err(PyValueError::new_err(
                    "give exactly one of peer_cert, pins and ca: whom this side trusts",
                ));
            }
        };
        let observers = observer_trust(observer_pins, observer_certs)?;
        if let Some(observers) = observers {
            inner = inner
                .with_observers(ndr_net::Trust::Pinned(observers))
                .map_err(|e| PyValueError::new_err(format!("observers: TLS: {}", words(&e))))?;
        }
        if let Some(t) = handshake_timeout {
            inner.handshake_timeout = crate::convert::period("handshake_timeout", t)?.into();
        }
        Ok(PyTlsConfig { inner })
    }

    /// This side's certificate fingerprint (SHA-256), to pin on the peer.
    #[getter]
    fn fingerprint(&self) -> String {
        self.inner.fingerprint().to_string()
    }

    fn __repr__(&self) -> String {
        format!("TlsConfig(fingerprint={:?})", self.fingerprint())
    }
}

/// The observers' fingerprints from `observer_pins` and `observer_certs`
/// (`None`: neither given).
fn observer_trust(
    pins: Option<&Bound<'_, PyAny>>,
    certs: Option<&Bound<'_, PyAny>>,
) -> PyResult<Option<Vec<Fingerprint>>> {
    if pins.is_none() && certs.is_none() {
        return Ok(None);
    }
    let mut all = Vec::new();
    for p in pins.map(pin_list).transpose()?.unwrap_or_default() {
        all.push(
            p.parse::<Fingerprint>()
                .map_err(|e| PyValueError::new_err(format!("observer_pins: {}", words(&e))))?,
        );
    }
    for path in certs.map(path_list).transpose()?.unwrap_or_default() {
        let found = ndr_net::tls::read_fingerprints(&path)
            .map_err(|e| PyValueError::new_err(format!("observer_certs: {}", words(&e))))?;
        all.extend(found);
    }
    if all.is_empty() {
        return Err(PyValueError::new_err(
            "observer_pins and observer_certs name no observer: give at least one \
             fingerprint or certificate file, or neither",
        ));
    }
    Ok(Some(all))
}

/// `observer_certs`: a path, or a list (any iterable) of them.
fn path_list(obj: &Bound<'_, PyAny>) -> PyResult<Vec<std::path::PathBuf>> {
    if let Ok(p) = obj.extract::<std::path::PathBuf>() {
        return Ok(vec![p]);
    }
    let items = obj.try_iter().map_err(|_| {
        PyTypeError::new_err("observer_certs must be a certificate file's path or a list of them")
    })?;
    items
        .map(|item| {
            item?.extract::<std::path::PathBuf>().map_err(|_| {
                PyTypeError::new_err(
                    "observer_certs must be a certificate file's path or a list of them",
                )
            })
        })
        .collect()
}

/// `pins`: a list (any iterable) of fingerprints, or one as a str.
fn pin_list(obj: &Bound<'_, PyAny>) -> PyResult<Vec<String>> {
    if let Ok(s) = obj.cast::<PyString>() {
        return Ok(vec![s.to_cow()?.into_owned()]);
    }
    let expected = "pins must be a list of SHA-256 fingerprints (64 hex digits each, as \
                    TlsConfig.fingerprint gives them) or one as a str";
    let type_error = || -> PyResult<PyErr> {
        Ok(PyTypeError::new_err(format!(
            "{expected}, got an object of type {}",
            obj.get_type().name()?
        )))
    };
    let Ok(items) = obj.try_iter() else {
        return Err(type_error()?);
    };
    let mut pins = Vec::new();
    for item in items {
        let item = item?;
        match item.cast::<PyString>() {
            Ok(s) => pins.push(s.to_cow()?.into_owned()),
            Err(_) => {
                return Err(PyTypeError::new_err(format!(
                    "{expected}, got an item of type {}",
                    item.get_type().name()?
                )));
            }
        }
    }
    Ok(pins)
}

/// A TLS setup error as a `ValueError`, in the words of the Python API.
fn tls_error(e: &TlsError) -> PyErr {
    PyValueError::new_err(format!("TLS: {}", words(e)))
}

/// The message of a TLS setup error, naming `TlsConfig`'s arguments and
/// `ndr.keygen` where the Rust message names the command line's.
fn words(e: &TlsError) -> String {
    match e {
        TlsError::Read { path, error } => {
            format!("cannot read {path}: {error} (give PEM files, e.g. from ndr.keygen())")
        }
        TlsError::NoCertificate(path) => {
            format!("{path} holds no PEM certificate (give a .crt file, e.g. from ndr.keygen())")
        }
        TlsError::Fingerprint(s) => format!(
            "{s:?} is not a SHA-256 fingerprint: give 64 hex digits, colons allowed \
             (ndr.keygen() returns it, TlsConfig.fingerprint gives it)"
        ),
        TlsError::NoTrust => "no peer to trust: give one of peer_cert, pins and ca".to_owned(),
        other => other.to_string(),
    }
}

/// Makes a self-signed certificate pair for a lab setup (as `ndr keygen`):
/// writes `dir/name.crt` and `dir/name.key` (PEM; the key readable by its
/// owner only) and returns `(cert_path, key_path, fingerprint)`. Refuses to
/// overwrite a key.
#[pyfunction]
#[pyo3(signature = (dir, name = "ndr"))]
pub fn keygen(dir: std::path::PathBuf, name: &str) -> PyResult<(String, String, String)> {
    // (The Rust message names the command line's `--name`.)
    let pair = ndr_net::keygen::write(&dir, name)
        .map_err(|e| PyValueError::new_err(e.replace("another --name", "another name")))?;
    Ok((
        pair.cert.display().to_string(),
        pair.key.display().to_string(),
        pair.fingerprint.to_string(),
    ))
}
