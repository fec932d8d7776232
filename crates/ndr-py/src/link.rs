//! The link natives behind `ndr.Link` and `ndr.Listener` (python/ndr/link.py
//! adds the context managers, iterators and asyncio).
//!
//! A `_Link` splits the Rust [`Link`] in two so that sending never waits for
//! a receive: the [`LinkSender`] half sets the next sample and reads stats
//! from any thread; the receiving half sits behind a mutex that is only ever
//! taken without the GIL (a thread holding the GIL while it waits for a
//! thread that waits for the GIL would deadlock).
//!
//! A link is handed to Python only once its handshake has succeeded: a peer
//! with other settings raises `HandshakeError` from `connect`, and a
//! listener logs it, counts it and keeps waiting for the next peer.

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError, mpsc};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr_core::Regulation;
use ndr_core::endpoint::{Config, Event, LinkError as CoreError, Mode, Underflow};
use ndr_core::floor::MAX_OBSERVERS;
use ndr_core::time::Duration;
use ndr_core::wire::MAX_CHANNELS;
use ndr_core::wire::{Role, Seat};
use ndr_net::metrics::{LinkLabels, Metrics};
use ndr_net::{EVENT_BACKLOG, LinkEvent};
use ndr_net::{Link, LinkConfig, LinkSender, Listener, NetError, Sample, Transport};
use ndr_net::{RecordConfig, RecordError, Recorder};
use numpy::PyArray1;
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};

use crate::blocking::{self, timed_out, wait};
use crate::convert::{count, int_in, period as positive, sample as to_sample, serialized};
use crate::errors::{net_error, os_error, transport_error};
use crate::log;
use crate::regulation;
use crate::tls::PyTlsConfig;

/// The most released samples and events that may wait for the application
/// (`queue=`): a bound on the memory a link that nobody reads can take
/// (about 100 MiB at 8 axes), far beyond the 1024 default.
const MAX_APP_QUEUE: usize = 1 << 20;

/// A sample released by the link's regulator at one of its ticks.
///
/// Times are seconds: `arrived_at` and `released_at` on this side's link
/// clock (`Link.now()`), `sent_at` on the peer's. Only differences on one
/// clock mean something; `released_at - sent_at` is the end-to-end delay
/// plus the (constant) offset between the clocks.
#[pyclass(frozen, module = "ndr", name = "Tick")]
pub struct PyTick {
    release: Sample,
}

#[pymethods]
impl PyTick {
    /// The sample's values: a new float64 array of shape `(axes,)`.
    #[getter]
    fn sample<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        PyArray1::from_slice(py, self.release.values())
    }

    /// The sample's sequence number (the peer's data frame count).
    #[getter]
    fn seq(&self) -> u64 {
        self.release.seq
    }

    /// When the peer sent it, on the peer's clock (s).
    #[getter]
    fn sent_at(&self) -> f64 {
        self.release.sent_at.as_secs_f64()
    }

    /// When it arrived here, on this side's clock (s).
    #[getter]
    fn arrived_at(&self) -> f64 {
        self.release.arrived_at.as_secs_f64()
    }

    /// The tick that released it, on this side's clock (s).
    #[getter]
    fn released_at(&self) -> f64 {
        self.release.released_at.as_secs_f64()
    }

    /// `"fresh"`, or `"held"` when the due sample had not arrived (an
    /// underflow) and the last one is repeated.
    #[getter]
    fn status(&self) -> &'static str {
        self.release.status.name()
    }

    /// The round trip as the application sees it (GRTT, s), when this
    /// release closes one; else `None`.
    #[getter]
    fn grtt(&self) -> Option<f64> {
        self.release.grtt.map(Duration::as_secs_f64)
    }

    /// The control term its frame carried (0 outside a shared robot's
    /// terms): on a base, the term under which the robot sent this state.
    #[getter]
    fn term(&self) -> u16 {
        self.release.term
    }

    /// Time the sample waited in the regulator: `released_at - arrived_at` (s).
    #[getter]
    fn added_delay(&self) -> f64 {
        self.release.added_delay().as_secs_f64()
    }

    fn __repr__(&self) -> String {
        format!(
            "Tick(seq={}, status={:?}, released_at={:.6}, sample={:?})",
            self.release.seq,
            self.release.status.name(),
            self.release.released_at.as_secs_f64(),
            self.release.values()
        )
    }
}

/// The receiving half of a link.
struct Rx {
    link: Link,
    /// Samples handed back by an interrupted asynchronous receive; served first.
    stash: VecDeque<Sample>,
    ended: Option<CoreError>,
    /// A base that asked to wait for control and observes meanwhile: until
    /// when it waits, and the seconds it was given (`wait_for_control=`).
    waiting: Option<(StdInstant, f64)>,
}

impl Rx {
    /// The next sample, waiting at most `slice` (`Ok(None)` when none came).
    fn take(&mut self, slice: StdDuration) -> Result<Option<Sample>, NetError> {
        if let Some(s) = self.stash.pop_front() {
            return Ok(Some(s));
        }
        if let Some(e) = self.ended {
            return Err(NetError::Link(e));
        }
        let got = if slice.is_zero() {
            self.link.try_recv()
        } else {
            match self.link.recv_timeout(slice) {
                Ok(s) => Ok(Some(s)),
                Err(NetError::Timeout) => Ok(None),
                Err(e) => Err(e),
            }
        };
        if let Err(NetError::Link(e)) = &got {
            self.ended = Some(*e);
        }
        got
    }
}

/// The events waiting for Python: moved out of the link after each receive,
/// so that reading them never waits for a receive in progress. The one
/// place they wait in Python: `ndr.Link` keeps none of its own.
#[derive(Default)]
struct Kept {
    events: VecDeque<LinkEvent>,
    /// The oldest `seen` went to Python's callbacks ([`PyLink::new_events`]).
    seen: usize,
    /// Dropped past [`EVENT_BACKLOG`], as the Rust link drops its own.
    dropped: u64,
}

impl Kept {
    /// Appends what came, the oldest going past [`EVENT_BACKLOG`]
    /// (counted); returns how many are not seen yet.
    fn extend(&mut self, came: impl IntoIterator<Item = LinkEvent>) -> usize {
        self.events.extend(came);
        let excess = self.events.len().saturating_sub(EVENT_BACKLOG);
        if excess > 0 {
            self.events.drain(..excess);
            self.seen = self.seen.saturating_sub(excess);
            self.dropped += excess as u64;
        }
        self.events.len() - self.seen
    }

    /// The events not seen yet, now seen (they stay).
    fn take_new(&mut self) -> Vec<LinkEvent> {
        let new = self.events.range(self.seen..).cloned().collect();
        self.seen = self.events.len();
        new
    }

    /// The events seen, which leave.
    fn take_seen(&mut self) -> Vec<LinkEvent> {
        let seen = self.events.drain(..self.seen).collect();
        self.seen = 0;
        seen
    }
}

/// The native link (`ndr.Link` wraps it).
#[pyclass(frozen, module = "ndr._native", name = "_Link")]
pub struct PyLink {
    sender: LinkSender,
    rx: Mutex<Rx>,
    kept: Mutex<Kept>,
    /// Events in `kept` not yet seen, readable without its lock.
    unseen: AtomicUsize,
    role: Role,
    /// The link's transport (the `transport` label of its metrics).
    transport: Transport,
    period: f64,
    peer: SocketAddr,
    /// Values in each command and in each state.
    widths: (usize, usize),
    /// The recording it goes to (`record=`), shared with its listener's
    /// other links; the last holder to let go finishes the file.
    recorder: Mutex<Option<Arc<Recorder>>>,
    /// Whether this link observes now (a base without control, a remote's
    /// link to such a base), as the link's events tell it.
    observer: AtomicBool,
    /// The seat the peer's Hello named (`Link::peer_seat`).
    peer_seat: Option<Seat>,
    /// The link was closed because control was not granted within
    /// `wait_for_control` seconds: the seconds.
    gave_up: Mutex<Option<f64>>,
}

fn lock(rx: &Mutex<Rx>) -> MutexGuard<'_, Rx> {
    rx.lock().unwrap_or_else(PoisonError::into_inner)
}

impl PyLink {
    fn new(link: Link, role: Role, transport: Transport, period: Duration) -> Self {
        let (sent, received) = link.widths();
        let peer_seat = link.peer_seat();
        // A base observes unless the remote's Hello gave it control; a
        // remote's link, if its listener says so.
        let observer = match role {
            Role::Base => peer_seat.is_some_and(|s| s != Seat::Control),
            Role::Remote => link.is_observer(),
        };
        PyLink {
            observer: AtomicBool::new(observer),
            peer_seat,
            gave_up: Mutex::new(None),
            widths: match role {
                Role::Base => (sent, received),
                Role::Remote => (received, sent),
            },
            sender: link.sender(),
            peer: link.peer_addr(),
            rx: Mutex::new(Rx {
                link,
                stash: VecDeque::new(),
                ended: None,
                waiting: None,
            }),
            kept: Mutex::new(Kept::default()),
            unseen: AtomicUsize::new(0),
            role,
            transport,
            period: period.as_secs_f64(),
            recorder: Mutex::new(None),
        }
    }

    /// Records the link into `recorder` from now on.
    fn recorded(self, recorder: Option<Arc<Recorder>>) -> Result<Self, NetError> {
        if let Some(r) = &recorder {
            lock(&self.rx).link.record(r)?;
        }
        *self.recorder.lock().unwrap_or_else(PoisonError::into_inner) = recorder;
        Ok(self)
    }

    /// Moves the events the last receive saw to where Python reads them
    /// (at most [`EVENT_BACKLOG`]; the oldest go first, as in the Rust link).
    fn publish(&self, rx: &mut Rx) {
        let came: Vec<LinkEvent> = rx.link.drain_events().collect();
        for e in &came {
            match e {
                Event::ControlGranted { .. } => {
                    self.observer.store(false, Ordering::Relaxed);
                    rx.waiting = None;
                }
                Event::ControlLost { .. } | Event::ControlYielded { .. } => {
                    self.observer.store(true, Ordering::Relaxed);
                }
                _ => {}
            }
        }
        let mut kept = self.kept();
        let unseen = kept.extend(came);
        // Under the lock, so that it cannot undo `new_events`' zero.
        self.unseen.store(unseen, Ordering::Release);
    }

    fn kept(&self) -> MutexGuard<'_, Kept> {
        self.kept.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The events as `(kind, fields)` pairs.
    fn listed<'py>(py: Python<'py>, events: &[LinkEvent]) -> PyResult<Bound<'py, PyList>> {
        let list = PyList::empty(py);
        for e in events {
            if let Some(item) = event(py, e)? {
                list.append(item)?;
            }
        }
        Ok(list)
    }

    /// [`Rx::take`], then [`publish`](Self::publish); a base whose wait
    /// for control ran out is closed here.
    fn take(&self, slice: StdDuration) -> Result<Option<Sample>, NetError> {
        let mut rx = lock(&self.rx);
        let got = rx.take(slice);
        self.publish(&mut rx);
        match rx.waiting {
            Some((until, secs)) if rx.ended.is_none() && StdInstant::now() >= until => {
                rx.waiting = None;
                *self.gave_up.lock().unwrap_or_else(PoisonError::into_inner) = Some(secs);
                rx.link.shutdown();
                rx.ended = Some(CoreError::Closed);
                self.publish(&mut rx);
                Err(NetError::Link(CoreError::Closed))
            }
            _ => got,
        }
    }

    /// The exception for `e`: a link closed because control was not granted
    /// in time says so.
    fn error(&self, py: Python<'_>, e: NetError) -> PyErr {
        match *self.gave_up.lock().unwrap_or_else(PoisonError::into_inner) {
            Some(secs) => crate::errors::LinkError::new_err(format!(
                "control was not granted within wait_for_control={secs} s (another base held \
                 it): the link was closed; connect again, or wait longer"
            )),
            None => net_error(py, e),
        }
    }

    fn ended(&self, py: Python<'_>) -> Option<CoreError> {
        py.detach(|| lock(&self.rx).ended)
    }

    /// Ends the link (`how`: close or abort), keeps the events that tell
    /// how, and marks it ended for the receive calls.
    fn end(&self, py: Python<'_>, how: fn(&mut Link)) {
        py.detach(|| {
            let mut rx = lock(&self.rx);
            how(&mut rx.link);
            if rx.ended.is_none() {
                rx.ended = Some(CoreError::Closed);
            }
            self.publish(&mut rx);
            // The link's end is in the recording: let it go (the last
            // holder finishes the file).
            drop(
                self.recorder
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .take(),
            );
        });
        log::flush(py);
    }
}

impl Drop for PyLink {
    /// A link dropped without `close()` (garbage-collected, or the
    /// interpreter exiting) was abandoned: the peer must not take that for a
    /// normal end. A no-op after `close()`.
    fn drop(&mut self) {
        self.rx
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner)
            .link
            .abort();
    }
}

#[pymethods]
impl PyLink {
    /// The next released sample, waiting at most `timeout` seconds (`None`:
    /// as long as it takes). Raises `TimeoutError` when none came, a
    /// `LinkError` subclass once the link has ended.
    #[pyo3(signature = (timeout = None))]
    fn recv(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<PyTick> {
        let limit = blocking::timeout("timeout", timeout)?;
        let got = wait(py, limit, |slice| self.take(slice));
        log::flush(py);
        match got? {
            Ok(Some(release)) => Ok(PyTick { release }),
            Ok(None) => Err(net_error(py, NetError::Timeout)),
            Err(e) => Err(self.error(py, e)),
        }
    }

    /// The next released sample if one is waiting, else `None`; never blocks.
    fn try_recv(&self, py: Python<'_>) -> PyResult<Option<PyTick>> {
        let got = py.detach(|| self.take(StdDuration::ZERO));
        log::flush(py);
        got.map(|s| s.map(|release| PyTick { release }))
            .map_err(|e| self.error(py, e))
    }

    /// Puts a tick back in front of the queue (an asynchronous receive that
    /// was cancelled after it got the tick gives it back, so nothing is lost).
    fn unrecv(&self, py: Python<'_>, tick: &Bound<'_, PyTick>) {
        let release = tick.get().release.clone();
        py.detach(|| lock(&self.rx).stash.push_front(release));
    }

    /// Sets the sample sent at the next tick (the previous one is repeated,
    /// and counted, at ticks where none was given).
    fn send(&self, py: Python<'_>, sample: &Bound<'_, PyAny>) -> PyResult<()> {
        let values = to_sample("sample", sample, self.sender.width())?;
        if let Some(e) = self.ended(py) {
            return Err(self.error(py, NetError::Link(e)));
        }
        self.sender.send(&values).map_err(|e| self.error(py, e))
    }

    /// Base: gives control up; the link goes on as an observer's (the
    /// remote hands control to a base waiting for it). A `control_lost`
    /// event follows; a base that holds no control gets none.
    fn yield_control(&self, py: Python<'_>) -> PyResult<()> {
        if self.role != Role::Base {
            return Err(PyValueError::new_err(
                "yield_control() is a base's: the remote's side does not hold control",
            ));
        }
        let done = py.detach(|| lock(&self.rx).link.yield_control());
        done.map_err(|e| self.error(py, e))
    }

    /// Whether this link observes now: a base without control (it asked to
    /// observe, waits for control, or lost or yielded it), or a remote's
    /// link to such a base.
    #[getter]
    fn is_observer(&self) -> bool {
        self.observer.load(Ordering::Relaxed)
    }

    /// The seat the peer's Hello named: at the remote, the one its base
    /// asked for; at the base, the one the remote gave (`"observe"` to a
    /// base waiting for control): `"control"`, `"observe"` or
    /// `"wait_for_control"`.
    #[getter]
    fn peer_seat(&self) -> Option<&'static str> {
        self.peer_seat.map(Seat::name)
    }

    /// The events `new_events()` has returned, oldest first, as
    /// `(kind, fields)`; they leave. One that came since stays for the next
    /// `new_events()`, so that none skips Python's callbacks.
    fn events<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let events = self.kept().take_seen();
        Self::listed(py, &events)
    }

    /// The events that came since the last call, oldest first, as
    /// `(kind, fields)`; they stay for `events()`.
    fn new_events<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyList>> {
        let events = {
            let mut kept = self.kept();
            self.unseen.store(0, Ordering::Release);
            kept.take_new()
        };
        Self::listed(py, &events)
    }

    /// Events waiting for `new_events()`.
    #[getter]
    fn unseen_events(&self) -> usize {
        self.unseen.load(Ordering::Acquire)
    }

    /// Events dropped because more than `EVENT_BACKLOG` waited for
    /// `events()`, here or in the Rust link (`stats()["events_dropped"]`).
    #[getter]
    fn events_dropped(&self) -> u64 {
        let here = self.kept().dropped;
        here + self.sender.stats().map_or(0, |s| s.events_dropped)
    }

    /// A snapshot of the link's state and counters (`None` before its first
    /// tick): `LinkStats` serialized, the events this binding dropped
    /// counted with the Rust link's.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let Some(mut s) = self.sender.stats() else {
            return Ok(None);
        };
        s.events_dropped += self.kept().dropped;
        let stats = serialized(py, &s)?;
        let role = if self.is_observer() {
            "observer"
        } else {
            "controller"
        };
        stats.set_item("role", role)?;
        Ok(Some(stats))
    }

    /// The link's figures as Prometheus text (version 0.0.4), the page
    /// `ndr remote --metrics` serves, for this link alone: labelled with
    /// its peer, role and transport.
    fn metrics(&self) -> String {
        let labels = LinkLabels::new(self.peer.to_string(), self.role, self.transport);
        let metrics = Metrics::new();
        metrics.watch_link(labels, &self.sender);
        metrics.encode()
    }

    /// The recording's counts (`record=`): `None` without one, or once
    /// the link has closed.
    fn recording<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let stats = self
            .recorder
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .as_ref()
            .map(|r| r.stats());
        stats.map(|s| serialized(py, &s)).transpose()
    }

    /// Now on this side's link clock (s): `released_at` and `arrived_at` are on it.
    fn now(&self) -> f64 {
        self.sender.now().as_secs_f64()
    }

    /// Closes the link (a Close frame tells the peer) and waits, two seconds
    /// at most, for it to be let go. Receiving then raises `LinkClosedError`.
    fn close(&self, py: Python<'_>) {
        self.end(py, Link::shutdown);
    }

    /// Ends the link as a failure of this application (the peer gets Close
    /// code 8, "application failure", not a normal end) and waits as
    /// `close` does. Receiving then raises `LinkClosedError`.
    fn abort(&self, py: Python<'_>) {
        self.end(py, Link::abort);
    }

    /// Values in each command (base → remote).
    #[getter]
    fn command_width(&self) -> usize {
        self.widths.0
    }

    /// Values in each state (remote → base).
    #[getter]
    fn state_width(&self) -> usize {
        self.widths.1
    }

    /// Axes: the width of both directions when they are the same.
    #[getter]
    fn axes(&self) -> PyResult<usize> {
        match self.widths {
            (c, s) if c == s => Ok(c),
            (c, s) => Err(pyo3::exceptions::PyAttributeError::new_err(format!(
                "this link's commands carry {c} values and its states {s}: read \
                 command_width and state_width"
            ))),
        }
    }

    /// The period the link was set up with (s).
    #[getter]
    fn period(&self) -> f64 {
        self.period
    }

    /// `"base"` or `"remote"`.
    #[getter]
    fn role(&self) -> &'static str {
        role_name(self.role)
    }

    /// The peer's address as `(host, port)`.
    #[getter]
    fn peer(&self) -> (String, u16) {
        (self.peer.ip().to_string(), self.peer.port())
    }
}

fn role_name(role: Role) -> &'static str {
    match role {
        Role::Base => "base",
        Role::Remote => "remote",
    }
}

fn event<'py>(py: Python<'py>, e: &LinkEvent) -> PyResult<Option<Bound<'py, PyAny>>> {
    let fields = PyDict::new(py);
    match e {
        Event::Connected { peer } => {
            fields.set_item("peer_role", role_name(peer.role))?;
            fields.set_item("command_width", peer.command_width)?;
            fields.set_item("state_width", peer.state_width)?;
            fields.set_item("layout", peer.layout)?;
            fields.set_item("period", peer.period.as_secs_f64())?;
            fields.set_item("mode", Mode::try_from(peer.mode).ok().map(Mode::name))?;
            fields.set_item("seat", peer.seat.name())?;
        }
        Event::ControlGranted { term }
        | Event::ControlLost { term }
        | Event::ControlYielded { term } => fields.set_item("term", term)?,
        Event::Applied(a) => {
            fields.set_item("term", a.term)?;
            fields.set_item("seq", a.seq)?;
            fields.set_item("sent_at", a.sent_at.as_secs_f64())?;
            fields.set_item("applied_at", a.applied_at.as_secs_f64())?;
            fields.set_item("arrived_at", a.arrived_at.as_secs_f64())?;
            fields.set_item("values", PyArray1::from_slice(py, a.values()))?;
        }
        Event::Started { period, ns } | Event::Paused { period, ns } => {
            fields.set_item("period", period.as_secs_f64())?;
            fields.set_item("ns", ns)?;
        }
        Event::LinkLost { silent_for } => {
            fields.set_item("silent_for", silent_for.as_secs_f64())?;
        }
        Event::LinkRestored { outage } => {
            fields.set_item("outage", outage.as_secs_f64())?;
        }
        Event::DelayChanged { delay, ticks } => {
            fields.set_item("delay", delay.as_secs_f64())?;
            fields.set_item("ticks", ticks)?;
        }
        Event::RoundTripChanged { grtt, ticks } => {
            fields.set_item("grtt", grtt.as_secs_f64())?;
            fields.set_item("ticks", ticks)?;
        }
        Event::Closed { error } => {
            let normal = matches!(
                error,
                None | Some(
                    CoreError::PeerClosed {
                        reason: ndr_core::wire::CloseReason::Normal
                    } | CoreError::Closed
                )
            );
            fields.set_item("error", error.map(|e| e.to_string()))?;
            fields.set_item("normal", normal)?;
        }
        // Releases reach Python as ticks, not events.
        Event::Released(_) => return Ok(None),
        // Its kind, the Rust name, and nothing else yet.
        _ => {}
    }
    Ok(Some((e.kind(), fields).into_pyobject(py)?.into_any()))
}

/// The settings of one side of a link, checked once (`ndr.Link.connect`
/// and `ndr.Link.listen` build one from their keyword arguments).
#[pyclass(frozen, module = "ndr._native", name = "_LinkSettings")]
pub struct PyLinkSettings {
    config: LinkConfig,
    role: Role,
    /// `wait_for_control=`: how long a base observes, waiting for control.
    wait_for_control: Option<f64>,
}

impl PyLinkSettings {
    /// Whether `tls` fits the transport: QUIC runs mutual TLS, plain UDP
    /// does not run beside it.
    fn check_tls(&self, tls: bool) -> PyResult<()> {
        self.config
            .transport
            .check_security(tls)
            .map_err(|e| transport_error(&e))
    }
}

#[pymethods]
impl PyLinkSettings {
    #[new]
    #[pyo3(signature = (*, role, axes, command_width, state_width, period, regulation, underflow, watchdog, liveness, handshake_timeout, app_queue, insecure, transport, realtime, rt_priority, rt_cpu, observers = None, observe = false, wait_for_control = None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        role: &str,
        axes: &Bound<'_, PyAny>,
        command_width: &Bound<'_, PyAny>,
        state_width: &Bound<'_, PyAny>,
        period: f64,
        regulation: Option<&str>,
        underflow: &str,
        watchdog: Option<f64>,
        liveness: Option<f64>,
        handshake_timeout: f64,
        app_queue: &Bound<'_, PyAny>,
        insecure: bool,
        transport: &str,
        realtime: &str,
        rt_priority: &Bound<'_, PyAny>,
        rt_cpu: &Bound<'_, PyAny>,
        observers: Option<&Bound<'_, PyAny>>,
        observe: bool,
        wait_for_control: Option<f64>,
    ) -> PyResult<Self> {
        let role = match role {
            "base" => Role::Base,
            "remote" => Role::Remote,
            other => {
                return Err(PyValueError::new_err(format!(
                    "role must be \"base\" (the operator's side) or \"remote\" (the robot's), got {other:?}"
                )));
            }
        };
        let max = u16::try_from(MAX_CHANNELS).unwrap_or(u16::MAX);
        let width = |name, value: &Bound<'_, PyAny>| -> PyResult<Option<u16>> {
            (!value.is_none())
                .then(|| int_in(name, value, 1, max))
                .transpose()
        };
        let axes = width("axes", axes)?;
        let widths = (
            width("command_width", command_width)?.or(axes).unwrap_or(1),
            width("state_width", state_width)?.or(axes).unwrap_or(1),
        );
        // (`queue` is the name `ndr.Link` gives it.)
        let app_queue = count("queue", app_queue, 1, MAX_APP_QUEUE)?;
        let mut endpoint = Config::new(role).with_widths(widths.0, widths.1);
        endpoint.period = positive("period", period)?;
        endpoint = endpoint.with_regulation(regulation::read(regulation, Regulation::ADAPTIVE)?);
        endpoint.underflow = underflow
            .parse::<Underflow>()
            .map_err(|e| PyValueError::new_err(format!("underflow: {e}")))?;
        endpoint.watchdog = watchdog.map(|w| positive("watchdog", w)).transpose()?;
        endpoint.liveness = liveness.map(|l| positive("liveness", l)).transpose()?;
        endpoint.handshake_timeout = positive("handshake_timeout", handshake_timeout)?;
        let transport = transport
            .parse::<ndr_net::Transport>()
            .map_err(|e| transport_error(&e))?;
        endpoint.transport = transport.carriage();
        // The link draws its datagram session token when it starts.
        let mut checked = endpoint;
        checked.session = checked.session.max(1);
        checked
            .validate()
            .map_err(|e| PyValueError::new_err(format!("link configuration: {e}")))?;
        let mut config = LinkConfig::new(endpoint).with_transport(transport);
        config.app_queue = app_queue;
        config.insecure = insecure;
        config.realtime = realtime_settings(realtime, rt_priority, rt_cpu)?;
        config.endpoint.seat = seat(role, observe, wait_for_control)?;
        config.admission.observers = observers
            .map(|n| {
                if role != Role::Remote {
                    return Err(PyValueError::new_err(
                        "observers= is a remote's: the robot's listener serves one \
                         controller and up to that many observers",
                    ));
                }
                count("observers", n, 0, MAX_OBSERVERS)
            })
            .transpose()?;
        Ok(PyLinkSettings {
            config,
            role,
            wait_for_control,
        })
    }
}

/// `observe=`, `wait_for_control=` as the seat a base asks for.
fn seat(role: Role, observe: bool, wait_for_control: Option<f64>) -> PyResult<Seat> {
    if let Some(s) = wait_for_control {
        positive("wait_for_control", s)?;
    }
    match (observe, wait_for_control) {
        (false, None) => Ok(Seat::Control),
        _ if role != Role::Base => Err(PyValueError::new_err(
            "observe= and wait_for_control= are a base's: a remote serves control, \
             it does not ask for it",
        )),
        (true, Some(_)) => Err(PyValueError::new_err(
            "observe=True and wait_for_control= ask for two seats: give observe=True to \
             watch and never control, or wait_for_control=SECONDS to watch until control \
             frees and then take it",
        )),
        (true, None) => Ok(Seat::Observe),
        (false, Some(_)) => Ok(Seat::WaitForControl),
    }
}

/// `realtime=`, `rt_priority=`, `rt_cpu=` as the hub's [`Realtime`](ndr_net::Realtime).
fn realtime_settings(
    mode: &str,
    priority: &Bound<'_, PyAny>,
    cpu: &Bound<'_, PyAny>,
) -> PyResult<ndr_net::Realtime> {
    let mode = mode
        .parse::<ndr_net::RealtimeMode>()
        .map_err(|e| PyValueError::new_err(format!("realtime: {e}")))?;
    let priority = int_in::<u8>("rt_priority", priority, 1, 99)?;
    // As many CPUs as a Linux CPU set holds.
    let cpu = (!cpu.is_none())
        .then(|| int_in::<usize>("rt_cpu", cpu, 0, 1023))
        .transpose()?;
    let rt = ndr_net::Realtime::default()
        .with_mode(mode)
        .with_priority(priority)
        .map_err(|e| PyValueError::new_err(format!("rt_priority: {e}")))?;
    Ok(match cpu {
        Some(cpu) => rt.on_cpu(cpu),
        None => rt,
    })
}

/// Connects to a peer (over mutual TLS with `tls`) and waits for the
/// handshake.
#[pyfunction]
#[pyo3(signature = (address, settings, *, connect_timeout, reconnect = false, tls = None, record = None))]
pub fn connect(
    py: Python<'_>,
    address: &Bound<'_, PyAny>,
    settings: &PyLinkSettings,
    connect_timeout: Option<f64>,
    reconnect: bool,
    tls: Option<&Bound<'_, PyTlsConfig>>,
    record: Option<PathBuf>,
) -> PyResult<PyLink> {
    let (mut config, role) = (settings.config.clone(), settings.role);
    let (period, transport) = (config.endpoint.period, config.transport);
    let wait_for_control = settings.wait_for_control;
    let addr = blocking::address(py, address)?;
    let limit = blocking::timeout("connect_timeout", connect_timeout)?;
    if reconnect && role == Role::Remote {
        return Err(PyValueError::new_err(
            "reconnect=True is a base's: a remote serves the next base that comes \
             (Link.listen), or connect as the base",
        ));
    }
    // The library waits for the remote up to the limit, and reconnects.
    config.wait_for_remote = limit.unwrap_or_default().into();
    config.reconnect = reconnect;
    let tls = tls.map(|t| t.get().inner.clone());
    settings.check_tls(tls.is_some())?;
    if tls.is_some() && role == Role::Remote {
        return Err(PyValueError::new_err(
            "a remote that dials out cannot use TLS (the TLS client is the base): \
             listen on the remote, or connect as the base",
        ));
    }
    if tls.is_none() && !ndr_net::tls::plain_allowed(addr.ip(), config.insecure) {
        return Err(net_error(py, NetError::Insecure(addr)));
    }
    // Before connecting: a path that cannot be written fails at once.
    let recorder = recorder(py, record)?;
    let rt = blocking::runtime()?;
    let hub = blocking::hub()?.clone();
    config.tls.clone_from(&tls);
    // The connection, the TLS handshake and ndr's run as a task, so a wait
    // cut short (Ctrl-C) can abandon it cleanly; each step has its limit.
    let handshake_limit: StdDuration = config.endpoint.handshake_timeout.into();
    let mut task = rt.spawn(async move {
        let connect = async {
            match (tls, role) {
                (Some(_), _) | (None, Role::Base) => Link::connect(addr, config.on_hub(hub)).await,
                (None, Role::Remote) => {
                    let stream = tokio::net::TcpStream::connect(addr).await?;
                    Link::from_stream(stream, role, config, &hub)
                }
            }
        };
        // A little past the library's own wait, which ends with the last
        // attempt's error (refused, unreachable) rather than a timeout.
        let mut link = match limit.map(|l| l + StdDuration::from_secs(1)) {
            Some(l) => tokio::time::timeout(l, connect)
                .await
                .map_err(|_| Step::Connect)??,
            None => connect.await?,
        };
        tokio::time::timeout(handshake_limit, link.handshake())
            .await
            .map_err(|_| Step::Handshake)??;
        Ok::<Link, Step>(link)
    });
    let attempt = |slice: StdDuration| {
        rt.block_on(async {
            match tokio::time::timeout(slice, &mut task).await {
                Ok(Ok(done)) => done.map(Some),
                Ok(Err(join)) => Err(Step::Failed(NetError::Io(std::io::Error::other(format!(
                    "the connection task failed: {join}"
                ))))),
                Err(_) => Ok(None),
            }
        })
    };
    let waited = wait(py, None, attempt);
    log::flush(py);
    let link = match waited {
        Ok(Ok(Some(link))) => link,
        // (The wait has no limit of its own: the task's steps have theirs.)
        Ok(Ok(None) | Err(Step::Connect)) => {
            return Err(timed_out(&format!("could not connect to {addr}"), limit));
        }
        Ok(Err(Step::Handshake)) => {
            return Err(timed_out(
                "the peer did not complete the handshake",
                Some(handshake_limit),
            ));
        }
        Ok(Err(Step::Failed(NetError::Io(e)))) => {
            return Err(os_error(py, &e, Some(&format!("cannot connect to {addr}"))));
        }
        Ok(Err(Step::Failed(e))) => return Err(net_error(py, e)),
        Err(interrupted) => {
            task.abort();
            return Err(interrupted);
        }
    };
    let py_link = PyLink::new(link, role, transport, period)
        .recorded(recorder)
        .map_err(|e| net_error(py, e))?;
    if let Some(secs) = wait_for_control
        && py_link.is_observer()
    {
        let until = StdInstant::now() + StdDuration::from_secs_f64(secs);
        lock(&py_link.rx).waiting = Some((until, secs));
    }
    Ok(py_link)
}

/// The recorder `record=` asks for, if any.
fn recorder(py: Python<'_>, record: Option<PathBuf>) -> PyResult<Option<Arc<Recorder>>> {
    let Some(path) = record else {
        return Ok(None);
    };
    match py.detach(|| Recorder::create(&path, RecordConfig::default())) {
        Ok(r) => Ok(Some(Arc::new(r))),
        Err(RecordError::Create { error, .. }) => Err(os_error(
            py,
            &error,
            Some(&format!("cannot create the recording {}", path.display())),
        )),
        Err(e) => Err(PyRuntimeError::new_err(e.to_string())),
    }
}

/// Where a connection attempt stopped.
enum Step {
    /// No TCP connection (and TLS handshake) within `connect_timeout`.
    Connect,
    /// No ndr handshake within `handshake_timeout`.
    Handshake,
    /// The link failed.
    Failed(NetError),
}

impl From<NetError> for Step {
    fn from(e: NetError) -> Self {
        Step::Failed(e)
    }
}

impl From<std::io::Error> for Step {
    fn from(e: std::io::Error) -> Self {
        Step::Failed(NetError::Io(e))
    }
}

/// The native listener (`ndr.Listener` wraps it).
#[pyclass(frozen, module = "ndr._native", name = "_Listener")]
pub struct PyListener {
    listener: Mutex<Option<Arc<Listener>>>,
    /// The accept under way on the runtime, kept across calls that gave
    /// up (a timeout, Ctrl-C), so that a peer it accepts is not lost.
    pending: Mutex<Option<PendingAccept>>,
    local: SocketAddr,
    period: Duration,
    role: Role,
    transport: Transport,
    /// The recording every accepted link goes to (`record=`), let go
    /// when the listener closes.
    recorder: Mutex<Option<Arc<Recorder>>>,
}

impl Drop for PyListener {
    /// A listener dropped unclosed: its pending accept must not keep it
    /// listening.
    fn drop(&mut self) {
        if let Some(p) = self
            .pending
            .get_mut()
            .unwrap_or_else(PoisonError::into_inner)
            .take()
        {
            p.task.abort();
        }
    }
}

/// An accept running as a task on the binding's runtime: the caller waits
/// on a plain channel (its own clock, no runtime timer), and the task is
/// aborted when the listener closes.
struct PendingAccept {
    result: mpsc::Receiver<Result<Link, NetError>>,
    task: tokio::task::JoinHandle<()>,
}

/// Listens for peers (over mutual TLS with `tls`).
#[pyfunction]
#[pyo3(signature = (address, settings, *, tls = None, record = None))]
pub fn listen(
    py: Python<'_>,
    address: &Bound<'_, PyAny>,
    settings: &PyLinkSettings,
    tls: Option<&Bound<'_, PyTlsConfig>>,
    record: Option<PathBuf>,
) -> PyResult<PyListener> {
    let (mut config, role) = (settings.config.clone(), settings.role);
    let period = config.endpoint.period;
    let addr = blocking::address(py, address)?;
    let rt = blocking::runtime()?;
    config.tls = tls.map(|t| t.get().inner.clone());
    settings.check_tls(config.tls.is_some())?;
    let recorder = recorder(py, record)?;
    let listener = py
        .detach(|| rt.block_on(Listener::listen(addr, config)))
        .map_err(|e| net_error(py, e))?
        .with_role(role);
    let local = listener.local_addr().map_err(|e| net_error(py, e))?;
    Ok(PyListener {
        listener: Mutex::new(Some(Arc::new(listener))),
        pending: Mutex::new(None),
        local,
        period,
        role,
        transport: settings.config.transport,
        recorder: Mutex::new(recorder),
    })
}

impl PyListener {
    fn tls_stats(&self, py: Python<'_>) -> ndr_net::ListenerStats {
        py.detach(|| {
            self.listener
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .as_ref()
                .map(|l| l.stats())
                .unwrap_or_default()
        })
    }
}

#[pymethods]
impl PyListener {
    /// The next peer whose handshakes succeed, as a running link; `None`
    /// when `timeout` passed first. A peer that fails its handshake is
    /// logged, counted in `stats` and skipped by the Rust listener.
    #[pyo3(signature = (timeout = None))]
    fn accept(&self, py: Python<'_>, timeout: Option<f64>) -> PyResult<Option<PyLink>> {
        let limit = blocking::timeout("timeout", timeout)?;
        let rt = blocking::runtime()?;
        let pending = py.detach(|| {
            let mut slot = self.pending.lock().unwrap_or_else(PoisonError::into_inner);
            if let Some(p) = slot.take() {
                return Ok(p);
            }
            let guard = self.listener.lock().unwrap_or_else(PoisonError::into_inner);
            let Some(listener) = guard.as_ref().map(Arc::clone) else {
                return Err(NetError::Link(CoreError::Closed));
            };
            let (tx, rx) = mpsc::sync_channel(1);
            let task = rt.spawn(async move {
                let _ = tx.send(listener.accept().await);
            });
            Ok(PendingAccept { result: rx, task })
        });
        let pending = match pending {
            Ok(p) => p,
            Err(e) => return Err(net_error(py, e)),
        };
        let mut pending = pending;
        let result = &mut pending.result;
        let got = wait(py, limit, move |slice| match result.recv_timeout(slice) {
            Ok(Ok(link)) => Ok(Some(link)),
            Ok(Err(e)) => Err(e),
            Err(mpsc::RecvTimeoutError::Timeout) => Ok(None),
            Err(mpsc::RecvTimeoutError::Disconnected) => Err(NetError::Link(CoreError::Closed)),
        });
        log::flush(py);
        let got = match got {
            Ok(Ok(None)) | Err(_) => {
                // Not done (timed out, or a signal): the next call waits on
                // the same accept.
                *self.pending.lock().unwrap_or_else(PoisonError::into_inner) = Some(pending);
                got
            }
            done => done,
        };
        match got? {
            Ok(Some(l)) => PyLink::new(l, self.role, self.transport, self.period)
                .recorded(
                    self.recorder
                        .lock()
                        .unwrap_or_else(PoisonError::into_inner)
                        .clone(),
                )
                .map(Some)
                .map_err(|e| net_error(py, e)),
            Ok(None) => Ok(None),
            Err(e) => Err(net_error(py, e)),
        }
    }

    /// Stops listening; links already accepted go on.
    fn close(&self, py: Python<'_>) {
        py.detach(|| {
            // The pending accept's task holds the listener too: abort it,
            // so that the listener (and its socket) goes now.
            if let Some(p) = self
                .pending
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .take()
            {
                p.task.abort();
            }
            // The last of the listener and its links to let go of the
            // recording finishes it.
            drop(
                self.recorder
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .take(),
            );
            self.listener
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .take()
        });
    }

    /// The address it listens on, as `(host, port)`.
    #[getter]
    fn address(&self) -> (String, u16) {
        (self.local.ip().to_string(), self.local.port())
    }

    /// Peers refused: their TLS handshake failed (unknown or missing
    /// certificate, old TLS, timeout) or their ndr handshake did (another
    /// role, other settings, no answer), or the listener turned them away
    /// (evicted, too many from one source, busy, never taken).
    #[getter]
    fn refused(&self, py: Python<'_>) -> u64 {
        let s = self.tls_stats(py);
        s.refused_certificate
            + s.refused_no_certificate
            + s.refused_version
            + s.timeouts
            + s.failed_other
            + s.refused_role
            + s.refused_layout
            + s.refused_settings
            + s.refused_wire_version
            + s.refused_protocol
            + s.refused_transport
            + s.evicted
            + s.refused_per_source
            + s.refused_busy
            + s.refused_observer_only
            + s.refused_observers_full
            + s.unclaimed
    }

    /// A listener that shares its robot (`observers=`): the floor's
    /// counters, the notes it dropped, the applied commands it forwarded
    /// (`SharingStats` serialized); `None` otherwise.
    #[getter]
    fn sharing<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let stats = py.detach(|| {
            self.listener
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .as_ref()
                .and_then(|l| l.sharing())
        });
        stats.map(|s| serialized(py, &s)).transpose()
    }

    /// What the listener counted, by reason (`ListenerStats` serialized).
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        serialized(py, &self.tls_stats(py))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lost(ms: u64) -> LinkEvent {
        Event::LinkLost {
            silent_for: Duration::from_millis(ms),
        }
    }

    #[test]
    fn events_go_to_the_callbacks_once_and_leave_only_once_seen() {
        let mut kept = Kept::default();
        assert_eq!(kept.extend([lost(1), lost(2)]), 2);
        assert_eq!(kept.take_new(), [lost(1), lost(2)]);
        assert_eq!(kept.extend([lost(3)]), 1);
        // The one that came after the callbacks ran waits for them.
        assert_eq!(kept.take_seen(), [lost(1), lost(2)]);
        assert_eq!(kept.take_seen(), []);
        assert_eq!(kept.take_new(), [lost(3)]);
        assert_eq!(kept.take_new(), []);
        assert_eq!(kept.take_seen(), [lost(3)]);
        assert_eq!(kept.dropped, 0);
    }

    #[test]
    fn past_the_backlog_the_oldest_events_go_and_are_counted() {
        let mut kept = Kept::default();
        let n = EVENT_BACKLOG as u64;
        kept.extend((0..n - 1).map(lost));
        assert_eq!(kept.take_new().len(), EVENT_BACKLOG - 1);
        // Three more than there is room for: the two oldest, seen, go.
        assert_eq!(kept.extend((n - 1..n + 2).map(lost)), 3);
        assert_eq!(kept.dropped, 2);
        assert_eq!(kept.take_new(), [lost(n - 1), lost(n), lost(n + 1)]);
        let seen = kept.take_seen();
        assert_eq!(seen.len(), EVENT_BACKLOG);
        assert_eq!(seen.first(), Some(&lost(2)));
        // Nobody looked: the oldest not seen go too.
        assert_eq!(kept.extend((0..n + 1).map(lost)), EVENT_BACKLOG);
        assert_eq!(kept.dropped, 3);
        assert_eq!(kept.take_new().first(), Some(&lost(1)));
    }
}
