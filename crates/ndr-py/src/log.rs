//! Rust logs (`tracing`) into Python's `logging`.
//!
//! The threads that log (the hub, the relay's tasks) must never wait for the
//! GIL: a release clock blocked behind a Python thread would lose its
//! microseconds. So the subscriber only appends the record to a bounded
//! queue (dropping and counting what does not fit), and the records reach
//! `logging` later, from a Python thread that already holds the GIL: every
//! call of the link, listener, relay and simulator bindings flushes them, as
//! does `ndr._native.flush_logs()`. The logger is named after the record's
//! target (`ndr_net::relay` becomes `ndr.net.relay`).

use std::collections::VecDeque;
use std::fmt::Write as _;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Mutex, PoisonError};

use pyo3::prelude::*;
use pyo3::sync::PyOnceLock;
use pyo3::types::PyModule;
use tracing::field::{Field, Visit};
use tracing::span::{Attributes, Id, Record};
use tracing::subscriber::Interest;
use tracing::{Event, Level, Metadata, Subscriber};

/// Records waiting for a Python thread; more are dropped and counted.
pub const QUEUE: usize = 1024;

struct Entry {
    level: Level,
    target: &'static str,
    message: String,
}

static QUEUED: Mutex<VecDeque<Entry>> = Mutex::new(VecDeque::new());
static PENDING: AtomicUsize = AtomicUsize::new(0);
static DROPPED: AtomicU64 = AtomicU64::new(0);
/// Levels recorded, from the least verbose: 0 none, 1 error … 5 trace.
static LEVELS: AtomicUsize = AtomicUsize::new(3);
static INSTALLED: AtomicBool = AtomicBool::new(false);

fn rank(level: Level) -> usize {
    match level {
        Level::ERROR => 0,
        Level::WARN => 1,
        Level::INFO => 2,
        Level::DEBUG => 3,
        Level::TRACE => 4,
    }
}

/// The subscriber: formats the event, queues it.
struct Bridge;

#[derive(Default)]
struct Fields(String);

impl Visit for Fields {
    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "message" {
            self.0.insert_str(0, value);
        } else {
            let _ = write!(self.0, " {}={value}", field.name());
        }
    }

    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.0.insert_str(0, &format!("{value:?}"));
        } else {
            let _ = write!(self.0, " {}={value:?}", field.name());
        }
    }
}

impl Subscriber for Bridge {
    fn register_callsite(&self, meta: &'static Metadata<'static>) -> Interest {
        if self.enabled(meta) {
            Interest::always()
        } else {
            Interest::never()
        }
    }

    fn enabled(&self, meta: &Metadata<'_>) -> bool {
        meta.is_event() && rank(*meta.level()) < LEVELS.load(Ordering::Relaxed)
    }

    fn new_span(&self, _: &Attributes<'_>) -> Id {
        Id::from_u64(1)
    }

    fn record(&self, _: &Id, _: &Record<'_>) {}

    fn record_follows_from(&self, _: &Id, _: &Id) {}

    fn event(&self, event: &Event<'_>) {
        let mut fields = Fields::default();
        event.record(&mut fields);
        let meta = event.metadata();
        let mut queue = QUEUED.lock().unwrap_or_else(PoisonError::into_inner);
        if queue.len() >= QUEUE {
            DROPPED.fetch_add(1, Ordering::Relaxed);
            return;
        }
        queue.push_back(Entry {
            level: *meta.level(),
            target: meta.target(),
            message: fields.0,
        });
        PENDING.store(queue.len(), Ordering::Release);
    }

    fn enter(&self, _: &Id) {}

    fn exit(&self, _: &Id) {}
}

/// Installs the bridge as the process's subscriber, unless another is set.
pub fn install() {
    if !INSTALLED.swap(true, Ordering::AcqRel) {
        // Another library may have set one first: then its choice stands.
        let _ = tracing::subscriber::set_global_default(Bridge);
    }
}

fn python_level(level: Level) -> u8 {
    match level {
        Level::ERROR => 40,
        Level::WARN => 30,
        Level::INFO => 20,
        Level::DEBUG => 10,
        Level::TRACE => 5,
    }
}

fn logger_name(target: &str) -> String {
    let name = target.replace("::", ".");
    match name.strip_prefix("ndr_") {
        Some(rest) => format!("ndr.{rest}"),
        None => name,
    }
}

/// Hands the queued records to `logging` (cheap when there are none).
pub fn flush(py: Python<'_>) {
    if PENDING.load(Ordering::Acquire) == 0 && DROPPED.load(Ordering::Relaxed) == 0 {
        return;
    }
    let entries: Vec<Entry> = {
        let mut queue = QUEUED.lock().unwrap_or_else(PoisonError::into_inner);
        PENDING.store(0, Ordering::Release);
        queue.drain(..).collect()
    };
    let dropped = DROPPED.swap(0, Ordering::Relaxed);
    // Logging must never turn a link call into an error: a failing handler
    // is Python's business (logging reports it itself).
    let _ = emit(py, entries, dropped);
}

fn emit(py: Python<'_>, entries: Vec<Entry>, dropped: u64) -> PyResult<()> {
    static GET_LOGGER: PyOnceLock<Py<PyAny>> = PyOnceLock::new();
    let get_logger = GET_LOGGER.get_or_try_init(py, || {
        PyModule::import(py, "logging")?
            .getattr("getLogger")
            .map(Bound::unbind)
    })?;
    let get_logger = get_logger.bind(py);
    if dropped > 0 {
        get_logger.call1(("ndr",))?.call_method1(
            "warning",
            (format!(
                "{dropped} Rust log records were dropped: more than {QUEUE} came between two calls"
            ),),
        )?;
    }
    for e in entries {
        let logger = get_logger.call1((logger_name(e.target),))?;
        logger.call_method1("log", (python_level(e.level), e.message))?;
    }
    Ok(())
}

/// Sets how verbose Rust is (default "info"): a name, "error", "warning",
/// "info", "debug" or "trace"; a `logging` level (`logging.DEBUG`: the Rust
/// records at or above it are kept, so `logging.CRITICAL` keeps none); or
/// "off" or None: no Rust records at all.
#[pyfunction]
#[pyo3(signature = (level))]
pub fn set_log_level(level: Option<&Bound<'_, PyAny>>) -> PyResult<()> {
    let levels = match level {
        None => 0,
        Some(obj) => levels(obj)?,
    };
    LEVELS.store(levels, Ordering::Relaxed);
    tracing::callsite::rebuild_interest_cache();
    Ok(())
}

/// How many Rust levels a `set_log_level` argument keeps.
fn levels(obj: &Bound<'_, PyAny>) -> PyResult<usize> {
    const EXPECTED: &str = "expected \"error\", \"warning\", \"info\", \"debug\", \"trace\", \
                            \"off\", None, or a logging level such as logging.DEBUG";
    if let Ok(name) = obj.extract::<String>() {
        return match name.to_ascii_lowercase().as_str() {
            "off" | "none" => Ok(0),
            "error" | "critical" => Ok(1),
            "warn" | "warning" => Ok(2),
            "info" => Ok(3),
            "debug" => Ok(4),
            "trace" => Ok(5),
            _ => Err(pyo3::exceptions::PyValueError::new_err(format!(
                "unknown log level {name:?}: {EXPECTED}"
            ))),
        };
    }
    if obj.is_instance_of::<pyo3::types::PyBool>() {
        return Err(pyo3::exceptions::PyTypeError::new_err(format!(
            "log level: {EXPECTED}, got a bool"
        )));
    }
    match obj.extract::<i128>() {
        // The Rust levels a logger at this level lets through.
        Ok(n) => Ok([
            Level::ERROR,
            Level::WARN,
            Level::INFO,
            Level::DEBUG,
            Level::TRACE,
        ]
        .iter()
        .take_while(|&&l| i128::from(python_level(l)) >= n)
        .count()),
        // Beyond 128 bits: above every level, or below.
        Err(_) if obj.is_instance_of::<pyo3::types::PyInt>() => Ok(if obj.gt(0)? { 0 } else { 5 }),
        Err(_) => Err(pyo3::exceptions::PyTypeError::new_err(format!(
            "log level: {EXPECTED}, got an object of type {}",
            obj.get_type().name()?
        ))),
    }
}

/// Hands the Rust log records waiting in the queue to `logging` now.
#[pyfunction]
pub fn flush_logs(py: Python<'_>) {
    flush(py);
}
