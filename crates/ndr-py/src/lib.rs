//! `ndr._native`: the Python extension module of ndr.
//!
//! Thin by design: it converts Python values to `ndr-core` types, calls the
//! core, and converts back; errors become `ValueError` with the core's
//! message. The Pythonic surface (docstrings, keyword arguments, helpers)
//! lives in the `ndr` package under `python/`.
//!
//! - [`convert`]: seconds, counts and arrays in, arrays out; every refusal
//!   names what was expected;
//! - [`regulator`]: `Regulator` and its `RegulatorFull` exception;
//! - [`kalman`]: `Kalman3`, `NetworkPredictor`, `Prediction`, `kalman3_filter`;
//! - [`rls`]: `Rls` (sizes 1 to 8), `rls_filter`;
//! - [`arx`]: `Tf2`, `Tf2State`, `Arx2`, `Estimator`;
//! - [`control`]: `SmithPredictor`, `Pid`, `WaveTransform`, `WaveEnergy`,
//!   `round_trip_ticks`;
//! - [`filters`]: `LowPass`, `Envelope`, `lowpass`, `envelope`;
//! - [`link`]: the link natives (`_Link`, `_Listener`, `Tick`, `connect`,
//!   `listen`) behind `ndr.Link`, with [`errors`] (the `ConnectionError`
//!   subclasses) and [`blocking`] (waits without the GIL, Ctrl-C);
//! - [`relay`]: `Relay`, the delaying proxy;
//! - [`sim`]: `sim_run`, the simulator behind `ndr.sim.run`;
//! - [`regulation`]: `regulation=`, read once for every function that
//!   takes it, and the names it takes;
//! - [`delay`]: the delay model of either from its keyword arguments;
//! - [`log`]: Rust's `tracing` records into Python's `logging`.
//!
//! Batch functions copy their inputs, then run without the GIL. Waits on
//! the network release the GIL too, and wake every 50 ms to let Ctrl-C in.

pub mod arx;
pub mod blocking;
pub mod control;
pub mod convert;
pub mod delay;
pub mod errors;
pub mod filters;
pub mod kalman;
pub mod link;
pub mod log;
pub mod regulation;
pub mod regulator;
pub mod relay;
pub mod rls;
pub mod sim;
pub mod tls;

use ndr_core::{INIT_EXCHANGES, InitPattern, Sizing};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyList;

use crate::convert::seconds;

fn sizing_law(eta: f64, min_period: f64) -> PyResult<Sizing> {
    Sizing::new(eta, seconds("min_period", min_period)?)
        .map_err(|e| PyValueError::new_err(e.to_string()))
}

/// Nominal NDR queue size `ns = 2 + floor(eta * mt / period)` (never below 2).
#[pyfunction]
#[pyo3(
    signature = (mt, period, *, eta = Sizing::default().eta()),
    text_signature = "(mt, period, *, eta=1.3)"
)]
fn nominal_size(mt: f64, period: f64, eta: f64) -> PyResult<usize> {
    let period = convert::period("period", period)?;
    Ok(sizing_law(eta, 0.05)?.nominal_size(seconds("mt", mt)?, period))
}

/// The paper's period law `max(min_period, nrtt / 3)`, in seconds.
#[pyfunction]
#[pyo3(signature = (nrtt, *, min_period = 0.05))]
fn period_law(nrtt: f64, min_period: f64) -> PyResult<f64> {
    let law = sizing_law(Sizing::default().eta(), min_period)?;
    Ok(law.period(seconds("nrtt", nrtt)?).as_secs_f64())
}

/// Statistics of an initialization pattern: `(nrtt_min, nrtt_max, nrtt_mean, mt)`.
#[pyfunction]
fn init_stats(nrtt: &Bound<'_, PyAny>) -> PyResult<(f64, f64, f64, f64)> {
    let nrtt = convert::vector("nrtt", nrtt, None)?;
    let mut pattern: InitPattern<{ INIT_EXCHANGES }> = InitPattern::new();
    for (i, &x) in nrtt.iter().enumerate() {
        pattern
            .record_nrtt(seconds(&format!("nrtt[{i}]"), x)?)
            .map_err(|e| PyValueError::new_err(e.to_string()))?;
    }
    let s = pattern
        .stats()
        .ok_or_else(|| PyValueError::new_err("init_stats needs at least one NRTT sample"))?;
    Ok((
        s.nrtt_min.as_secs_f64(),
        s.nrtt_max.as_secs_f64(),
        s.nrtt_mean.as_secs_f64(),
        s.mt.as_secs_f64(),
    ))
}

/// The extension module.
#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("INIT_EXCHANGES", INIT_EXCHANGES)?;
    m.add_function(wrap_pyfunction!(nominal_size, m)?)?;
    m.add_function(wrap_pyfunction!(period_law, m)?)?;
    m.add_function(wrap_pyfunction!(init_stats, m)?)?;
    m.add(
        "RegulatorFull",
        m.py().get_type::<regulator::RegulatorFull>(),
    )?;
    m.add_class::<regulator::PyRegulator>()?;
    m.add_class::<kalman::PyKalman3>()?;
    m.add_class::<kalman::PyPrediction>()?;
    m.add_class::<kalman::PyNetworkPredictor>()?;
    m.add_function(wrap_pyfunction!(kalman::kalman3_filter, m)?)?;
    m.add_class::<rls::PyRls>()?;
    m.add_function(wrap_pyfunction!(rls::rls_filter, m)?)?;
    m.add_class::<arx::PyTf2>()?;
    m.add_class::<arx::PyTf2State>()?;
    m.add_class::<arx::PyArx2>()?;
    m.add_class::<arx::PyEstimator>()?;
    m.add_class::<control::PySmithPredictor>()?;
    m.add_class::<control::PyPid>()?;
    m.add_class::<control::PyWaveTransform>()?;
    m.add_class::<control::PyWaveEnergy>()?;
    m.add_function(wrap_pyfunction!(control::round_trip_ticks_py, m)?)?;
    m.add("SMITH_HISTORY", control::SMITH_HISTORY)?;
    m.add_class::<filters::PyLowPass>()?;
    m.add_class::<filters::PyEnvelope>()?;
    m.add_function(wrap_pyfunction!(filters::lowpass, m)?)?;
    m.add_function(wrap_pyfunction!(filters::envelope, m)?)?;
    m.add("MAX_CAPACITY", regulator::MAX_CAPACITY)?;
    m.add("ESTIMATOR_HISTORY", arx::ESTIMATOR_HISTORY)?;
    errors::register(m)?;
    m.add_class::<link::PyTick>()?;
    m.add_class::<link::PyLink>()?;
    m.add_class::<link::PyListener>()?;
    m.add_class::<link::PyLinkSettings>()?;
    m.add_class::<tls::PyTlsConfig>()?;
    m.add_function(wrap_pyfunction!(tls::keygen, m)?)?;
    m.add_function(wrap_pyfunction!(link::connect, m)?)?;
    m.add_function(wrap_pyfunction!(link::listen, m)?)?;
    m.add("MAX_WIDTH", ndr_core::wire::MAX_CHANNELS)?;
    m.add("MAX_AXES", ndr_core::wire::MAX_CHANNELS)?;
    m.add_class::<relay::PyRelay>()?;
    m.add_function(wrap_pyfunction!(sim::run, m)?)?;
    m.add_function(wrap_pyfunction!(regulation::parts, m)?)?;
    m.add(
        "REGULATIONS",
        pyo3::types::PyTuple::new(m.py(), regulation::bare_names())?,
    )?;
    m.add(
        "REGULATION_NAMES",
        ndr_core::Regulation::names(Some(ndr_core::Regulation::ADAPTIVE)).to_string(),
    )?;
    m.add_class::<sim::PySignal>()?;
    m.add_function(wrap_pyfunction!(log::set_log_level, m)?)?;
    m.add_function(wrap_pyfunction!(log::flush_logs, m)?)?;
    private_out_of_all(m)?;
    log::install();
    Ok(())
}

/// Takes the private names (`_Link`, `_Listener`, `_LinkSettings`: the
/// natives behind `ndr.Link`) out of the `__all__` pyo3 keeps; `__version__`
/// stays.
fn private_out_of_all(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let all = m.getattr("__all__")?.cast_into::<PyList>()?;
    let public: Vec<Bound<'_, PyAny>> = all
        .iter()
        .filter(|name| {
            name.extract::<String>()
                .map_or(true, |n| !n.starts_with('_') || n.starts_with("__"))
        })
        .collect();
    m.setattr("__all__", PyList::new(m.py(), public)?)
}
