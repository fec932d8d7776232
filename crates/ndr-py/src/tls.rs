//! `ndr.TlsConfig`: mutual TLS 1.3 for a link (certificates from PEM files,
//! the peer trusted by its pinned fingerprint or through a CA).

use ndr_net::TlsConfig;
use ndr_net::tls::Fingerprint;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// This side's certificate and key, and whom it trusts. Give exactly one of
/// `peer_cert` (the peer's certificate file: its fingerprint is pinned, the
/// lab setup of `ndr keygen`), `pins` (SHA-256 fingerprints, hex) or `ca`
/// (a CA certificate file; the server's certificate must then name
/// `server_name`).
#[pyclass(frozen, module = "ndr", name = "TlsConfig")]
pub struct PyTlsConfig {
    pub(crate) inner: TlsConfig,
}

#[pymethods]
impl PyTlsConfig {
    #[new]
    #[pyo3(signature = (cert, key, *, peer_cert = None, pins = None, ca = None, server_name = None, handshake_timeout = None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        cert: std::path::PathBuf,
        key: std::path::PathBuf,
        peer_cert: Option<std::path::PathBuf>,
        pins: Option<Vec<String>>,
        ca: Option<std::path::PathBuf>,
        server_name: Option<&str>,
        handshake_timeout: Option<f64>,
    ) -> PyResult<Self> {
        let err = |e: ndr_net::TlsError| PyValueError::new_err(format!("TLS: {e}"));
        let mut inner = match (peer_cert, pins, ca) {
            (Some(peer), None, None) => TlsConfig::from_files(&cert, &key, peer).map_err(err)?,
            (None, Some(pins), None) => {
                let pins = pins
                    .iter()
                    .map(|p| {
                        p.parse::<Fingerprint>().map_err(|e| {
                            PyValueError::new_err(format!(
                                "pins: {p:?} is not a SHA-256 fingerprint: {e}"
                            ))
                        })
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

/// Makes a self-signed certificate pair for a lab setup (as `ndr keygen`):
/// writes `dir/name.crt` and `dir/name.key` (PEM; the key readable by its
/// owner only) and returns `(cert_path, key_path, fingerprint)`. Refuses to
/// overwrite a key.
#[pyfunction]
#[pyo3(signature = (dir, name = "ndr"))]
pub fn keygen(dir: std::path::PathBuf, name: &str) -> PyResult<(String, String, String)> {
    let pair = ndr_net::keygen::write(&dir, name).map_err(PyValueError::new_err)?;
    Ok((
        pair.cert.display().to_string(),
        pair.key.display().to_string(),
        pair.fingerprint.to_string(),
    ))
}
