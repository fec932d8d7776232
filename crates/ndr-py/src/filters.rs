//! `ndr.LowPass`, `ndr.Envelope` and the batch `ndr.lowpass`, `ndr.envelope`.

use ndr_core::{Envelope, FilterError, LowPass};
use numpy::PyArray1;
use pyo3::prelude::*;

use crate::convert::{array1, finite, seconds, value_error, vector};

/// First-order low-pass `y ← y + α·(x − y)`, `α = 1 − exp(−period/tau)`,
/// starting at the first sample.
#[pyclass(module = "ndr", name = "LowPass")]
#[derive(Clone)]
pub struct PyLowPass {
    inner: LowPass,
}

#[pymethods]
impl PyLowPass {
    #[new]
    fn new(tau: f64, period: f64) -> PyResult<Self> {
        let inner = LowPass::new(
            seconds("tau", tau)?,
            crate::convert::period("period", period)?,
        )
        .map_err(value_error)?;
        Ok(PyLowPass { inner })
    }

    /// A low-pass with the smoothing factor `alpha` in (0, 1] given directly.
    #[staticmethod]
    fn from_alpha(alpha: f64) -> PyResult<Self> {
        Ok(PyLowPass {
            inner: LowPass::from_alpha(alpha).map_err(value_error)?,
        })
    }

    /// Filters one sample; returns the output.
    fn update(&mut self, x: f64) -> PyResult<f64> {
        self.inner.update(x).map_err(value_error)
    }

    /// Filters a series, shape `(n,)`; returns the outputs.
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let f = &mut self.inner;
        filter_series(py, x, |v| f.update(v))
    }

    /// The output, None before the first sample.
    #[getter]
    fn value(&self) -> Option<f64> {
        self.inner.value()
    }

    /// The smoothing factor α.
    #[getter]
    fn alpha(&self) -> f64 {
        self.inner.alpha()
    }

    /// Changes the sampling period, keeping the time constant in seconds.
    fn set_period(&mut self, period: f64) -> PyResult<()> {
        let p = crate::convert::period("period", period)?;
        self.inner.set_period(p).map_err(value_error)
    }

    /// Forgets the output: the next sample is taken as is.
    fn reset(&mut self) {
        self.inner.reset();
    }

    fn __repr__(&self) -> String {
        format!(
            "LowPass(alpha={}, value={:?})",
            self.inner.alpha(),
            self.inner.value()
        )
    }
}

/// The paper's envelope: `e ← x` if `x > e`, else `e ← e / decay`.
#[pyclass(module = "ndr", name = "Envelope")]
#[derive(Clone)]
pub struct PyEnvelope {
    inner: Envelope,
}

#[pymethods]
impl PyEnvelope {
    #[new]
    #[pyo3(signature = (decay = Envelope::default().decay()), text_signature = "(decay=1.00005)")]
    fn new(decay: f64) -> PyResult<Self> {
        Ok(PyEnvelope {
            inner: Envelope::new(decay).map_err(value_error)?,
        })
    }

    /// Follows one sample; returns the envelope.
    fn update(&mut self, x: f64) -> PyResult<f64> {
        self.inner.update(x).map_err(value_error)
    }

    /// Follows a series, shape `(n,)`; returns the envelope.
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let f = &mut self.inner;
        filter_series(py, x, |v| f.update(v))
    }

    /// The envelope, None before the first sample.
    #[getter]
    fn value(&self) -> Option<f64> {
        self.inner.value()
    }

    /// The decay `vd` (≥ 1).
    #[getter]
    fn decay(&self) -> f64 {
        self.inner.decay()
    }

    /// Forgets the envelope.
    fn reset(&mut self) {
        self.inner.reset();
    }

    fn __repr__(&self) -> String {
        format!(
            "Envelope(decay={}, value={:?})",
            self.inner.decay(),
            self.inner.value()
        )
    }
}

/// Runs a filter over the series `x` (shape `(n,)`) without the GIL.
fn filter_series<'py>(
    py: Python<'py>,
    x: &Bound<'py, PyAny>,
    mut step: impl FnMut(f64) -> Result<f64, FilterError> + Send,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let x = vector("x", x, None)?;
    // `vector` refused non-finite values: the steps cannot fail.
    let y = py.detach(|| x.iter().map(|&v| step(v).unwrap_or(v)).collect());
    Ok(array1(py, y))
}

/// Low-passes the series `x` (shape `(n,)`) with time constant `tau` at
/// sampling period `period` (seconds); starts at `x[0]`.
#[pyfunction]
#[pyo3(signature = (x, tau, period))]
pub fn lowpass<'py>(
    py: Python<'py>,
    x: &Bound<'py, PyAny>,
    tau: f64,
    period: f64,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    PyLowPass::new(tau, period)?.run(py, x)
}

/// The envelope of the series `x` (shape `(n,)`) with decay `decay`.
#[pyfunction]
#[pyo3(
    signature = (x, *, decay = Envelope::default().decay()),
    text_signature = "(x, *, decay=1.00005)"
)]
pub fn envelope<'py>(
    py: Python<'py>,
    x: &Bound<'py, PyAny>,
    decay: f64,
) -> PyResult<Bound<'py, PyArray1<f64>>> {
    let decay = finite("decay", decay)?;
    PyEnvelope::new(decay)?.run(py, x)
}
