//! QUIC links in a hub: quinn-proto's sans-IO state machine driven on the
//! hub's thread, as rustls's is on a TLS link.
//!
//! A QUIC endpoint (`quinn_proto::Endpoint`) owns one UDP socket of the
//! hub's ([`super::udp`] reads and writes it in batches, with the kernel's
//! arrival stamps); a base's link has an endpoint of its own, a listener's
//! endpoint serves every link it accepts. Each link's connection lives in
//! its [`Entry`]: the endpoint's reliable frames (Hello, Control, Close)
//! go on one bidirectional stream that the connecting side opens, each
//! Bundle as one DATAGRAM frame (RFC 9221), never sent again. The
//! connection's timers join the link's deadline in the hub's index; its
//! packets go out with the tick's batched send.
//!
//! The endpoint's Close frame travels as the reason of QUIC's
//! CONNECTION_CLOSE, which QUIC sends at once and does not hold behind
//! the stream: the peer hands it to its endpoint as the last frame.
//!
//! A listener's endpoint runs on a hub of its own, with the handshakes
//! (anyone may start one, and each costs a key exchange and a
//! signature): no stranger's work runs on a hub that releases a live
//! link's samples. Once a link's handshakes are done, it moves to the hub
//! that will drive it ([`Move`]): its connection goes with it, and the
//! endpoint's hub, which still reads the port, hands it each of its
//! packets ([`Forwarded`]) and takes its requests ([`Request`]); the link
//! sends from the same port itself.

use rustls::pki_types::CertificateDer;
use std::collections::HashMap;
use std::io;
use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::Instant as StdInstant;

use bytes::{Bytes, BytesMut};
use ndr_core::endpoint::{LinkError, Origin};
use ndr_core::time::Instant;
use ndr_core::wire::{Frame, Kind};
use quinn_proto::{
    ConnectionError, ConnectionEvent, ConnectionHandle, DatagramEvent, Dir, EndpointEvent,
    StreamEvent, StreamId, VarInt,
};

use super::udp::{Outgoing, Udp};
use super::{Entry, Hub, Msg, handle_frames};

/// Frames a link may have waiting for its stream (flow control, or the
/// stream not open yet) before it is cut off.
const MAX_PENDING: usize = 1 << 16;
/// QUIC's application error code for a link that ended: the reason is then
/// the endpoint's Close frame.
const CLOSED: VarInt = VarInt::from_u32(0);
/// Packets of a moved link that may wait for its hub; past them one is
/// dropped (counted as a stray), as the kernel drops what a full socket
/// buffer cannot take.
const MAX_FORWARDED: usize = 1024;

/// Builds the link for a connection a listener's endpoint accepted: its
/// id and entry for the hub, or `None` if the listener refuses it (its
/// handshakes are all taken, or it is gone).
pub(crate) type Accept =
    Box<dyn FnMut(ConnectionHandle, quinn_proto::Connection) -> Option<(u64, Entry)> + Send>;

/// A QUIC endpoint handed to a hub ([`super::Msg::Quic`]).
pub(crate) struct NewEndpoint {
    pub endpoint: quinn_proto::Endpoint,
    /// A listener's: what it accepts connections with.
    pub server: Option<Server>,
    /// A handle on the endpoint's socket, for the links that move to
    /// another hub to send from (a listener's).
    pub socket: Option<Arc<UdpSocket>>,
}

/// A link leaving its endpoint's hub for the hub `to`, which will drive
/// it (`Msg::Move`); `from` is the endpoint's hub. Told its id there, or
/// `None` if it stays (it has ended, or cannot move).
pub(crate) struct Move {
    pub to: Hub,
    pub from: Hub,
    pub reply: tokio::sync::oneshot::Sender<Option<u64>>,
}

/// What a moved link's endpoint hands its connection (`Msg::QuicForwarded`):
/// a packet and when it arrived (counted as a stray of the endpoint's
/// socket if the link has left its hub meanwhile), or the answer to a
/// request.
pub(crate) struct Forwarded {
    event: ConnectionEvent,
    arrived: Option<(StdInstant, Arc<AtomicU64>)>,
}

/// What a moved link's connection asks of its endpoint
/// (`Msg::QuicRequest`): new connection ids, retiring old ones, and that
/// it forget the connection once it has ended.
pub(crate) struct Request {
    handle: ConnectionHandle,
    event: EndpointEvent,
}

/// A moved link's way back to its endpoint.
struct Home {
    /// The endpoint's hub.
    hub: Hub,
    /// The endpoint's socket: the link's packets leave from its port.
    socket: Arc<UdpSocket>,
    /// Its packets handed over and not handled yet.
    backlog: Arc<AtomicUsize>,
}

/// Where an endpoint's hub hands a connection's packets.
enum Route {
    /// To link `id` on this hub.
    Here(u64),
    /// To link `id` on the hub it moved to, with the count of its packets
    /// waiting there.
    Moved {
        hub: Hub,
        id: u64,
        backlog: Arc<AtomicUsize>,
    },
}

/// A listener's side of its endpoint.
pub(crate) struct Server {
    pub config: Arc<quinn_proto::ServerConfig>,
    pub accept: Accept,
    /// Whether the listener is crowded: a new connection from an address
    /// not validated yet must then prove it first (a stateless Retry).
    pub crowded: Box<dyn Fn() -> bool + Send>,
    /// Retries sent.
    pub retried: Arc<AtomicU64>,
}

/// One link's QUIC connection.
pub(crate) struct QuicPath {
    /// The hub's key of the endpoint (and of its UDP socket).
    pub key: u64,
    pub handle: ConnectionHandle,
    pub conn: quinn_proto::Connection,
    /// The stream of the endpoint's frames, once open (the connecting
    /// side opens it; the other side takes it when the first bytes come).
    stream: Option<StreamId>,
    /// Frames the stream has not taken yet, in order.
    pending: Vec<u8>,
    /// The stream's bytes of one read (kept to reuse its memory).
    inbox: Vec<u8>,
    /// The endpoint's Close frame, for the CONNECTION_CLOSE.
    close: Option<Bytes>,
    /// Datagrams quinn did not take (its buffer full, the peer cannot take
    /// them) or dropped unsent.
    pub dropped: u64,
    /// The connection's next timer.
    pub timer: Option<StdInstant>,
    /// Datagrams to its endpoint's socket that no connection took
    /// (shared by the links on it; set when the hub attaches the link).
    pub stray: Arc<AtomicU64>,
    /// Where the peer is now, and how many times that changed (the peer
    /// moved, or a NAT gave it a new mapping: QUIC follows it).
    pub peer: SocketAddr,
    pub path_changes: u64,
    /// The connection ended (lost, or closed by either side).
    lost: bool,
    /// Its endpoint has forgotten it (a handle it may give another
    /// connection now).
    drained: bool,
    /// Its endpoint's hub, once the link has moved to another.
    home: Option<Home>,
}

impl QuicPath {
    pub(crate) fn new(key: u64, handle: ConnectionHandle, conn: quinn_proto::Connection) -> Self {
        QuicPath {
            peer: conn.remote_address(),
            path_changes: 0,
            key,
            handle,
            conn,
            stream: None,
            pending: Vec::new(),
            inbox: Vec::new(),
            close: None,
            dropped: 0,
            timer: None,
            stray: Arc::default(),
            lost: false,
            drained: false,
            home: None,
        }
    }
}

struct Point {
    endpoint: quinn_proto::Endpoint,
    /// Connection → its link.
    links: HashMap<ConnectionHandle, Route>,
    server: Option<Server>,
    /// The socket's count of datagrams no connection took.
    stray: Arc<AtomicU64>,
    /// For the links that move.
    socket: Option<Arc<UdpSocket>>,
}

/// The hub's QUIC endpoints.
pub(super) struct Quic {
    points: HashMap<u64, Point>,
    buf: Vec<u8>,
}

impl Quic {
    pub(super) fn new() -> Quic {
        Quic {
            points: HashMap::new(),
            buf: Vec::new(),
        }
    }

    /// Whether `key` (a poll token) is a QUIC endpoint's socket.
    pub(super) fn has(&self, key: u64) -> bool {
        self.points.contains_key(&key)
    }

    /// Takes the endpoint `new` on the socket `key` (already in `udp`),
    /// counting what no connection takes in `stray`.
    pub(super) fn add(&mut self, key: u64, new: NewEndpoint, stray: Arc<AtomicU64>) {
        self.points.insert(
            key,
            Point {
                endpoint: new.endpoint,
                links: HashMap::new(),
                server: new.server,
                stray,
                socket: new.socket,
            },
        );
    }

    /// Routes the connection of link `id` to it; `false` if its endpoint
    /// is gone. A moved link's endpoint routes it already.
    pub(super) fn attach(&mut self, id: u64, path: &mut QuicPath) -> bool {
        if path.home.is_some() {
            return true;
        }
        let Some(point) = self.points.get_mut(&path.key) else {
            return false;
        };
        point.links.insert(path.handle, Route::Here(id));
        path.stray = Arc::clone(&point.stray);
        true
    }

    /// The connection of link `e` leaves with its link for the hub `to`,
    /// where it is link `id`; `from` is this hub. `false` if it cannot
    /// (not a listener's connection): the link stays.
    pub(super) fn move_out(&mut self, e: &mut Entry, id: u64, to: &Hub, from: Hub) -> bool {
        let Some(q) = e.path.quic_mut() else {
            return false;
        };
        let Some(point) = self.points.get_mut(&q.key) else {
            return false;
        };
        let Some(socket) = point.socket.clone() else {
            return false;
        };
        let backlog = Arc::new(AtomicUsize::new(0));
        point.links.insert(
            q.handle,
            Route::Moved {
                hub: to.clone(),
                id,
                backlog: Arc::clone(&backlog),
            },
        );
        q.home = Some(Home {
            hub: from,
            socket,
            backlog,
        });
        true
    }

    /// The link that was to take over connection `handle` of endpoint
    /// `key` never will (its hub has stopped): the endpoint forgets it;
    /// `true` if the endpoint closed now.
    pub(super) fn forget(&mut self, key: u64, handle: ConnectionHandle) -> bool {
        if let Some(point) = self.points.get_mut(&key) {
            point.links.remove(&handle);
            let _ = point
                .endpoint
                .handle_event(handle, EndpointEvent::drained());
        }
        self.close_if_unused(key)
    }

    /// A moved link's connection asks its endpoint `key`; the answer goes
    /// back to it. `true` if the endpoint closed now (it forgot its last
    /// connection, and its listener is gone).
    pub(super) fn request(&mut self, key: u64, r: Request) -> bool {
        let Some(point) = self.points.get_mut(&key) else {
            return false;
        };
        let drained = r.event.is_drained();
        if let Some(back) = point.endpoint.handle_event(r.handle, r.event)
            && let Some(Route::Moved { hub, id, .. }) = point.links.get(&r.handle)
        {
            let answer = Box::new(Forwarded {
                event: back,
                arrived: None,
            });
            let _ = hub.send(Msg::QuicForwarded(*id, answer));
        }
        if drained {
            point.links.remove(&r.handle);
            return self.close_if_unused(key);
        }
        false
    }

    /// The listener is gone: its endpoint accepts no more connections and
    /// closes with its last link; `true` if it closed now (its socket can go).
    pub(super) fn release(&mut self, key: u64) -> bool {
        if let Some(point) = self.points.get_mut(&key) {
            point.server = None;
        }
        self.close_if_unused(key)
    }

    fn close_if_unused(&mut self, key: u64) -> bool {
        let unused = self
            .points
            .get(&key)
            .is_some_and(|p| p.server.is_none() && p.links.is_empty());
        if unused {
            self.points.remove(&key);
        }
        unused
    }

    /// Link `id` has left the hub: its connection is forgotten; `true` if
    /// its endpoint closed with it (its socket can go).
    pub(super) fn detach(&mut self, path: &QuicPath) -> bool {
        if let Some(home) = &path.home {
            if !path.drained {
                let forget = Request {
                    handle: path.handle,
                    event: EndpointEvent::drained(),
                };
                let _ = home.hub.send(Msg::QuicRequest(path.key, Box::new(forget)));
            }
            return false;
        }
        if let Some(point) = self.points.get_mut(&path.key) {
            point.links.remove(&path.handle);
            // The connection is dropped with its link: its endpoint forgets
            // its identifiers now instead of waiting for a drain.
            if !path.drained {
                let _ = point
                    .endpoint
                    .handle_event(path.handle, EndpointEvent::drained());
            }
        }
        self.close_if_unused(path.key)
    }

    /// Hands the datagrams `udp` read from socket `key` to the endpoint;
    /// the links that got one are added to `touched`, the links a
    /// listener accepted to `accepted`.
    pub(super) fn receive(
        &mut self,
        key: u64,
        udp: &mut Udp,
        origin: StdInstant,
        entries: &mut HashMap<u64, Entry>,
        touched: &mut Vec<u64>,
        accepted: &mut Vec<(u64, Entry)>,
    ) {
        let Some(point) = self.points.get_mut(&key) else {
            return;
        };
        loop {
            let got = match udp.read(key) {
                Ok(n) => n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                Err(_) => return,
            };
            let handled = StdInstant::now();
            for i in 0..got {
                let Some((from, at, datagrams)) = udp.received(i) else {
                    continue;
                };
                let (Some(from), at) = (from, at.unwrap_or(handled)) else {
                    continue;
                };
                // A run the kernel coalesced is one packet each to quinn.
                let datagrams: Vec<BytesMut> = datagrams.map(BytesMut::from).collect();
                for data in datagrams {
                    self.buf.clear();
                    let event = point
                        .endpoint
                        .handle(at, from, None, None, data, &mut self.buf);
                    // What no connection takes is a stray: garbage, a
                    // stranger's packet, a link's after it left the hub.
                    let stray = || point.stray.fetch_add(1, Ordering::Relaxed);
                    match event {
                        Some(DatagramEvent::ConnectionEvent(handle, event)) => {
                            let id = match point.links.get(&handle) {
                                Some(&Route::Here(id)) => id,
                                Some(Route::Moved { hub, id, backlog }) => {
                                    if backlog.fetch_add(1, Ordering::Relaxed) >= MAX_FORWARDED {
                                        backlog.fetch_sub(1, Ordering::Relaxed);
                                        stray();
                                        continue;
                                    }
                                    let packet = Box::new(Forwarded {
                                        event,
                                        arrived: Some((at, Arc::clone(&point.stray))),
                                    });
                                    if !hub.send(Msg::QuicForwarded(*id, packet)) {
                                        stray();
                                    }
                                    continue;
                                }
                                None => {
                                    stray();
                                    continue;
                                }
                            };
                            let Some(e) = entries.get_mut(&id) else {
                                stray();
                                continue;
                            };
                            if let Some(q) = e.path.quic_mut() {
                                q.conn.handle_event(event);
                            }
                            e.rx_lag
                                .push_duration(handled.saturating_duration_since(at).into());
                            input(e, origin, at);
                            if !touched.contains(&id) {
                                touched.push(id);
                            }
                        }
                        Some(DatagramEvent::NewConnection(incoming)) => {
                            let Some(server) = point.server.as_mut() else {
                                point.endpoint.ignore(incoming);
                                stray();
                                continue;
                            };
                            self.buf.clear();
                            // Under load a peer must show it gets what is
                            // sent to its address before it takes a slot:
                            // a spoofed source cannot, and costs no state.
                            if !incoming.remote_address_validated() && (server.crowded)() {
                                match point.endpoint.retry(incoming, &mut self.buf) {
                                    Ok(t) => {
                                        server.retried.fetch_add(1, Ordering::Relaxed);
                                        udp.out.push_to(
                                            key,
                                            u64::MAX,
                                            t.destination,
                                            slice(&self.buf, &t),
                                        );
                                    }
                                    // Not validated, so always retriable.
                                    Err(e) => point.endpoint.ignore(e.into_incoming()),
                                }
                                continue;
                            }
                            match point.endpoint.accept(
                                incoming,
                                at,
                                &mut self.buf,
                                Some(Arc::clone(&server.config)),
                            ) {
                                Ok((handle, conn)) => match (server.accept)(handle, conn) {
                                    Some((id, entry)) => {
                                        point.links.insert(handle, Route::Here(id));
                                        accepted.push((id, entry));
                                    }
                                    None => {
                                        let _ = point
                                            .endpoint
                                            .handle_event(handle, EndpointEvent::drained());
                                    }
                                },
                                Err(refused) => {
                                    // No connection took it either: an
                                    // Initial that does not decrypt (quinn
                                    // finds out only here), or one refused.
                                    stray();
                                    if let Some(t) = refused.response {
                                        let out = &mut udp.out;
                                        out.push_to(
                                            key,
                                            u64::MAX,
                                            t.destination,
                                            slice(&self.buf, &t),
                                        );
                                    }
                                }
                            }
                        }
                        Some(DatagramEvent::Response(t)) => {
                            // No connection's: quinn answers a stranger
                            // (a stateless reset, a version negotiation).
                            stray();
                            udp.out
                                .push_to(key, u64::MAX, t.destination, slice(&self.buf, &t));
                        }
                        None => {
                            stray();
                        }
                    }
                }
            }
            if got < super::udp::BATCH {
                return;
            }
        }
    }

    /// The connection's packets to `out`, its requests to its endpoint
    /// answered, and its next timer noted.
    pub(super) fn output(&mut self, e: &mut Entry, id: u64, now: StdInstant, out: &mut Outgoing) {
        let Some(q) = e.path.quic_mut() else {
            return;
        };
        if q.home.is_some() {
            self.output_moved(q, now);
            return;
        }
        let point = self.points.get_mut(&q.key);
        if let Some(point) = point {
            while let Some(event) = q.conn.poll_endpoint_events() {
                q.drained |= event.is_drained();
                if let Some(back) = point.endpoint.handle_event(q.handle, event) {
                    q.conn.handle_event(back);
                }
            }
        }
        loop {
            self.buf.clear();
            let Some(t) = q.conn.poll_transmit(now, 1, &mut self.buf) else {
                break;
            };
            out.push_to(q.key, id, t.destination, slice(&self.buf, &t));
        }
        note_output(q);
    }

    /// [`output`](Self::output) for a moved link: its requests go to its
    /// endpoint's hub, its packets from the endpoint's socket.
    fn output_moved(&mut self, q: &mut QuicPath, now: StdInstant) {
        let Some(home) = &q.home else {
            return;
        };
        while let Some(event) = q.conn.poll_endpoint_events() {
            q.drained |= event.is_drained();
            let request = Box::new(Request {
                handle: q.handle,
                event,
            });
            // Its hub gone, the endpoint is too: nothing routes to it.
            let _ = home.hub.send(Msg::QuicRequest(q.key, request));
        }
        loop {
            self.buf.clear();
            let Some(t) = q.conn.poll_transmit(now, 1, &mut self.buf) else {
                break;
            };
            // Refused (a full buffer, an unreachable path): lost, as on
            // the network.
            if home
                .socket
                .send_to(slice(&self.buf, &t), t.destination)
                .is_err()
            {
                q.dropped += 1;
            }
        }
        note_output(q);
    }
}

/// The connection's next timer, and where its peer is now.
fn note_output(q: &mut QuicPath) {
    q.timer = q.conn.poll_timeout();
    let peer = q.conn.remote_address();
    if peer != q.peer {
        tracing::debug!(from = %peer, before = %q.peer, "QUIC path changed");
        q.peer = peer;
        q.path_changes += 1;
    }
}

/// A packet (or an answer) a moved link's endpoint handed it; `e` is
/// `None` if the link has left the hub.
pub(super) fn forwarded(e: Option<&mut Entry>, f: Forwarded, origin: StdInstant) {
    let Some(e) = e.filter(|e| e.path.quic().is_some()) else {
        if let Some((_, stray)) = f.arrived {
            stray.fetch_add(1, Ordering::Relaxed);
        }
        return;
    };
    if let Some(q) = e.path.quic_mut() {
        q.conn.handle_event(f.event);
        if let (Some(home), Some(_)) = (&q.home, &f.arrived) {
            home.backlog.fetch_sub(1, Ordering::Relaxed);
        }
    }
    let now = StdInstant::now();
    let at = match f.arrived {
        Some((at, _)) => {
            e.rx_lag
                .push_duration(now.saturating_duration_since(at).into());
            at
        }
        None => now,
    };
    input(e, origin, at);
}

fn slice<'a>(buf: &'a [u8], t: &quinn_proto::Transmit) -> &'a [u8] {
    buf.get(..t.size).unwrap_or_default()
}

/// A timer of the connection passed: it runs what is due.
pub(super) fn on_timeout(e: &mut Entry, now: StdInstant) {
    if let Some(q) = e.path.quic_mut()
        && q.timer.is_some_and(|t| t <= now)
    {
        q.conn.handle_timeout(now);
    }
}

/// The connection's next timer on the hub's clock.
pub(super) fn timer(e: &Entry, origin: StdInstant) -> Option<Instant> {
    e.path
        .quic()
        .and_then(|q| q.timer)
        .map(|t| Instant::from_std(origin, t))
}

/// What the connection has for the endpoint: the stream's frames and the
/// datagrams (arrived at `at`), its opening, its end.
pub(super) fn input(e: &mut Entry, origin: StdInstant, at: StdInstant) {
    loop {
        let Some(q) = e.path.quic_mut() else {
            return;
        };
        let Some(event) = q.conn.poll() else {
            break;
        };
        match event {
            quinn_proto::Event::Connected => {
                if q.conn.side().is_client() && q.stream.is_none() {
                    q.stream = q.conn.streams().open(Dir::Bi);
                }
                let chain = q
                    .conn
                    .crypto_session()
                    .peer_identity()
                    .and_then(|id| id.downcast::<Vec<CertificateDer<'static>>>().ok());
                if let Some(chain) = chain {
                    *e.shared
                        .peer_chain
                        .lock()
                        .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(*chain);
                }
                write_pending(e);
            }
            quinn_proto::Event::Stream(StreamEvent::Opened { dir: Dir::Bi }) => {
                if q.stream.is_none() {
                    q.stream = q.conn.streams().accept(Dir::Bi);
                }
                read_stream(e, origin, at);
                write_pending(e);
            }
            quinn_proto::Event::Stream(StreamEvent::Readable { .. }) => read_stream(e, origin, at),
            quinn_proto::Event::Stream(StreamEvent::Writable { .. }) => write_pending(e),
            quinn_proto::Event::DatagramReceived => {
                while let Some(bytes) = q.conn.datagrams().recv() {
                    // Refused datagrams are counted by the endpoint; QUIC
                    // validates its paths itself.
                    let _ = e.endpoint.handle_datagram(
                        Instant::from_std(origin, at),
                        &bytes,
                        Origin::Path,
                    );
                }
            }
            quinn_proto::Event::ConnectionLost { reason } => {
                q.lost = true;
                lost(e, origin, at, &reason);
                return;
            }
            _ => {}
        }
    }
}

/// The connection ended: the peer's Close frame, if it sent one, goes to
/// the endpoint; otherwise the link ends with what QUIC says.
fn lost(e: &mut Entry, origin: StdInstant, at: StdInstant, reason: &ConnectionError) {
    if let ConnectionError::ApplicationClosed(close) = reason
        && close.error_code == CLOSED
    {
        let _ = e
            .endpoint
            .handle_frame(Instant::from_std(origin, at), &close.reason);
        if e.endpoint.is_closed() {
            return;
        }
    }
    tracing::debug!("QUIC link: {reason}");
    e.endpoint.abort(ended_by(reason));
}

/// What a lost connection ends the link with: a TLS alert about a
/// certificate is a refusal, by the peer (its close) or here (our own
/// transport error).
fn ended_by(reason: &ConnectionError) -> LinkError {
    let (code, here) = match reason {
        ConnectionError::TransportError(t) => (Some(t.code), true),
        ConnectionError::ConnectionClosed(c) => (Some(c.error_code), false),
        ConnectionError::TimedOut => return LinkError::Timeout,
        _ => (None, false),
    };
    // TLS alerts are the crypto error codes 0x100 + alert.
    let alert = code
        .map(u64::from)
        .filter(|c| (0x100..0x200).contains(c))
        .map(|c| rustls::AlertDescription::from((c - 0x100) as u8));
    let refused = matches!(
        alert,
        Some(
            rustls::AlertDescription::BadCertificate
                | rustls::AlertDescription::UnsupportedCertificate
                | rustls::AlertDescription::CertificateRevoked
                | rustls::AlertDescription::CertificateExpired
                | rustls::AlertDescription::CertificateUnknown
                | rustls::AlertDescription::UnknownCA
                | rustls::AlertDescription::AccessDenied
                | rustls::AlertDescription::DecryptError
                | rustls::AlertDescription::CertificateRequired,
        )
    );
    match (refused, here) {
        (true, true) => LinkError::PeerCertificateRefused,
        (true, false) => LinkError::CertificateRefused,
        (false, _) => LinkError::Disconnected,
    }
}

/// The stream's bytes to the deframer, each whole frame to the endpoint.
fn read_stream(e: &mut Entry, origin: StdInstant, at: StdInstant) {
    let Some(q) = e.path.quic_mut() else {
        return;
    };
    let Some(id) = q.stream else {
        return;
    };
    let mut inbox = std::mem::take(&mut q.inbox);
    inbox.clear();
    let mut failed = false;
    {
        let mut stream = q.conn.recv_stream(id);
        let Ok(mut chunks) = stream.read(true) else {
            return;
        };
        // The stream's receive window bounds what one read takes.
        loop {
            match chunks.next(usize::MAX) {
                Ok(Some(chunk)) => inbox.extend_from_slice(&chunk.bytes),
                Ok(None) | Err(quinn_proto::ReadError::Blocked) => break,
                Err(_) => {
                    failed = true;
                    break;
                }
            }
        }
        // Flow-control credit for the peer.
        let _ = chunks.finalize();
    }
    let mut rest = inbox.as_slice();
    while !rest.is_empty() && !e.endpoint.is_closed() {
        let spare = e.deframer.spare();
        let n = spare.len().min(rest.len());
        if n == 0 {
            // Cannot happen: frames are taken out after every fill.
            failed = true;
            break;
        }
        let (now, later) = rest.split_at(n);
        spare.get_mut(..n).unwrap_or_default().copy_from_slice(now);
        e.deframer.filled(n);
        rest = later;
        if !handle_frames(e, origin, at) {
            break;
        }
    }
    if failed && !e.endpoint.is_closed() {
        e.endpoint.abort(LinkError::Disconnected);
    }
    if let Some(q) = e.path.quic_mut() {
        q.inbox = inbox;
    }
}

/// Writes what waits for the stream, as far as flow control lets it.
fn write_pending(e: &mut Entry) {
    let Some(q) = e.path.quic_mut() else {
        return;
    };
    let Some(id) = q.stream else {
        return;
    };
    while !q.pending.is_empty() {
        match q.conn.send_stream(id).write(&q.pending) {
            Ok(n) => {
                q.pending.drain(..n);
            }
            Err(quinn_proto::WriteError::Blocked) => return,
            Err(_) => {
                q.pending.clear();
                e.endpoint.abort(LinkError::Disconnected);
                return;
            }
        }
    }
}

/// One of the endpoint's frames: a Bundle as a datagram, the others on
/// the stream (a Close kept for the CONNECTION_CLOSE as well).
pub(super) fn send(e: &mut Entry, frame: &[u8]) {
    let Some(q) = e.path.quic_mut() else {
        return;
    };
    if ndr_core::wire::is_bundle(frame) {
        // Never held back behind older ones: the newest sample matters.
        if q.conn
            .datagrams()
            .send(Bytes::copy_from_slice(frame), false)
            .is_err()
        {
            q.dropped += 1;
        }
        return;
    }
    if Frame::new_checked(frame).is_ok_and(|f| f.kind() == Kind::Close) {
        q.close = Some(Bytes::copy_from_slice(frame));
    }
    if q.pending.len() + frame.len() > MAX_PENDING {
        q.pending.clear();
        e.endpoint.abort(LinkError::Disconnected);
        return;
    }
    q.pending.extend_from_slice(frame);
    write_pending(e);
}

/// The link is leaving the hub: the connection is closed with the
/// endpoint's Close frame as its reason (unless it is over already).
pub(super) fn close(e: &mut Entry, now: StdInstant) {
    let Some(q) = e.path.quic_mut() else {
        return;
    };
    if q.lost || q.conn.is_closed() {
        return;
    }
    let reason = q.close.take().unwrap_or_default();
    q.conn.close(now, CLOSED, reason);
}

/// The peer's address as the connection sees it now (it follows a peer
/// that moved).
pub(super) fn peer(e: &Entry) -> Option<SocketAddr> {
    e.path.quic().map(|q| q.peer)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refused_certificate_is_told_by_the_side_that_refused() {
        // AccessDenied is what this side's verifier sends for a pin that
        // does not match.
        let code =
            quinn_proto::TransportErrorCode::crypto(rustls::AlertDescription::AccessDenied.into());
        let here = ConnectionError::TransportError(quinn_proto::TransportError {
            code,
            frame: None,
            reason: String::new(),
        });
        assert_eq!(ended_by(&here), LinkError::PeerCertificateRefused);
        let there = ConnectionError::ConnectionClosed(quinn_proto::ConnectionClose {
            error_code: code,
            frame_type: None,
            reason: Bytes::new(),
        });
        assert_eq!(ended_by(&there), LinkError::CertificateRefused);
    }
}
