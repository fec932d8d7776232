//! `ndr.Rls` (padasip's names) over the core's const-generic `Rls<P>`, sizes
//! 1 to 8, and the batch `ndr.rls_filter`.

use ndr_core::{Rls, RlsError};
use numpy::{PyArray1, PyArray2};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert::{
    array1, array2, count, finite, matrix, same_len, sample, value_error, vector,
};

/// The largest regressor an `ndr.Rls` takes.
pub const MAX_WEIGHTS: usize = 8;

/// Outputs, errors and weights of a run.
type Series = (Vec<f64>, Vec<f64>, Vec<f64>);

#[derive(Clone)]
enum AnyRls {
    R1(Rls<1>),
    R2(Rls<2>),
    R3(Rls<3>),
    R4(Rls<4>),
    R5(Rls<5>),
    R6(Rls<6>),
    R7(Rls<7>),
    R8(Rls<8>),
}

/// Runs `$body` with `$r` bound to the filter of whatever size it is.
macro_rules! with_rls {
    ($any:expr, $r:ident => $body:expr) => {
        match $any {
            AnyRls::R1($r) => $body,
            AnyRls::R2($r) => $body,
            AnyRls::R3($r) => $body,
            AnyRls::R4($r) => $body,
            AnyRls::R5($r) => $body,
            AnyRls::R6($r) => $body,
            AnyRls::R7($r) => $body,
            AnyRls::R8($r) => $body,
        }
    };
}

/// Why an update did not happen.
enum UpdateError {
    /// The regressor does not have `n` entries.
    Len { got: usize, want: usize },
    /// The core refused it.
    Core(RlsError),
}

impl From<RlsError> for UpdateError {
    fn from(e: RlsError) -> Self {
        UpdateError::Core(e)
    }
}

impl std::fmt::Display for UpdateError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            UpdateError::Len { got, want } => {
                write!(f, "expected {want} values, got {got}")
            }
            UpdateError::Core(e) => e.fmt(f),
        }
    }
}

impl AnyRls {
    fn new(n: usize, lambda: f64, delta: f64) -> Result<Self, RlsError> {
        Ok(match n {
            1 => AnyRls::R1(Rls::new(lambda, delta)?),
            2 => AnyRls::R2(Rls::new(lambda, delta)?),
            3 => AnyRls::R3(Rls::new(lambda, delta)?),
            4 => AnyRls::R4(Rls::new(lambda, delta)?),
            5 => AnyRls::R5(Rls::new(lambda, delta)?),
            6 => AnyRls::R6(Rls::new(lambda, delta)?),
            7 => AnyRls::R7(Rls::new(lambda, delta)?),
            _ => AnyRls::R8(Rls::new(lambda, delta)?),
        })
    }

    fn n(&self) -> usize {
        with_rls!(self, r => r.weights().len())
    }

    fn update(&mut self, x: &[f64], d: f64) -> Result<f64, UpdateError> {
        with_rls!(self, r => {
            let want = r.weights().len();
            let x = x.try_into().map_err(|_| UpdateError::Len { got: x.len(), want })?;
            Ok(r.update(x, d)?)
        })
    }

    fn predict(&self, x: &[f64]) -> f64 {
        with_rls!(self, r => match x.try_into() {
            Ok(x) => r.predict(x),
            Err(_) => f64::NAN,
        })
    }

    fn weights(&self) -> Vec<f64> {
        with_rls!(self, r => r.weights().to_vec())
    }

    fn set_weights(&mut self, w: &[f64]) -> Result<(), UpdateError> {
        with_rls!(self, r => {
            let want = r.weights().len();
            let w = w.try_into().map_err(|_| UpdateError::Len { got: w.len(), want })?;
            Ok(r.set_weights(w)?)
        })
    }

    fn covariance(&self) -> Vec<f64> {
        with_rls!(self, r => {
            let p = r.covariance();
            let n = p.nrows();
            let mut v = Vec::with_capacity(n * n);
            for i in 0..n {
                for j in 0..n {
                    v.push(p[(i, j)]);
                }
            }
            v
        })
    }

    /// padasip's `run`: per sample, the output before adapting, the a-priori
    /// error, and the weights used; stops at the first failed update.
    fn run(&mut self, d: &[f64], x: &[f64]) -> Result<Series, (usize, UpdateError)> {
        with_rls!(self, r => run_fixed(r, d, x))
    }
}

/// [`AnyRls::run`] for one size, with no dispatch or allocation per sample.
fn run_fixed<const P: usize>(
    r: &mut Rls<P>,
    d: &[f64],
    x: &[f64],
) -> Result<Series, (usize, UpdateError)> {
    let mut y = Vec::with_capacity(d.len());
    let mut e = Vec::with_capacity(d.len());
    let mut w = Vec::with_capacity(d.len() * P);
    for (k, (&dk, xk)) in d.iter().zip(x.chunks_exact(P)).enumerate() {
        let xk: &[f64; P] = xk.try_into().map_err(|_| {
            (
                k,
                UpdateError::Len {
                    got: xk.len(),
                    want: P,
                },
            )
        })?;
        w.extend_from_slice(r.weights());
        y.push(r.predict(xk));
        e.push(r.update(xk, dk).map_err(|err| (k, err.into()))?);
    }
    Ok((y, e, w))
}

type RunOutput<'py> = (
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray2<f64>>,
);

/// Recursive least squares with exponential forgetting, padasip's names:
/// `adapt(d, x)`, `predict(x)`, `w`.
#[pyclass(module = "ndr", name = "Rls")]
#[derive(Clone)]
pub struct PyRls {
    inner: AnyRls,
}

impl PyRls {
    /// `run` on a regressor matrix already read (`rows × n`, row-major).
    fn run_values<'py>(
        &mut self,
        py: Python<'py>,
        d: &Bound<'py, PyAny>,
        x: &[f64],
        rows: usize,
    ) -> PyResult<RunOutput<'py>> {
        let n = self.inner.n();
        let d = vector("d", d, None)?;
        same_len(("d", d.len()), ("x", rows))?;
        let mut work = self.inner.clone();
        let out = py.detach(|| work.run(&d, x));
        let (y, e, w) = out.map_err(|(k, err)| {
            PyValueError::new_err(format!("sample {k}: {err} (the filter is unchanged)"))
        })?;
        self.inner = work;
        Ok((array1(py, y), array1(py, e), array2(py, w, rows, n)?))
    }
}

#[pymethods]
impl PyRls {
    #[new]
    #[pyo3(signature = (n, *, lam = 0.99, delta = 1000.0, trace_bound = None))]
    fn new(n: &Bound<'_, PyAny>, lam: f64, delta: f64, trace_bound: Option<f64>) -> PyResult<Self> {
        let n = count("n", n, 1, MAX_WEIGHTS)?;
        let mut inner = AnyRls::new(n, lam, delta).map_err(value_error)?;
        if let Some(b) = trace_bound {
            with_rls!(&mut inner, r => r.set_trace_bound(b)).map_err(value_error)?;
        }
        Ok(PyRls { inner })
    }

    /// Adapts the weights to one sample: desired value `d`, regressor `x`
    /// (shape `(n,)`, or a number when n is 1). Returns the a-priori error
    /// `d − w·x`.
    fn adapt(&mut self, d: f64, x: &Bound<'_, PyAny>) -> PyResult<f64> {
        let d = finite("d", d)?;
        let x = sample("x", x, self.inner.n())?;
        self.inner.update(&x, d).map_err(value_error)
    }

    /// The model's output `w·x`.
    fn predict(&self, x: &Bound<'_, PyAny>) -> PyResult<f64> {
        let x = sample("x", x, self.inner.n())?;
        Ok(self.inner.predict(&x))
    }

    /// Filters a whole series (padasip's `run`): `d` shape `(N,)`, `x` shape
    /// `(N, n)`. Returns `(y, e, w)`: outputs before each adaptation `(N,)`,
    /// a-priori errors `(N,)`, and the weights used for each sample `(N, n)`.
    /// If an update fails the filter is left as it was and ValueError is raised.
    #[allow(clippy::type_complexity)]
    fn run<'py>(
        &mut self,
        py: Python<'py>,
        d: &Bound<'py, PyAny>,
        x: &Bound<'py, PyAny>,
    ) -> PyResult<RunOutput<'py>> {
        let (x, rows, _) = matrix("x", x, None, Some(self.inner.n()))?;
        self.run_values(py, d, &x, rows)
    }

    /// The weights, shape `(n,)` (a copy; assign to change them).
    #[getter]
    fn w<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        array1(py, self.inner.weights())
    }

    #[setter]
    fn set_w(&mut self, w: &Bound<'_, PyAny>) -> PyResult<()> {
        let w = vector("w", w, Some(self.inner.n()))?;
        self.inner.set_weights(&w).map_err(value_error)
    }

    /// The covariance, shape `(n, n)`.
    #[getter(P)]
    fn p<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let n = self.inner.n();
        array2(py, self.inner.covariance(), n, n)
    }

    /// The number of weights.
    #[getter]
    fn n(&self) -> usize {
        self.inner.n()
    }

    /// The forgetting factor λ in (0, 1].
    #[getter]
    fn lam(&self) -> f64 {
        with_rls!(&self.inner, r => r.lambda())
    }

    #[setter]
    fn set_lam(&mut self, lam: f64) -> PyResult<()> {
        with_rls!(&mut self.inner, r => r.set_lambda(lam)).map_err(value_error)
    }

    /// The initial covariance scale δ (`P` starts and resets at `δ·I`).
    #[getter]
    fn delta(&self) -> f64 {
        with_rls!(&self.inner, r => r.delta())
    }

    /// The bound on `trace(P)` above which the covariance is reset to `δ·I`.
    #[getter]
    fn trace_bound(&self) -> f64 {
        with_rls!(&self.inner, r => r.trace_bound())
    }

    #[setter]
    fn set_trace_bound(&mut self, bound: f64) -> PyResult<()> {
        with_rls!(&mut self.inner, r => r.set_trace_bound(bound)).map_err(value_error)
    }

    /// Successful adaptations so far.
    #[getter]
    fn updates(&self) -> u64 {
        with_rls!(&self.inner, r => r.updates())
    }

    /// Automatic covariance resets (wind-up guard or lost definiteness).
    #[getter]
    fn covariance_resets(&self) -> u64 {
        with_rls!(&self.inner, r => r.covariance_resets())
    }

    /// Resets `P` to `δ·I`, keeping the weights.
    fn reset_covariance(&mut self) {
        with_rls!(&mut self.inner, r => r.reset_covariance());
    }

    /// Back to zero weights, `P = δ·I`, counters at zero.
    fn reset(&mut self) {
        with_rls!(&mut self.inner, r => r.reset());
    }

    fn __copy__(&self) -> Self {
        self.clone()
    }

    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> Self {
        self.clone()
    }

    fn __repr__(&self) -> String {
        format!(
            "Rls(n={}, lam={}, delta={}, w={:?})",
            self.inner.n(),
            self.lam(),
            self.delta(),
            self.inner.weights()
        )
    }
}

/// Runs a fresh `Rls(x.shape[1], lam=lam, delta=delta)` over `(d, x)`;
/// returns `(y, e, w)` as `Rls.run`.
#[pyfunction]
#[pyo3(signature = (d, x, *, lam = 0.99, delta = 1000.0))]
pub fn rls_filter<'py>(
    py: Python<'py>,
    d: &Bound<'py, PyAny>,
    x: &Bound<'py, PyAny>,
    lam: f64,
    delta: f64,
) -> PyResult<RunOutput<'py>> {
    let (xv, rows, n) = matrix("x", x, None, None)?;
    if !(1..=MAX_WEIGHTS).contains(&n) {
        return Err(PyValueError::new_err(format!(
            "x: expected a 2-D array of shape (N, n) with 1 <= n <= {MAX_WEIGHTS} regressors, \
             got n = {n}"
        )));
    }
    let inner = AnyRls::new(n, lam, delta).map_err(value_error)?;
    PyRls { inner }.run_values(py, d, &xv, rows)
}

impl PyRls {
    /// A Python `Rls` holding a copy of an identifier's filter.
    pub(crate) fn from_rls5(r: Rls<5>) -> Self {
        PyRls {
            inner: AnyRls::R5(r),
        }
    }
}
