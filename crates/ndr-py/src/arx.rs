//! The remote system's model: `ndr.Tf2`, `ndr.Tf2State`, `ndr.Arx2` and
//! `ndr.Estimator`. Transfer functions go out in scipy.signal's convention,
//! `(num, den, dt)` with `num = [b0, b1, b2]`, `den = [1, a1, a2]`.

use ndr_core::{Arx2, Tf2, Tf2State};
use ndr_core::{Estimate, Estimator, EstimatorError};
use numpy::PyArray1;
use pyo3::exceptions::{PyRuntimeWarning, PyValueError};
use pyo3::prelude::*;

use crate::convert::{
    array_of, array1, coefficients, count, finite, same_len, value_error, vector, vector_with_nan,
};
use crate::rls::PyRls;

/// The command history of a Python estimator: `Df + Db + 3` must fit.
pub const ESTIMATOR_HISTORY: usize = 4096;

type PyTf<'py> = (Bound<'py, PyArray1<f64>>, Bound<'py, PyArray1<f64>>, f64);

fn check_dt(dt: f64) -> PyResult<f64> {
    if dt.is_finite() && dt > 0.0 {
        Ok(dt)
    } else {
        Err(PyValueError::new_err(format!(
            "dt must be the sampling period, a finite number of seconds > 0, got {dt}"
        )))
    }
}

/// A RuntimeWarning when the data has not determined the identified model
/// (a constant input, say): its coefficients are then the prior's, not the
/// system's, and nothing else would say so.
fn warn_unexcited(py: Python<'_>, arx: &Arx2) -> PyResult<()> {
    let n = arx.unexcited();
    if arx.rls().updates() == 0 || n == 0 {
        return Ok(());
    }
    let message = format!(
        "Arx2: the input did not excite the model: {n} of its 5 directions are not determined \
         by the data (a constant or too simple input), so the identified coefficients along \
         them are made up; identify on an input with more frequencies (steps, noise, a chirp)"
    );
    let category = py.get_type::<PyRuntimeWarning>();
    PyErr::warn(py, &category, &std::ffi::CString::new(message)?, 1)
}

fn to_tf<'py>(py: Python<'py>, tf: &Tf2, dt: f64) -> PyTf<'py> {
    (
        array1(py, tf.b.to_vec()),
        array1(py, vec![1.0, tf.a[0], tf.a[1]]),
        dt,
    )
}

/// A second-order discrete transfer function
/// `(b0 + b1 z⁻¹ + b2 z⁻²) / (1 + a1 z⁻¹ + a2 z⁻²)` sampled every `dt` seconds.
#[pyclass(module = "ndr", name = "Tf2", frozen)]
#[derive(Clone)]
pub struct PyTf2 {
    pub(crate) tf: Tf2,
    pub(crate) dt: f64,
}

#[pymethods]
impl PyTf2 {
    #[new]
    fn new(num: &Bound<'_, PyAny>, den: &Bound<'_, PyAny>, dt: f64) -> PyResult<Self> {
        // Polynomials in z, highest power first, as scipy.signal's `dlti`
        // and `cont2discrete` (a `(1, 3)` numerator) and python-control (a
        // shorter numerator) give them: a short one is padded on the left.
        let given = coefficients("num", num, 3)?;
        let mut b = [0.0; 3];
        b[3 - given.len()..].copy_from_slice(&given);
        let a: [f64; 3] = array_of("den", den)?;
        let dt = check_dt(dt)?;
        if a[0] == 0.0 {
            return Err(PyValueError::new_err(
                "den[0] must be non-zero (den = [1, a1, a2] in scipy.signal's convention)",
            ));
        }
        let tf = Tf2 {
            b: [b[0] / a[0], b[1] / a[0], b[2] / a[0]],
            a: [a[1] / a[0], a[2] / a[0]],
        };
        if !tf.is_finite() {
            return Err(PyValueError::new_err(
                "num / den[0] and den / den[0] must be finite",
            ));
        }
        Ok(PyTf2 { tf, dt })
    }

    /// The bilinear (Tustin) discretization of the continuous low-pass
    /// `gain·ωn² / (s² + 2ζωn·s + ωn²)`, `wn` in rad/s.
    #[staticmethod]
    fn low_pass(wn: f64, zeta: f64, gain: f64, dt: f64) -> PyResult<Self> {
        let tf = Tf2::low_pass(wn, zeta, gain, dt).map_err(value_error)?;
        Ok(PyTf2 { tf, dt })
    }

    /// `(num, den, dt)` in scipy.signal's convention: `num = [b0, b1, b2]`,
    /// `den = [1, a1, a2]`. For scipy give `dt` by name,
    /// `scipy.signal.dlti(num, den, dt=dt)`: three positional arguments are
    /// zeros, poles and gain there. `control.tf(*tf.to_tf())` is right.
    fn to_tf<'py>(&self, py: Python<'py>) -> PyTf<'py> {
        to_tf(py, &self.tf, self.dt)
    }

    /// `[b0, b1, b2]`.
    #[getter]
    fn num<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array1(py, self.tf.b.to_vec())
    }

    /// `[1, a1, a2]`.
    #[getter]
    fn den<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array1(py, vec![1.0, self.tf.a[0], self.tf.a[1]])
    }

    /// The sampling period in seconds.
    #[getter]
    fn dt(&self) -> f64 {
        self.dt
    }

    /// The static gain `H(1)`.
    #[getter]
    fn dc_gain(&self) -> f64 {
        self.tf.dc_gain()
    }

    /// Whether both poles lie strictly inside the unit circle.
    fn is_stable(&self) -> bool {
        self.tf.is_stable()
    }

    /// The response to the input series `u`, from rest unless `u_past =
    /// [u[-1], u[-2]]` and `y_past = [y[-1], y[-2]]` are given.
    #[pyo3(signature = (u, *, u_past = None, y_past = None))]
    fn simulate<'py>(
        &self,
        py: Python<'py>,
        u: &Bound<'py, PyAny>,
        u_past: Option<&Bound<'py, PyAny>>,
        y_past: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let mut state = PyTf2State::new(self, u_past, y_past)?;
        state.run(py, u)
    }

    fn __eq__(&self, other: &Bound<'_, PyAny>) -> bool {
        other
            .cast::<PyTf2>()
            .is_ok_and(|o| o.get().tf == self.tf && o.get().dt == self.dt)
    }

    fn __repr__(&self) -> String {
        format!(
            "Tf2(num=[{}, {}, {}], den=[1.0, {}, {}], dt={})",
            self.tf.b[0], self.tf.b[1], self.tf.b[2], self.tf.a[0], self.tf.a[1], self.dt
        )
    }
}

/// A `Tf2` being simulated: its input and output history.
#[pyclass(module = "ndr", name = "Tf2State")]
#[derive(Clone)]
pub struct PyTf2State {
    state: Tf2State,
    dt: f64,
}

#[pymethods]
impl PyTf2State {
    #[new]
    #[pyo3(signature = (model, *, u_past = None, y_past = None))]
    fn new(
        model: &PyTf2,
        u_past: Option<&Bound<'_, PyAny>>,
        y_past: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let u: [f64; 2] = u_past.map_or(Ok([0.0; 2]), |v| array_of("u_past", v))?;
        let y: [f64; 2] = y_past.map_or(Ok([0.0; 2]), |v| array_of("y_past", v))?;
        Ok(PyTf2State {
            state: Tf2State::with_initial(model.tf, u, y),
            dt: model.dt,
        })
    }

    /// Applies the input `u`; returns the output.
    fn step(&mut self, u: f64) -> PyResult<f64> {
        Ok(self.state.step(finite("u", u)?))
    }

    /// Applies every input of the series `u`; returns the outputs, shape `(n,)`.
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        u: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let u = vector("u", u, None)?;
        let state = &mut self.state;
        let y = py.detach(|| u.iter().map(|&uk| state.step(uk)).collect());
        Ok(array1(py, y))
    }

    /// The latest output.
    #[getter]
    fn output(&self) -> f64 {
        self.state.output()
    }

    /// The model simulated; assigning one keeps the history.
    #[getter]
    fn model(&self) -> PyTf2 {
        PyTf2 {
            tf: *self.state.model(),
            dt: self.dt,
        }
    }

    #[setter]
    fn set_model(&mut self, model: &PyTf2) {
        self.state.set_model(model.tf);
        self.dt = model.dt;
    }

    /// Back to rest (zero history).
    fn reset(&mut self) {
        self.state.reset();
    }
}

/// Online identification of a `Tf2` by recursive least squares on
/// `[u[k], u[k-1], u[k-2], -y[k-1], -y[k-2]]`.
#[pyclass(module = "ndr", name = "Arx2")]
#[derive(Clone)]
pub struct PyArx2 {
    pub(crate) arx: Arx2,
    pub(crate) dt: f64,
}

#[pymethods]
impl PyArx2 {
    #[new]
    #[pyo3(signature = (dt, *, lam = 1.0, delta = 1e6))]
    fn new(dt: f64, lam: f64, delta: f64) -> PyResult<Self> {
        Ok(PyArx2 {
            arx: Arx2::new(lam, delta).map_err(value_error)?,
            dt: check_dt(dt)?,
        })
    }

    /// Records the input `u[k]` and output `y[k]`; adapts once two earlier
    /// samples are known and returns the a-priori error, else None.
    fn update(&mut self, u: f64, y: f64) -> PyResult<Option<f64>> {
        self.arx.update(u, y).map_err(value_error)
    }

    /// Identifies on whole series `u`, `y` (shape `(n,)` each); returns the
    /// a-priori errors, NaN where no adaptation happened (the first two
    /// samples). If an update fails, nothing is changed and ValueError is raised.
    fn fit<'py>(
        &mut self,
        py: Python<'py>,
        u: &Bound<'py, PyAny>,
        y: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let u = vector("u", u, None)?;
        let y = vector("y", y, None)?;
        same_len(("u", u.len()), ("y", y.len()))?;
        let mut work = self.arx.clone();
        let out: Result<Vec<f64>, (usize, String)> = py.detach(|| {
            u.iter()
                .zip(&y)
                .enumerate()
                .map(|(k, (&uk, &yk))| {
                    work.update(uk, yk)
                        .map(|e| e.unwrap_or(f64::NAN))
                        .map_err(|e| (k, e.to_string()))
                })
                .collect()
        });
        let e = out.map_err(|(k, e)| {
            PyValueError::new_err(format!("sample {k}: {e} (nothing was changed)"))
        })?;
        self.arx = work;
        warn_unexcited(py, &self.arx)?;
        Ok(array1(py, e))
    }

    /// Records a stand-in pair (e.g. the model's own output during an
    /// underflow) without adapting on it.
    fn record_substitute(&mut self, u: f64, y: f64) -> PyResult<()> {
        self.arx.record_substitute(finite("u", u)?, finite("y", y)?);
        Ok(())
    }

    /// Forgets the input/output history, keeping the model.
    fn clear_history(&mut self) {
        self.arx.clear_history();
    }

    /// The model's output for input `u`, or None until two samples are known.
    fn predict(&self, u: f64) -> PyResult<Option<f64>> {
        Ok(self.arx.predict(finite("u", u)?))
    }

    /// The identified model (a RuntimeWarning if the input did not excite it).
    #[getter]
    fn model(&self, py: Python<'_>) -> PyResult<PyTf2> {
        warn_unexcited(py, &self.arx)?;
        Ok(PyTf2 {
            tf: self.arx.model(),
            dt: self.dt,
        })
    }

    /// `(num, den, dt)` of the identified model, scipy.signal's convention
    /// (a RuntimeWarning if the input did not excite it).
    fn to_tf<'py>(&self, py: Python<'py>) -> PyResult<PyTf<'py>> {
        warn_unexcited(py, &self.arx)?;
        Ok(to_tf(py, &self.arx.model(), self.dt))
    }

    /// How many of the model's 5 directions the data has not determined
    /// (0 once the input excites them all; a constant input leaves 2 or more).
    #[getter]
    fn unexcited(&self) -> usize {
        self.arx.unexcited()
    }

    /// The sampling period in seconds.
    #[getter]
    fn dt(&self) -> f64 {
        self.dt
    }

    /// A copy of the underlying `Rls` (5 weights `[b0, b1, b2, a1, a2]`).
    #[getter]
    fn rls(&self) -> PyRls {
        PyRls::from_rls5(self.arx.rls().clone())
    }

    /// Adaptations so far.
    #[getter]
    fn updates(&self) -> u64 {
        self.arx.rls().updates()
    }

    /// Back to a zero model and no history.
    fn reset(&mut self) {
        self.arx.reset();
    }

    fn __repr__(&self) -> String {
        let tf = self.arx.model();
        format!(
            "Arx2(dt={}, updates={}, num=[{}, {}, {}], den=[1.0, {}, {}])",
            self.dt,
            self.arx.rls().updates(),
            tf.b[0],
            tf.b[1],
            tf.b[2],
            tf.a[0],
            tf.a[1]
        )
    }
}

fn estimator_error(e: EstimatorError) -> PyErr {
    match e {
        EstimatorError::HistoryTooShort {
            delay_fwd,
            delay_bwd,
            ..
        } => PyValueError::new_err(format!(
            "delays delay_fwd = {delay_fwd}, delay_bwd = {delay_bwd} ticks are too long: \
             delay_fwd + delay_bwd + 3 must be at most {ESTIMATOR_HISTORY}"
        )),
        e => value_error(e),
    }
}

/// `x3e` (the remote's state now) and `x3p` (its state when the command sent
/// now takes effect) from the commands in flight and the delayed feedback.
#[pyclass(module = "ndr", name = "Estimator")]
#[derive(Clone)]
pub struct PyEstimator {
    inner: Box<Estimator<ESTIMATOR_HISTORY>>,
    dt: f64,
}

type EstimateTuple = (f64, f64, bool);

fn tuple(e: Estimate) -> EstimateTuple {
    (e.x3e, e.x3p, e.from_model)
}

#[pymethods]
impl PyEstimator {
    #[new]
    #[pyo3(signature = (delay_fwd, delay_bwd, *, dt = None, model = None, lam = 1.0, delta = 1e6))]
    fn new(
        delay_fwd: &Bound<'_, PyAny>,
        delay_bwd: &Bound<'_, PyAny>,
        dt: Option<f64>,
        model: Option<&PyTf2>,
        lam: f64,
        delta: f64,
    ) -> PyResult<Self> {
        let df = count("delay_fwd", delay_fwd, 0, ESTIMATOR_HISTORY)?;
        let db = count("delay_bwd", delay_bwd, 0, ESTIMATOR_HISTORY)?;
        let dt = match (dt, model) {
            (Some(dt), Some(m)) if dt != m.dt => {
                return Err(PyValueError::new_err(format!(
                    "dt = {dt} differs from the model's dt = {}: give one or the other",
                    m.dt
                )));
            }
            (Some(dt), _) => check_dt(dt)?,
            (None, Some(m)) => m.dt,
            (None, None) => {
                return Err(PyValueError::new_err(
                    "Estimator needs dt (the link period in seconds) or a model (a Tf2)",
                ));
            }
        };
        let inner = match model {
            Some(m) => Estimator::with_model(df, db, m.tf),
            None => Estimator::new(df, db, Arx2::new(lam, delta).map_err(value_error)?),
        }
        .map_err(estimator_error)?;
        Ok(PyEstimator {
            inner: Box::new(inner),
            dt,
        })
    }

    /// One tick: `u` is the command sent now, `y` the state sample released
    /// now (None on an underflow). Returns `(x3e, x3p, from_model)`.
    #[pyo3(signature = (u, y = None))]
    fn step(&mut self, u: f64, y: Option<f64>) -> PyResult<EstimateTuple> {
        let u = finite("u", u)?;
        let y = y.map(|y| finite("y", y)).transpose()?;
        self.inner.step(u, y).map(tuple).map_err(estimator_error)
    }

    /// Steps over whole series: `u` and `y` shape `(n,)`; `received` (bool,
    /// shape `(n,)`, default all True) marks the ticks that released a state
    /// sample, and `y` is ignored (may be NaN) where it is False. Returns
    /// `(x3e, x3p, from_model)` arrays. If a step fails, nothing is changed.
    #[pyo3(signature = (u, y, received = None))]
    #[allow(clippy::type_complexity)]
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        u: &Bound<'py, PyAny>,
        y: &Bound<'py, PyAny>,
        received: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<(
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<bool>>,
    )> {
        let u = vector("u", u, None)?;
        let yv = vector_with_nan("y", y, None)?;
        same_len(("u", u.len()), ("y", yv.len()))?;
        let mask: Vec<bool> = match received {
            None => vec![true; yv.len()],
            Some(r) => {
                let m = bool_vector("received", r)?;
                same_len(("u", u.len()), ("received", m.len()))?;
                m
            }
        };
        if let Some(i) = (0..yv.len()).find(|&i| mask[i] && !yv[i].is_finite()) {
            return Err(PyValueError::new_err(format!(
                "y[{i}] is {}: expected finite numbers where a sample was received \
                 (mark missing samples False in `received`)",
                yv[i]
            )));
        }
        let mut work = self.inner.clone();
        let out = py.detach(|| {
            let n = u.len();
            let (mut e, mut p, mut m) = (
                Vec::with_capacity(n),
                Vec::with_capacity(n),
                Vec::with_capacity(n),
            );
            for k in 0..n {
                let yk = mask[k].then_some(yv[k]);
                let est = work.step(u[k], yk).map_err(|err| (k, err))?;
                e.push(est.x3e);
                p.push(est.x3p);
                m.push(est.from_model);
            }
            Ok((e, p, m))
        });
        let (e, p, m) = out.map_err(|(k, err): (usize, EstimatorError)| {
            PyValueError::new_err(format!("tick {k}: {err} (nothing was changed)"))
        })?;
        self.inner = work;
        Ok((array1(py, e), array1(py, p), PyArray1::from_vec(py, m)))
    }

    /// The model in use (identified or fixed).
    #[getter]
    fn model(&self) -> PyTf2 {
        PyTf2 {
            tf: self.inner.model(),
            dt: self.dt,
        }
    }

    /// `(num, den, dt)` of the model in use, scipy.signal's convention.
    fn to_tf<'py>(&self, py: Python<'py>) -> PyTf<'py> {
        to_tf(py, &self.inner.model(), self.dt)
    }

    /// A copy of the identifier, or None with a fixed model.
    #[getter]
    fn arx(&self) -> Option<PyArx2> {
        self.inner.arx().map(|a| PyArx2 {
            arx: a.clone(),
            dt: self.dt,
        })
    }

    /// Whether the model is being identified (no fixed model was given).
    #[getter]
    fn is_identifying(&self) -> bool {
        self.inner.arx().is_some()
    }

    /// `(delay_fwd, delay_bwd)` in ticks; assigning new delays restarts the anchoring.
    #[getter]
    fn delays(&self) -> (usize, usize) {
        self.inner.delays()
    }

    #[setter]
    fn set_delays(&mut self, delays: (Bound<'_, PyAny>, Bound<'_, PyAny>)) -> PyResult<()> {
        let df = count("delay_fwd", &delays.0, 0, ESTIMATOR_HISTORY)?;
        let db = count("delay_bwd", &delays.1, 0, ESTIMATOR_HISTORY)?;
        self.inner.set_delays(df, db).map_err(estimator_error)
    }

    /// The sampling period in seconds.
    #[getter]
    fn dt(&self) -> f64 {
        self.dt
    }

    /// Ticks stepped so far.
    #[getter]
    fn ticks(&self) -> u64 {
        self.inner.ticks()
    }

    /// The last state sample received, or None.
    #[getter]
    fn last_received(&self) -> Option<f64> {
        self.inner.last_received()
    }

    /// Forgets the command history and anchors, keeping the model.
    fn reset(&mut self) {
        self.inner.reset();
    }

    /// Restarts identification from a zero model.
    fn reset_identification(&mut self) {
        self.inner.reset_identification();
    }

    fn __repr__(&self) -> String {
        let (df, db) = self.inner.delays();
        format!(
            "Estimator(delay_fwd={df}, delay_bwd={db}, dt={}, identifying={}, ticks={})",
            self.dt,
            self.inner.arx().is_some(),
            self.inner.ticks()
        )
    }
}

/// A 1-D array of booleans.
fn bool_vector(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<Vec<bool>> {
    use numpy::{PyArrayDescrMethods, PyArrayMethods, PyUntypedArrayMethods};
    let expected = format!("{name}: expected a 1-D array of bool of shape (n,)");
    let a = obj
        .py()
        .import("numpy")?
        .getattr("asarray")?
        .call1((obj,))
        .map_err(|e| PyValueError::new_err(format!("{expected} ({e})")))?;
    let untyped = a
        .cast::<numpy::PyUntypedArray>()
        .map_err(|_| PyValueError::new_err(expected.clone()))?;
    if untyped.dtype().kind() != b'b' || untyped.ndim() != 1 {
        return Err(PyValueError::new_err(format!(
            "{expected}, got dtype {} with {} axes",
            untyped.dtype(),
            untyped.ndim()
        )));
    }
    let arr = a
        .cast_into::<numpy::PyArrayDyn<bool>>()
        .map_err(|_| PyValueError::new_err(expected.clone()))?;
    let ro = arr
        .try_readonly()
        .map_err(|e| PyValueError::new_err(format!("{name}: cannot be read now ({e})")))?;
    Ok(ro.as_array().iter().copied().collect())
}
