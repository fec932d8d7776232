//! Classical control across the link: `ndr.SmithPredictor`,
//! `ndr.WaveTransform`, `ndr.WaveEnergy`, `ndr.Pid` and
//! `ndr.round_trip_ticks`, thin wrappers of `ndr_core::control`.

use ndr_core::control::{
    ControlError, Pid, PidConfig, SmithPredictor, WaveEnergy, WaveTransform, round_trip_ticks,
};
use numpy::PyArray1;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::arx::{PyArx2, PyTf2};
use crate::convert::{self, array1, count, finite, same_len, seconds, vector, vector_with_nan};

/// The longest round trip a Python `SmithPredictor` follows, ticks.
pub const SMITH_HISTORY: usize = 8192;

fn control_error(e: ControlError) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// `⌈grtt / period⌉`: the round trip in ticks a release's GRTT is, for an
/// application that takes each release at its next tick.
#[pyfunction]
#[pyo3(name = "round_trip_ticks", signature = (grtt, period))]
pub fn round_trip_ticks_py(grtt: f64, period: f64) -> PyResult<usize> {
    let grtt = seconds("grtt", grtt)?;
    let p = convert::period("period", period)?;
    round_trip_ticks(grtt, p)
        .ok_or_else(|| PyValueError::new_err("period must be positive (at least 1 ns)"))
}

/// A Smith predictor closing a loop on the remote's state, `round_trip`
/// ticks late.
#[pyclass(module = "ndr", name = "SmithPredictor")]
#[derive(Clone)]
pub struct PySmithPredictor {
    inner: Box<SmithPredictor<SMITH_HISTORY>>,
    dt: f64,
}

fn round_trip_arg(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<usize> {
    count(name, obj, 1, SMITH_HISTORY)
}

#[pymethods]
impl PySmithPredictor {
    #[new]
    #[pyo3(signature = (model, *, round_trip))]
    fn new(model: &Bound<'_, PyAny>, round_trip: &Bound<'_, PyAny>) -> PyResult<Self> {
        let d = round_trip_arg("round_trip", round_trip)?;
        if let Ok(tf) = model.cast::<PyTf2>() {
            let tf = tf.get();
            let inner = SmithPredictor::with_model(tf.tf, d).map_err(control_error)?;
            return Ok(PySmithPredictor {
                inner: Box::new(inner),
                dt: tf.dt,
            });
        }
        if let Ok(arx) = model.cast::<PyArx2>() {
            let arx = arx.borrow();
            let inner = SmithPredictor::identifying(arx.arx.clone(), d).map_err(control_error)?;
            return Ok(PySmithPredictor {
                inner: Box::new(inner),
                dt: arx.dt,
            });
        }
        let ty = model.get_type().name()?;
        Err(pyo3::exceptions::PyTypeError::new_err(format!(
            "model must be a Tf2 (the plant's model) or an Arx2 (to identify it online), \
             got an object of type {ty}"
        )))
    }

    /// Tick `k`, first half: the state released now (`None` for a held
    /// repeat or no release); returns what the controller should take as
    /// the plant's state.
    #[pyo3(signature = (measured))]
    fn feedback(&mut self, measured: Option<f64>) -> PyResult<f64> {
        let m = measured.map(|y| finite("measured", y)).transpose()?;
        self.inner.feedback(m).map_err(control_error)
    }

    /// Tick `k`, second half: the command sent now; the local model steps on it.
    #[pyo3(signature = (u))]
    fn command(&mut self, u: f64) -> PyResult<()> {
        self.inner.command(finite("u", u)?).map_err(control_error)
    }

    /// Replays recorded ticks: for each `k`, `feedback(measured[k])` (NaN
    /// for none) then `command(commands[k])`; returns the feedbacks. If a
    /// tick is refused, nothing is changed.
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        measured: &Bound<'py, PyAny>,
        commands: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let y = vector_with_nan("measured", measured, None)?;
        if let Some(i) = y.iter().position(|v| v.is_infinite()) {
            return Err(PyValueError::new_err(format!(
                "measured[{i}] is infinite: give a finite state, or NaN for a tick without one"
            )));
        }
        let u = vector("commands", commands, None)?;
        same_len(("measured", y.len()), ("commands", u.len()))?;
        let mut work = self.inner.clone();
        let out: Result<Vec<f64>, ControlError> = py.detach(|| {
            y.iter()
                .zip(&u)
                .map(|(&yk, &uk)| {
                    let seen = work.feedback((!yk.is_nan()).then_some(yk))?;
                    work.command(uk)?;
                    Ok(seen)
                })
                .collect()
        });
        let seen = out.map_err(control_error)?;
        self.inner = work;
        Ok(array1(py, seen))
    }

    /// The link announced a new round trip (ticks, 1 to `SMITH_HISTORY`).
    fn set_round_trip(&mut self, round_trip: &Bound<'_, PyAny>) -> PyResult<()> {
        let d = round_trip_arg("round_trip", round_trip)?;
        self.inner.set_round_trip(d).map_err(control_error)
    }

    /// The same from the one-way delays in ticks: `delay_fwd + delay_bwd`.
    fn set_delays(
        &mut self,
        delay_fwd: &Bound<'_, PyAny>,
        delay_bwd: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        let df = count("delay_fwd", delay_fwd, 0, SMITH_HISTORY)?;
        let db = count("delay_bwd", delay_bwd, 0, SMITH_HISTORY)?;
        if !(1..=SMITH_HISTORY).contains(&(df + db)) {
            return Err(PyValueError::new_err(format!(
                "delay_fwd + delay_bwd must be from 1 to {SMITH_HISTORY} ticks, got {}",
                df + db
            )));
        }
        self.inner.set_round_trip(df + db).map_err(control_error)
    }

    /// The round trip in ticks.
    #[getter]
    fn round_trip(&self) -> usize {
        self.inner.round_trip()
    }

    /// The local model in use; assigning one keeps the history.
    #[getter]
    fn model(&self) -> PyTf2 {
        PyTf2 {
            tf: self.inner.model(),
            dt: self.dt,
        }
    }

    #[setter]
    fn set_model(&mut self, model: &PyTf2) -> PyResult<()> {
        self.inner.set_model(model.tf).map_err(control_error)?;
        self.dt = model.dt;
        Ok(())
    }

    /// Whether the model is used (always for a given one; after enough
    /// adaptations for an identified one).
    #[getter]
    fn model_ready(&self) -> bool {
        self.inner.model_ready()
    }

    /// Whether the model is identified online.
    #[getter]
    fn is_identifying(&self) -> bool {
        self.inner.is_identifying()
    }

    /// Commands given so far (the tick of the next one).
    #[getter]
    fn ticks(&self) -> u64 {
        self.inner.ticks()
    }

    /// The last correction: the measured state less the model's one round trip ago.
    #[getter]
    fn correction(&self) -> f64 {
        self.inner.correction()
    }

    /// The model's sampling period in seconds.
    #[getter]
    fn dt(&self) -> f64 {
        self.dt
    }

    fn __repr__(&self) -> String {
        format!(
            "SmithPredictor(round_trip={}, ticks={}, identifying={}, model_ready={})",
            self.inner.round_trip(),
            self.inner.ticks(),
            self.inner.is_identifying(),
            self.inner.model_ready()
        )
    }
}

/// A discrete PID with output limits and anti-windup; the derivative acts
/// on the measurement.
#[pyclass(module = "ndr", name = "Pid")]
#[derive(Clone)]
pub struct PyPid {
    inner: Pid,
}

#[pymethods]
impl PyPid {
    #[new]
    #[pyo3(signature = (kp, ki = 0.0, kd = 0.0, *, dt, out_min = f64::NEG_INFINITY, out_max = f64::INFINITY, derivative_filter = 0.0))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        kp: f64,
        ki: f64,
        kd: f64,
        dt: f64,
        out_min: f64,
        out_max: f64,
        derivative_filter: f64,
    ) -> PyResult<Self> {
        let mut cfg = PidConfig::new(kp, ki, kd, dt);
        (cfg.out_min, cfg.out_max) = (out_min, out_max);
        cfg.derivative_filter_s = derivative_filter;
        Ok(PyPid {
            inner: Pid::new(cfg).map_err(control_error)?,
        })
    }

    /// One step: the output for reference `r` and measurement `y`.
    fn step(&mut self, r: f64, y: f64) -> PyResult<f64> {
        self.inner
            .step(finite("r", r)?, finite("y", y)?)
            .map_err(control_error)
    }

    /// Steps over the series `r` and `y` (shape `(n,)` each, an open loop:
    /// the measurements are given); returns the outputs. If a step is
    /// refused, nothing is changed.
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        r: &Bound<'py, PyAny>,
        y: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let r = vector("r", r, None)?;
        let y = vector("y", y, None)?;
        same_len(("r", r.len()), ("y", y.len()))?;
        let mut work = self.inner;
        let out: Result<Vec<f64>, ControlError> = py.detach(|| {
            r.iter()
                .zip(&y)
                .map(|(&rk, &yk)| work.step(rk, yk))
                .collect()
        });
        let u = out.map_err(control_error)?;
        self.inner = work;
        Ok(array1(py, u))
    }

    /// Back to rest (integral, derivative and last measurement cleared).
    fn reset(&mut self) {
        self.inner.reset();
    }

    /// Proportional gain.
    #[getter]
    fn kp(&self) -> f64 {
        self.inner.config().kp
    }

    /// Integral gain, per second.
    #[getter]
    fn ki(&self) -> f64 {
        self.inner.config().ki
    }

    /// Derivative gain, seconds.
    #[getter]
    fn kd(&self) -> f64 {
        self.inner.config().kd
    }

    /// The derivative's low-pass time constant, seconds (0: none).
    #[getter]
    fn derivative_filter(&self) -> f64 {
        self.inner.config().derivative_filter_s
    }

    /// `(out_min, out_max)`.
    #[getter]
    fn limits(&self) -> (f64, f64) {
        let c = self.inner.config();
        (c.out_min, c.out_max)
    }

    /// The period between steps, seconds; assigning one (the link resized)
    /// keeps the state.
    #[getter]
    fn dt(&self) -> f64 {
        self.inner.config().period_s
    }

    #[setter]
    fn set_dt(&mut self, dt: f64) -> PyResult<()> {
        self.inner.set_period(dt).map_err(control_error)
    }

    fn __repr__(&self) -> String {
        let c = self.inner.config();
        format!(
            "Pid(kp={}, ki={}, kd={}, dt={}, out_min={}, out_max={}, derivative_filter={})",
            c.kp, c.ki, c.kd, c.period_s, c.out_min, c.out_max, c.derivative_filter_s
        )
    }
}

/// Niemeyer and Slotine's wave variables at impedance `b`.
#[pyclass(module = "ndr", name = "WaveTransform", frozen)]
#[derive(Clone)]
pub struct PyWaveTransform {
    inner: WaveTransform,
}

/// Floats in, a float out; arrays (or a float with an array) in, an array out.
fn elementwise<'py>(
    py: Python<'py>,
    (a_name, a): (&str, &Bound<'py, PyAny>),
    (b_name, b): (&str, &Bound<'py, PyAny>),
    f: impl Fn(f64, f64) -> f64,
) -> PyResult<Bound<'py, PyAny>> {
    if let (Ok(x), Ok(y)) = (a.extract::<f64>(), b.extract::<f64>()) {
        let v = f(finite(a_name, x)?, finite(b_name, y)?);
        return Ok(v.into_pyobject(py)?.into_any());
    }
    let spread = |name: &str, obj: &Bound<'py, PyAny>, n: Option<usize>| -> PyResult<Vec<f64>> {
        match (obj.extract::<f64>(), n) {
            (Ok(x), Some(n)) => Ok(vec![finite(name, x)?; n]),
            _ => vector(name, obj, n),
        }
    };
    let (xs, ys) = if a.extract::<f64>().is_ok() {
        let ys = vector(b_name, b, None)?;
        (spread(a_name, a, Some(ys.len()))?, ys)
    } else {
        let xs = vector(a_name, a, None)?;
        let n = xs.len();
        (xs, spread(b_name, b, Some(n))?)
    };
    let out: Vec<f64> = xs.iter().zip(&ys).map(|(&x, &y)| f(x, y)).collect();
    Ok(array1(py, out).into_any())
}

#[pymethods]
impl PyWaveTransform {
    #[new]
    #[pyo3(signature = (b))]
    fn new(b: f64) -> PyResult<Self> {
        Ok(PyWaveTransform {
            inner: WaveTransform::new(b).map_err(control_error)?,
        })
    }

    /// The wave impedance `b` (force per velocity).
    #[getter]
    fn b(&self) -> f64 {
        self.inner.impedance()
    }

    /// `u = (b·v + F)/√(2b)`; floats or arrays of the same shape.
    fn forward_wave<'py>(
        &self,
        py: Python<'py>,
        velocity: &Bound<'py, PyAny>,
        force: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let w = self.inner;
        elementwise(py, ("velocity", velocity), ("force", force), |x, f| {
            w.forward_wave(x, f)
        })
    }

    /// `v = (b·v − F)/√(2b)`; floats or arrays of the same shape.
    fn backward_wave<'py>(
        &self,
        py: Python<'py>,
        velocity: &Bound<'py, PyAny>,
        force: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let w = self.inner;
        elementwise(py, ("velocity", velocity), ("force", force), |x, f| {
            w.backward_wave(x, f)
        })
    }

    /// The master at `velocity` receives the backward wave `v`: returns
    /// `(force, u)`, the force reflected and the forward wave to send.
    fn master(&self, velocity: f64, v: f64) -> PyResult<(f64, f64)> {
        let p = self
            .inner
            .master(finite("velocity", velocity)?, finite("v", v)?)
            .map_err(control_error)?;
        Ok((p.force, p.wave))
    }

    /// The slave receives the forward wave `u` and meets `force`: returns
    /// `(velocity, v)`, the velocity to command and the backward wave.
    fn slave(&self, u: f64, force: f64) -> PyResult<(f64, f64)> {
        let p = self
            .inner
            .slave(finite("u", u)?, finite("force", force)?)
            .map_err(control_error)?;
        Ok((p.velocity, p.wave))
    }

    fn __repr__(&self) -> String {
        format!("WaveTransform(b={})", self.inner.impedance())
    }
}

/// The energy account of a wave channel (both directions).
#[pyclass(module = "ndr", name = "WaveEnergy")]
#[derive(Clone, Default)]
pub struct PyWaveEnergy {
    inner: WaveEnergy,
}

fn check_dt(dt: f64) -> PyResult<f64> {
    if dt.is_finite() && dt > 0.0 {
        Ok(dt)
    } else {
        Err(PyValueError::new_err(format!(
            "dt must be the time the wave lasts, a finite number of seconds > 0, got {dt}"
        )))
    }
}

#[pymethods]
impl PyWaveEnergy {
    #[new]
    fn new() -> Self {
        PyWaveEnergy::default()
    }

    /// A wave (a float, or an array of successive ones) entered the channel
    /// for `dt` seconds each.
    #[pyo3(signature = (wave, *, dt))]
    fn sent(&mut self, wave: &Bound<'_, PyAny>, dt: f64) -> PyResult<()> {
        let dt = check_dt(dt)?;
        for w in waves(wave)? {
            self.inner.sent(w, dt);
        }
        Ok(())
    }

    /// A wave (or an array of successive ones) left the channel for `dt`
    /// seconds each.
    #[pyo3(signature = (wave, *, dt))]
    fn delivered(&mut self, wave: &Bound<'_, PyAny>, dt: f64) -> PyResult<()> {
        let dt = check_dt(dt)?;
        for w in waves(wave)? {
            self.inner.delivered(w, dt);
        }
        Ok(())
    }

    /// Energy that entered the channel so far.
    #[getter]
    fn entered(&self) -> f64 {
        self.inner.entered()
    }

    /// Energy that left it so far.
    #[getter]
    fn left(&self) -> f64 {
        self.inner.left()
    }

    /// Entered less left (negative once the channel generated energy).
    #[getter]
    fn stored(&self) -> f64 {
        self.inner.entered() - self.inner.left()
    }

    /// The most the channel ever gave beyond what it received: zero when passive.
    #[getter]
    fn generated(&self) -> f64 {
        self.inner.generated()
    }

    fn __repr__(&self) -> String {
        format!(
            "WaveEnergy(entered={}, left={}, generated={})",
            self.inner.entered(),
            self.inner.left(),
            self.inner.generated()
        )
    }
}

fn waves(obj: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
    match obj.extract::<f64>() {
        Ok(w) => Ok(vec![finite("wave", w)?]),
        Err(_) => vector("wave", obj, None),
    }
}
