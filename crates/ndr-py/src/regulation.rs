//! `regulation=`, and the deprecated `mode=` and `playout=` it replaces:
//! one reading of the three for every function that takes them.

use std::ffi::CString;

use ndr_core::endpoint::Mode;
use ndr_core::playout::Playout;
use ndr_core::regulation::Regulation;
use pyo3::exceptions::{PyDeprecationWarning, PyRuntimeError, PyValueError};
use pyo3::prelude::*;

/// What a call gave: `regulation=`, `mode=`, `playout=`.
pub type Given<'a> = (Option<&'a str>, Option<&'a str>, Option<&'a str>);

/// The mode and playout asked for (each missing one `default`'s under the
/// old spellings), and whether through the old spellings.
fn read(
    (regulation, mode, playout): Given<'_>,
    default: Regulation,
) -> PyResult<(Mode, Playout, bool)> {
    if let Some(name) = regulation {
        if mode.is_some() || playout.is_some() {
            return Err(PyValueError::new_err(
                "regulation replaces mode and playout: give regulation alone",
            ));
        }
        let r = name
            .parse::<Regulation>()
            .map_err(|e| PyValueError::new_err(format!("regulation: {e}")))?;
        return Ok((r.mode(), r.playout(), false));
    }
    let m = match mode {
        Some(m) => m
            .parse::<Mode>()
            .map_err(|e| PyValueError::new_err(format!("mode: {e}")))?,
        None => default.mode(),
    };
    let p = match playout {
        Some(p) => p
            .parse::<Playout>()
            .map_err(|e| PyValueError::new_err(format!("playout: {e}")))?,
        None => default.playout(),
    };
    Ok((m, p, mode.is_some() || playout.is_some()))
}

/// A `DeprecationWarning` at the user's call, `stacklevel` frames up from
/// the Python function that called the native one, naming the regulation
/// that asks for `mode` and `playout`.
fn warn(py: Python<'_>, mode: Mode, playout: Playout, stacklevel: i32) -> PyResult<()> {
    let instead = Regulation::of(mode, playout).map_or_else(
        || {
            "regulation= (the dynamic mode under a target playout has no name: the Rust \
             Config still takes it, field by field)"
                .to_owned()
        },
        |r| format!("regulation={:?}", r.to_string()),
    );
    let message =
        format!("mode= and playout= are deprecated and go in the next release: use {instead}");
    let message = CString::new(message).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    let category = py.get_type::<PyDeprecationWarning>();
    PyErr::warn(py, category.as_any(), &message, stacklevel)
}

/// The mode and playout asked for ([`parts`] reads them the same way),
/// with a `DeprecationWarning` at `stacklevel` when the old spellings were
/// used.
pub fn mode_playout(
    py: Python<'_>,
    given: Given<'_>,
    default: Regulation,
    stacklevel: i32,
) -> PyResult<(Mode, Playout)> {
    let (mode, playout, old) = read(given, default)?;
    if old {
        warn(py, mode, playout, stacklevel)?;
    }
    Ok((mode, playout))
}

/// `(name, mode, playout)` of what a call gave, as reports write them
/// (`name` is `None` for the pairing no regulation names), with the same
/// checks and warning as `ndr.Link.connect`'s (`default`: the regulation
/// when none is given; `stacklevel`: the user's call, counted from the
/// Python function that calls this one).
#[pyfunction]
#[pyo3(name = "_regulation", signature = (*, regulation, mode, playout, default, stacklevel))]
pub fn parts(
    py: Python<'_>,
    regulation: Option<&str>,
    mode: Option<&str>,
    playout: Option<&str>,
    default: &str,
    stacklevel: i32,
) -> PyResult<(Option<String>, String, String)> {
    let default = default
        .parse::<Regulation>()
        .map_err(|e| PyValueError::new_err(format!("default: {e}")))?;
    let (mode, playout) = mode_playout(py, (regulation, mode, playout), default, stacklevel)?;
    let name = Regulation::of(mode, playout).map(|r| r.to_string());
    Ok((name, mode.to_string(), playout.to_string()))
}
