//! One driver thread for many links: the [`Hub`].
//!
//! Each link's endpoint needs its deadlines kept to microseconds, which takes
//! a thread that sleeps, then spins the last stretch. One such thread per
//! link does not scale: at 100 Hz each spins about 2 % of a core. A hub runs
//! every endpoint it owns on one tick grid (one origin for all), so links of
//! the same period tick at the same instants and one spin serves them all.
//! Deadlines live in an ordered index; frames from the readers arrive on one
//! channel tagged with their link.

use std::collections::{BTreeSet, HashMap};
use std::io::{self, Write as _};
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering as AtomicOrdering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender, SyncSender, TrySendError};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Instant as StdInstant;

use ndr_core::endpoint::{Endpoint, Event, LinkError, Running};
use ndr_core::time::{Duration, Instant};
use ndr_core::wire::MAX_FRAME_LEN;
use tokio::sync::Notify;

use crate::clock::{DEFAULT_SPIN_MARGIN, DEFAULT_TIMER_SLACK, LatenessHistogram, LatenessStats};
use crate::framing::FramingError;
use crate::link::{LinkStats, MAX_AXES, QUEUE, Sample};

pub(crate) type LinkEndpoint = Endpoint<MAX_AXES, QUEUE>;

/// What a link's reader (or its application) tells the hub.
pub(crate) enum Input {
    Frame { at: StdInstant, bytes: Vec<u8> },
    Bad(FramingError),
    Eof,
    Close,
}

/// What the hub hands to a link's application.
pub(crate) enum Delivery {
    Sample(Sample),
    Event(Event<MAX_AXES>),
}

/// State a link's handle and the hub share.
pub(crate) struct Shared {
    /// The application's latest sample and whether it is new since the last tick.
    pub sample: Mutex<(Vec<f64>, bool)>,
    pub stats: Mutex<Option<LinkStats>>,
    pub notify: Notify,
}

/// One link as the hub drives it.
pub(crate) struct Entry {
    pub endpoint: Box<LinkEndpoint>,
    pub shared: Arc<Shared>,
    pub deliveries: SyncSender<Delivery>,
    /// The socket, written directly (non-blocking) while nothing waits in `out`.
    pub direct: std::net::TcpStream,
    pub queued: Arc<AtomicUsize>,
    pub out: tokio::sync::mpsc::UnboundedSender<Vec<u8>>,
    pub app_dropped: u64,
    /// From a frame's arrival (the kernel's stamp) to the hub handling it.
    pub rx_lag: Running,
    /// The deadline this entry holds in the hub's index.
    pub deadline: Option<Instant>,
}

pub(crate) enum Msg {
    Add(u64, Box<Entry>),
    Input(u64, Input),
}

struct Inner {
    tx: Sender<Msg>,
    next_id: AtomicU64,
    origin: StdInstant,
    links: Arc<AtomicUsize>,
}

/// A driver thread for any number of links; cheap to clone.
///
/// [`Link::connect`](crate::Link::connect) gives each link a hub of its own;
/// [`Hub::connect`] and [`Listener::with_hub`](crate::Listener::with_hub)
/// put many links on one.
#[derive(Clone)]
pub struct Hub {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for Hub {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Hub").field("links", &self.links()).finish()
    }
}

impl Hub {
    /// A hub with its driver thread (`ndr-hub`), spinning the last
    /// `spin_margin` before each deadline.
    pub fn new(spin_margin: Duration) -> io::Result<Hub> {
        let (tx, rx) = mpsc::channel();
        let origin = StdInstant::now();
        let links = Arc::new(AtomicUsize::new(0));
        let driver = Driver {
            origin,
            margin: spin_margin.into(),
            input: rx,
            entries: HashMap::new(),
            timers: BTreeSet::new(),
            lateness: LatenessHistogram::new(Duration::from_millis(1)),
            lateness_stats: LatenessStats::default(),
            wakes: 0,
            buf: vec![0; MAX_FRAME_LEN],
            links: Arc::clone(&links),
        };
        std::thread::Builder::new()
            .name("ndr-hub".into())
            .stack_size(8 << 20)
            .spawn(move || driver.run())?;
        Ok(Hub {
            inner: Arc::new(Inner {
                tx,
                next_id: AtomicU64::new(0),
                origin,
                links,
            }),
        })
    }

    /// A hub with the default spin margin (200 µs).
    pub fn with_defaults() -> io::Result<Hub> {
        Hub::new(DEFAULT_SPIN_MARGIN)
    }

    /// Links the hub drives now.
    #[must_use]
    pub fn links(&self) -> usize {
        self.inner.links.load(AtomicOrdering::Relaxed)
    }

    pub(crate) fn origin(&self) -> StdInstant {
        self.inner.origin
    }

    pub(crate) fn register(&self) -> (u64, Sender<Msg>) {
        let id = self.inner.next_id.fetch_add(1, AtomicOrdering::Relaxed);
        (id, self.inner.tx.clone())
    }
}

struct Driver {
    origin: StdInstant,
    margin: std::time::Duration,
    input: Receiver<Msg>,
    entries: HashMap<u64, Entry>,
    timers: BTreeSet<(Instant, u64)>,
    lateness: LatenessHistogram,
    /// Recomputed every so often: percentiles cost a histogram scan.
    lateness_stats: LatenessStats,
    wakes: u64,
    buf: Vec<u8>,
    links: Arc<AtomicUsize>,
}

impl Driver {
    fn local(&self, t: StdInstant) -> Instant {
        Instant::from_std(self.origin, t)
    }

    fn run(mut self) {
        // Best effort: a 1 µs timer slack makes the native sleep precise.
        let _ = crate::clock::set_current_thread_timer_slack(DEFAULT_TIMER_SLACK);
        loop {
            let next = self.timers.first().map(|&(t, _)| t);
            let deadline = next.and_then(|t| t.to_std(self.origin));
            let msg = match deadline {
                Some(d) => {
                    let wait = d
                        .saturating_duration_since(StdInstant::now())
                        .saturating_sub(self.margin);
                    self.input.recv_timeout(wait)
                }
                None => self
                    .input
                    .recv()
                    .map_err(|_| RecvTimeoutError::Disconnected),
            };
            match msg {
                Ok(m) => self.handle(m),
                Err(RecvTimeoutError::Timeout) => {
                    if let Some(d) = deadline {
                        self.tick(d);
                    }
                }
                // Every handle and reader is gone: nothing can reach the
                // remaining links (there are none in practice).
                Err(RecvTimeoutError::Disconnected) => return,
            }
        }
    }

    fn handle(&mut self, msg: Msg) {
        match msg {
            Msg::Add(id, entry) => {
                self.entries.insert(id, *entry);
                self.links
                    .store(self.entries.len(), AtomicOrdering::Relaxed);
                self.flush(id);
            }
            Msg::Input(id, input) => {
                let Some(e) = self.entries.get_mut(&id) else {
                    return;
                };
                match input {
                    Input::Frame { at, bytes } => {
                        e.rx_lag
                            .push_duration(StdInstant::now().saturating_duration_since(at).into());
                        let t = Instant::from_std(self.origin, at);
                        // A fatal error closes the endpoint, which reports it as an event.
                        let _ = e.endpoint.handle_frame(t, &bytes);
                    }
                    Input::Bad(FramingError::Wire(err)) => e.endpoint.abort(LinkError::from(err)),
                    Input::Eof => e.endpoint.abort(LinkError::Disconnected),
                    Input::Close => e.endpoint.close(),
                }
                self.flush(id);
            }
        }
    }

    /// The deadline `d` has come: spin to it, take what arrived before it,
    /// then run every endpoint that is due.
    fn tick(&mut self, d: StdInstant) {
        while StdInstant::now() < d {
            std::hint::spin_loop();
        }
        while let Ok(m) = self.input.try_recv() {
            self.handle(m);
        }
        let woke = StdInstant::now();
        self.lateness
            .record(woke.saturating_duration_since(d).into());
        self.wakes += 1;
        if self.wakes % 64 == 1 {
            self.lateness_stats = self.lateness.stats();
        }
        let now = self.local(woke);
        let due: Vec<u64> = self
            .timers
            .iter()
            .take_while(|&&(t, _)| t <= now)
            .map(|&(_, id)| id)
            .collect();
        for id in due {
            if let Some(e) = self.entries.get_mut(&id) {
                take_sample(e);
                e.endpoint.handle_timeout(now);
            }
            self.flush(id);
        }
    }

    /// Events to the application, frames to the socket, the deadline to the
    /// index; a closed link leaves the hub.
    fn flush(&mut self, id: u64) {
        let Some(e) = self.entries.get_mut(&id) else {
            return;
        };
        // Frames first: the application's answer to this tick's events
        // cannot make this tick anyway (its sample was taken before), and
        // waking its thread first would delay the frame by the wake-up.
        let now = Instant::from_std(self.origin, StdInstant::now());
        while let Ok(Some(n)) = e.endpoint.poll_transmit(now, &mut self.buf) {
            send_frame(e, &self.buf[..n]);
        }
        let mut delivered = false;
        while let Some(event) = e.endpoint.poll_event() {
            let d = match event {
                Event::Released(s) => Delivery::Sample(s),
                other => Delivery::Event(other),
            };
            match e.deliveries.try_send(d) {
                Ok(()) => delivered = true,
                Err(TrySendError::Full(_)) => e.app_dropped += 1,
                Err(TrySendError::Disconnected(_)) => {}
            }
        }
        if delivered {
            e.shared.notify.notify_one();
        }
        publish(e, self.lateness_stats);
        let next = e.endpoint.poll_timeout();
        if next != e.deadline {
            if let Some(old) = e.deadline {
                self.timers.remove(&(old, id));
            }
            if let Some(new) = next {
                self.timers.insert((new, id));
            }
            e.deadline = next;
        }
        if e.endpoint.is_closed() {
            if let Some(old) = e.deadline.take() {
                self.timers.remove(&(old, id));
            }
            // Dropping the entry ends its writer (which shuts the socket's
            // write side) and tells the application nothing more will come.
            self.entries.remove(&id);
            self.links
                .store(self.entries.len(), AtomicOrdering::Relaxed);
        }
    }
}

fn take_sample(e: &mut Entry) {
    let mut slot = e
        .shared
        .sample
        .lock()
        .unwrap_or_else(PoisonError::into_inner);
    if slot.1 {
        slot.1 = false;
        // Checked by `Link::send`.
        let _ = e.endpoint.set_sample(&slot.0);
    }
}

/// Writes a frame on the socket now if nothing waits for the writer task,
/// else queues it behind what waits (frames stay in order).
fn send_frame(e: &mut Entry, bytes: &[u8]) {
    let mut rest = bytes;
    if e.queued.load(AtomicOrdering::Acquire) == 0 {
        match e.direct.write(bytes) {
            Ok(n) if n == bytes.len() => return,
            Ok(n) => rest = &bytes[n..],
            // Full buffer, or a broken socket the writer will report.
            Err(_) => {}
        }
    }
    e.queued.fetch_add(1, AtomicOrdering::AcqRel);
    if e.out.send(rest.to_vec()).is_err() {
        e.queued.fetch_sub(1, AtomicOrdering::AcqRel);
    }
}

fn publish(e: &Entry, lateness: LatenessStats) {
    let ep = &e.endpoint;
    let stats = LinkStats {
        phase: ep.phase(),
        period: ep.period(),
        ns: ep.ns(),
        queue_len: ep.queue_len(),
        queue_range: ep.occupancy().map(|o| (o.min, o.max)),
        last_nrtt: ep.last_nrtt(),
        endpoint: ep.stats(),
        lateness,
        app_dropped: e.app_dropped,
        rx_lag: e.rx_lag,
    };
    *e.shared
        .stats
        .lock()
        .unwrap_or_else(PoisonError::into_inner) = Some(stats);
}
