//! One driver thread for many links: the [`Hub`].
//!
//! Each link's endpoint needs its deadlines kept to microseconds, which takes
//! a thread that sleeps, then spins the last stretch. One such thread per
//! link does not scale: at 100 Hz each spins about 2 % of a core. A hub runs
//! every endpoint it owns on one tick grid (one origin for all), so links of
//! the same period tick at the same instants and one spin serves them all.
//!
//! The hub also owns the links' sockets (non-blocking, polled with mio): a
//! frame goes from the kernel to its endpoint in one thread wake-up, with no
//! hand-over between threads, and frames are written from the same thread.
//! The same holds for UDP datagrams (`udp`) and QUIC connections (`quic`,
//! quinn-proto's state machine on the hub's UDP sockets).

mod quic;
mod tls_io;
mod udp;
#[cfg(feature = "zenoh")]
pub(crate) mod zenoh;

pub(crate) use quic::{Move as QuicMove, NewEndpoint, QuicPath, Server as QuicServer};
pub(crate) use tls_io::Session;
pub(crate) use udp::{DatagramPath, NewSocket, bind as bind_datagram_socket, session_token};

use std::collections::{BTreeSet, HashMap, VecDeque};
use std::io::{self, Write as _};
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering as AtomicOrdering};
use std::sync::mpsc::{self, Receiver, Sender};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Instant as StdInstant;

use mio::net::TcpStream as MioStream;
use mio::{Events, Interest, Poll, Token, Waker};
use ndr_core::endpoint::{Endpoint, Event, LinkError, Running};
use ndr_core::storage::Heap;
use ndr_core::time::{Duration, Instant};
use ndr_core::wire::{HEADER_LEN, MAX_DATAGRAM_LEN, MAX_FRAME_LEN};
use tokio::sync::Notify;

use crate::clock::{DEFAULT_SPIN_MARGIN, DEFAULT_TIMER_SLACK, LatenessHistogram, LatenessStats};
use crate::delivery::Sample;
use crate::delivery::{Delivery, Outbox, Refused};
use crate::framing::{Deframer, FramingError};
use crate::realtime::Realtime;
use crate::spin::SpinMargin;
use crate::stats::LinkStats;

/// The waker's token; links use their id.
const WAKER: Token = Token(usize::MAX);
/// The deadline timer's token.
const TIMER: Token = Token(usize::MAX - 1);
/// Bytes a link may have waiting for a slow socket before it is cut off.
const MAX_PENDING: usize = 1 << 20;
/// Frames of its largest size a link's socket may be read for a period of
/// its link, on average (and at least 4 KiB): a peer that sends faster
/// than that (a flood) is read no further until its link's next deadline,
/// so that it holds neither the hub from its other links' deadlines nor
/// its CPU; TCP's flow control then slows the peer. An honest peer sends a
/// frame or two a tick.
const READ_FRAMES_PER_DEADLINE: usize = 8;

/// How long before a release the hub wakes an application thread blocked
/// in `recv` (when its own wake-up came earlier), so that the thread is
/// running, spinning, when the release is queued: a thread's wake-up
/// takes tens of microseconds, which would otherwise follow the release.
const READER_LEAD: std::time::Duration = std::time::Duration::from_micros(100);

/// How long past the deadline a reader woken ahead spins for its release
/// before it blocks again (the release came late, or the deadline released
/// nothing).
const READER_SPIN_PAST: std::time::Duration = std::time::Duration::from_micros(100);
/// What a link's unused read allowance may grow to, in bytes: the backlog
/// a held process finds on its socket when it resumes (the frames its peer
/// sent meanwhile) is read at once, so that its endpoint sees them arrive
/// together, as an outage, rather than spread over ticks as delays.
const READ_ALLOWANCE_MAX: usize = MAX_PENDING;

/// What a link with frames of at most `max_frame` bytes may read a period.
fn read_budget(max_frame: usize) -> usize {
    (READ_FRAMES_PER_DEADLINE * max_frame).max(4096)
}

/// State a link's handle and the hub share.
pub(crate) struct Shared {
    /// The application's latest sample and whether it is new since the last tick.
    pub sample: Mutex<(Vec<f64>, bool)>,
    pub stats: Mutex<Option<LinkStats>>,
    pub notify: Notify,
    /// The certificate chain the peer presented (TLS, QUIC), once known:
    /// a shared robot's listener asks whether it may hold control.
    pub peer_chain: Mutex<Option<Vec<rustls::pki_types::CertificateDer<'static>>>>,
}

/// The application's code run at each release on the hub's thread
/// ([`Link::on_release`](crate::Link::on_release)).
pub(crate) type Handler = Box<dyn FnMut(&Sample) + Send>;

/// What sees every event of a link on the hub's thread before the
/// application does (a recorder's): it must only copy and hand off.
pub(crate) type Tap = Box<dyn FnMut(Tapped<'_>) + Send>;

/// What a [`Tap`] sees: the link's events, and its probes' arrivals
/// (which the application never gets).
// Only a recorder reads them: without `record` the hub still builds them.
#[cfg_attr(not(feature = "record"), allow(dead_code))]
pub(crate) enum Tapped<'a> {
    Event(&'a crate::delivery::LinkEvent),
    Probe(ndr_core::endpoint::ProbeArrival),
}

/// One link as the hub drives it.
pub(crate) struct Entry {
    endpoint: Endpoint<Heap>,
    shared: Arc<Shared>,
    /// How its frames reach the peer: the link's transport. Dropped
    /// before `deliveries`, whose end tells the application the link is
    /// gone: a zenoh session closes (sending what it queued, the Close)
    /// before the application may exit.
    path: Path,
    deliveries: Outbox,
    deframer: Deframer,
    /// Bytes the TCP stream would not take yet, in order.
    pending: Vec<u8>,
    app_dropped: u64,
    /// From a frame's arrival (the kernel's stamp) to the hub handling it.
    rx_lag: Running,
    /// The deadline this entry holds in the hub's index.
    deadline: Option<Instant>,
    /// Takes the releases instead of the application's queue, if set.
    pub(crate) handler: Option<Handler>,
    /// What its listener's floor hears of it (a shared robot's link).
    pub(crate) notes: Option<crate::sharing::Notes>,
    /// Sees every event first, if set.
    pub(crate) tap: Option<Tap>,
    /// Bytes its socket may still be read for (see
    /// [`READ_FRAMES_PER_DEADLINE`]), when that was last topped up, and
    /// whether the socket was left unread for want of them.
    read_left: usize,
    read_budget: usize,
    read_topped: StdInstant,
    throttled: bool,
}

/// A link's TCP stream, as the hub reads and writes it.
pub(crate) struct Stream {
    socket: MioStream,
    /// The kernel stamps what arrives on it (`SO_TIMESTAMPNS`).
    kernel_stamps: bool,
}

impl Stream {
    pub(crate) fn new(socket: MioStream, kernel_stamps: bool) -> Stream {
        Stream {
            socket,
            kernel_stamps,
        }
    }
}

/// How a link's frames reach its peer: one per transport.
pub(crate) enum Path {
    /// Every frame on a plain TCP stream.
    Tcp(Stream),
    /// Every frame on a TCP stream, in the TLS session continued from the
    /// handshake.
    Tls(Stream, Box<tls_io::Session>),
    /// The samples as UDP datagrams, the rest on the TCP stream.
    Udp(Stream, DatagramPath),
    /// Every frame on a QUIC connection: the samples as its datagrams.
    Quic(Box<QuicPath>),
    /// Every frame as a zenoh publication.
    #[cfg(feature = "zenoh")]
    Zenoh(Box<zenoh::ZenohPath>),
}

impl Path {
    fn stream(&self) -> Option<&Stream> {
        match self {
            Path::Tcp(s) | Path::Tls(s, _) | Path::Udp(s, _) => Some(s),
            _ => None,
        }
    }

    fn socket(&self) -> Option<&MioStream> {
        self.stream().map(|s| &s.socket)
    }

    fn socket_mut(&mut self) -> Option<&mut MioStream> {
        match self {
            Path::Tcp(s) | Path::Tls(s, _) | Path::Udp(s, _) => Some(&mut s.socket),
            _ => None,
        }
    }

    fn kernel_stamps(&self) -> bool {
        self.stream().is_none_or(|s| s.kernel_stamps)
    }

    fn has_tls(&self) -> bool {
        matches!(self, Path::Tls(..))
    }

    fn is_zenoh(&self) -> bool {
        #[cfg(feature = "zenoh")]
        return matches!(self, Path::Zenoh(_));
        #[cfg(not(feature = "zenoh"))]
        false
    }

    /// What a zenoh link counted: frames dropped on arrival, not sent.
    fn zenoh_counts(&self) -> (u64, u64) {
        #[cfg(feature = "zenoh")]
        if let Path::Zenoh(z) = self {
            return (
                z.counters.dropped.load(AtomicOrdering::Relaxed),
                z.counters.unsent.load(AtomicOrdering::Relaxed),
            );
        }
        (0, 0)
    }

    /// The TLS session and its stream.
    fn tls_mut(&mut self) -> Option<(&mut tls_io::Session, &mut Stream)> {
        match self {
            Path::Tls(s, tls) => Some((tls, s)),
            _ => None,
        }
    }

    fn datagram(&self) -> Option<&DatagramPath> {
        match self {
            Path::Udp(_, d) => Some(d),
            _ => None,
        }
    }

    fn datagram_mut(&mut self) -> Option<&mut DatagramPath> {
        match self {
            Path::Udp(_, d) => Some(d),
            _ => None,
        }
    }

    fn quic(&self) -> Option<&QuicPath> {
        match self {
            Path::Quic(q) => Some(q),
            _ => None,
        }
    }

    fn quic_mut(&mut self) -> Option<&mut QuicPath> {
        match self {
            Path::Quic(q) => Some(q),
            _ => None,
        }
    }
}

impl Entry {
    /// A link for the hub: its endpoint, what its handle shares, its queue
    /// to the application and its path; frames of at most `max_frame` bytes
    /// come in.
    pub(crate) fn new(
        endpoint: Endpoint<Heap>,
        shared: Arc<Shared>,
        deliveries: Outbox,
        path: Path,
        max_frame: usize,
    ) -> Entry {
        Entry {
            endpoint,
            shared,
            deliveries,
            path,
            deframer: Deframer::with_max_frame(max_frame),
            pending: Vec::new(),
            app_dropped: 0,
            rx_lag: Running::default(),
            deadline: None,
            handler: None,
            notes: None,
            tap: None,
            read_left: read_budget(max_frame),
            read_budget: read_budget(max_frame),
            read_topped: StdInstant::now(),
            throttled: false,
        }
    }

    /// Sets what sees its events first; a tap sees its probes' arrivals
    /// too, kept by its endpoint from now on.
    pub(crate) fn set_tap(&mut self, tap: Option<Tap>) {
        self.endpoint.keep_probe_arrivals(tap.is_some());
        self.tap = tap;
    }

    /// Takes `n` bytes read from its socket off what it may read before
    /// its next deadline; `true` if it may read no more (unless `drain`:
    /// a closing socket is read to its end).
    /// Adds to what its socket may be read for, by the periods elapsed
    /// since the last top-up, up to [`READ_ALLOWANCE_MAX`].
    fn top_up_read(&mut self, now: StdInstant) {
        let period = self.endpoint.period().as_secs_f64();
        let elapsed = now
            .saturating_duration_since(self.read_topped)
            .as_secs_f64();
        let periods = if period > 0.0 { elapsed / period } else { 1.0 };
        // At least a period's worth at each deadline (`as` saturates).
        let grant = ((periods * self.read_budget as f64) as usize).max(self.read_budget);
        self.read_left = self
            .read_left
            .saturating_add(grant)
            .min(READ_ALLOWANCE_MAX.max(self.read_budget));
        self.read_topped = now;
    }

    fn spend_read(&mut self, n: usize, drain: bool) -> bool {
        self.read_left = self.read_left.saturating_sub(n);
        self.throttled = self.read_left == 0 && !drain;
        self.throttled
    }

    /// Writes a plain base's Hello now, from the connecting task, rather
    /// than when its hub next runs: it leaves with the connection, so a
    /// listener that looks at the connection as it accepts it sees a peer
    /// that spoke, not a silent one it could take for a stale connection
    /// from the same address. Anything the socket does not take waits for
    /// the hub.
    pub(crate) fn say_hello(&mut self, origin: StdInstant) {
        if self.path.has_tls() {
            return;
        }
        let Some(socket) = self.path.socket_mut() else {
            return;
        };
        let mut frame = [0u8; HEADER_LEN + 64];
        let now = Instant::from_std(origin, StdInstant::now());
        // The Hello alone is queued when a base's endpoint is made.
        if let Ok(Some(n)) = self.endpoint.poll_transmit(now, &mut frame)
            && let Some(bytes) = frame.get(..n)
            && !ndr_core::wire::is_bundle(bytes)
        {
            write_or_queue(socket, &mut self.pending, bytes);
        }
    }
}

pub(crate) enum Msg {
    Add(u64, Box<Entry>),
    Close(u64),
    /// Ends the link with this error, whose close reason the peer gets
    /// (an application failure, [`LinkError::Abandoned`]; a listener's
    /// refusal, [`LinkError::Busy`]).
    Fail(u64, LinkError),
    Handler(u64, Handler),
    Tap(u64, Tap),
    /// A UDP socket for datagram links, polled under this key.
    Socket(u64, Box<NewSocket>),
    /// The socket's owner (a listener) is gone: it closes with its last link.
    ReleaseSocket(u64),
    /// A QUIC endpoint on a UDP socket, polled under this key.
    Quic(u64, Box<NewSocket>, Box<NewEndpoint>),
    /// A listener's link, its handshakes done, leaves for the hub that
    /// will drive it.
    Move(u64, Box<quic::Move>),
    /// A packet of a link's connection (or an answer), from the hub of
    /// the endpoint that routes it.
    QuicForwarded(u64, Box<quic::Forwarded>),
    /// A request of a moved link's connection to the endpoint under this
    /// key.
    QuicRequest(u64, Box<quic::Request>),
    /// Something of control's hand-over for the link's endpoint to do
    /// (its listener's floor asks, or its base's application).
    Seat(u64, Box<crate::sharing::SeatOp>),
}

struct Inner {
    /// `None` only while dropping (see `Drop`).
    tx: Option<Sender<Msg>>,
    /// Shared with the driver: the waker's eventfd must stay open until the
    /// thread has taken the last wake (closing it drops a pending event).
    waker: Arc<Waker>,
    next_id: AtomicU64,
    origin: StdInstant,
    links: Arc<AtomicUsize>,
    /// The keys of the hub's own UDP sockets (IPv4, IPv6), once made.
    own_udp: Mutex<[Option<u64>; 2]>,
}

impl Drop for Inner {
    /// The last handle is gone: close the channel, then wake the thread so it
    /// sees that and ends (it has no link left: links hold handles).
    fn drop(&mut self) {
        drop(self.tx.take());
        let _ = self.waker.wake();
    }
}

/// A driver thread for any number of links; cheap to clone.
///
/// [`Link::connect`](crate::Link::connect) gives each link a hub of its own
/// unless its configuration names one
/// ([`LinkConfig::on_hub`](crate::LinkConfig::on_hub), for links and
/// listeners alike): then many links share it.
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
    /// A hub with its driver thread (`ndr-hub`), spinning at most the last
    /// `spin_margin` before each deadline: given as a [`Duration`], it learns
    /// a shorter margin from how late its timer wakes ([`crate::spin`]);
    /// [`SpinMargin::fixed`] spins the whole of it.
    ///
    /// The thread asks for real-time scheduling as [`Realtime::default`]
    /// says (`SCHED_FIFO` if the host grants it, a warning if not): see
    /// [`with_realtime`](Self::with_realtime).
    pub fn new(spin_margin: impl Into<SpinMargin>) -> io::Result<Hub> {
        Hub::with_realtime(spin_margin, Realtime::default())
    }

    /// [`new`](Self::new), its thread asking for `realtime` as it starts
    /// ([`crate::realtime`]).
    ///
    /// # Errors
    ///
    /// The thread cannot start, or under [`RealtimeMode::Enforce`](crate::realtime::RealtimeMode::Enforce)
    /// the host refuses: an [`io::Error`] holding the
    /// [`RealtimeError`](crate::realtime::RealtimeError) (a
    /// [`NetError`](crate::NetError) made from it is `NetError::Realtime`).
    pub fn with_realtime(
        spin_margin: impl Into<SpinMargin>,
        realtime: Realtime,
    ) -> io::Result<Hub> {
        Hub::with_origin(spin_margin.into(), StdInstant::now(), realtime)
    }

    /// A hub whose tick grid starts at `origin` (hubs of one pool share it,
    /// so their links tick at the same instants, in parallel).
    pub(crate) fn with_origin(
        spin: SpinMargin,
        origin: StdInstant,
        realtime: Realtime,
    ) -> io::Result<Hub> {
        let (tx, rx) = mpsc::channel();
        let poll = Poll::new()?;
        let waker = Arc::new(Waker::new(poll.registry(), WAKER)?);
        let links = Arc::new(AtomicUsize::new(0));
        let timer = precise::Timer::new(poll.registry(), TIMER);
        let driver = Driver {
            poll,
            timer,
            origin,
            spin,
            armed: None,
            readers_woken: None,
            input: rx,
            entries: HashMap::new(),
            timers: BTreeSet::new(),
            lateness: LatenessHistogram::new(Duration::from_millis(1)),
            releases: LatenessHistogram::new(Duration::from_millis(1)),
            figures: HubFigures {
                lateness: LatenessStats::default(),
                release_lateness: LatenessStats::default(),
                spin_margin: spin.current(),
            },
            wakes: 0,
            backlog: VecDeque::new(),
            events: Events::with_capacity(1024),
            due: Vec::new(),
            udp: udp::Udp::new(),
            quic: quic::Quic::new(),
            accepted: Vec::new(),
            touched: Vec::new(),
            service: Cost::new(),
            polling: Cost::new(),
            waking: Cost::new(),
            // A datagram's Bundle may be longer than any frame of a stream.
            buf: vec![0; MAX_FRAME_LEN.max(MAX_DATAGRAM_LEN)],
            links: Arc::clone(&links),
            _waker: Arc::clone(&waker),
        };
        crate::realtime::spawn("ndr-hub", 8 << 20, realtime, move || driver.run())?;
        Ok(Hub {
            inner: Arc::new(Inner {
                tx: Some(tx),
                waker,
                next_id: AtomicU64::new(0),
                origin,
                links,
                own_udp: Mutex::new([None, None]),
            }),
        })
    }

    /// A hub with the default spin margin (200 µs).
    pub fn with_defaults() -> io::Result<Hub> {
        Hub::new(DEFAULT_SPIN_MARGIN)
    }

    /// Links the hub drives now (counted from the moment a link is handed
    /// to it until it has let the link go).
    #[must_use]
    pub fn links(&self) -> usize {
        self.inner.links.load(AtomicOrdering::Relaxed)
    }

    pub(crate) fn origin(&self) -> StdInstant {
        self.inner.origin
    }

    pub(crate) fn next_id(&self) -> u64 {
        self.inner.next_id.fetch_add(1, AtomicOrdering::Relaxed)
    }

    /// The key of the hub's own UDP socket for peers of `peer`'s address
    /// family, bound (to an ephemeral port on every address) at the first
    /// call; the links the hub connects share it.
    pub(crate) fn own_datagram_socket(&self, peer: SocketAddr) -> io::Result<u64> {
        let family = usize::from(peer.is_ipv6());
        let mut own = self
            .inner
            .own_udp
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        if let Some(key) = own.get(family).copied().flatten() {
            return Ok(key);
        }
        let any: SocketAddr = if peer.is_ipv6() {
            (std::net::Ipv6Addr::UNSPECIFIED, 0).into()
        } else {
            (std::net::Ipv4Addr::UNSPECIFIED, 0).into()
        };
        let socket = udp::bind(any)?;
        let key = self.next_id();
        let new = NewSocket {
            socket,
            stray: Arc::default(),
            held: true,
        };
        if !self.send(Msg::Socket(key, Box::new(new))) {
            return Err(io::Error::other("the hub's thread has stopped"));
        }
        if let Some(slot) = own.get_mut(family) {
            *slot = Some(key);
        }
        Ok(key)
    }

    /// Hands the hub a message and wakes it; `false` if its thread is gone.
    pub(crate) fn send(&self, msg: Msg) -> bool {
        // Counted here, not when the thread gets to it: a pool placing many
        // links at once must see the ones still in flight.
        let adds = matches!(msg, Msg::Add(..));
        if adds {
            self.inner.links.fetch_add(1, AtomicOrdering::Relaxed);
        }
        let sent = self
            .inner
            .tx
            .as_ref()
            .is_some_and(|tx| tx.send(msg).is_ok())
            && self.inner.waker.wake().is_ok();
        if adds && !sent {
            self.inner.links.fetch_sub(1, AtomicOrdering::Relaxed);
        }
        sent
    }
}

/// A socket the poll reported ready.
#[derive(Clone, Copy)]
struct Ready {
    id: u64,
    readable: bool,
    /// The peer closed or the socket failed: read to the end, a short read
    /// does not mean there is nothing left (the end raises no new edge).
    closing: bool,
    writable: bool,
}

/// What every link's stats show of its hub.
#[derive(Clone, Copy)]
struct HubFigures {
    lateness: LatenessStats,
    release_lateness: LatenessStats,
    spin_margin: Duration,
}

/// What a look at the poll set found besides sockets.
#[derive(Clone, Copy, Default)]
struct Woke {
    /// Anything at all.
    any: bool,
    /// The waker: links added or closed.
    messages: bool,
    /// The timer.
    timer: bool,
}

/// How long a piece of the hub's work takes: a peak that decays by 1/32 at
/// each new measure, to tell whether one more piece fits before a deadline.
struct Cost {
    peak: std::time::Duration,
}

impl Cost {
    /// A guard on top of the peak: the clock read and the loop itself.
    const GUARD: std::time::Duration = std::time::Duration::from_micros(2);

    fn new() -> Cost {
        Cost {
            peak: std::time::Duration::from_micros(20),
        }
    }

    fn fits(&self, now: StdInstant, deadline: StdInstant) -> bool {
        now + self.peak + Self::GUARD <= deadline
    }

    /// A measure longer than `cap` (the spin margin) was a preemption, not
    /// the work: it counts as `cap`.
    fn record(&mut self, took: std::time::Duration, cap: std::time::Duration) {
        let decayed = self.peak - self.peak / 32;
        self.peak = took.min(cap).max(decayed);
    }
}

struct Driver {
    poll: Poll,
    /// A nanosecond timer in the poll set, where the platform has one.
    timer: Option<precise::Timer>,
    origin: StdInstant,
    /// How long before a deadline the poll's timer ends and the spin starts,
    /// learned from how late the timer wakes.
    spin: SpinMargin,
    /// When the timer was armed to end, while the thread waits in the poll.
    armed: Option<StdInstant>,
    /// The deadline whose links' blocked readers were woken ahead.
    readers_woken: Option<StdInstant>,
    input: Receiver<Msg>,
    entries: HashMap<u64, Entry>,
    timers: BTreeSet<(Instant, u64)>,
    /// How late the hub woke for its deadlines.
    lateness: LatenessHistogram,
    /// How late each link's deadline was served (its release stamp).
    releases: LatenessHistogram,
    /// What every link's stats show of the hub: recomputed every so often
    /// (percentiles cost a histogram scan) and for a link's last stats.
    figures: HubFigures,
    wakes: u64,
    /// Sockets reported ready and not served yet, in order.
    backlog: VecDeque<Ready>,
    events: Events,
    /// The deadlines due at a tick (kept to reuse its memory).
    due: Vec<(Instant, u64)>,
    /// How long serving one socket takes, and one look at the poll set.
    service: Cost,
    polling: Cost,
    /// How long waking the links' blocked readers ahead of a deadline takes.
    waking: Cost,
    buf: Vec<u8>,
    /// The datagram sockets, and the datagrams waiting to be sent.
    udp: udp::Udp,
    /// The QUIC endpoints on some of those sockets.
    quic: quic::Quic,
    /// Links that took datagrams in one read (kept to reuse its memory).
    touched: Vec<u64>,
    /// Links a QUIC listener accepted in one read.
    accepted: Vec<(u64, Entry)>,
    links: Arc<AtomicUsize>,
    /// Kept open while the thread runs (see [`Inner::waker`]).
    _waker: Arc<Waker>,
}

impl Driver {
    fn run(mut self) {
        // Best effort: a 1 µs timer slack makes the native sleep precise.
        let _ = crate::clock::set_current_thread_timer_slack(DEFAULT_TIMER_SLACK);
        loop {
            let deadline = self
                .timers
                .first()
                .and_then(|&(t, _)| t.to_std(self.origin));
            let margin = std::time::Duration::from(self.spin.current());
            let now = StdInstant::now();
            // Blocked readers to wake ahead of the deadline end the sleep
            // earlier than the spin would.
            let lead = match deadline {
                Some(d) if self.readers_woken != Some(d) && self.readers_due(d) => {
                    margin.max(READER_LEAD)
                }
                _ => margin,
            };
            let wait = deadline.map(|d| d.saturating_duration_since(now).saturating_sub(lead));
            let timeout = match (&self.timer, wait) {
                // The timer wakes the poll to the nanosecond.
                (Some(timer), Some(w)) => {
                    timer.arm(w);
                    self.armed = (!w.is_zero()).then(|| now + w);
                    None
                }
                // epoll counts whole milliseconds and rounds up: ask it for
                // one millisecond less than the whole milliseconds to the
                // target, and sleep the rest natively below.
                (None, Some(w)) => {
                    let ms = u64::try_from(w.as_millis()).unwrap_or(u64::MAX);
                    Some(std::time::Duration::from_millis(ms.saturating_sub(1)))
                }
                (_, None) => None,
            };
            let Ok(woke) = self.poll_ready(timeout) else {
                return;
            };
            // The timer armed just now ended this wait: how late it woke is
            // what the spin margin must cover.
            if let Some(end) = self.armed.take().filter(|_| woke.timer) {
                let overshoot = StdInstant::now().saturating_duration_since(end);
                self.spin.record(overshoot.into());
            }
            if woke.messages && !self.messages() {
                return;
            }
            let Some(d) = deadline else {
                self.serve_backlog();
                continue;
            };
            let now = StdInstant::now();
            if self.readers_woken != Some(d) && now + READER_LEAD >= d {
                self.readers_woken = Some(d);
                self.wake_readers_ahead(d);
            }
            // Serve what woke us while a service fits before the spin should
            // start (the tick serves the rest as it fits): a burst of frames
            // just before a deadline must not make it late, however short
            // the learned margin.
            let target = d.checked_sub(margin).unwrap_or(d);
            while let Some(&r) = self.backlog.front() {
                if !self.service.fits(StdInstant::now(), target) {
                    break;
                }
                self.backlog.pop_front();
                self.serve_timed(r);
            }
            // The timer fires at the target, never before: a tick is due
            // exactly when the target has passed.
            let left = target.saturating_duration_since(StdInstant::now());
            if left.is_zero() {
                if !self.tick(d) {
                    return;
                }
                continue;
            }
            if self.timer.is_none() && !woke.any && left < std::time::Duration::from_millis(2) {
                // Without a precise timer: sleep the last stretch natively.
                // Frames arriving meanwhile keep their kernel stamps and are
                // read before the tick.
                std::thread::sleep(left);
                if !self.tick(d) {
                    return;
                }
            }
        }
    }

    /// Waits for the poll set (at most `timeout`; `None`: until something
    /// happens), queueing the ready sockets in the backlog.
    fn poll_ready(&mut self, timeout: Option<std::time::Duration>) -> io::Result<Woke> {
        let mut woke = Woke::default();
        if let Err(e) = self.poll.poll(&mut self.events, timeout) {
            return if e.kind() == io::ErrorKind::Interrupted {
                Ok(woke)
            } else {
                Err(e)
            };
        }
        for ev in &self.events {
            woke.any = true;
            match ev.token() {
                WAKER => woke.messages = true,
                TIMER => {
                    woke.timer = true;
                    if let Some(timer) = &self.timer {
                        timer.clear();
                    }
                }
                Token(t) => self.backlog.push_back(Ready {
                    id: t as u64,
                    readable: ev.is_readable(),
                    closing: ev.is_read_closed() || ev.is_error(),
                    writable: ev.is_writable(),
                }),
            }
        }
        Ok(woke)
    }

    /// Reads and writes for every socket in the backlog.
    fn serve_backlog(&mut self) {
        while let Some(r) = self.backlog.pop_front() {
            self.serve_timed(r);
        }
    }

    /// [`serve`](Self::serve), measuring what it costs.
    fn serve_timed(&mut self, r: Ready) {
        let start = StdInstant::now();
        self.serve(r);
        self.service.record(start.elapsed(), self.spin.max().into());
    }

    /// Reads and writes for one ready socket.
    fn serve(&mut self, r: Ready) {
        if self.quic.has(r.id) {
            self.receive_quic(r.id);
            return;
        }
        if self.udp.has(r.id) {
            self.receive_datagrams(r.id);
            return;
        }
        if r.readable || r.closing {
            self.read(r.id, r.closing);
        }
        if r.writable {
            self.write_pending(r.id);
        }
        self.flush(r.id);
        self.udp.send_all(&mut self.entries);
    }

    /// Reads the datagram socket `key` dry; each link that took a datagram
    /// then runs as after a frame.
    fn receive_datagrams(&mut self, key: u64) {
        let mut touched = std::mem::take(&mut self.touched);
        touched.clear();
        self.udp
            .receive(key, self.origin, &mut self.entries, &mut touched);
        for &id in &touched {
            self.flush(id);
        }
        self.touched = touched;
        self.udp.send_all(&mut self.entries);
    }

    /// Reads the QUIC endpoint's socket `key` dry; each link that got a
    /// packet then runs as after a frame, and links it accepted join.
    fn receive_quic(&mut self, key: u64) {
        let mut touched = std::mem::take(&mut self.touched);
        let mut accepted = std::mem::take(&mut self.accepted);
        touched.clear();
        self.quic.receive(
            key,
            &mut self.udp,
            self.origin,
            &mut self.entries,
            &mut touched,
            &mut accepted,
        );
        for (id, entry) in accepted.drain(..) {
            // Counted as `Hub::send` counts a link handed over: its
            // leaving is counted down.
            self.links.fetch_add(1, AtomicOrdering::Relaxed);
            self.add(id, entry);
        }
        for &id in &touched {
            self.flush(id);
        }
        self.touched = touched;
        self.accepted = accepted;
        self.udp.send_all(&mut self.entries);
    }

    /// Takes link `id`'s entry and runs it once.
    fn add(&mut self, id: u64, mut entry: Entry) {
        let token = Token(id as usize);
        if let Some(socket) = entry.path.socket_mut()
            && self
                .poll
                .registry()
                .register(socket, token, Interest::READABLE)
                .is_err()
        {
            entry.endpoint.abort(LinkError::Disconnected);
        }
        if let Some(path) = entry.path.datagram_mut()
            && !self.udp.attach(id, path)
        {
            // Its socket failed, or a token drawn twice.
            tracing::warn!("a datagram link could not take its socket");
            entry.endpoint.abort(LinkError::Disconnected);
        }
        if let Some(path) = entry.path.quic_mut()
            && !self.quic.attach(id, path)
        {
            tracing::warn!("a QUIC link could not take its endpoint");
            entry.endpoint.abort(LinkError::Disconnected);
        }
        #[cfg(feature = "zenoh")]
        if let Path::Zenoh(z) = &mut entry.path
            && self
                .poll
                .registry()
                .register(&mut z.wake, token, Interest::READABLE)
                .is_err()
        {
            entry.endpoint.abort(LinkError::Disconnected);
        }
        let tls = entry.path.has_tls() || entry.path.is_zenoh();
        self.entries.insert(id, entry);
        if tls {
            // (A zenoh link's inbox may hold frames already.)
            // The handshake may have read records past its end:
            // rustls holds them, and no new edge will say so.
            self.read(id, false);
        }
        self.flush(id);
    }

    /// Links added or closed by their handles; `false` once every handle
    /// and the hub itself are gone and no link is left.
    fn messages(&mut self) -> bool {
        loop {
            match self.input.try_recv() {
                Ok(Msg::Socket(key, new)) => {
                    if let Err(e) = self.udp.add(self.poll.registry(), key, *new) {
                        tracing::warn!("a datagram socket could not be polled: {e}");
                    }
                }
                Ok(Msg::ReleaseSocket(key)) => {
                    if !self.quic.has(key) || self.quic.release(key) {
                        self.udp.release(self.poll.registry(), key);
                    }
                }
                Ok(Msg::Quic(key, socket, endpoint)) => {
                    match self.udp.add(self.poll.registry(), key, *socket) {
                        Ok(()) => {
                            let stray = self.udp.stray(key).unwrap_or_default();
                            self.quic.add(key, *endpoint, stray);
                        }
                        Err(e) => tracing::warn!("a QUIC socket could not be polled: {e}"),
                    }
                }
                Ok(Msg::Add(id, entry)) => self.add(id, *entry),
                Ok(Msg::Move(id, to)) => self.move_out(id, *to),
                Ok(Msg::QuicForwarded(id, f)) => {
                    quic::forwarded(self.entries.get_mut(&id), *f, self.origin);
                    self.flush(id);
                }
                Ok(Msg::QuicRequest(key, r)) => {
                    if self.quic.request(key, *r) {
                        self.udp.send_all(&mut self.entries);
                        self.udp.release(self.poll.registry(), key);
                    }
                }
                Ok(Msg::Close(id)) => {
                    if let Some(e) = self.entries.get_mut(&id) {
                        e.endpoint.close();
                    }
                    self.flush(id);
                }
                Ok(Msg::Fail(id, error)) => {
                    if let Some(e) = self.entries.get_mut(&id) {
                        e.endpoint.abort(error);
                    }
                    self.flush(id);
                }
                Ok(Msg::Seat(id, op)) => {
                    if let Some(e) = self.entries.get_mut(&id) {
                        op.apply(&mut e.endpoint);
                    }
                    self.flush(id);
                }
                Ok(Msg::Handler(id, handler)) => {
                    if let Some(e) = self.entries.get_mut(&id) {
                        e.handler = Some(handler);
                    }
                }
                Ok(Msg::Tap(id, tap)) => {
                    if let Some(e) = self.entries.get_mut(&id) {
                        e.set_tap(Some(tap));
                    }
                }
                Err(mpsc::TryRecvError::Empty) => {
                    self.udp.send_all(&mut self.entries);
                    return true;
                }
                Err(mpsc::TryRecvError::Disconnected) => {
                    self.udp.send_all(&mut self.entries);
                    return !self.entries.is_empty();
                }
            }
        }
    }

    /// Hands link `id` to the hub `m.to` (`hub::quic`), whose id for it
    /// `m.reply` is told; it stays if it has ended or cannot move.
    fn move_out(&mut self, id: u64, m: quic::Move) {
        let new_id = m.to.next_id();
        let moved = self
            .entries
            .get_mut(&id)
            .is_some_and(|e| self.quic.move_out(e, new_id, &m.to, m.from));
        let Some(mut e) = moved.then(|| self.entries.remove(&id)).flatten() else {
            let _ = m.reply.send(None);
            return;
        };
        if let Some(old) = e.deadline.take() {
            self.timers.remove(&(old, id));
        }
        let route = e.path.quic().map(|q| (q.key, q.handle));
        self.links.fetch_sub(1, AtomicOrdering::Relaxed);
        if m.to.send(Msg::Add(new_id, Box::new(e))) {
            let _ = m.reply.send(Some(new_id));
        } else if let Some((key, handle)) = route
            && self.quic.forget(key, handle)
        {
            // The link is gone with the hub that was to take it.
            self.udp.release(self.poll.registry(), key);
        }
    }

    /// Reads everything the socket has, handing each frame to the endpoint
    /// with its arrival time; to `WouldBlock` or the end if `drain`.
    fn read(&mut self, id: u64, drain: bool) {
        let origin = self.origin;
        let Some(e) = self.entries.get_mut(&id) else {
            return;
        };
        if e.path.has_tls() {
            tls_io::read(e, origin, drain);
            return;
        }
        #[cfg(feature = "zenoh")]
        if e.path.is_zenoh() {
            zenoh::receive(e, origin);
            return;
        }
        loop {
            let spare = e.deframer.spare();
            let room = spare.len();
            let Some(socket) = e.path.socket() else {
                return;
            };
            match crate::arrival::read_now(socket, spare, e.path.kernel_stamps()) {
                Ok((0, _)) => {
                    e.endpoint.abort(LinkError::Disconnected);
                    return;
                }
                Ok((n, at)) => {
                    e.deframer.filled(n);
                    if !handle_frames(e, origin, at) {
                        return;
                    }
                    // A short read emptied the socket: data arriving later
                    // raises a new edge in the poll, so the read that would
                    // only say `WouldBlock` (a syscall per frame) is skipped.
                    if e.endpoint.is_closed() || (n < room && !drain) {
                        return;
                    }
                    // The rest waits for its next deadline (no new edge
                    // will say it is there: the deadline reads it).
                    if e.spend_read(n, drain) {
                        return;
                    }
                }
                Err(err) if err.kind() == io::ErrorKind::WouldBlock => return,
                Err(err) if err.kind() == io::ErrorKind::Interrupted => {}
                Err(_) => {
                    e.endpoint.abort(LinkError::Disconnected);
                    return;
                }
            }
        }
    }

    /// The socket can take more: write what was waiting.
    fn write_pending(&mut self, id: u64) {
        let Some(e) = self.entries.get_mut(&id) else {
            return;
        };
        let Some(socket) = e.path.socket_mut() else {
            return;
        };
        while !e.pending.is_empty() {
            match socket.write(&e.pending) {
                Ok(n) => {
                    e.pending.drain(..n);
                }
                Err(err) if err.kind() == io::ErrorKind::WouldBlock => break,
                Err(err) if err.kind() == io::ErrorKind::Interrupted => {}
                Err(_) => {
                    e.endpoint.abort(LinkError::Disconnected);
                    return;
                }
            }
        }
        let interest = if e.pending.is_empty() {
            Interest::READABLE
        } else {
            Interest::READABLE | Interest::WRITABLE
        };
        let _ = self
            .poll
            .registry()
            .reregister(socket, Token(id as usize), interest);
    }

    /// The deadline `d` is near: spin to it, serving the sockets that become
    /// ready meanwhile one at a time, as long as one more service fits before
    /// `d` (frames reach their endpoints as they arrive, and the deadline
    /// keeps its microseconds); then take what is still waiting and run every
    /// endpoint that is due. `false` once the hub has nothing left to drive.
    fn tick(&mut self, d: StdInstant) -> bool {
        let mut messages = false;
        loop {
            let now = StdInstant::now();
            if now >= d {
                break;
            }
            if self.readers_woken != Some(d) && now + READER_LEAD >= d {
                self.readers_woken = Some(d);
                self.wake_readers_ahead(d);
                continue;
            }
            if let Some(&r) = self.backlog.front() {
                if self.service.fits(now, d) {
                    self.backlog.pop_front();
                    self.serve_timed(r);
                    continue;
                }
            } else if self.polling.fits(now, d) {
                let woke = self.poll_ready(Some(std::time::Duration::ZERO));
                self.polling.record(now.elapsed(), self.spin.max().into());
                messages |= woke.is_ok_and(|w| w.messages);
                continue;
            }
            std::hint::spin_loop();
        }
        // The clock's own precision: how late it woke for this deadline.
        self.lateness
            .record(StdInstant::now().saturating_duration_since(d).into());
        self.wakes += 1;
        if self.wakes % 64 == 1 {
            self.figures = figures(&self.lateness, &self.releases, self.spin);
        }
        // Frames that arrived before the deadline belong before the releases.
        let woke = self.poll_ready(Some(std::time::Duration::ZERO));
        if (messages || woke.is_ok_and(|w| w.messages)) && !self.messages() {
            return false;
        }
        self.serve_backlog();
        // Each release is stamped when it really happens, after those reads.
        let now = Instant::from_std(self.origin, StdInstant::now());
        let mut due = std::mem::take(&mut self.due);
        due.clear();
        due.extend(self.timers.iter().take_while(|&&(t, _)| t <= now));
        // One link: its frame first, then its application (waking that
        // thread first would delay the frame by the wake-up). Several: every
        // release first, then the frames, so that the last link's release
        // does not wait for every other link's write (a syscall of a few µs).
        let releases_first = due.len() > 1;
        for &(t, id) in &due {
            let now = Instant::from_std(self.origin, StdInstant::now());
            if let Some(e) = self.entries.get_mut(&id) {
                self.releases.record(now - t);
                take_sample(e);
                quic::on_timeout(e, StdInstant::now());
                run_due(e, now, self.figures);
                e.top_up_read(StdInstant::now());
                if std::mem::take(&mut e.throttled) {
                    // Read after this tick's releases and frames.
                    self.backlog.push_back(Ready {
                        id,
                        readable: true,
                        closing: false,
                        writable: false,
                    });
                }
                if e.endpoint.is_closed() {
                    // Its last stats go out with its Closed event (below).
                    self.figures = figures(&self.lateness, &self.releases, self.spin);
                }
                if releases_first {
                    // A panicked handler's Close frame goes with the frames below.
                    let _ = deliver(e, true, self.figures);
                }
            }
            if !releases_first {
                self.flush_with(id, true);
                self.udp.send_all(&mut self.entries);
            }
        }
        if releases_first {
            for &(_, id) in &due {
                self.flush(id);
            }
            self.udp.send_all(&mut self.entries);
        }
        self.due = due;
        true
    }

    /// Whether a link due at `d` may have a reader to wake ahead of it (it
    /// has no handler).
    fn readers_due(&self, d: StdInstant) -> bool {
        let at = Instant::from_std(self.origin, d);
        self.timers
            .iter()
            .take_while(|&&(t, _)| t <= at)
            .any(|(_, id)| self.entries.get(id).is_some_and(|e| e.handler.is_none()))
    }

    /// Wakes the application threads blocked in `recv` on the links whose
    /// endpoints are due at `d`, to spin for their releases; only while
    /// the wake-ups fit before `d`, so the releases are never later.
    fn wake_readers_ahead(&mut self, d: StdInstant) {
        let at = Instant::from_std(self.origin, d);
        for &(_, id) in self.timers.iter().take_while(|&&(t, _)| t <= at) {
            let start = StdInstant::now();
            if !self.waking.fits(start, d) {
                break;
            }
            let Some(e) = self.entries.get(&id) else {
                continue;
            };
            // A link with a handler has no reader; a QUIC timer alone
            // releases nothing.
            if e.handler.is_none()
                && e.endpoint.poll_timeout().is_some_and(|t| t <= at)
                && e.deliveries.wake_ahead(d, READER_SPIN_PAST)
            {
                self.waking.record(start.elapsed(), self.spin.max().into());
            }
        }
    }

    /// Frames to the socket, events to the application, the deadline to the
    /// index; a closed link leaves the hub. The link's stats are published
    /// after a tick (before its releases reach the application, so the
    /// application reads the stats of the tick it got) and with any event:
    /// not after every read, a copy of a few hundred bytes under a lock.
    fn flush(&mut self, id: u64) {
        self.flush_with(id, false);
    }

    fn flush_with(&mut self, id: u64, ticked: bool) {
        let Some(e) = self.entries.get_mut(&id) else {
            return;
        };
        let now = Instant::from_std(self.origin, StdInstant::now());
        let mut wants_write = false;
        if e.handler.is_some() {
            // The application runs here: its answer to this tick's releases
            // goes out in this tick's frame, as the drive contract has it.
            if e.endpoint.is_closed() {
                self.figures = figures(&self.lateness, &self.releases, self.spin);
            }
            // A panicked handler's Close frame goes with the others.
            let _ = deliver(e, ticked, self.figures);
            take_sample(e);
            wants_write = transmit(e, id, now, &mut self.buf, &mut self.udp.out);
        } else if ticked && e.deliveries.reader_spinning() {
            // A reader woken ahead spins for its release: handing it over
            // costs no syscall, so it goes before the frame's write.
            if e.endpoint.is_closed() {
                self.figures = figures(&self.lateness, &self.releases, self.spin);
            }
            let _ = deliver(e, ticked, self.figures);
            wants_write |= transmit(e, id, now, &mut self.buf, &mut self.udp.out);
        } else {
            // Frames first: an application on a thread of its own answers
            // at the next tick, and waking it first would delay the frame
            // by the wake-up.
            wants_write |= transmit(e, id, now, &mut self.buf, &mut self.udp.out);
            if e.endpoint.is_closed() {
                // The link's last stats: the clock's figures up to now, not
                // as of the last periodic refresh (a short run has had only
                // one), published before its Closed event wakes the
                // application.
                self.figures = figures(&self.lateness, &self.releases, self.spin);
            }
            if deliver(e, ticked, self.figures) {
                // Cannot happen without a handler; a Close frame if it did.
                wants_write |= transmit(e, id, now, &mut self.buf, &mut self.udp.out);
            }
        }
        if e.path.quic().is_some() {
            // What the frames and the timers gave the connection (its end,
            // the stream opening) may give the endpoint more to say.
            let std_now = StdInstant::now();
            quic::input(e, self.origin, std_now);
            wants_write |= transmit(e, id, now, &mut self.buf, &mut self.udp.out);
            if e.endpoint.is_closed() {
                quic::close(e, std_now);
            }
            self.quic.output(e, id, std_now, &mut self.udp.out);
        }
        if e.pending.len() > MAX_PENDING {
            // The peer does not read: cut it off rather than grow without bound.
            e.pending.clear();
            e.endpoint.abort(LinkError::Disconnected);
        }
        if wants_write && let Some(socket) = e.path.socket_mut() {
            let _ = self.poll.registry().reregister(
                socket,
                Token(id as usize),
                Interest::READABLE | Interest::WRITABLE,
            );
        }
        if e.endpoint.is_closed() {
            // Again if it closed above (a panicked handler) or had no event.
            self.figures = figures(&self.lateness, &self.releases, self.spin);
            publish(e, self.figures);
        }
        let next = match (e.endpoint.poll_timeout(), quic::timer(e, self.origin)) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
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
            // The Close frame was written above if the socket took it;
            // dropping the entry closes the socket and tells the application
            // that nothing more will come.
            if let Some(mut gone) = self.entries.remove(&id) {
                tls_io::close_notify(&mut gone);
                if let Some(path) = gone.path.datagram() {
                    self.udp.detach(self.poll.registry(), id, path);
                }
                if let Some(path) = gone.path.quic()
                    && self.quic.detach(path)
                {
                    // Its CONNECTION_CLOSE goes before its socket closes.
                    self.udp.send_all(&mut self.entries);
                    self.udp.release(self.poll.registry(), path.key);
                }
                if let Some(socket) = gone.path.socket_mut() {
                    let _ = self.poll.registry().deregister(socket);
                    let _ = socket.shutdown(std::net::Shutdown::Write);
                }
                self.links.fetch_sub(1, AtomicOrdering::Relaxed);
            }
        }
    }
}

/// A nanosecond timer that wakes the poll: Linux's timerfd.
mod precise {
    use mio::{Registry, Token};

    #[cfg(target_os = "linux")]
    pub(super) struct Timer(nix::sys::timerfd::TimerFd);

    #[cfg(target_os = "linux")]
    impl Timer {
        /// A timer registered in `registry`; `None` if the kernel refuses one.
        pub(super) fn new(registry: &Registry, token: Token) -> Option<Timer> {
            use nix::sys::timerfd::{ClockId, TimerFd, TimerFlags};
            use std::os::fd::{AsFd, AsRawFd};
            let fd = TimerFd::new(
                ClockId::CLOCK_MONOTONIC,
                TimerFlags::TFD_NONBLOCK | TimerFlags::TFD_CLOEXEC,
            )
            .ok()?;
            let raw = fd.as_fd().as_raw_fd();
            registry
                .register(
                    &mut mio::unix::SourceFd(&raw),
                    token,
                    mio::Interest::READABLE,
                )
                .ok()?;
            Some(Timer(fd))
        }

        /// Fires once, `after` from now (at once for zero).
        pub(super) fn arm(&self, after: std::time::Duration) {
            use nix::sys::time::TimeSpec;
            use nix::sys::timerfd::{Expiration, TimerSetTimeFlags};
            // A zero expiration would disarm the timer instead.
            let after = after.max(std::time::Duration::from_nanos(1));
            let _ = self.0.set(
                Expiration::OneShot(TimeSpec::from_duration(after)),
                TimerSetTimeFlags::empty(),
            );
        }

        /// Reads the expiry so the next one wakes the poll again.
        pub(super) fn clear(&self) {
            let _ = self.0.wait();
        }
    }

    #[cfg(not(target_os = "linux"))]
    pub(super) struct Timer;

    #[cfg(not(target_os = "linux"))]
    impl Timer {
        pub(super) fn new(_: &Registry, _: Token) -> Option<Timer> {
            None
        }
        pub(super) fn arm(&self, _: std::time::Duration) {}
        pub(super) fn clear(&self) {}
    }
}

/// The endpoint's frames to the socket (or behind what waits for it), its
/// datagrams to `out`; `true` if bytes are left waiting.
fn transmit(e: &mut Entry, id: u64, now: Instant, buf: &mut [u8], out: &mut udp::Outgoing) -> bool {
    let mut wants_write = false;
    while let Ok(Some(n)) = e.endpoint.poll_transmit(now, buf) {
        let frame = buf.get(..n).unwrap_or_default();
        match &mut e.path {
            Path::Udp(_, path) if ndr_core::wire::is_bundle(frame) => out.push(id, path, frame),
            Path::Quic(_) => quic::send(e, frame),
            #[cfg(feature = "zenoh")]
            Path::Zenoh(z) => zenoh::send(z, frame),
            _ => wants_write |= send_frame(e, frame),
        }
    }
    wants_write
}

/// Events to the application, the stats first (so the application reads
/// the stats of the tick or event it got: after a tick always, otherwise
/// just before the first event delivered; published after it, a closed
/// link's last stats raced the application that woke on its Closed event). Releases go to the
/// link's handler if it has one; `true` if the handler panicked (the link
/// is then aborted, its Close frame queued).
fn deliver(e: &mut Entry, ticked: bool, hub: HubFigures) -> bool {
    if ticked {
        publish(e, hub);
    }
    let mut delivered = false;
    let mut published = ticked;
    let mut panicked = false;
    if let Some(tap) = e.tap.as_mut() {
        while let Some(probe) = e.endpoint.poll_probe_arrival() {
            tap(Tapped::Probe(probe));
        }
    }
    while let Some(event) = e.endpoint.poll_event() {
        if let Some(notes) = &e.notes {
            notes.note(&event, &e.endpoint);
        }
        if let Some(tap) = e.tap.as_mut() {
            tap(Tapped::Event(&event));
        }
        let d = match event {
            Event::Released(s) => {
                if let Some(handler) = e.handler.as_mut() {
                    // The handler is the application's code: its panic ends
                    // its own link, not the hub and every link on it.
                    let run = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                        handler(&s);
                    }));
                    if run.is_err() {
                        e.handler = None;
                        e.endpoint.abort(LinkError::HandlerPanicked);
                        panicked = true;
                    }
                    continue;
                }
                Delivery::Sample(s)
            }
            other => Delivery::Event(other),
        };
        if !published {
            publish(e, hub);
            published = true;
        }
        match e.deliveries.try_send(d) {
            Ok(()) => delivered = true,
            Err(Refused::Full) => e.app_dropped += 1,
            Err(Refused::Gone) => {}
        }
    }
    if delivered {
        e.shared.notify.notify_one();
    }
    panicked
}

/// Runs the endpoint's deadlines due at `now`. After a stall of the hub,
/// the catch-up stops each time the endpoint's event queue fills: the
/// events go to the application, and it goes on, so that no release is
/// dropped.
fn run_due(e: &mut Entry, now: Instant, hub: HubFigures) {
    e.endpoint.handle_timeout(now);
    while e.endpoint.catching_up(now) {
        // A panicked handler aborts the endpoint, which ends the catch-up.
        let _ = deliver(e, true, hub);
        e.endpoint.handle_timeout(now);
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

/// Hands the endpoint every whole frame the deframer holds, arrived at
/// `at`; `false` if the stream is corrupt (the endpoint is aborted).
pub(crate) fn handle_frames(e: &mut Entry, origin: StdInstant, at: StdInstant) -> bool {
    let handled = StdInstant::now();
    loop {
        match e.deframer.next_frame() {
            Ok(Some(frame)) => {
                e.rx_lag
                    .push_duration(handled.saturating_duration_since(at).into());
                // A fatal error closes the endpoint, which reports it.
                let _ = e
                    .endpoint
                    .handle_frame(Instant::from_std(origin, at), frame.as_bytes());
            }
            Ok(None) => return true,
            Err(FramingError::Wire(err)) => {
                e.endpoint.abort(LinkError::from(err));
                return false;
            }
            // Only a Data frame has no fixed length: this one has more
            // channels than the link carries.
            Err(FramingError::TooLong { len, .. }) => {
                let expected = e.endpoint.config().received_width();
                let got = len.saturating_sub(HEADER_LEN) / 8;
                e.endpoint.abort(LinkError::ChannelCount { expected, got });
                return false;
            }
        }
    }
}

/// Writes a frame now if nothing is waiting, else queues it behind what is
/// (frames stay in order); `true` if bytes are left waiting for the socket.
/// On a TLS link the frame is sealed into records first.
fn send_frame(e: &mut Entry, bytes: &[u8]) -> bool {
    if e.path.has_tls() {
        return tls_io::send(e, bytes);
    }
    match e.path.socket_mut() {
        Some(socket) => write_or_queue(socket, &mut e.pending, bytes),
        None => false,
    }
}

/// Writes `bytes` now if nothing is waiting, else queues them; `true` if
/// bytes are left waiting for the socket.
pub(crate) fn write_or_queue(socket: &mut MioStream, pending: &mut Vec<u8>, bytes: &[u8]) -> bool {
    if pending.is_empty() {
        match socket.write(bytes) {
            Ok(n) if n == bytes.len() => return false,
            Ok(n) => pending.extend_from_slice(&bytes[n..]),
            // Full buffer (or a broken socket, which the next read reports).
            Err(_) => pending.extend_from_slice(bytes),
        }
        return true;
    }
    pending.extend_from_slice(bytes);
    true
}

/// The hub's figures now: a scan of each histogram.
fn figures(
    lateness: &LatenessHistogram,
    releases: &LatenessHistogram,
    spin: SpinMargin,
) -> HubFigures {
    HubFigures {
        lateness: lateness.stats(),
        release_lateness: releases.stats(),
        spin_margin: spin.current(),
    }
}

fn publish(e: &Entry, hub: HubFigures) {
    let ep = &e.endpoint;
    let stats = LinkStats {
        phase: ep.phase(),
        period: ep.period(),
        ns: ep.ns(),
        queue_len: ep.queue_len(),
        queue_range: ep.occupancy().map(|o| (o.min, o.max)),
        last_nrtt: ep.last_nrtt(),
        endpoint: ep.stats(),
        lateness: hub.lateness,
        release_lateness: hub.release_lateness,
        spin_margin: hub.spin_margin,
        app_dropped: e.app_dropped,
        // Filled in by `LinkSender::stats`: the link counts them.
        events_dropped: 0,
        waited: ndr_core::time::Duration::ZERO,
        reconnect: ndr_core::reconnect::ReconnectStats::default(),
        endpoint_events_dropped: ep.events_dropped(),
        rx_lag: e.rx_lag,
        datagram_peer: e
            .path
            .datagram()
            .and_then(|p| p.peer)
            .or_else(|| quic::peer(e)),
        datagrams_unsent: e.path.datagram().map_or(0, |p| p.unsent)
            + e.path.quic().map_or(0, |q| q.dropped)
            + e.path.zenoh_counts().1,
        zenoh_dropped: e.path.zenoh_counts().0,
        datagram_path_changes: e.path.datagram().map_or(0, |p| p.path_changes)
            + e.path.quic().map_or(0, |q| q.path_changes),
        datagrams_stray: e
            .path
            .datagram()
            .map(|p| &p.stray)
            .or_else(|| e.path.quic().map(|q| &q.stray))
            .map_or(0, |stray| stray.load(AtomicOrdering::Relaxed)),
    };
    *e.shared
        .stats
        .lock()
        .unwrap_or_else(PoisonError::into_inner) = Some(stats);
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndr_core::endpoint::{Config, Underflow};
    use ndr_core::pair::{Pair, World};
    use ndr_core::wire::Role;

    use crate::delivery::{self, Delivery};

    /// A wire of 2 ms each way, between applications that only listen.
    struct Wire;

    impl World<Heap> for Wire {
        type Error = LinkError;

        fn arrival(&mut self, _: Role, sent: Instant, _: &[u8]) -> Option<Instant> {
            Some(sent + Duration::from_millis(2))
        }

        fn event(
            &mut self,
            _: Role,
            _: &mut Endpoint<Heap>,
            _: Instant,
            _: Event<Box<[f64]>>,
        ) -> Result<(), LinkError> {
            Ok(())
        }

        fn failed(&mut self, _: Role, _: Instant, error: LinkError) -> Result<(), LinkError> {
            Err(error)
        }
    }

    /// One end of a loopback TCP connection (the entry's path; the test
    /// writes nothing to it).
    fn loopback() -> (MioStream, std::net::TcpStream) {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let ours = std::net::TcpStream::connect(listener.local_addr().unwrap()).unwrap();
        let (theirs, _) = listener.accept().unwrap();
        (MioStream::from_std(ours), theirs)
    }

    #[test]
    fn a_hub_back_from_a_stall_hands_the_application_every_release() {
        let config = |role| {
            let mut c = Config::new(role);
            c.period = Duration::from_millis(10);
            // Each tick releases a sample, the last one again when none came.
            c.underflow = Underflow::Hold;
            c
        };
        let endpoint = |role| Endpoint::<Heap>::new(config(role), Instant::ZERO).unwrap();
        let mut pair = Pair::new(endpoint(Role::Base), endpoint(Role::Remote), Wire);
        let start = Instant::from_millis(1000);
        pair.run_until(start).unwrap();
        let (base, _, _) = pair.into_parts();
        let counted = |ep: &Endpoint<Heap>| ep.stats().released_fresh + ep.stats().released_held;
        let before = counted(&base);
        let (outbox, inbox) = delivery::queue(1024);
        let shared = Arc::new(Shared {
            sample: Mutex::new((vec![0.0; 1], false)),
            stats: Mutex::new(None),
            notify: Notify::new(),
            peer_chain: Mutex::new(None),
        });
        let (socket, _peer) = loopback();
        let path = Path::Tcp(Stream::new(socket, false));
        let mut e = Entry::new(base, shared, outbox, path, MAX_FRAME_LEN);
        let hub = HubFigures {
            lateness: LatenessStats::default(),
            release_lateness: LatenessStats::default(),
            spin_margin: Duration::ZERO,
        };
        // The hub's thread held for 60 periods: its next tick runs them all.
        run_due(&mut e, start + Duration::from_millis(600), hub);
        let _ = deliver(&mut e, true, hub);
        let mut samples = 0u64;
        while let Ok(d) = inbox.try_recv() {
            samples += u64::from(matches!(d, Delivery::Sample(_)));
        }
        let released = counted(&e.endpoint) - before;
        assert!(
            released >= 55,
            "{released} released, {samples} delivered, {} dropped",
            e.endpoint.events_dropped()
        );
        assert_eq!(e.endpoint.events_dropped(), 0);
        assert_eq!(e.app_dropped, 0);
        assert_eq!(samples, released);
    }
}
