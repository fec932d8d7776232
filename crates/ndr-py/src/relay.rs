//! `ndr.Relay`: the delay-injecting TCP and UDP proxy of `ndr relay`,
//! in-process.
//!
//! It runs on the process's I/O thread; each frame and each datagram in each
//! direction is delayed by the same models as the simulator, in order.

use std::sync::{Mutex, PoisonError};

use ndr_net::{Relay, RelayConfig, RelayHandle, RelayStats};
use ndr_netem::LossModel;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::blocking;
use crate::convert::{in_range, serialized};
use crate::delay::delay_model;
use crate::errors::os_error;
use crate::log;

/// A running relay: listens on `listen` and forwards each connection to
/// `upstream`, delaying every frame by the chosen delay model: one of
/// `profile`, `trace`, `dist` (with `mean` and `std`), or, with none of
/// them, the "lan-75km" profile. Datagrams to the same port over UDP go to
/// `upstream`'s port over UDP, delayed the same way and lost by `loss`
/// ("none", a percent such as "1", or "ge:PERCENT:BURST" for bursts).
#[pyclass(frozen, module = "ndr", name = "Relay")]
pub struct PyRelay {
    handle: Mutex<Option<RelayHandle>>,
    address: (String, u16),
    model: String,
    last: Mutex<RelayStats>,
}

#[pymethods]
impl PyRelay {
    #[new]
    #[pyo3(signature = (listen, upstream, *, profile = None, trace = None, dist = None, mean = None, std = None, seed = 1, insecure = false, loss = "none"))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        listen: &Bound<'_, PyAny>,
        upstream: &Bound<'_, PyAny>,
        profile: Option<&str>,
        trace: Option<&str>,
        dist: Option<&str>,
        mean: Option<f64>,
        std: Option<f64>,
        seed: i128,
        insecure: bool,
        loss: &str,
    ) -> PyResult<Self> {
        let seed = in_range("seed", seed, 0, u64::MAX)?;
        let loss = loss
            .parse::<LossModel>()
            .map_err(|e| PyValueError::new_err(format!("loss: {e}")))?;
        let model = delay_model(profile, trace, dist, mean, std, "lan-75km")?;
        let name = model.name();
        let listen = blocking::address(py, listen)?;
        let upstream = blocking::address(py, upstream)?;
        // As a plain link off loopback: a ValueError that names the switch.
        if !ndr_net::tls::plain_allowed(listen.ip(), insecure) {
            return Err(PyValueError::new_err(format!(
                "refusing to listen on {listen}: it is not loopback, and the relay passes plain \
                 links through to the network; listen on 127.0.0.1, or pass insecure=True"
            )));
        }
        let rt = blocking::runtime()?;
        let handle = py.detach(|| {
            rt.block_on(async {
                let relay = if insecure {
                    Relay::listen_insecure(listen, upstream, model, seed).await?
                } else {
                    Relay::listen(listen, upstream, model, seed).await?
                };
                relay
                    .with_config(RelayConfig::default().with_loss(loss))
                    .spawn()
            })
        });
        log::flush(py);
        let handle = handle.map_err(|e| os_error(py, &e, None))?;
        let local = handle.local_addr();
        Ok(PyRelay {
            handle: Mutex::new(Some(handle)),
            address: (local.ip().to_string(), local.port()),
            model: name,
            last: Mutex::new(RelayStats::default()),
        })
    }

    /// The address it listens on, as `(host, port)`.
    #[getter]
    fn address(&self) -> (String, u16) {
        self.address.clone()
    }

    /// The delay model's name.
    #[getter]
    fn model(&self) -> &str {
        &self.model
    }

    /// Its counters: connections, how they ended, and frames per direction
    /// (`RelayStats` serialized).
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        log::flush(py);
        let snapshot = {
            let guard = self.handle.lock().unwrap_or_else(PoisonError::into_inner);
            match guard.as_ref() {
                Some(h) => h.stats(),
                None => *self.last.lock().unwrap_or_else(PoisonError::into_inner),
            }
        };
        serialized(py, &snapshot)
    }

    /// Stops it: connections in flight are cut. Idempotent.
    fn close(&self, py: Python<'_>) -> PyResult<()> {
        let handle = self
            .handle
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take();
        let Some(handle) = handle else {
            return Ok(());
        };
        let rt = blocking::runtime()?;
        let last = py.detach(|| rt.block_on(handle.shutdown()));
        *self.last.lock().unwrap_or_else(PoisonError::into_inner) = last;
        log::flush(py);
        Ok(())
    }

    fn __enter__(slf: Py<Self>) -> Py<Self> {
        slf
    }

    #[pyo3(signature = (*_exc))]
    fn __exit__(&self, py: Python<'_>, _exc: &Bound<'_, pyo3::types::PyTuple>) -> PyResult<bool> {
        self.close(py)?;
        Ok(false)
    }

    fn __repr__(&self) -> String {
        format!(
            "Relay(address={}:{}, model={:?})",
            self.address.0, self.address.1, self.model
        )
    }
}
