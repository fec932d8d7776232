//! A regulated link over TCP: the sans-IO [`Endpoint`] driven for real.
//!
//! Three parties per link:
//!
//! - a **hub** thread ([`Hub`], `ndr-hub`) owns the endpoint and the socket:
//!   it polls the socket (mio) until just before the next deadline, then
//!   spins to it, so ticks are kept to microseconds rather than tokio's
//!   milliseconds; it reads frames as they come, stamped with the kernel's
//!   arrival time, and writes frames itself; one hub can drive many links
//!   on one tick grid;
//! - tokio only connects and accepts.
//!
//! The application holds a [`Link`]: [`Link::send`] sets the sample sent at
//! the next tick, [`Link::recv`] / [`Link::recv_async`] give the next released
//! sample, [`Link::stats`] a snapshot of everything counted.
//! A thread blocked in [`Link::recv`] is woken by the hub shortly before
//! each release and spins for it, a bounded while (`delivery`).

use std::collections::VecDeque;
use std::fmt;
use std::io;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Instant as StdInstant;

use ndr_core::endpoint::{DEFAULT_LIVENESS, Endpoint, Event, LinkError, Status};
use ndr_core::reconnect::ReconnectStats;
use ndr_core::storage::Heap;
use ndr_core::time::{Duration, Instant};
use ndr_core::wire::{HEADER_LEN, Role};
use tokio::net::TcpStream;
use tokio::runtime::Handle;
use tokio::sync::Notify;

use crate::arrival;
use crate::delivery::{self, Delivery, Inbox};
use crate::hub::{
    DatagramPath, Entry, Hub, Msg, Path, QuicMove, QuicPath, Session, Shared, Stream,
};
use crate::reconnect::{Redial, Resumed, recoverable};
use crate::seats::Seat;
use crate::transport::{Transport, TransportError};

use crate::config::LinkConfig;
use crate::delivery::{LinkEvent, Sample};
use crate::error::NetError;
use crate::stats::LinkStats;

/// Events a [`Link`] keeps for [`drain_events`](Link::drain_events); past
/// it the oldest go, counted in [`LinkStats::events_dropped`].
pub const EVENT_BACKLOG: usize = 256;

/// One side of a running link. Dropping it closes the link.
pub struct Link {
    id: u64,
    deliveries: Inbox,
    shared: Arc<Shared>,
    events: VecDeque<LinkEvent>,
    /// Events dropped from `events`; [`LinkSender::stats`] reports them.
    events_dropped: Arc<AtomicU64>,
    /// Values in each sample this side sends, and in each it receives.
    widths: (usize, usize),
    role: Role,
    closed: Option<LinkError>,
    shut: bool,
    peer: SocketAddr,
    // The hub driving it (a link's own, or shared).
    hub: Hub,
    /// Its place among the links its listener serves at once, given back
    /// when the link is dropped (after it is closed).
    seat: Option<Seat>,
    /// A shared robot's link: its key, the seat its endpoint offered, and
    /// where its listener's floor reaches it.
    sharing: Option<Sharing>,
    /// How long connecting waited for the remote, and the reconnects.
    reach: Arc<Mutex<Reach>>,
    /// A base that reconnects ([`LinkConfig::reconnect`]).
    redial: Option<Box<Redial>>,
}

/// What [`LinkStats::waited`] and [`LinkStats::reconnect`] report.
type Reach = (Duration, ReconnectStats);

/// What a listener gives the links it starts: its datagram socket (over
/// `udp`), and its robot's floor if it shares one.
#[derive(Default)]
pub(crate) struct Listened<'a> {
    pub(crate) udp: Option<u64>,
    pub(crate) sharing: Option<&'a Arc<crate::sharing::Sharing>>,
}

/// A listener's link to a shared robot, as its floor knows it.
pub(crate) struct Sharing {
    pub(crate) key: ndr_core::floor::LinkId,
    pub(crate) offered: ndr_core::wire::Seat,
    pub(crate) address: crate::sharing::Address,
    /// Whether the floor admitted it as an observer.
    pub(crate) observer: bool,
}

impl fmt::Debug for Link {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Link")
            .field("peer", &self.peer)
            .field("widths", &self.widths)
            .field("closed", &self.closed)
            .finish()
    }
}

impl Link {
    /// Drives an already connected stream in `role`.
    /// The stream is taken as it is: no TLS (so `tcp` or `udp`, refused
    /// with [`NetError::Transport`] otherwise), and no check of its peer's
    /// address.
    /// Over `udp`, its datagrams go to the stream's peer address (the same
    /// port, over UDP) from the hub's own UDP socket.
    pub fn from_stream(
        stream: TcpStream,
        role: Role,
        config: LinkConfig,
        hub: &Hub,
    ) -> Result<Link, NetError> {
        Link::start(
            stream,
            role,
            config,
            Handle::current(),
            hub,
            None,
            Listened::default(),
        )
    }

    /// Drives `stream` on `hub`; on the datagram transport, over the UDP
    /// socket `udp` (a listener's, the peer's address learned from its
    /// first datagram), or else the hub's own (to the stream's peer).
    pub(crate) fn start(
        stream: TcpStream,
        role: Role,
        config: LinkConfig,
        rt: Handle,
        hub: &Hub,
        tls: Option<rustls::Connection>,
        listened: Listened<'_>,
    ) -> Result<Link, NetError> {
        let Listened { udp, sharing } = listened;
        let transport = config.checked_transport(tls.is_some())?;
        let mut cfg = config.endpoint;
        cfg.role = role;
        cfg.tick_origin = Instant::ZERO;
        let datagram = match transport {
            Transport::Udp { .. } => {
                cfg.session = session_token()?;
                let peer = stream.peer_addr()?;
                Some(match udp {
                    Some(key) => DatagramPath::new(key, cfg.session, None),
                    None => {
                        DatagramPath::new(hub.own_datagram_socket(peer)?, cfg.session, Some(peer))
                    }
                })
            }
            Transport::Tcp => None,
            Transport::Zenoh { .. } => {
                return Err(NetError::Transport(TransportError::ZenohByName));
            }
            // Not reached: a QUIC link starts in `start_quic` (`dial`,
            // `listen_quic`), and one without TLS is refused above.
            _ => return Err(NetError::Transport(TransportError::QuicWithoutTls)),
        };
        cfg.validate().map_err(NetError::Config)?;
        stream.set_nodelay(true)?;
        // Best effort: the endpoint's liveness ends a silent link anyway.
        let liveness = cfg.liveness.unwrap_or(DEFAULT_LIVENESS).into();
        if let Err(e) = crate::keepalive::enable(&stream, liveness) {
            tracing::debug!("no TCP keepalive on the link's socket: {e}");
        }
        let peer = stream.peer_addr()?;
        // The hub owns the socket from here: it reads and writes it itself.
        let _guard = rt.enter();
        let std_stream = stream.into_std()?;
        std_stream.set_nonblocking(true)?;
        let kernel_stamps = arrival::enable(&std_stream);
        let socket = Stream::new(mio::net::TcpStream::from_std(std_stream), kernel_stamps);
        let path = match (tls, datagram) {
            (Some(conn), _) => Path::Tls(socket, Box::new(Session::new(conn))),
            (None, Some(datagram)) => Path::Udp(socket, datagram),
            (None, None) => Path::Tcp(socket),
        };
        let (id, mut entry, link) = Link::assemble(cfg, &config, hub, path, peer, sharing)?;
        if role == Role::Base {
            entry.say_hello(hub.origin());
        }
        if !hub.send(Msg::Add(id, Box::new(entry))) {
            return Err(NetError::Io(io::Error::other(
                "the link's hub thread has stopped",
            )));
        }
        Ok(link)
    }

    /// The endpoint's configuration for a link whose transport routes its
    /// datagrams (QUIC, zenoh): `role`, time from zero, a fresh token.
    fn routed_endpoint(
        config: &LinkConfig,
        role: Role,
    ) -> Result<ndr_core::endpoint::Config, NetError> {
        let mut cfg = config.endpoint;
        cfg.role = role;
        cfg.tick_origin = Instant::ZERO;
        cfg.session = session_token()?;
        cfg.validate().map_err(NetError::Config)?;
        Ok(cfg)
    }

    /// A QUIC link over the connection `conn` (`handle` on the endpoint
    /// `key` of `hub`), in `role`: its id, its entry for the hub, its handle.
    pub(crate) fn start_quic(
        config: &LinkConfig,
        role: Role,
        hub: &Hub,
        path: QuicPath,
        sharing: Option<&Arc<crate::sharing::Sharing>>,
    ) -> Result<(u64, Entry, Link), NetError> {
        // QUIC routes the datagrams and authenticates them: the token only
        // has to be one the endpoint checks, as on UDP.
        let cfg = Self::routed_endpoint(config, role)?;
        let peer = path.conn.remote_address();
        Link::assemble(cfg, config, hub, Path::Quic(Box::new(path)), peer, sharing)
    }

    /// A zenoh link over `path` on `hub`, in `role`: its id, its entry
    /// for the hub, its handle.
    #[cfg(feature = "zenoh")]
    pub(crate) fn start_zenoh(
        config: &LinkConfig,
        role: Role,
        hub: &Hub,
        path: crate::hub::zenoh::ZenohPath,
        sharing: Option<&Arc<crate::sharing::Sharing>>,
    ) -> Result<(u64, Entry, Link), NetError> {
        // The keys route the datagrams; the token is one the endpoint checks.
        let cfg = Self::routed_endpoint(config, role)?;
        // A zenoh peer has no address this side knows.
        let peer = SocketAddr::from((std::net::Ipv4Addr::UNSPECIFIED, 0));
        Link::assemble(cfg, config, hub, Path::Zenoh(Box::new(path)), peer, sharing)
    }

    /// The endpoint, the entry its hub drives and the application's handle.
    fn assemble(
        cfg: ndr_core::endpoint::Config,
        config: &LinkConfig,
        hub: &Hub,
        path: Path,
        peer: SocketAddr,
        sharing: Option<&Arc<crate::sharing::Sharing>>,
    ) -> Result<(u64, Entry, Link), NetError> {
        let widths = (
            usize::from(cfg.sent_width()),
            usize::from(cfg.received_width()),
        );
        let id = hub.next_id();
        let (del_tx, del_rx) = delivery::queue(config.app_queue);
        let shared = Arc::new(Shared {
            sample: Mutex::new((vec![0.0; widths.0], false)),
            stats: Mutex::new(None),
            notify: Notify::new(),
            peer_chain: Mutex::new(None),
        });
        // A reconnecting link's new session takes over its handle's state.
        let shared = config.rejoin.shared.clone().unwrap_or(shared);
        // The endpoint's clock is the hub's: links on one hub share a tick grid.
        let now = Instant::from_std(hub.origin(), StdInstant::now());
        let mut endpoint = Endpoint::<Heap>::with_capacity(cfg, now, config.queue_capacity)
            .map_err(NetError::Config)?;
        // A shared robot's link offers what its floor says now.
        let notes = sharing.map(|s| {
            let (seat, term) = s.offer();
            // A remote's endpoint before its handshake takes any offer.
            let _ = endpoint.offer(seat, term);
            (seat, s.notes())
        });
        // Memory per link follows the width the peer's samples carry (and
        // what an observer is told of the commands).
        let applied = ndr_core::wire::Applied::FIXED_LEN + 8 * usize::from(cfg.command_width);
        let max_frame = HEADER_LEN + (8 * widths.1).max(applied);
        let mut entry = Entry::new(endpoint, Arc::clone(&shared), del_tx, path, max_frame);
        entry.handler = config.rejoin.handler();
        entry.set_tap(config.rejoin.tap());
        let sharing = notes.map(|(offered, notes)| {
            let key = notes.link();
            entry.notes = Some(notes);
            Sharing {
                key,
                offered,
                address: Arc::new(Mutex::new((hub.clone(), id))),
                observer: false,
            }
        });
        let link = Link {
            id,
            deliveries: del_rx,
            shared,
            events: VecDeque::new(),
            events_dropped: Arc::new(AtomicU64::new(0)),
            widths,
            role: cfg.role,
            closed: None,
            shut: false,
            peer,
            hub: hub.clone(),
            seat: None,
            sharing,
            reach: Arc::default(),
            redial: None,
        };
        Ok((id, entry, link))
    }

    /// Ends the link with `error`, whose close reason the peer gets,
    /// without waiting for the hub to let it go: for the listener's tasks,
    /// which must not block their runtime.
    pub(crate) fn dismiss(mut self, error: LinkError) {
        self.shut = true;
        let _ = self.hub.send(Msg::Fail(self.id, error));
    }

    /// Moves a listener's QUIC link, its handshakes done, from the hub of
    /// the listener's endpoint to `to` (`hub::quic`); `false` if it stays
    /// (it has ended, or `to` keeps another clock).
    pub(crate) async fn move_to(&mut self, to: &Hub) -> bool {
        if to.origin() != self.hub.origin() {
            return false;
        }
        let (reply, moved) = tokio::sync::oneshot::channel();
        let m = QuicMove {
            to: to.clone(),
            from: self.hub.clone(),
            reply,
        };
        if !self.hub.send(Msg::Move(self.id, Box::new(m))) {
            return false;
        }
        match moved.await {
            Ok(Some(id)) => {
                self.id = id;
                self.hub = to.clone();
                if let Some(s) = &self.sharing {
                    *s.address.lock().unwrap_or_else(PoisonError::into_inner) = (to.clone(), id);
                }
                true
            }
            _ => false,
        }
    }

    /// A shared robot's link, as its floor knows it.
    pub(crate) fn sharing(&mut self) -> Option<&mut Sharing> {
        self.sharing.as_mut()
    }

    /// The seat the peer's Hello named, once the handshake is done: at the
    /// remote, the one its base asked for; at the base, the one the remote
    /// gave ([`Seat::Observe`](ndr_core::wire::Seat::Observe) to a base
    /// waiting for control). Control's later changes come as events
    /// ([`Event::ControlGranted`], [`Event::ControlLost`]).
    #[must_use]
    pub fn peer_seat(&self) -> Option<ndr_core::wire::Seat> {
        self.events.iter().find_map(|e| match e {
            Event::Connected { peer } => Some(peer.seat),
            _ => None,
        })
    }

    /// Whether this link is an observer's, at a listener that shares its
    /// robot: its peer gets the states and the applied commands, and sends
    /// no command.
    #[must_use]
    pub fn is_observer(&self) -> bool {
        self.sharing.as_ref().is_some_and(|s| s.observer)
    }

    /// Base: gives control up (the link goes on as an observer's; the
    /// remote hands control to a base waiting for it). An
    /// [`Event::ControlLost`] follows; a base that holds no control gets
    /// none, and nothing changes.
    pub fn yield_control(&self) -> Result<(), NetError> {
        if let Some(e) = self.closed {
            return Err(NetError::Link(e));
        }
        if self
            .hub
            .send(Msg::Seat(self.id, Box::new(crate::sharing::SeatOp::Yield)))
        {
            Ok(())
        } else {
            Err(NetError::Link(LinkError::Closed))
        }
    }

    /// Keeps `seat` until the link is dropped.
    pub(crate) fn hold(&mut self, seat: Seat) {
        self.seat = Some(seat);
    }

    /// What the link's handle and its hub share.
    pub(crate) fn shared(&self) -> &Arc<Shared> {
        &self.shared
    }

    /// The peer's address.
    #[must_use]
    pub fn peer_addr(&self) -> SocketAddr {
        self.peer
    }

    /// Sets the sample sent at the next tick. If none is given before a tick,
    /// the previous one is sent again (and counted).
    pub fn send(&self, values: &[f64]) -> Result<(), NetError> {
        if let Some(e) = self.closed {
            return Err(NetError::Link(e));
        }
        self.sender().send(values)
    }

    /// Values in each sample this side sends and in each it receives: at
    /// the base (command width, state width), at the remote the reverse.
    #[must_use]
    pub fn widths(&self) -> (usize, usize) {
        self.widths
    }

    /// This side's role: base or remote.
    #[must_use]
    pub fn role(&self) -> Role {
        self.role
    }

    /// Has `tap` see every event of the link on its hub's thread, before
    /// the application (a recorder's: [`Link::record`](crate::Link::record)).
    #[cfg_attr(not(feature = "record"), allow(dead_code))]
    pub(crate) fn tap(&mut self, tap: crate::hub::Tap) -> Result<(), NetError> {
        if let Some(e) = self.closed {
            return Err(NetError::Link(e));
        }
        // A reconnecting link's sessions share it.
        let tap = match self.redial.as_deref_mut() {
            Some(r) => r.keep_tap(tap),
            None => tap,
        };
        if self.hub.send(Msg::Tap(self.id, tap)) {
            Ok(())
        } else {
            Err(NetError::Link(LinkError::Closed))
        }
    }

    /// A handle that sets the samples this link sends and reads its stats,
    /// for another thread while this one waits in [`recv`](Self::recv).
    #[must_use]
    pub fn sender(&self) -> LinkSender {
        LinkSender {
            shared: Arc::clone(&self.shared),
            events_dropped: Arc::clone(&self.events_dropped),
            reach: Arc::clone(&self.reach),
            width: self.widths.0,
            origin: self.hub.origin(),
        }
    }

    /// Now, on the link's clock: the one its samples' `arrived_at` and
    /// `released_at` are on (its hub's; the peer's `sent_at` is on the peer's).
    #[must_use]
    pub fn now(&self) -> Instant {
        Instant::from_std(self.hub.origin(), StdInstant::now())
    }

    /// The next released sample, waiting as long as it takes; an error once
    /// the link has ended.
    pub fn recv(&mut self) -> Result<Sample, NetError> {
        loop {
            if self.is_down() {
                self.rejoin(None)?;
                continue;
            }
            let d = self.deliveries.recv().map_err(|_| self.ended())?;
            if let Some(s) = self.accept(d)? {
                return Ok(s);
            }
        }
    }

    /// The next released sample if one is waiting, without blocking
    /// (`Ok(None)` if none is); for an application that serves many links
    /// from one thread.
    pub fn try_recv(&mut self) -> Result<Option<Sample>, NetError> {
        loop {
            if self.is_down() {
                if self.rejoin(Some(StdInstant::now()))? {
                    continue;
                }
                return Ok(None);
            }
            let d = match self.deliveries.try_recv() {
                Ok(d) => d,
                Err(mpsc::TryRecvError::Empty) => return Ok(None),
                Err(mpsc::TryRecvError::Disconnected) => return Err(self.ended()),
            };
            if let Some(s) = self.accept(d)? {
                return Ok(Some(s));
            }
        }
    }

    /// [`recv`](Self::recv) waiting at most `timeout` ([`NetError::Timeout`] then).
    pub fn recv_timeout(&mut self, timeout: std::time::Duration) -> Result<Sample, NetError> {
        let end = StdInstant::now() + timeout;
        loop {
            if self.is_down() {
                if self.rejoin(Some(end))? {
                    continue;
                }
                return Err(NetError::Timeout);
            }
            let left = end.saturating_duration_since(StdInstant::now());
            let d = match self.deliveries.recv_timeout(left) {
                Ok(d) => d,
                Err(RecvTimeoutError::Timeout) => return Err(NetError::Timeout),
                Err(RecvTimeoutError::Disconnected) => return Err(self.ended()),
            };
            if let Some(s) = self.accept(d)? {
                return Ok(s);
            }
        }
    }

    /// The next released sample, for async callers.
    pub async fn recv_async(&mut self) -> Result<Sample, NetError> {
        let shared = Arc::clone(&self.shared);
        loop {
            if let Some(found) = self.redial.as_ref().and_then(|r| r.notify()) {
                // The search's wake-up is kept until awaited: none is lost
                // between the look and the wait.
                if !self.rejoin(Some(StdInstant::now()))? {
                    found.notified().await;
                }
                continue;
            }
            let notified = shared.notify.notified();
            match self.deliveries.try_recv() {
                Ok(d) => {
                    if let Some(s) = self.accept(d)? {
                        return Ok(s);
                    }
                }
                Err(mpsc::TryRecvError::Empty) => notified.await,
                Err(mpsc::TryRecvError::Disconnected) => return Err(self.ended()),
            }
        }
    }

    /// Waits until the handshake is over: `Ok` once the peer's Hello was
    /// accepted ([`Event::Connected`], kept for
    /// [`drain_events`](Self::drain_events)); the link's error if it failed.
    pub async fn handshake(&mut self) -> Result<(), NetError> {
        let shared = Arc::clone(&self.shared);
        loop {
            if self
                .events
                .iter()
                .any(|e| matches!(e, Event::Connected { .. }))
            {
                return Ok(());
            }
            let notified = shared.notify.notified();
            match self.deliveries.try_recv() {
                // Samples only flow after the handshake and the
                // initialization pattern: none can come before it.
                Ok(d) => {
                    let _ = self.accept(d)?;
                }
                Err(mpsc::TryRecvError::Empty) => notified.await,
                Err(mpsc::TryRecvError::Disconnected) => return Err(self.ended()),
            }
        }
    }

    fn ended(&self) -> NetError {
        NetError::Link(self.closed.unwrap_or(LinkError::Closed))
    }

    fn accept(&mut self, d: Delivery) -> Result<Option<Sample>, NetError> {
        match d {
            Delivery::Sample(mut s) => {
                let Some(r) = self.redial.as_deref_mut() else {
                    return Ok(Some(s));
                };
                let fresh = s.status == Status::Fresh;
                let session = r.sessions.session();
                let Some(seq) = r.sessions.admit(session, s.seq, fresh) else {
                    self.publish_reach();
                    return Ok(None);
                };
                s.seq = seq;
                if fresh {
                    r.last_fresh = Some(s.released_at);
                }
                Ok(Some(s))
            }
            Delivery::Event(Event::Closed { error }) => {
                let e = error.unwrap_or(LinkError::Closed);
                if !self.shut && error.is_some_and(|e| recoverable(&e)) && self.redial.is_some() {
                    let now = self.now();
                    let hub = self.hub.clone();
                    if let Some(r) = self.redial.as_deref_mut() {
                        match r.lost(now, &hub) {
                            Ok(announce) => {
                                tracing::warn!(
                                    "the link to {} was lost ({e}); reconnecting",
                                    self.peer
                                );
                                if let Some(silent_for) = announce {
                                    self.push_event(Event::LinkLost { silent_for });
                                }
                                return Ok(None);
                            }
                            Err(why) => tracing::error!("cannot reconnect the link: {why}"),
                        }
                    }
                }
                self.closed = Some(e);
                self.push_event(Event::Closed { error });
                Err(NetError::Link(e))
            }
            Delivery::Event(e) => {
                let now = self.now();
                if let Some(r) = self.redial.as_deref_mut() {
                    match e {
                        Event::LinkLost { silent_for } => r.silent_since = Some(now - silent_for),
                        Event::LinkRestored { .. } => r.silent_since = None,
                        Event::Started { .. } => {
                            if let Some(outage) = r.sessions.restored(now) {
                                tracing::warn!("the link to {} is back after {outage}", self.peer);
                                self.push_event(e);
                                self.push_event(Event::LinkRestored { outage });
                                self.publish_reach();
                                return Ok(None);
                            }
                        }
                        _ => {}
                    }
                }
                self.push_event(e);
                Ok(None)
            }
        }
    }

    /// Whether the link is down, looking for its peer again.
    fn is_down(&self) -> bool {
        self.redial.as_ref().is_some_and(|r| r.down())
    }

    /// While the link is down: waits for its new session until `until`
    /// (`None`: as long as it takes); `Ok(true)` once it is here, an error
    /// if there will be none.
    fn rejoin(&mut self, until: Option<StdInstant>) -> Result<bool, NetError> {
        let Some(r) = self.redial.as_deref_mut() else {
            return Err(self.ended());
        };
        match r.resume(until) {
            Resumed::NotYet => Ok(false),
            Resumed::Link(new) => {
                self.adopt(*new);
                Ok(true)
            }
            Resumed::Failed(e) => {
                let error = match &e {
                    NetError::Link(l) => *l,
                    _ => LinkError::Disconnected,
                };
                self.closed = Some(error);
                self.push_event(Event::Closed { error: Some(error) });
                Err(e)
            }
        }
    }

    /// Takes over `new`, a new session of this link: its deliveries come
    /// to this handle from now on; it keeps the old session's parts, over.
    fn adopt(&mut self, mut new: Link) {
        std::mem::swap(&mut self.id, &mut new.id);
        std::mem::swap(&mut self.deliveries, &mut new.deliveries);
        std::mem::swap(&mut self.hub, &mut new.hub);
        std::mem::swap(&mut self.peer, &mut new.peer);
        for e in new.events.drain(..) {
            keep_event(&mut self.events, &self.events_dropped, e);
        }
        new.shut = true;
    }

    /// How long connecting waited for the remote.
    pub(crate) fn waited(&mut self, waited: std::time::Duration) {
        self.reach.lock().unwrap_or_else(PoisonError::into_inner).0 = waited.into();
    }

    /// Makes the link one that reconnects to `addr` when it loses its peer.
    pub(crate) fn redial_to(&mut self, addr: SocketAddr, config: LinkConfig) {
        self.redial = Some(Box::new(Redial::new(addr, config, &self.hub, &self.shared)));
    }

    fn publish_reach(&self) {
        if let Some(r) = &self.redial {
            self.reach.lock().unwrap_or_else(PoisonError::into_inner).1 = r.sessions.stats();
        }
    }

    fn push_event(&mut self, e: LinkEvent) {
        keep_event(&mut self.events, &self.events_dropped, e);
    }

    /// Events seen while receiving (started, paused, link lost, …), oldest
    /// first: the latest [`EVENT_BACKLOG`] (the others are counted in
    /// [`LinkStats::events_dropped`]).
    pub fn drain_events(&mut self) -> impl Iterator<Item = LinkEvent> + '_ {
        self.events.drain(..)
    }

    /// A snapshot of the link's counters (`None` before the first tick).
    #[must_use]
    pub fn stats(&self) -> Option<LinkStats> {
        self.sender().stats()
    }

    /// Runs `handler` on the link's hub thread at each release from now on,
    /// instead of queueing the sample for [`recv`](Self::recv): the lowest
    /// latency a control loop can have, with no thread woken per tick (on
    /// a machine with few cores, the application's wake-up at each release
    /// competes with the peer's). To answer, give the handler a
    /// [`LinkSender`] ([`sender`](Self::sender)): a sample it sends goes out
    /// at the next tick.
    ///
    /// The handler shares the hub's thread with every link on that hub: it
    /// must return in microseconds and never block (its time shows as
    /// release lateness in [`LinkStats`]). If it panics, the link ends with
    /// [`LinkError::HandlerPanicked`] (its peer gets a Close) and the hub
    /// goes on with its other links (in a build with `panic = "abort"`, a
    /// panic ends the process, as anywhere else).
    ///
    /// Events (and the end of the link) still come through
    /// [`try_recv`](Self::try_recv) and [`recv`](Self::recv), which then
    /// wait for the link to end; releases queued before the handler took
    /// over are still there to read. Python has no handler: its code would
    /// hold the GIL on the hub's thread.
    ///
    /// A link that reconnects ([`LinkConfig::reconnect`]) keeps its
    /// handler for its new sessions; the handler sees each session's own
    /// sequence numbers (from 0 again), not the rising ones of
    /// [`recv`](Self::recv).
    ///
    /// ```no_run
    /// # async fn robot(mut link: ndr_net::Link) -> Result<(), ndr_net::NetError> {
    /// let tx = link.sender();
    /// link.on_release(move |command| {
    ///     // The plant's step, in microseconds and without allocating; its
    ///     // state goes out at the next tick.
    ///     let mut state = [0.0; 8];
    ///     for (s, c) in state.iter_mut().zip(command.values()) {
    ///         *s = 0.5 * c;
    ///     }
    ///     let _ = tx.send(&state[..tx.width()]);
    /// })?;
    /// // Events and the end of the link.
    /// let end = link.recv_async().await;
    /// # let _ = end;
    /// # Ok(())
    /// # }
    /// ```
    pub fn on_release<F>(&mut self, handler: F) -> Result<(), NetError>
    where
        F: FnMut(&Sample) + Send + 'static,
    {
        if let Some(e) = self.closed {
            return Err(NetError::Link(e));
        }
        // A reconnecting link's sessions share it.
        let handler: crate::hub::Handler = match self.redial.as_deref_mut() {
            Some(r) => r.keep_handler(Box::new(handler)),
            None => Box::new(handler),
        };
        if self.hub.send(Msg::Handler(self.id, handler)) {
            Ok(())
        } else {
            Err(NetError::Link(LinkError::Closed))
        }
    }

    /// Closes the link (a Close frame is sent) and waits for its thread.
    pub fn close(mut self) -> Option<LinkStats> {
        self.shutdown();
        self.stats()
    }

    /// [`close`](Self::close) for a link that is not owned (one behind a
    /// mutex, say): asks the hub to close it (a Close frame goes out), then
    /// waits — two seconds at most — until the hub has let it go. Receiving
    /// then reports the end.
    pub fn shutdown(&mut self) {
        self.end(Msg::Close(self.id));
    }

    /// Ends the link as a failure of this side's application: the peer gets
    /// Close code 8, "application failure" (its receive reports
    /// `PeerClosed { reason: Application }`, not a normal end), so a robot can tell an
    /// operator who stopped from one whose program failed. Dropping a link
    /// while its thread panics does this; Python's `Link` does it when an
    /// exception leaves its `with` block or the link is dropped unclosed.
    /// Waits as [`shutdown`](Self::shutdown) does; a no-op once closed.
    pub fn abort(&mut self) {
        self.end(Msg::Fail(self.id, LinkError::Abandoned));
    }

    fn end(&mut self, how: Msg) {
        if self.shut {
            return;
        }
        self.shut = true;
        if let Some(r) = self.redial.as_deref_mut()
            && r.down()
        {
            // No session to close: the search stops.
            r.stop();
            return;
        }
        let _ = self.hub.send(how);
        let end = StdInstant::now() + std::time::Duration::from_secs(2);
        loop {
            let left = end.saturating_duration_since(StdInstant::now());
            match self.deliveries.recv_timeout(left) {
                // Samples after the end are not the application's any more;
                // events are (the Closed one says how this side ended).
                Ok(Delivery::Sample(_)) => {}
                Ok(d @ Delivery::Event(_)) => {
                    let _ = self.accept(d);
                }
                Err(RecvTimeoutError::Timeout | RecvTimeoutError::Disconnected) => return,
            }
        }
    }
}

impl Drop for Link {
    /// Closes the link; while the thread panics, as a failure ([`abort`](Link::abort)).
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.abort();
        } else {
            self.shutdown();
        }
    }
}

/// The sending half of a [`Link`] ([`Link::sender`]): it sets the sample
/// sent at the next tick and reads the counters, from any thread, without
/// waiting for a thread blocked in [`Link::recv`]. It does not know whether
/// the link has ended: the receiving side reports that, and a sample set
/// after the end is simply never sent.
#[derive(Clone)]
pub struct LinkSender {
    shared: Arc<Shared>,
    events_dropped: Arc<AtomicU64>,
    reach: Arc<Mutex<Reach>>,
    width: usize,
    origin: StdInstant,
}

impl fmt::Debug for LinkSender {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LinkSender")
            .field("width", &self.width)
            .finish_non_exhaustive()
    }
}

impl LinkSender {
    /// Sets the sample sent at the next tick (see [`Link::send`]).
    pub fn send(&self, values: &[f64]) -> Result<(), NetError> {
        if values.len() != self.width {
            return Err(NetError::Link(LinkError::SampleShape {
                expected: u16::try_from(self.width).unwrap_or(u16::MAX),
                got: values.len(),
            }));
        }
        if let Some(index) = values.iter().position(|v| !v.is_finite()) {
            return Err(NetError::Link(LinkError::NonFinite { index }));
        }
        let mut slot = self
            .shared
            .sample
            .lock()
            .unwrap_or_else(PoisonError::into_inner);
        slot.0.copy_from_slice(values);
        slot.1 = true;
        Ok(())
    }

    /// A snapshot of the link's counters (`None` before the first tick).
    #[must_use]
    pub fn stats(&self) -> Option<LinkStats> {
        let mut stats = (*self
            .shared
            .stats
            .lock()
            .unwrap_or_else(PoisonError::into_inner))?;
        // Counted on the application's side, which the hub does not see.
        stats.events_dropped = self.events_dropped.load(Ordering::Relaxed);
        (stats.waited, stats.reconnect) =
            *self.reach.lock().unwrap_or_else(PoisonError::into_inner);
        Some(stats)
    }

    /// Values in each sample this side sends: the command width at the
    /// base, the state width at the remote.
    #[must_use]
    pub fn width(&self) -> usize {
        self.width
    }

    /// Now, on the link's clock (see [`Link::now`]).
    #[must_use]
    pub fn now(&self) -> Instant {
        Instant::from_std(self.origin, StdInstant::now())
    }
}

/// Appends `e` to the events waiting for [`Link::drain_events`]; past
/// [`EVENT_BACKLOG`] the oldest goes, counted in `dropped`.
fn keep_event(events: &mut VecDeque<LinkEvent>, dropped: &AtomicU64, e: LinkEvent) {
    if events.len() >= EVENT_BACKLOG {
        events.pop_front();
        dropped.fetch_add(1, Ordering::Relaxed);
    }
    events.push_back(e);
}

/// A link's datagram session token.
pub(crate) fn session_token() -> Result<u64, NetError> {
    Ok(crate::hub::session_token()?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndr_core::time::Duration;

    #[test]
    fn events_past_the_backlog_drop_the_oldest_and_are_counted() {
        let mut events = VecDeque::new();
        let dropped = AtomicU64::new(0);
        let lost = |ms| Event::LinkLost {
            silent_for: Duration::from_millis(ms),
        };
        for ms in 0..EVENT_BACKLOG as u64 + 3 {
            keep_event(&mut events, &dropped, lost(ms));
        }
        assert_eq!(events.len(), EVENT_BACKLOG);
        assert_eq!(dropped.load(Ordering::Relaxed), 3);
        assert_eq!(events.front(), Some(&lost(3)));
        assert_eq!(events.back(), Some(&lost(EVENT_BACKLOG as u64 + 2)));
    }
}
