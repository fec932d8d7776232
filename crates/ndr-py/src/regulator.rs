//! `ndr.Regulator`: the NDR queue holding float64 vectors of a fixed width.
//!
//! The core's `Regulator<u64, MAX_CAPACITY>` keeps the order, the phase and
//! the counters; it queues sequence numbers, and the samples themselves live
//! in a ring of `capacity × width` floats here (the queue always holds
//! consecutive sequence numbers, so `seq % capacity` is a free slot). A
//! capacity below `MAX_CAPACITY` is enforced here, with the rejection counted
//! exactly as the core would.

use ndr_core::regulator::{Counters, Phase, Regulator as Core, RegulatorError, Tick};
use numpy::PyArray1;
use pyo3::create_exception;
use pyo3::exceptions::{PyOverflowError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::convert::{array1, count, value_error};

/// The largest capacity a Python regulator can have.
pub const MAX_CAPACITY: usize = 4096;
/// The widest sample a Python regulator can hold.
pub const MAX_WIDTH: usize = 1 << 16;

create_exception!(
    ndr,
    RegulatorFull,
    PyOverflowError,
    "Raised by Regulator.push when the queue is full. Nothing is lost: the \
     sample is handed back as the exception's `sample` attribute, and the \
     rejection is counted in `Regulator.rejected`."
);

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum LastTick {
    None,
    Released,
    Prefilling,
    Underflow,
}

/// The Network Delay Regulator: a FIFO of float64 vectors released one per
/// tick after a pre-fill to the nominal size `ns`.
#[pyclass(module = "ndr", name = "Regulator")]
#[derive(Clone)]
pub struct PyRegulator {
    core: Box<Core<u64, MAX_CAPACITY>>,
    data: Vec<f64>,
    width: usize,
    capacity: usize,
    next_seq: u64,
    /// Pushes refused here because of a capacity below `MAX_CAPACITY`.
    extra_rejected: u64,
    last: LastTick,
}

impl PyRegulator {
    fn slot(&self, seq: u64) -> std::ops::Range<usize> {
        // capacity ≥ 1, and the result is below capacity, so it fits a usize.
        let i = usize::try_from(seq % self.capacity as u64).unwrap_or(0) * self.width;
        i..i + self.width
    }

    fn sample<'py>(&self, py: Python<'py>, seq: u64) -> Bound<'py, PyArray1<f64>> {
        let r = self.slot(seq);
        PyArray1::from_slice(py, self.data.get(r).unwrap_or(&[]))
    }

    fn totals(&self) -> Counters {
        let mut c = self.core.counters();
        c.arrived += self.extra_rejected;
        c.rejected += self.extra_rejected;
        c
    }

    fn check_ns(&self, ns: usize) -> PyResult<()> {
        if ns >= self.capacity {
            return Err(value_error(RegulatorError::NominalSize {
                ns,
                capacity: self.capacity,
            }));
        }
        Ok(())
    }
}

#[pymethods]
impl PyRegulator {
    #[new]
    #[pyo3(
        signature = (ns, width = None, *, capacity = None),
        text_signature = "(ns, width=1, *, capacity=64)"
    )]
    fn new(
        ns: &Bound<'_, PyAny>,
        width: Option<&Bound<'_, PyAny>>,
        capacity: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let width = match width {
            Some(w) => count("width", w, 1, MAX_WIDTH)?,
            None => 1,
        };
        let capacity = match capacity {
            Some(c) => count("capacity", c, 1, MAX_CAPACITY)?,
            None => 64,
        };
        let ns = count("ns", ns, 0, MAX_CAPACITY)?;
        let data_len = capacity
            .checked_mul(width)
            .filter(|&n| n <= 1 << 24)
            .ok_or_else(|| {
                PyValueError::new_err(format!(
                    "capacity × width = {capacity} × {width} is too large: at most 16 Mi floats"
                ))
            })?;
        let mut r = PyRegulator {
            core: Box::new(Core::new(0).map_err(value_error)?),
            data: vec![0.0; data_len],
            width,
            capacity,
            next_seq: 0,
            extra_rejected: 0,
            last: LastTick::None,
        };
        r.check_ns(ns)?;
        r.core.set_nominal(ns).map_err(value_error)?;
        Ok(r)
    }

    /// Queues a sample (a float when width is 1, else a 1-D array of `width`
    /// floats). Raises `RegulatorFull` (an `OverflowError`) when the queue is
    /// full, with the sample in its `sample` attribute.
    fn push(&mut self, py: Python<'_>, sample: &Bound<'_, PyAny>) -> PyResult<()> {
        let values = crate::convert::sample("sample", sample, self.width)?;
        if self.core.len() >= self.capacity {
            self.extra_rejected += 1;
            return Err(full(py, &values));
        }
        let seq = self.next_seq;
        let r = self.slot(seq);
        if let Some(dst) = self.data.get_mut(r) {
            dst.copy_from_slice(&values);
        }
        match self.core.push(seq) {
            Ok(()) => {
                self.next_seq += 1;
                Ok(())
            }
            Err(_) => Err(full(py, &values)),
        }
    }

    /// One tick of the release clock: the released sample (a 1-D array), or
    /// `None` while pre-filling or on an underflow (see `last_tick`).
    fn tick<'py>(&mut self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        match self.core.tick() {
            Tick::Released(seq) => {
                self.last = LastTick::Released;
                Some(self.sample(py, seq))
            }
            Tick::Prefilling { .. } => {
                self.last = LastTick::Prefilling;
                None
            }
            Tick::Underflow => {
                self.last = LastTick::Underflow;
                None
            }
        }
    }

    /// What the last tick did: "released", "prefilling", "underflow", or
    /// None before the first tick.
    #[getter]
    fn last_tick(&self) -> Option<&'static str> {
        match self.last {
            LastTick::None => None,
            LastTick::Released => Some("released"),
            LastTick::Prefilling => Some("prefilling"),
            LastTick::Underflow => Some("underflow"),
        }
    }

    /// "prefilling" until a tick finds more than `ns` queued, then "running".
    #[getter]
    fn phase(&self) -> &'static str {
        match self.core.phase() {
            Phase::Prefilling => "prefilling",
            Phase::Running => "running",
        }
    }

    /// The oldest queued sample (the next to be released), without removing it.
    fn front<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.core.front().map(|&seq| self.sample(py, seq))
    }

    /// The queued samples, oldest first, as a `(len, width)` array.
    fn samples<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, numpy::PyArray2<f64>>> {
        let mut v = Vec::with_capacity(self.core.len() * self.width);
        for &seq in self.core.iter() {
            v.extend_from_slice(self.data.get(self.slot(seq)).unwrap_or(&[]));
        }
        crate::convert::array2(py, v, self.core.len(), self.width)
    }

    /// Removes the oldest sample without releasing it (counted as discarded).
    fn discard_front<'py>(&mut self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.core.discard_front().map(|seq| self.sample(py, seq))
    }

    /// Empties the queue (counted as discarded); returns how many were removed.
    fn clear(&mut self) -> usize {
        self.core.clear()
    }

    /// Goes back to pre-filling; queued samples stay.
    fn restart_prefill(&mut self) {
        self.core.restart_prefill();
    }

    /// Forgets the occupancy statistics; the counters stay.
    fn reset_occupancy(&mut self) {
        self.core.reset_occupancy();
    }

    /// The nominal size: the stock kept between releases (`ns < capacity`).
    #[getter]
    fn ns(&self) -> usize {
        self.core.nominal()
    }

    #[setter]
    fn set_ns(&mut self, ns: &Bound<'_, PyAny>) -> PyResult<()> {
        let ns = count("ns", ns, 0, MAX_CAPACITY)?;
        self.check_ns(ns)?;
        self.core.set_nominal(ns).map_err(value_error)
    }

    /// The most samples the queue holds.
    #[getter]
    fn capacity(&self) -> usize {
        self.capacity
    }

    /// The number of floats in a sample.
    #[getter]
    fn width(&self) -> usize {
        self.width
    }

    fn __len__(&self) -> usize {
        self.core.len()
    }

    /// Samples offered to `push`.
    #[getter]
    fn arrived(&self) -> u64 {
        self.totals().arrived
    }

    /// Samples released by a tick.
    #[getter]
    fn released(&self) -> u64 {
        self.totals().released
    }

    /// Samples refused because the queue was full.
    #[getter]
    fn rejected(&self) -> u64 {
        self.totals().rejected
    }

    /// Samples removed other than by a release (`discard_front`, `clear`).
    #[getter]
    fn discarded(&self) -> u64 {
        self.totals().discarded
    }

    /// Running ticks that released nothing.
    #[getter]
    fn underflows(&self) -> u64 {
        self.totals().underflows
    }

    /// Running ticks (pre-fill ticks excluded).
    #[getter]
    fn ticks(&self) -> u64 {
        self.totals().ticks
    }

    /// All counters as a dict; `arrived == released + len + rejected + discarded`.
    #[getter(counters)]
    fn counters_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = self.totals();
        let d = PyDict::new(py);
        d.set_item("arrived", c.arrived)?;
        d.set_item("released", c.released)?;
        d.set_item("rejected", c.rejected)?;
        d.set_item("discarded", c.discarded)?;
        d.set_item("underflows", c.underflows)?;
        d.set_item("ticks", c.ticks)?;
        Ok(d)
    }

    /// Occupancy seen by the running ticks just before each release, as a
    /// dict `{min, max, mean, ticks}`, or None before the first one.
    #[getter]
    fn occupancy<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(o) = self.core.occupancy() else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        d.set_item("min", o.min)?;
        d.set_item("max", o.max)?;
        d.set_item("mean", o.mean)?;
        d.set_item("ticks", o.ticks)?;
        Ok(Some(d))
    }

    /// An independent copy: queue, samples, phase and counters.
    fn __copy__(&self) -> Self {
        self.clone()
    }

    /// As `__copy__` (the samples are floats: nothing is shared).
    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> Self {
        self.clone()
    }

    fn __repr__(&self) -> String {
        format!(
            "Regulator(ns={}, width={}, capacity={}, len={}, phase='{}')",
            self.core.nominal(),
            self.width,
            self.capacity,
            self.core.len(),
            self.phase()
        )
    }
}

fn full(py: Python<'_>, values: &[f64]) -> PyErr {
    let err = RegulatorFull::new_err(
        "regulator queue is full; the sample was handed back (in the exception's \
         `sample`): give the regulator a larger capacity or a smaller nominal size",
    );
    // Setting an attribute on a fresh exception instance cannot fail in practice;
    // if it did, the exception is still raised, without the attribute.
    let _ = err.value(py).setattr("sample", array1(py, values.to_vec()));
    err
}
