//! The network's delay models (`ndr-netem`) from Python's arguments: shared
//! by `ndr.sim.run` and `ndr.Relay`, as the simulator and the relay share
//! the models themselves.

use std::sync::Arc;

use ndr_netem::{DelayModel, DistTable, Trace};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::convert::{seconds, value_error};

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
