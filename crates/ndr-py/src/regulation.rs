//! `regulation=`: one reading for every function that takes it, and the
//! names it takes, from the playout registry.

use ndr_core::Regulation;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

/// The regulation asked for, or `default` when none is given.
pub fn read(regulation: Option<&str>, default: Regulation) -> PyResult<Regulation> {
    regulation.map_or(Ok(default), |name| {
        name.parse::<Regulation>()
            .map_err(|e| PyValueError::new_err(format!("regulation: {e}")))
    })
}

/// The names `regulation=` takes without a value, in the registry's order
/// (`ndr.sim.REGULATIONS`).
pub fn bare_names() -> Vec<String> {
    Regulation::every()
        .map(|r| {
            let name = r.to_string();
            name.split(':').next().unwrap_or_default().to_owned()
        })
        .collect()
}

/// `(name, mode, playout)` of `regulation=` as reports write them
/// (`default`: the regulation when none is given).
#[pyfunction]
#[pyo3(name = "_regulation", signature = (*, regulation, default))]
pub fn parts(regulation: Option<&str>, default: &str) -> PyResult<(String, String, String)> {
    let default = default
        .parse::<Regulation>()
        .map_err(|e| PyValueError::new_err(format!("default: {e}")))?;
    let r = read(regulation, default)?;
    Ok((r.to_string(), r.mode().to_string(), r.playout().to_string()))
}
