//! `ndr.sim.run` (the simulator of `ndr sim`) and the delay models it
//! shares with the relay.
//!
//! The run happens without the GIL; the summary comes back as the JSON of
//! `ndr sim --json` (the Python side parses it into a dict) and the per-tick
//! series as float64 arrays, one per column of `ndr sim --out`.

use std::sync::Arc;

use ndr_core::endpoint::{Mode, Underflow};
use ndr_core::playout::Playout;
use ndr_core::sim::delay::{DelayModel, DistTable, Trace};
use ndr_core::sim::signal::Signal;
use ndr_core::sim::{self, Row, SimConfig};
use numpy::PyArray1;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{finite, period as positive_period, seconds, value_error};
use crate::log;

/// The network's delays, from exactly one of a profile, a trace CSV or a
/// netem table (with its mean and standard deviation, in seconds).
pub fn delay_model(
    profile: Option<&str>,
    trace: Option<&str>,
    dist: Option<&str>,
    mean: Option<f64>,
    std: Option<f64>,
    default: &str,
) -> PyResult<DelayModel> {
    let given = [profile.is_some(), trace.is_some(), dist.is_some()];
    if given.iter().filter(|&&g| g).count() > 1 {
        return Err(PyValueError::new_err(
            "give one of profile, trace and dist, not several",
        ));
    }
    if (mean.is_some() || std.is_some()) && dist.is_none() {
        return Err(PyValueError::new_err(
            "mean and std go with dist (a netem table); profiles and traces set their own delays",
        ));
    }
    if let Some(path) = trace {
        let trace = Trace::from_path(path).map_err(|e| PyValueError::new_err(format!("{e}")))?;
        return Ok(DelayModel::Trace(Arc::new(trace)));
    }
    if let Some(path) = dist {
        let (Some(mean), Some(std)) = (mean, std) else {
            return Err(PyValueError::new_err(
                "dist needs mean and std: the one-way delay's mean and standard deviation, in seconds",
            ));
        };
        let table = DistTable::from_path(path).map_err(value_error)?;
        return Ok(DelayModel::Dist {
            table: Arc::new(table),
            mean: seconds("mean", mean)?,
            std: seconds("std", std)?,
        });
    }
    DelayModel::profile(profile.unwrap_or(default)).map_err(value_error)
}

/// One simulation; returns `(summary_json, series)`.
#[pyfunction]
#[pyo3(name = "sim_run", signature = (*, profile = None, trace = None, dist = None, mean = None, std = None, mode = "paper-static", playout = "fifo", underflow = "hold", period = 0.2, duration = 600.0, seed = 1, axes = 1, signal = "sine", series = true))]
#[allow(clippy::too_many_arguments)]
pub fn run<'py>(
    py: Python<'py>,
    profile: Option<&str>,
    trace: Option<&str>,
    dist: Option<&str>,
    mean: Option<f64>,
    std: Option<f64>,
    mode: &str,
    playout: &str,
    underflow: &str,
    period: f64,
    duration: f64,
    seed: u64,
    axes: u16,
    signal: &str,
    series: bool,
) -> PyResult<(String, Bound<'py, PyDict>)> {
    let model = delay_model(profile, trace, dist, mean, std, "paris-newyork")?;
    let mut cfg = SimConfig::paper(model);
    cfg.mode = mode
        .parse::<Mode>()
        .map_err(|e| PyValueError::new_err(format!("mode: {e}")))?;
    cfg.underflow = underflow
        .parse::<Underflow>()
        .map_err(|e| PyValueError::new_err(format!("underflow: {e}")))?;
    cfg.playout = playout
        .parse::<Playout>()
        .map_err(|e| PyValueError::new_err(format!("playout: {e}")))?;
    cfg.period = positive_period("period", period)?;
    finite("duration", duration)?;
    cfg.duration = seconds("duration", duration)?;
    if cfg.duration.is_zero() {
        return Err(PyValueError::new_err("duration must be positive (seconds)"));
    }
    cfg.seed = seed;
    cfg.axes = axes;
    cfg.signal = signal
        .parse::<Signal>()
        .map_err(|e| PyValueError::new_err(format!("signal: {e}")))?;
    cfg.record_series = series;
    let out = py.detach(|| sim::run(&cfg));
    log::flush(py);
    let out = out.map_err(|e| match e {
        sim::SimError::Thread(_) => PyRuntimeError::new_err(e.to_string()),
        other => PyValueError::new_err(other.to_string()),
    })?;
    let summary = serde_json::to_string(&out.report)
        .map_err(|e| PyRuntimeError::new_err(format!("cannot encode the report: {e}")))?;
    Ok((summary, columns(py, &out.series)?))
}

/// The series as one float64 array per column (`NaN` where nothing was
/// measured yet).
fn columns<'py>(py: Python<'py>, rows: &[Row]) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let column = |f: fn(&Row) -> f64| PyArray1::from_iter(py, rows.iter().map(f));
    d.set_item("t", column(|r| r.t_s))?;
    d.set_item("period", column(|r| r.period_s))?;
    d.set_item("ns", column(|r| r.ns as f64))?;
    d.set_item("queue_base", column(|r| r.queue_base as f64))?;
    d.set_item("queue_remote", column(|r| r.queue_remote as f64))?;
    d.set_item("nrtt", column(|r| r.nrtt_s))?;
    d.set_item("nrtt_mean", column(|r| r.nrtt_mean_s))?;
    d.set_item("nrtt_ahead", column(|r| r.nrtt_ahead_s))?;
    d.set_item("mt", column(|r| r.mt_s))?;
    d.set_item("mt_ahead", column(|r| r.mt_ahead_s))?;
    d.set_item("grtt", column(|r| r.grtt_s))?;
    d.set_item("e2e_fwd", column(|r| r.e2e_fwd_s))?;
    d.set_item("e2e_bwd", column(|r| r.e2e_bwd_s))?;
    d.set_item("truth_nrtt", column(|r| r.truth_nrtt_s))?;
    Ok(d)
}

/// An operator's command signal, as `ndr sim --signal` and `ndr demo
/// --signal` take it: `"sine[:amp=A,freq=F,offset=O]"`,
/// `"steps[:low=L,high=H,period=P]"` or `"constant:V"`.
#[pyclass(frozen, module = "ndr", name = "Signal")]
pub struct PySignal {
    inner: Signal,
    spec: String,
}

#[pymethods]
impl PySignal {
    #[new]
    #[pyo3(signature = (spec = "sine"))]
    fn new(spec: &str) -> PyResult<Self> {
        let inner = spec
            .parse::<Signal>()
            .map_err(|e| PyValueError::new_err(format!("signal: {e}")))?;
        Ok(PySignal {
            inner,
            spec: spec.to_owned(),
        })
    }

    /// The value at time `t` (s) for `axis` (axes are phase-shifted).
    #[pyo3(signature = (t, axis = 0))]
    fn __call__(&self, t: f64, axis: usize) -> PyResult<f64> {
        Ok(self.inner.value(finite("t", t)?, axis))
    }

    /// The kind of signal: "sine", "steps" or "constant".
    #[getter]
    fn kind(&self) -> &'static str {
        self.inner.kind()
    }

    fn __repr__(&self) -> String {
        format!("Signal({:?})", self.spec)
    }
}
