//! `ndr.Kalman3`, `ndr.NetworkPredictor` and the batch `ndr.kalman3_filter`.

use ndr_core::{Envelope, Sizing};
use ndr_core::{Kalman3, KalmanModel};
use ndr_core::{NetworkPredictor, Prediction, PredictorConfig};
use numpy::{PyArray1, PyArray2};
use pyo3::prelude::*;

use crate::convert::{
    array_of, array1, array2, count, mat3, matrix, period, read_only, row, seconds, single,
    value_error, vector,
};

/// The largest horizon accepted, in periods.
const MAX_HORIZON: usize = 1_000_000;

/// The horizon given, or `paper`'s (50 periods).
fn horizon_arg(horizon: Option<&Bound<'_, PyAny>>, paper: &PredictorConfig) -> PyResult<u32> {
    match horizon {
        // MAX_HORIZON fits a u32.
        Some(h) => Ok(u32::try_from(count("horizon", h, 0, MAX_HORIZON)?).unwrap_or(u32::MAX)),
        None => Ok(paper.horizon),
    }
}

/// A `(3, 3)` matrix from Python, row-major, into `m` (finite values only).
fn set_mat3<M>(name: &str, obj: &Bound<'_, PyAny>, mut m: M) -> PyResult<M>
where
    M: core::ops::IndexMut<(usize, usize), Output = f64>,
{
    let (v, _, _) = matrix(name, obj, Some(3), Some(3))?;
    for (k, value) in v.into_iter().enumerate() {
        m[(k / 3, k % 3)] = value;
    }
    Ok(m)
}

/// The paper's triple-integrator Kalman filter, with filterpy's names.
#[pyclass(module = "ndr", name = "Kalman3")]
#[derive(Clone)]
pub struct PyKalman3 {
    pub(crate) inner: Kalman3,
    y: f64,
}

impl PyKalman3 {
    /// Changes one part of the model; the filter refuses a model with a
    /// value that is not finite, or `R` not positive, and keeps its own.
    fn set_model(&mut self, change: impl FnOnce(&mut KalmanModel) -> PyResult<()>) -> PyResult<()> {
        let mut model = *self.inner.model();
        change(&mut model)?;
        self.inner.set_model(model).map_err(value_error)
    }

    fn run_values(&mut self, z: &[f64]) -> (Vec<f64>, Vec<f64>) {
        let mut xs = Vec::with_capacity(z.len() * 3);
        let mut ahead = Vec::with_capacity(z.len());
        for &zk in z {
            // z was checked finite: the step cannot fail.
            self.inner.predict();
            if let Ok(e) = self.inner.update(zk) {
                self.y = e;
            }
            xs.extend_from_slice(self.inner.x().as_slice());
            ahead.push(self.inner.predict_ahead());
        }
        (xs, ahead)
    }
}

#[pymethods]
impl PyKalman3 {
    #[new]
    #[pyo3(
        signature = (period, *, sigma_q = 1.0, horizon = None),
        text_signature = "(period, *, sigma_q=1.0, horizon=50)"
    )]
    fn new(period: f64, sigma_q: f64, horizon: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let period = crate::convert::period("period", period)?;
        let horizon = horizon_arg(horizon, &PredictorConfig::paper(period))?;
        let inner = Kalman3::new(sigma_q, period, horizon).map_err(value_error)?;
        Ok(PyKalman3 { inner, y: 0.0 })
    }

    /// Time update: `x ← F·x`, `P ← F·P·Fᵀ + Q`.
    fn predict(&mut self) {
        self.inner.predict();
    }

    /// Measurement update with the scalar `z`; returns the innovation
    /// `z − H·x` (also kept as `y`).
    fn update(&mut self, z: f64) -> PyResult<f64> {
        let e = self.inner.update(z).map_err(value_error)?;
        self.y = e;
        Ok(e)
    }

    /// `predict()` then `update(z)`; returns the filtered value `x[0]`.
    fn step(&mut self, z: f64) -> PyResult<f64> {
        if !z.is_finite() {
            return Err(value_error(format_args!(
                "Kalman input {z} is not finite; the filter is unchanged"
            )));
        }
        self.inner.predict();
        self.update(z)?;
        Ok(self.inner.value())
    }

    /// Filters a whole series: a `step` per sample. Returns `(x, ahead)`: the
    /// states after each step, shape `(n, 3)`, and the value predicted
    /// `horizon` periods ahead after each step, shape `(n,)`.
    #[allow(clippy::type_complexity)]
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        z: &Bound<'py, PyAny>,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>)> {
        let z = vector("z", z, None)?;
        let n = z.len();
        let (xs, ahead) = py.detach(|| self.run_values(&z));
        Ok((array2(py, xs, n, 3)?, array1(py, ahead)))
    }

    /// The value predicted `horizon` periods ahead, `H·F^l·x`.
    fn predict_ahead(&self) -> f64 {
        self.inner.predict_ahead()
    }

    /// The whole state predicted `horizon` periods ahead, `F^l·x`.
    fn predict_ahead_state<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let ahead = self.inner.a_ahead() * self.inner.x();
        PyArray1::from_slice(py, ahead.as_slice())
    }

    /// Back to state zero and `P = sigma_q²·I`.
    fn reset(&mut self) {
        self.inner.reset();
        self.y = 0.0;
    }

    /// The state `[value, rate, acceleration]`, shape `(3,)`: a read-only
    /// copy (`kf.x[0] = 5` raises); assign the whole state to change it.
    #[getter]
    fn x<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        read_only(PyArray1::from_slice(py, self.inner.x().as_slice()))
    }

    #[setter]
    fn set_x(&mut self, x: &Bound<'_, PyAny>) -> PyResult<()> {
        let v: [f64; 3] = array_of("x", x)?;
        let mut state = *self.inner.x();
        for (s, v) in state.iter_mut().zip(v) {
            *s = v;
        }
        self.inner
            .set_state(state, *self.inner.p())
            .map_err(value_error)
    }

    /// The filtered value `x[0]`.
    #[getter]
    fn value(&self) -> f64 {
        self.inner.value()
    }

    /// The last innovation `z − H·x` (filterpy's `y`), 0 before the first update.
    #[getter]
    fn y(&self) -> f64 {
        self.y
    }

    /// The state covariance, shape `(3, 3)` (read-only copy; assignable).
    #[getter(P)]
    fn p<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        read_only(mat3(py, self.inner.p())?)
    }

    #[setter(P)]
    fn set_p(&mut self, value: &Bound<'_, PyAny>) -> PyResult<()> {
        let p = set_mat3("P", value, *self.inner.p())?;
        self.inner
            .set_state(*self.inner.x(), p)
            .map_err(value_error)
    }

    /// The transition matrix, `[[1, T, T²/2], [0, 1, T], [0, 0, 1]]` unless
    /// assigned, shape `(3, 3)` (read-only copy; assignable).
    #[getter(F)]
    fn f<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        read_only(mat3(py, &self.inner.model().a)?)
    }

    #[setter(F)]
    fn set_f(&mut self, value: &Bound<'_, PyAny>) -> PyResult<()> {
        self.set_model(|m| {
            m.a = set_mat3("F", value, m.a)?;
            Ok(())
        })
    }

    /// The paper's name for `F`.
    #[getter(A)]
    fn a<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        self.f(py)
    }

    #[setter(A)]
    fn set_a(&mut self, value: &Bound<'_, PyAny>) -> PyResult<()> {
        self.set_model(|m| {
            m.a = set_mat3("A", value, m.a)?;
            Ok(())
        })
    }

    /// `F` to the power `horizon`, shape `(3, 3)` (read-only).
    #[getter(F_ahead)]
    fn f_ahead<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        read_only(mat3(py, self.inner.a_ahead())?)
    }

    /// The measurement matrix, `[[1, 0, 0]]` unless assigned, shape `(1, 3)`
    /// (read-only copy; assignable as `(1, 3)` or `(3,)`).
    #[getter(H)]
    fn h<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        read_only(array2(py, self.inner.model().h.as_slice().to_vec(), 1, 3)?)
    }

    #[setter(H)]
    fn set_h(&mut self, value: &Bound<'_, PyAny>) -> PyResult<()> {
        let v = row("H", value, 3)?;
        self.set_model(|m| {
            for (slot, v) in m.h.iter_mut().zip(v) {
                *slot = v;
            }
            Ok(())
        })
    }

    /// The process noise, `diag(0, 0, sigma_q²)` unless assigned, shape
    /// `(3, 3)` (read-only copy; assignable).
    #[getter(Q)]
    fn q<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        read_only(mat3(py, &self.inner.model().q)?)
    }

    #[setter(Q)]
    fn set_q(&mut self, value: &Bound<'_, PyAny>) -> PyResult<()> {
        self.set_model(|m| {
            m.q = set_mat3("Q", value, m.q)?;
            Ok(())
        })
    }

    /// The measurement noise, `[[sigma_q²]]` unless assigned, shape `(1, 1)`
    /// (read-only copy; assignable as a number or `(1, 1)`).
    #[getter(R)]
    fn r<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        read_only(array2(py, vec![self.inner.model().r], 1, 1)?)
    }

    #[setter(R)]
    fn set_r(&mut self, value: &Bound<'_, PyAny>) -> PyResult<()> {
        self.set_model(|m| {
            m.r = single("R", value)?;
            Ok(())
        })
    }

    /// The noise level σQ given at construction (`P0 = sigma_q²·I`).
    #[getter]
    fn sigma_q(&self) -> f64 {
        self.inner.sigma_q()
    }

    /// The period `T` in seconds; setting it keeps the estimate.
    #[getter]
    fn period(&self) -> f64 {
        self.inner.period().as_secs_f64()
    }

    #[setter]
    fn set_period(&mut self, value: f64) -> PyResult<()> {
        let p = period("period", value)?;
        self.inner.set_period(p).map_err(value_error)
    }

    /// The prediction horizon, in periods.
    #[getter]
    fn horizon(&self) -> u32 {
        self.inner.horizon()
    }

    fn __copy__(&self) -> Self {
        self.clone()
    }

    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> Self {
        self.clone()
    }

    fn __repr__(&self) -> String {
        let x = self.inner.x();
        format!(
            "Kalman3(period={}, sigma_q={}, horizon={}, x=[{}, {}, {}])",
            self.period(),
            self.sigma_q(),
            self.inner.horizon(),
            x[0],
            x[1],
            x[2]
        )
    }
}

/// Filters `z` with a fresh `Kalman3`; returns `(x, ahead)` as `Kalman3.run`.
#[pyfunction]
#[pyo3(
    signature = (z, *, period, sigma_q = 1.0, horizon = None, x0 = None),
    text_signature = "(z, *, period, sigma_q=1.0, horizon=50, x0=None)"
)]
#[allow(clippy::type_complexity)]
pub fn kalman3_filter<'py>(
    py: Python<'py>,
    z: &Bound<'py, PyAny>,
    period: f64,
    sigma_q: f64,
    horizon: Option<&Bound<'py, PyAny>>,
    x0: Option<&Bound<'py, PyAny>>,
) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>)> {
    let mut k = PyKalman3::new(period, sigma_q, horizon)?;
    if let Some(x0) = x0 {
        k.set_x(x0)?;
    }
    k.run(py, z)
}

/// One step of the network predictor; times in seconds.
#[pyclass(module = "ndr", name = "Prediction", frozen, get_all)]
#[derive(Clone, Copy)]
pub struct PyPrediction {
    /// Measured mean NRTT (the low-passed samples).
    nrtt_mean: f64,
    /// Measured `mt` (the low-passed envelope of the gaps).
    mt: f64,
    /// Mean NRTT predicted `horizon` periods ahead, smoothed.
    nrtt_ahead: f64,
    /// `mt` predicted `horizon` periods ahead, smoothed.
    mt_ahead: f64,
    /// The period the paper's law would choose.
    period: f64,
    /// The nominal size the paper's law would choose at that period.
    ns: usize,
}

impl From<Prediction> for PyPrediction {
    fn from(p: Prediction) -> Self {
        PyPrediction {
            nrtt_mean: p.nrtt_mean,
            mt: p.mt,
            nrtt_ahead: p.nrtt_ahead,
            mt_ahead: p.mt_ahead,
            period: p.period.as_secs_f64(),
            ns: p.ns,
        }
    }
}

#[pymethods]
impl PyPrediction {
    fn __repr__(&self) -> String {
        format!(
            "Prediction(nrtt_mean={}, mt={}, nrtt_ahead={}, mt_ahead={}, period={}, ns={})",
            self.nrtt_mean, self.mt, self.nrtt_ahead, self.mt_ahead, self.period, self.ns
        )
    }

    fn __eq__(&self, other: &Bound<'_, PyAny>) -> bool {
        other.cast::<PyPrediction>().is_ok_and(|o| {
            let o = o.get();
            (o.nrtt_mean, o.mt, o.nrtt_ahead, o.mt_ahead, o.period, o.ns)
                == (
                    self.nrtt_mean,
                    self.mt,
                    self.nrtt_ahead,
                    self.mt_ahead,
                    self.period,
                    self.ns,
                )
        })
    }
}

/// The paper's two-channel network predictor.
#[pyclass(module = "ndr", name = "NetworkPredictor")]
pub struct PyNetworkPredictor {
    inner: NetworkPredictor,
}

#[pymethods]
impl PyNetworkPredictor {
    #[new]
    #[pyo3(
        signature = (
            period, *, horizon = None, nrtt_tau = 250.0, mt_tau = 25.0, ahead_tau = 50.0,
            decay = Envelope::default().decay(), sigma_q = 1.0, eta = Sizing::default().eta(),
            min_period = 0.05
        ),
        text_signature = "(period, *, horizon=50, nrtt_tau=250.0, mt_tau=25.0, \
                          ahead_tau=50.0, decay=1.00005, sigma_q=1.0, eta=1.3, min_period=0.05)"
    )]
    #[allow(clippy::too_many_arguments)]
    fn new(
        period: f64,
        horizon: Option<&Bound<'_, PyAny>>,
        nrtt_tau: f64,
        mt_tau: f64,
        ahead_tau: f64,
        decay: f64,
        sigma_q: f64,
        eta: f64,
        min_period: f64,
    ) -> PyResult<Self> {
        let mut cfg = PredictorConfig::paper(crate::convert::period("period", period)?);
        cfg.horizon = horizon_arg(horizon, &cfg)?;
        for (name, tau) in [
            ("nrtt_tau", nrtt_tau),
            ("mt_tau", mt_tau),
            ("ahead_tau", ahead_tau),
        ] {
            if !(tau.is_finite() && tau >= 0.0) {
                return Err(value_error(format_args!(
                    "{name} must be a finite, non-negative number of periods, got {tau}"
                )));
            }
        }
        cfg.nrtt_tau = nrtt_tau;
        cfg.mt_tau = mt_tau;
        cfg.ahead_tau = ahead_tau;
        cfg.decay = decay;
        cfg.sigma_q = sigma_q;
        cfg.sizing = Sizing::new(eta, seconds("min_period", min_period)?).map_err(value_error)?;
        Ok(PyNetworkPredictor {
            inner: NetworkPredictor::new(cfg).map_err(value_error)?,
        })
    }

    /// A round trip was measured (seconds).
    fn observe_nrtt(&mut self, nrtt: f64) -> PyResult<()> {
        self.inner.observe_nrtt(seconds("nrtt", nrtt)?);
        Ok(())
    }

    /// A frame arrived `gap` seconds later than its schedule relative to the previous one.
    fn observe_gap(&mut self, gap: f64) -> PyResult<()> {
        self.inner.observe_gap(seconds("gap", gap)?);
        Ok(())
    }

    /// Runs the filters one period; None until one NRTT and one gap were observed.
    fn step(&mut self) -> Option<PyPrediction> {
        self.inner.step().map(Into::into)
    }

    /// Observes what is given, then steps.
    #[pyo3(signature = (nrtt = None, gap = None))]
    fn update(&mut self, nrtt: Option<f64>, gap: Option<f64>) -> PyResult<Option<PyPrediction>> {
        // Both checked before either is observed: an error changes nothing.
        let nrtt = nrtt.map(|v| seconds("nrtt", v)).transpose()?;
        let gap = gap.map(|v| seconds("gap", v)).transpose()?;
        if let Some(n) = nrtt {
            self.inner.observe_nrtt(n);
        }
        if let Some(g) = gap {
            self.inner.observe_gap(g);
        }
        Ok(self.step())
    }

    /// The latest prediction, or None.
    #[getter]
    fn last(&self) -> Option<PyPrediction> {
        self.inner.last().map(Into::into)
    }

    /// Periods stepped so far.
    #[getter]
    fn steps(&self) -> u64 {
        self.inner.steps()
    }

    /// The period in seconds; setting it keeps what was learnt.
    #[getter]
    fn period(&self) -> f64 {
        self.inner.config().period.as_secs_f64()
    }

    #[setter]
    fn set_period(&mut self, value: f64) -> PyResult<()> {
        let p = period("period", value)?;
        self.inner.set_period(p).map_err(value_error)
    }

    /// The prediction horizon, in periods.
    #[getter]
    fn horizon(&self) -> u32 {
        self.inner.config().horizon
    }

    /// A copy of the Kalman filter of the mean NRTT.
    #[getter]
    fn nrtt_filter(&self) -> PyKalman3 {
        PyKalman3 {
            inner: self.inner.nrtt_filter().clone(),
            y: 0.0,
        }
    }

    /// A copy of the Kalman filter of `mt`.
    #[getter]
    fn mt_filter(&self) -> PyKalman3 {
        PyKalman3 {
            inner: self.inner.mt_filter().clone(),
            y: 0.0,
        }
    }

    fn __repr__(&self) -> String {
        format!(
            "NetworkPredictor(period={}, horizon={}, steps={})",
            self.period(),
            self.horizon(),
            self.inner.steps()
        )
    }
}
