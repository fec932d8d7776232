//! Conversions between Python values and the core's types, and error mapping.
//!
//! Every check names what was expected, so a wrong shape, dtype, number of
//! axes, a NaN or an out-of-range count is a `ValueError` that says how to
//! call the function, never a panic.

use core::fmt::Display;

use ndr_core::time::Duration;
use numpy::ndarray::Array2;
use numpy::{
    PyArray1, PyArray2, PyArrayDescrMethods, PyArrayDyn, PyArrayMethods, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyOverflowError, PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::{PyDict, PyTuple};
use serde_json::Value;

/// A `ValueError` carrying the core's message.
pub fn value_error(e: impl Display) -> PyErr {
    PyValueError::new_err(e.to_string())
}

/// A number as a message shows it: in scientific notation when very large
/// or very small (`1e300`, not 301 digits; `1e-10`, not ten zeros), as
/// written otherwise.
pub fn shown(value: f64) -> String {
    let size = value.abs();
    if value.is_finite() && (size >= 1e15 || (size > 0.0 && size < 1e-4)) {
        format!("{value:e}")
    } else {
        format!("{value}")
    }
}

/// A duration in seconds from Python, refusing what cannot be one.
pub fn seconds(name: &str, value: f64) -> PyResult<Duration> {
    if !value.is_finite() || value < 0.0 {
        return Err(PyValueError::new_err(format!(
            "{name} must be a finite, non-negative number of seconds, got {}",
            shown(value)
        )));
    }
    if value > u64::MAX as f64 / 1e9 {
        return Err(PyValueError::new_err(format!(
            "{name} = {} s is too long: durations are integer nanoseconds up to about 584 years",
            shown(value)
        )));
    }
    Ok(Duration::from_secs_f64(value))
}

/// A positive duration in seconds (a period).
pub fn period(name: &str, value: f64) -> PyResult<Duration> {
    let d = seconds(name, value)?;
    if d.is_zero() {
        return Err(PyValueError::new_err(format!(
            "{name} must be a positive number of seconds (at least 1 ns), got {}",
            shown(value)
        )));
    }
    Ok(d)
}

/// A finite float.
pub fn finite(name: &str, value: f64) -> PyResult<f64> {
    if value.is_finite() {
        Ok(value)
    } else {
        Err(PyValueError::new_err(format!(
            "{name} must be a finite number, got {}",
            shown(value)
        )))
    }
}

/// An integer in `min..=max`, from any Python int; out of range (even beyond
/// 64 bits) is a `ValueError`, a non-integer a `TypeError`.
pub fn count(name: &str, obj: &Bound<'_, PyAny>, min: usize, max: usize) -> PyResult<usize> {
    int_in(name, obj, min, max)
}

/// An integer of type `T` in `min..=max`, from any Python int: a negative or
/// too large one (even beyond 128 bits) is a `ValueError` naming `name` and
/// the range (`"axes must be an integer from 1 to 256, got -1"`), a
/// non-integer a `TypeError`. Take unsigned parameters (axes, seeds, sizes)
/// this way, or as `i128` checked by [`in_range`], rather than as `u16`,
/// `u64` or `usize`, whose refusal is pyo3's `OverflowError` naming no
/// parameter.
pub fn int_in<T>(name: &str, obj: &Bound<'_, PyAny>, min: T, max: T) -> PyResult<T>
where
    T: Copy + Display + TryFrom<i128>,
    i128: TryFrom<T>,
{
    match obj.extract::<i128>() {
        Ok(v) => in_range(name, v, min, max),
        Err(e) if e.is_instance_of::<PyOverflowError>(obj.py()) => Err(PyValueError::new_err(
            format!("{}, got {obj}", expected_int(name, min, max)),
        )),
        Err(_) => {
            let ty = obj.get_type().name()?;
            Err(PyTypeError::new_err(format!(
                "{}, got an object of type {ty}",
                expected_int(name, min, max)
            )))
        }
    }
}

/// `v` as a `T` in `min..=max`, else a `ValueError` naming `name` and the
/// range (for a parameter taken as `i128`, e.g. one with a default).
pub fn in_range<T>(name: &str, v: i128, min: T, max: T) -> PyResult<T>
where
    T: Copy + Display + TryFrom<i128>,
    i128: TryFrom<T>,
{
    match T::try_from(v) {
        Ok(t) if (wide(min)..=wide(max)).contains(&v) => Ok(t),
        _ => Err(PyValueError::new_err(format!(
            "{}, got {v}",
            expected_int(name, min, max)
        ))),
    }
}

fn wide<T>(x: T) -> i128
where
    i128: TryFrom<T>,
{
    i128::try_from(x).unwrap_or(i128::MAX)
}

/// "`name` must be an integer from `min` to `max`" (`2**64 - 1` for the
/// largest `u64`).
fn expected_int<T>(name: &str, min: T, max: T) -> String
where
    T: Copy + Display,
    i128: TryFrom<T>,
{
    if wide(max) == i128::from(u64::MAX) {
        format!("{name} must be an integer from {min} to 2**64 - 1")
    } else {
        format!("{name} must be an integer from {min} to {max}")
    }
}

static ASARRAY: PyOnceLock<Py<PyAny>> = PyOnceLock::new();

/// Any array-like as a float64 numpy array (no copy if it already is one).
///
/// Booleans and integers are converted; strings, objects, complex numbers and
/// ragged sequences are refused with a `ValueError` naming `expected`.
fn float_array<'py>(
    name: &str,
    obj: &Bound<'py, PyAny>,
    expected: &str,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    if let Ok(a) = obj.cast::<PyArrayDyn<f64>>() {
        return Ok(a.clone());
    }
    let py = obj.py();
    let asarray = ASARRAY.import(py, "numpy", "asarray")?;
    let array = if obj.cast::<PyUntypedArray>().is_ok() {
        obj.clone()
    } else {
        asarray.call1((obj,)).map_err(|e| {
            PyValueError::new_err(format!(
                "{name}: expected {expected}, got something numpy cannot read as an array ({e})"
            ))
        })?
    };
    let untyped = array
        .cast::<PyUntypedArray>()
        .map_err(|_| PyValueError::new_err(format!("{name}: expected {expected}, got {obj}")))?;
    let dtype = untyped.dtype();
    if !matches!(dtype.kind(), b'b' | b'i' | b'u' | b'f') {
        return Err(PyValueError::new_err(format!(
            "{name}: expected {expected} of real numbers (float64), got dtype {dtype}"
        )));
    }
    let converted = asarray.call1((untyped, numpy::dtype::<f64>(py)))?;
    converted
        .cast_into::<PyArrayDyn<f64>>()
        .map_err(|_| PyValueError::new_err(format!("{name}: expected {expected} of float64")))
}

/// An array's number of dimensions, in words that cannot be taken for the
/// link's axes (numpy calls both "axes").
fn dimensions(n: usize) -> String {
    if n == 1 {
        "1 dimension".to_owned()
    } else {
        format!("{n} dimensions")
    }
}

fn shape_str(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// Copies the values out (C order).
fn read_values(name: &str, array: &Bound<'_, PyArrayDyn<f64>>) -> PyResult<Vec<f64>> {
    let ro = array.try_readonly().map_err(|e| {
        PyValueError::new_err(format!("{name}: the array cannot be read now ({e})"))
    })?;
    // A contiguous array is one copy; iterating a dynamic-rank view costs far more.
    match ro.as_slice() {
        Ok(values) => Ok(values.to_vec()),
        Err(_) => Ok(ro.as_array().iter().copied().collect()),
    }
}

/// Copies the values out (C order) and refuses NaN and infinities.
fn finite_values(name: &str, array: &Bound<'_, PyArrayDyn<f64>>) -> PyResult<Vec<f64>> {
    let values = read_values(name, array)?;
    if let Some(i) = values.iter().position(|v| !v.is_finite()) {
        let shape = array.shape();
        let index = unravel(i, shape);
        return Err(PyValueError::new_err(format!(
            "{name}{index} is {}: expected finite numbers (no NaN or infinity)",
            values[i]
        )));
    }
    Ok(values)
}

fn unravel(mut i: usize, shape: &[usize]) -> String {
    let mut idx = vec![0usize; shape.len()];
    for (slot, &n) in idx.iter_mut().zip(shape).rev() {
        if n > 0 {
            *slot = i % n;
            i /= n;
        }
    }
    format!(
        "[{}]",
        idx.iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// A 1-D array of finite floats, of length `len` if given.
pub fn vector(name: &str, obj: &Bound<'_, PyAny>, len: Option<usize>) -> PyResult<Vec<f64>> {
    let v = vector_with_nan(name, obj, len)?;
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "{name}[{i}] is {}: expected finite numbers (no NaN or infinity)",
            v[i]
        )));
    }
    Ok(v)
}

/// A 1-D array of floats, of length `len` if given; NaN and infinities pass.
pub fn vector_with_nan(
    name: &str,
    obj: &Bound<'_, PyAny>,
    len: Option<usize>,
) -> PyResult<Vec<f64>> {
    let expected = match len {
        Some(n) => format!("a 1-D array of shape ({n},)"),
        None => "a 1-D array of shape (n,)".to_owned(),
    };
    let array = float_array(name, obj, &expected)?;
    let shape = array.shape();
    match (shape, len) {
        ([_], None) => {}
        ([n], Some(want)) if *n == want => {}
        _ => {
            return Err(PyValueError::new_err(format!(
                "{name}: expected {expected}, got shape {} ({})",
                shape_str(shape),
                dimensions(shape.len())
            )));
        }
    }
    read_values(name, &array)
}

/// A fixed-size vector, e.g. a state.
pub fn array_of<const N: usize>(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<[f64; N]> {
    let v = vector(name, obj, Some(N))?;
    let mut out = [0.0; N];
    out.copy_from_slice(&v);
    Ok(out)
}

/// A 2-D array of finite floats with `rows` rows if given and `cols` columns
/// if given, in row-major order, with its shape.
pub fn matrix(
    name: &str,
    obj: &Bound<'_, PyAny>,
    rows: Option<usize>,
    cols: Option<usize>,
) -> PyResult<(Vec<f64>, usize, usize)> {
    let dim = |d: Option<usize>, letter: &str| d.map_or(letter.to_owned(), |n| n.to_string());
    let expected = format!(
        "a 2-D array of shape ({}, {})",
        dim(rows, "n"),
        dim(cols, "m")
    );
    let array = float_array(name, obj, &expected)?;
    let shape = array.shape();
    let ok = match shape {
        [r, c] => rows.is_none_or(|n| n == *r) && cols.is_none_or(|n| n == *c),
        _ => false,
    };
    if !ok {
        return Err(PyValueError::new_err(format!(
            "{name}: expected {expected}, got shape {} ({})",
            shape_str(shape),
            dimensions(shape.len())
        )));
    }
    let (r, c) = (shape[0], shape[1]);
    Ok((finite_values(name, &array)?, r, c))
}

/// A row of `n` finite floats given as shape `(n,)` or `(1, n)` (filterpy's
/// `H` is 2-D).
pub fn row(name: &str, obj: &Bound<'_, PyAny>, n: usize) -> PyResult<Vec<f64>> {
    let expected = format!("a 2-D array of shape (1, {n}) or a 1-D array of shape ({n},)");
    let array = float_array(name, obj, &expected)?;
    match array.shape() {
        [m] | [1, m] if *m == n => finite_values(name, &array),
        shape => Err(PyValueError::new_err(format!(
            "{name}: expected {expected}, got shape {} ({})",
            shape_str(shape),
            dimensions(shape.len())
        ))),
    }
}

/// At most `max` finite coefficients, shape `(k,)` or `(1, k)` (scipy's
/// `cont2discrete` gives a numerator as a `(1, k)` array), `1 ≤ k ≤ max`.
pub fn coefficients(name: &str, obj: &Bound<'_, PyAny>, max: usize) -> PyResult<Vec<f64>> {
    let expected = format!("a 1-D array of 1 to {max} coefficients, or one row of them");
    let array = float_array(name, obj, &expected)?;
    match array.shape() {
        [k] | [1, k] if (1..=max).contains(k) => finite_values(name, &array),
        shape => Err(PyValueError::new_err(format!(
            "{name}: expected {expected}, got shape {} ({})",
            shape_str(shape),
            dimensions(shape.len())
        ))),
    }
}

/// A single finite float given as a number or an array of one element,
/// shape `()`, `(1,)` or `(1, 1)` (filterpy's `R` of one measurement).
pub fn single(name: &str, obj: &Bound<'_, PyAny>) -> PyResult<f64> {
    let expected = "a number or a 2-D array of shape (1, 1)";
    let array = float_array(name, obj, expected)?;
    match array.shape() {
        [] | [1] | [1, 1] => Ok(finite_values(name, &array)?[0]),
        shape => Err(PyValueError::new_err(format!(
            "{name}: expected {expected}, got shape {} ({})",
            shape_str(shape),
            dimensions(shape.len())
        ))),
    }
}

/// `array`, made read-only: writing into a copy of a Rust object's state
/// would change nothing, so numpy raises instead (assign the whole
/// attribute to change it).
pub fn read_only<'py, T>(array: Bound<'py, T>) -> PyResult<Bound<'py, T>> {
    array
        .as_any()
        .getattr("flags")?
        .setattr("writeable", false)?;
    Ok(array)
}

/// Two lengths that must agree.
pub fn same_len(a: (&str, usize), b: (&str, usize)) -> PyResult<()> {
    if a.1 == b.1 {
        Ok(())
    } else {
        Err(PyValueError::new_err(format!(
            "{} and {} must have the same number of samples, got {} and {}",
            a.0, b.0, a.1, b.1
        )))
    }
}

/// A 1-D float64 array.
pub fn array1<'py>(py: Python<'py>, v: Vec<f64>) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_vec(py, v)
}

/// A 2-D float64 array from row-major values.
pub fn array2<'py>(
    py: Python<'py>,
    v: Vec<f64>,
    rows: usize,
    cols: usize,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let a = Array2::from_shape_vec((rows, cols), v).map_err(value_error)?;
    Ok(PyArray2::from_owned_array(py, a))
}

/// A `(3, 3)` array from anything indexable by `(row, column)`.
pub fn mat3<'py, M>(py: Python<'py>, m: &M) -> PyResult<Bound<'py, PyArray2<f64>>>
where
    M: core::ops::Index<(usize, usize), Output = f64>,
{
    let mut v = Vec::with_capacity(9);
    for i in 0..3 {
        for j in 0..3 {
            v.push(m[(i, j)]);
        }
    }
    array2(py, v, 3, 3)
}

/// A 1-D array of `len` finite floats, or a plain number when `len` is 1.
pub fn sample(name: &str, obj: &Bound<'_, PyAny>, len: usize) -> PyResult<Vec<f64>> {
    if len == 1
        && obj.cast::<PyUntypedArray>().is_err()
        && let Ok(v) = obj.extract::<f64>()
    {
        return Ok(vec![finite(name, v)?]);
    }
    vector(name, obj, Some(len))
}

/// A Rust value (the link's, listener's and relay's stats) as Python sees
/// it: its serde serialization, so that the Rust type is the one list of
/// names and units (durations in seconds, `#[serde]` attributes for the
/// rest). A struct or map becomes a dict, a sequence a tuple (the stats'
/// pairs), a whole number an int, another number a float, `None` `None`
/// (as would a float that is not finite: JSON holds no NaN).
pub fn serialized<'py, T: serde::Serialize>(
    py: Python<'py>,
    value: &T,
) -> PyResult<Bound<'py, PyAny>> {
    let v = serde_json::to_value(value)
        .map_err(|e| PyRuntimeError::new_err(format!("cannot serialize the stats: {e}")))?;
    json(py, &v)
}

fn json<'py>(py: Python<'py>, v: &Value) -> PyResult<Bound<'py, PyAny>> {
    Ok(match v {
        Value::Null => py.None().into_bound(py),
        Value::Bool(b) => b.into_pyobject(py)?.to_owned().into_any(),
        Value::Number(n) => match (n.as_u64(), n.as_i64()) {
            (Some(u), _) => u.into_pyobject(py)?.into_any(),
            (None, Some(i)) => i.into_pyobject(py)?.into_any(),
            // serde_json holds every other number as a finite f64.
            (None, None) => n.as_f64().unwrap_or(f64::NAN).into_pyobject(py)?.into_any(),
        },
        Value::String(s) => s.into_pyobject(py)?.into_any(),
        Value::Array(items) => {
            let items = items
                .iter()
                .map(|x| json(py, x))
                .collect::<PyResult<Vec<_>>>()?;
            PyTuple::new(py, items)?.into_any()
        }
        Value::Object(fields) => {
            let d = PyDict::new(py);
            for (k, x) in fields {
                d.set_item(k, json(py, x)?)?;
            }
            d.into_any()
        }
    })
}
