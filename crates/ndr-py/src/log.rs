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
/// The most verbose level recorded: 0 error … 4 trace.
static MAX_LEVEL: AtomicUsize = AtomicUsize::new(2);
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
        meta.is_event() && rank(*meta.level()) <= MAX_LEVEL.load(Ordering::Relaxed)
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

/// Sets the most verbose Rust level recorded: "error", "warning", "info",
/// "debug" or "trace" (default "info").
#[pyfunction]
pub fn set_log_level(level: &str) -> PyResult<()> {
    let rank = match level.to_ascii_lowercase().as_str() {
        "error" | "critical" => 0,
        "warn" | "warning" => 1,
        "info" => 2,
        "debug" => 3,
        "trace" => 4,
        _ => {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "unknown log level {level:?}: expected one of error, warning, info, debug, trace"
            )));
        }
    };
    MAX_LEVEL.store(rank, Ordering::Relaxed);
    tracing::callsite::rebuild_interest_cache();
    Ok(())
}

/// Hands the Rust log records waiting in the queue to `logging` now.
#[pyfunction]
pub fn flush_logs(py: Python<'_>) {
    flush(py);
}
