//! `ndr.sim.run`: the simulator of `ndr sim`.
//!
//! The run happens without the GIL; the summary comes back as the JSON of
//! `ndr sim --json`, with `null` for what nothing measured (see `summary`;
//! the Python side parses it into a dict), and the per-tick series as float64
//! arrays, one per column of `ndr sim --out`.

use ndr_core::Regulation;
use ndr_core::endpoint::Underflow;
use ndr_sim::signal::Signal;
use ndr_sim::{MAX_SIM_AXES, Report, Row, SimConfig};
use numpy::PyArray1;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{finite, in_range, period as positive_period, seconds};
use crate::delay::delay_model;
use crate::log;

/// One simulation; returns `(summary_json, series)`.
#[pyfunction]
#[pyo3(name = "sim_run", signature = (*, profile = None, trace = None, dist = None, mean = None, std = None, regulation = None, underflow = "hold", period = 0.2, duration = 600.0, seed = 1, axes = 1, signal = "sine", series = true, loss = "none", transport = "stream"))]
#[allow(clippy::too_many_arguments)]
pub fn run<'py>(
    py: Python<'py>,
    profile: Option<&str>,
    trace: Option<&str>,
    dist: Option<&str>,
    mean: Option<f64>,
    std: Option<f64>,
    regulation: Option<&str>,
    underflow: &str,
    period: f64,
    duration: f64,
    seed: i128,
    axes: i128,
    signal: &str,
    series: bool,
    loss: &str,
    transport: &str,
) -> PyResult<(String, Bound<'py, PyDict>)> {
    let seed = in_range("seed", seed, 0, u64::MAX)?;
    let max_axes = u16::try_from(MAX_SIM_AXES).unwrap_or(u16::MAX);
    let axes = in_range("axes", axes, 1, max_axes)?;
    let model = delay_model(profile, trace, dist, mean, std, "paris-newyork")?;
    let mut cfg = SimConfig::paper(model).with_regulation(crate::regulation::read(
        regulation,
        Regulation::PaperStatic,
    )?);
    cfg.underflow = underflow
        .parse::<Underflow>()
        .map_err(|e| PyValueError::new_err(format!("underflow: {e}")))?;
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
    cfg.loss = loss
        .parse()
        .map_err(|e| PyValueError::new_err(format!("loss: {e}")))?;
    // The link's names (QUIC as its datagrams: its handshake and
    // encryption take no part in the samples' timing).
    cfg.transport = transport
        .parse::<ndr_net::Transport>()
        .map(ndr_net::Transport::carriage)
        .map_err(|e| PyValueError::new_err(format!("transport: {e}")))?;
    let out = py.detach(|| ndr_sim::run(&cfg));
    log::flush(py);
    let out = out.map_err(|e| PyValueError::new_err(e.to_string()))?;
    let summary = summary(&out.report)
        .map_err(|e| PyRuntimeError::new_err(format!("cannot encode the report: {e}")))?;
    Ok((summary, columns(py, &out.series)?))
}

/// The report as JSON, with `null` instead of the zeros the core writes for
/// what nothing measured (a run too short for a GRTT or a forecast):
///
/// - no GRTT (`grtt_count` 0): `grtt_mean_s`, `grtt_std_s`, `grtt_p99_s`;
/// - no GRTT since the last parameter change (none at all, or a settled
///   mean of exactly 0, which a GRTT, at least a period, cannot give):
///   `settled_grtt_mean_s`, `settled_grtt_std_s`, and the relations' errors;
/// - no forecast compared (`pred_count` 0): `pred_*_mae_s`, `pred_*_rmse_s`;
/// - no sample released (`samples_released` 0): `e2e_*_mean_s`, `e2e_*_std_s`;
/// - no running tick on a side since the last parameter change (a maximum
///   occupancy of 0: the first running tick finds more than `ns ≥ 0`):
///   that side's `queue_*_min`, `_max`, `_mean`, and then the relations;
/// - no initialization pattern finished (`initial_ns` 0; a size is ≥ 2):
///   `initial_ns`.
///
/// Non-finite values (`remote_clock_offset_s` before the clock estimate) are
/// already `null` in serde_json.
fn summary(report: &Report) -> serde_json::Result<String> {
    let mut value = serde_json::to_value(report)?;
    if let Some(fields) = value.as_object_mut() {
        let mut none = |names: &[&str]| {
            for name in names {
                debug_assert!(fields.contains_key(*name), "no field {name} in the report");
                if let Some(v) = fields.get_mut(*name) {
                    *v = serde_json::Value::Null;
                }
            }
        };
        let r = report;
        let no_settled = r.grtt_count == 0 || r.settled_grtt_mean_s == 0.0;
        let no_base_queue = r.queue_base_max == 0;
        let no_remote_queue = r.queue_remote_max == 0;
        if r.grtt_count == 0 {
            none(&["grtt_mean_s", "grtt_std_s", "grtt_p99_s"]);
        }
        if no_settled {
            none(&["settled_grtt_mean_s", "settled_grtt_std_s"]);
        }
        if r.pred_count == 0 {
            none(&[
                "pred_nrtt_mae_s",
                "pred_nrtt_rmse_s",
                "pred_mt_mae_s",
                "pred_mt_rmse_s",
            ]);
        }
        if r.samples_released == 0 {
            none(&[
                "e2e_fwd_mean_s",
                "e2e_fwd_std_s",
                "e2e_bwd_mean_s",
                "e2e_bwd_std_s",
            ]);
        }
        if no_base_queue {
            none(&["queue_base_min", "queue_base_max", "queue_base_mean"]);
        }
        if no_remote_queue {
            none(&["queue_remote_min", "queue_remote_max", "queue_remote_mean"]);
        }
        if no_base_queue || no_remote_queue {
            none(&["relation_grtt_s", "relation_mean_grtt_s"]);
        }
        if no_settled || no_base_queue || no_remote_queue {
            none(&["relation_error_s", "relation_mean_error_s"]);
        }
        if r.initial_ns == 0 {
            none(&["initial_ns"]);
        }
    }
    serde_json::to_string(&value)
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
    fn __call__(&self, t: f64, axis: i128) -> PyResult<f64> {
        let axis = in_range("axis", axis, 0, usize::MAX)?;
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
