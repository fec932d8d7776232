//! The remote's side of connecting: a [`Listener`] accepts peers and hands
//! the application running links.
//!
//! Its accept loop runs in the background from the moment it is bound, so
//! connections are accepted and handshaken while the application is busy
//! with a link; finished links wait in a short queue for
//! [`Listener::accept`]. Before a peer has authenticated (TLS, if any, and
//! ndr's Hello), it gets little: a short budget of time
//! ([`Admission::preauth_timeout`](crate::Admission::preauth_timeout)), one of a fixed number of handshake
//! slots, at most a few of them per source
//! ([`Admission::max_pending_per_source`](crate::Admission::max_pending_per_source)). At its source's cap
//! a newcomer takes the slot of one of that source's handshakes that has
//! said less than it, or as much and not moved for a while (else it waits a moment on
//! probation for its first message, or is turned away), and when all slots
//! are taken that of a handshake stuck for a while, of the source holding
//! the most. Peers that never authenticate therefore cannot lock out one
//! who does, even from its own address (a NAT, a relay); the peer whose
//! slot is taken, or that is turned away, is told why (a Close with reason
//! `EVICTED_SOURCE` or `EVICTED`) where it can be. Every refusal is counted
//! by reason ([`ListenerStats`]) and logged, at most one line per reason a
//! second.
//!
//! A QUIC listener's endpoint has a hub of its own, which accepts
//! connections and runs their handshakes: strangers' handshakes never run
//! on a hub that releases a live link's samples; a link moves to the hub
//! that will drive it once its handshakes are done. The listener sees only
//! when each handshake starts and ends: the same slots and cap per source
//! apply (a connection beyond its source's cap is closed at once), and when
//! all slots are taken the newcomer takes that of the oldest pending
//! handshake of the source holding the most (one younger than a round trip
//! or two goes last). Once half the slots are taken, a new connection must
//! first prove it gets what is sent to its address (QUIC's stateless
//! Retry), so that spoofed sources take none.

mod first;
mod gate;
mod handshake;
mod ledger;
mod probation;
mod quic_slots;
mod source;
#[cfg(feature = "zenoh")]
mod zenoh;

use std::fmt;
use std::io;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use ndr_core::endpoint::{LinkError, Phase};
use ndr_core::wire::Role;
use tokio::net::{TcpListener, TcpSocket};
use tokio::runtime::Handle;
use tokio::sync::mpsc;

use crate::config::LinkConfig;
use crate::error::NetError;
use crate::hub::{Hub, Msg, NewEndpoint, NewSocket, QuicPath, QuicServer, bind_datagram_socket};
use crate::link::Link;
use crate::pool::{HubChoice, HubPool};
use crate::ports;
use crate::runtime::{not_in_a_runtime, own_runtime, plain_allowed};
use crate::tls::TlsConfig;

use crate::seats::Seats;
use crate::sharing::{Sharing, SharingStats};
use crate::spin::SpinMargin;
use ledger::{Ledger, Refusal};

/// Connections a [`Listener`] accepted, and those it refused before they
/// became links, by reason. None of the refused reached the application.
/// New counters may be added: read the fields, do not build the struct.
#[non_exhaustive]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct ListenerStats {
    /// Links accepted (handed to the application).
    pub accepted: u64,
    /// TLS handshakes refused for an unknown (untrusted, unpinned)
    /// certificate.
    pub refused_certificate: u64,
    /// TLS handshakes refused because the peer presented no certificate.
    pub refused_no_certificate: u64,
    /// TLS handshakes refused because the peer does not speak TLS 1.3 (an
    /// older TLS, or a plain link).
    pub refused_version: u64,
    /// Handshakes (TLS, then ndr's Hello) that did not finish within the
    /// pre-authentication budget ([`Admission::preauth_timeout`](crate::Admission::preauth_timeout)) or their
    /// own timeout.
    pub timeouts: u64,
    /// Handshakes that failed otherwise (the peer closed, a reset).
    pub failed_other: u64,
    /// ndr handshakes refused: the peer claims this side's role.
    pub refused_role: u64,
    /// ndr handshakes refused: the peer has other sample widths or another
    /// channel layout.
    pub refused_layout: u64,
    /// ndr handshakes refused: another period, regulation mode or
    /// parameters this side cannot take.
    pub refused_settings: u64,
    /// ndr handshakes refused: the peer speaks another wire version.
    pub refused_wire_version: u64,
    /// ndr handshakes refused: the peer sent bytes that are not ndr frames.
    pub refused_protocol: u64,
    /// ndr handshakes refused: the peer runs another transport (one side
    /// over a stream, the other over datagrams).
    pub refused_transport: u64,
    /// Pending handshakes closed to make room for a new connection, every
    /// slot being taken ([`TlsConfig::max_pending_handshakes`]): the oldest
    /// of the source holding the most slots goes, its peer told why (Close
    /// `EVICTED`) where it can be. Many mean a flood of connections that do
    /// not authenticate.
    pub evicted: u64,
    /// Connections closed for their source's cap
    /// ([`Admission::max_pending_per_source`](crate::Admission::max_pending_per_source)
    /// handshakes pending from one source): a pending handshake whose slot
    /// went to a newer connection from its source that had said more, or
    /// as much once it had not moved for a while; or a newcomer that found
    /// no such slot (at once if its first message was whole, else after a
    /// moment on probation without it). Its peer is told why (Close
    /// `EVICTED_SOURCE`) where it can be. Over QUIC: connections closed at
    /// once for that cap.
    pub refused_per_source: u64,
    /// Peers refused after their handshake because the listener served as
    /// many links as [`Listener::with_max_links`] allows: each got a Close
    /// with reason `BUSY`.
    pub refused_busy: u64,
    /// Links that completed their handshake but that the application did
    /// not take: the accept queue was full ([`Admission::accept_queue`](crate::Admission::accept_queue); the
    /// peer was told the listener is busy), or the link ended while it
    /// waited.
    pub unclaimed: u64,
    /// Times the kernel could not hand over a connection (out of file
    /// descriptors or memory); the listener waits a moment and goes on.
    /// Raise the process's open-file limit if this grows.
    pub accept_errors: u64,
    /// Datagram transport: datagrams to the listener's UDP port that
    /// carried no token of a link it accepted (strays, spoofs, truncated
    /// or not samples), or over QUIC that no connection took and that did
    /// not open one, dropped.
    pub datagrams_stray: u64,
    /// QUIC: new connections asked to prove their address first (a
    /// stateless Retry, answered by the peer's QUIC without a round trip
    /// of the application's) because at least half the handshake slots
    /// were taken. A source that does not get what is sent to it (a
    /// spoofed one) never answers and takes no slot.
    pub retried: u64,
    /// Bases that asked for control with an identity the listener lets only
    /// observe ([`TlsConfig`]'s observers' allow-list): each got a Close
    /// with reason `OBSERVER_ONLY`.
    pub refused_observer_only: u64,
    /// Bases that asked to observe when as many observers as
    /// [`Admission::observers`](crate::Admission::observers) were served:
    /// each got a Close with reason `OBSERVERS_FULL`.
    pub refused_observers_full: u64,
}

/// Where a listener puts the links it accepts.
enum Hubs {
    One(Hub),
    Pool(HubPool),
}

/// What the builders set after listening, read by each handshake as it starts.
struct Setup {
    role: Role,
    hubs: Hubs,
}

/// A datagram listener's UDP socket, bound at its TCP port and driven by
/// one hub: every link it accepts runs there.
struct DatagramSocket {
    hub: Hub,
    key: u64,
    stray: Arc<AtomicU64>,
    /// QUIC's Retries ([`ListenerStats::retried`]).
    retried: Arc<AtomicU64>,
}

/// What the listener, its accept loop and its handshakes share.
pub(crate) struct Common {
    config: LinkConfig,
    udp: Option<DatagramSocket>,
    tls: Option<TlsConfig>,
    setup: Mutex<Setup>,
    seats: Arc<Seats>,
    /// The robot's floor, if it is shared: one controller, the observers.
    sharing: Option<Arc<Sharing>>,
    ledger: Mutex<Ledger>,
    /// Why the accept loop stopped, once it has.
    stopped: Mutex<Option<String>>,
}

impl Common {
    /// A listener's state as it is bound (the remote's role by default).
    fn new(
        config: LinkConfig,
        udp: Option<DatagramSocket>,
        tls: Option<TlsConfig>,
        hubs: Hubs,
    ) -> Result<Arc<Common>, NetError> {
        let sharing = match config.admission.observers {
            Some(n) => Some(Sharing::start(n)?),
            None => None,
        };
        Ok(Arc::new(Common {
            config,
            udp,
            tls,
            setup: Mutex::new(Setup {
                role: Role::Remote,
                hubs,
            }),
            seats: Arc::new(Seats::default()),
            sharing,
            ledger: Mutex::new(Ledger::default()),
            stopped: Mutex::new(None),
        }))
    }

    /// The floor a link in `role` is seated by: a remote's links share
    /// their robot.
    fn sharing_for(&self, role: Role) -> Option<&Arc<Sharing>> {
        self.sharing.as_ref().filter(|_| role == Role::Remote)
    }

    /// The hub that will drive a QUIC link whose handshakes are done.
    fn live_hub(&self) -> Hub {
        let setup = self.setup.lock().unwrap_or_else(PoisonError::into_inner);
        match &setup.hubs {
            Hubs::One(hub) => hub.clone(),
            Hubs::Pool(pool) => pool.least_loaded().clone(),
        }
    }

    /// The role and the hub for a link starting now.
    fn setup(&self) -> (Role, Hub) {
        let setup = self.setup.lock().unwrap_or_else(PoisonError::into_inner);
        let hub = match (&self.udp, &setup.hubs) {
            (Some(udp), _) => udp.hub.clone(),
            (None, Hubs::One(hub)) => hub.clone(),
            (None, Hubs::Pool(pool)) => pool.least_loaded().clone(),
        };
        (setup.role, hub)
    }

    fn refuse(&self, why: Refusal, peer: impl Into<Option<SocketAddr>>, what: &dyn fmt::Display) {
        ledger::refuse(&self.ledger, why, peer.into(), what);
    }
}

/// Accepts links as the remote side, one per connecting base.
///
/// From [`listen`](Self::listen) on, a task on the listener's runtime accepts
/// connections and runs their handshakes, whether or not the application is
/// in [`accept`](Self::accept): a peer that comes while the application
/// serves another is answered at once (queued, or refused as busy with
/// [`with_max_links`](Self::with_max_links)) instead of waiting unseen in
/// the kernel. Dropping the listener stops listening and ends the
/// handshakes under way and the links nobody took; links already taken go
/// on.
pub struct Listener {
    local: SocketAddr,
    common: Arc<Common>,
    /// Links whose handshake is done, for [`Listener::accept`].
    ready: tokio::sync::Mutex<mpsc::Receiver<Link>>,
    /// The accept loop, aborted with the listener.
    gate: tokio::task::AbortHandle,
    /// The listening socket's other descriptor, to stop listening at once
    /// on drop whether or not the runtime gets to cancel the accept loop.
    listening: Option<std::os::fd::OwnedFd>,
    /// The runtime of a listener made by [`Listener::listen_blocking`]: its
    /// accepts and handshakes run there.
    runtime: Option<tokio::runtime::Runtime>,
}

impl fmt::Debug for Listener {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Listener")
            .field("local_addr", &self.local)
            .field("tls", &self.common.tls.is_some())
            .field("blocking", &self.runtime.is_some())
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

impl Drop for Listener {
    fn drop(&mut self) {
        if let Some(fd) = self.listening.take() {
            stop_listening(&fd);
        }
        self.gate.abort();
        if let Some(udp) = &self.common.udp {
            // Its links keep it until they end.
            let _ = udp.hub.send(Msg::ReleaseSocket(udp.key));
        }
        // Without waiting for its threads: a blocking listener may still be
        // dropped from async code.
        if let Some(rt) = self.runtime.take() {
            rt.shutdown_background();
        }
    }
}

/// Makes the kernel refuse new connections on a listening socket now
/// (Linux: `shutdown` on a listening socket stops it listening).
#[cfg(target_os = "linux")]
fn stop_listening(fd: &std::os::fd::OwnedFd) {
    use std::os::fd::AsRawFd;
    let _ = nix::sys::socket::shutdown(fd.as_raw_fd(), nix::sys::socket::Shutdown::Both);
}

#[cfg(not(target_os = "linux"))]
fn stop_listening(_: &std::os::fd::OwnedFd) {}

/// The UDP socket of a datagram listener, handed to the hub that will
/// drive its links (a pool's least loaded: datagrams reach one socket, so
/// its links share that hub).
fn datagram_socket(socket: std::net::UdpSocket, hubs: &Hubs) -> Result<DatagramSocket, NetError> {
    let hub = match hubs {
        Hubs::One(hub) => hub.clone(),
        Hubs::Pool(pool) => pool.least_loaded().clone(),
    };
    let stray = Arc::new(AtomicU64::new(0));
    let key = hub.next_id();
    let new = NewSocket {
        socket,
        stray: Arc::clone(&stray),
        held: true,
    };
    if !hub.send(Msg::Socket(key, Box::new(new))) {
        return Err(NetError::Io(io::Error::other(
            "the listener's hub thread has stopped",
        )));
    }
    Ok(DatagramSocket {
        hub,
        key,
        stray,
        retried: Arc::default(),
    })
}

/// A listening socket with `backlog`, reusing the address as
/// [`TcpListener::bind`] does (a restarted robot binds its port at once).
fn tcp_listener(addr: SocketAddr, backlog: u32) -> io::Result<TcpListener> {
    let socket = if addr.is_ipv4() {
        TcpSocket::new_v4()?
    } else {
        TcpSocket::new_v6()?
    };
    #[cfg(unix)]
    socket.set_reuseaddr(true)?;
    socket.bind(addr)?;
    socket.listen(backlog.max(1))
}

/// A datagram listener's sockets: UDP, bound by `udp`, and TCP listening
/// with `backlog`, at one port number (the links' datagrams go to the TCP
/// port's number). At port 0 a number another program holds over TCP
/// draws another ([`ports::bind_pair`]).
fn bind_both(
    addr: SocketAddr,
    backlog: u32,
    udp: impl FnMut(SocketAddr) -> io::Result<(std::net::UdpSocket, SocketAddr)>,
) -> io::Result<(TcpListener, std::net::UdpSocket)> {
    let (datagrams, listener, _) =
        ports::bind_pair(addr, ports::BIND_ATTEMPTS, "listener", udp, |at| {
            tcp_listener(at, backlog)
        })?;
    Ok((listener, datagrams))
}

/// Binds a hub's UDP socket at `at`, and the address it got.
fn bind_udp(at: SocketAddr) -> io::Result<(std::net::UdpSocket, SocketAddr)> {
    let socket = bind_datagram_socket(at)?;
    let local = socket.local_addr()?;
    Ok((socket, local))
}

impl Listener {
    /// Listens on `addr`; the accept loop runs on the current tokio runtime
    /// (on a current-thread runtime, only while it runs), over the
    /// [`LinkConfig::transport`] (one that does not fit the TLS is
    /// [`NetError::Transport`]). Over mutual TLS 1.3 if [`LinkConfig::tls`]
    /// is set (over `quic`: one UDP port at `addr`, no TCP): a peer whose
    /// handshake fails is counted ([`stats`](Self::stats)), logged and
    /// dropped, and never returned by [`accept`](Self::accept). Plain links are refused with
    /// [`NetError::Insecure`] unless `addr` is loopback (then no other host
    /// can connect) or [`LinkConfig::insecure`]. The links it accepts go to
    /// the hub [`LinkConfig::hub`] names (a hub of its own by default).
    pub async fn listen(addr: SocketAddr, config: LinkConfig) -> Result<Listener, NetError> {
        config.checked_transport(config.tls.is_some())?;
        if config.tls.is_none() {
            plain_allowed(addr, &config)?;
        }
        Listener::listen_with(addr, config).await
    }

    async fn listen_with(addr: SocketAddr, config: LinkConfig) -> Result<Listener, NetError> {
        let tls = config.tls.clone();
        let transport = config.checked_transport(tls.is_some())?;
        if transport.is_zenoh() {
            return Err(NetError::Transport(crate::TransportError::ZenohByName));
        }
        let datagrams = transport.datagrams();
        let hubs = match &config.hub {
            HubChoice::Own => Hubs::One(Hub::with_realtime(config.spin_margin, config.realtime)?),
            HubChoice::Shared(hub) => Hubs::One(hub.clone()),
            HubChoice::Pool(pool) => Hubs::Pool(pool.clone()),
        };
        if let (true, Some(tls)) = (transport.is_quic(), tls.as_ref()) {
            return Listener::listen_quic(addr, config.clone(), tls, hubs);
        }
        let backlog = config.admission.backlog;
        let (socket, udp) = if datagrams {
            let (socket, udp) = bind_both(addr, backlog, bind_udp)?;
            (socket, Some(datagram_socket(udp, &hubs)?))
        } else {
            (tcp_listener(addr, backlog)?, None)
        };
        let accept_queue = config.admission.accept_queue.max(1);
        let local = socket.local_addr()?;
        let listening = std::os::fd::AsFd::as_fd(&socket).try_clone_to_owned().ok();
        let slots = tls
            .as_ref()
            .map_or(crate::tls::DEFAULT_MAX_PENDING_HANDSHAKES, |t| {
                t.max_pending_handshakes
            });
        let common = Common::new(config, udp, tls, hubs)?;
        let (tx, rx) = mpsc::channel(accept_queue);
        let gate = gate::Gate::new(socket, &common, tx, slots);
        let gate = Handle::current().spawn(gate.run()).abort_handle();
        Ok(Listener {
            local,
            common,
            ready: tokio::sync::Mutex::new(rx),
            gate,
            listening,
            runtime: None,
        })
    }

    /// A QUIC listener: one QUIC endpoint on a UDP socket at `addr`, on a
    /// hub of its own, which accepts connections and drives their
    /// handshakes; a task on the current runtime waits for each (within
    /// the pre-authentication budget), moves its link to one of `hubs`
    /// and queues it for [`accept`](Self::accept).
    fn listen_quic(
        addr: SocketAddr,
        config: LinkConfig,
        tls: &TlsConfig,
        hubs: Hubs,
    ) -> Result<Listener, NetError> {
        let server = crate::quic::server(&config.endpoint, tls)
            .map_err(|e| NetError::Handshake(crate::tls::HandshakeError::Other(e.to_string())))?;
        let socket = bind_datagram_socket(addr)?;
        let local = socket.local_addr()?;
        // The links' packets leave from the listener's port.
        let send = Arc::new(socket.try_clone()?);
        let origin = match &hubs {
            Hubs::One(hub) => hub.origin(),
            Hubs::Pool(pool) => pool.least_loaded().origin(),
        };
        // On the links' clock, so that a link keeps its tick grid when it
        // moves; its deadlines (handshake timers) need no spin.
        let hub = Hub::with_origin(
            SpinMargin::fixed(ndr_core::time::Duration::ZERO),
            origin,
            config.realtime,
        )?;
        let key = hub.next_id();
        let stray = Arc::new(AtomicU64::new(0));
        let retried = Arc::new(AtomicU64::new(0));
        let accept_queue = config.admission.accept_queue.max(1);
        let udp = DatagramSocket {
            hub: hub.clone(),
            key,
            stray: Arc::clone(&stray),
            retried: Arc::clone(&retried),
        };
        let slots = quic_slots::Slots::new(
            tls.max_pending_handshakes,
            config.admission.max_pending_per_source,
        );
        let common = Common::new(config, Some(udp), Some(tls.clone()), hubs)?;
        let (tx, rx) = mpsc::channel(accept_queue);
        // Room for every slot twice: an evicted handshake's link may wait
        // here for its task beside the one that took its slot.
        let (started_tx, mut started_rx) =
            mpsc::channel::<(Link, quic_slots::Slot)>(2 * slots.capacity());
        let accept = {
            let common = Arc::clone(&common);
            let hub = hub.clone();
            let slots = Arc::clone(&slots);
            // Runs on the hub's thread: it must never wait on the hub.
            move |handle, conn: quinn_proto::Connection| {
                let peer = conn.remote_address();
                let admitted = match slots.admit(peer, std::time::Instant::now()) {
                    Ok(admitted) => admitted,
                    // quinn closes the connection.
                    Err(full) => {
                        common.refuse(
                            Refusal::PerSource,
                            peer,
                            &format_args!(
                                "{} QUIC handshakes from its source are already pending, the \
                                 most one source may have \
                                 (LinkConfig::admission.max_pending_per_source)",
                                full.held
                            ),
                        );
                        return None;
                    }
                };
                if let Some(gone) = admitted.evicted {
                    common.refuse(
                        Refusal::Evicted,
                        gone,
                        &format_args!(
                            "its QUIC handshake was cut short to make room: all {} handshake \
                             slots were taken (TlsConfig::max_pending_handshakes), and it was \
                             the oldest of the source holding the most",
                            slots.capacity()
                        ),
                    );
                }
                let (role, _) = common.setup();
                let path = QuicPath::new(key, handle, conn);
                let sharing = common.sharing_for(role);
                let (id, entry, link) =
                    match Link::start_quic(&common.config, role, &hub, path, sharing) {
                        Ok(started) => started,
                        Err(e) => {
                            common.refuse(Refusal::of_link(&e), peer, &e);
                            return None;
                        }
                    };
                match started_tx.try_send((link, admitted.slot)) {
                    Ok(()) => Some((id, entry)),
                    Err(
                        mpsc::error::TrySendError::Full((link, _))
                        | mpsc::error::TrySendError::Closed((link, _)),
                    ) => {
                        // Not dropped here: that would wait on this hub.
                        link.dismiss(LinkError::Busy);
                        None
                    }
                }
            }
        };
        let server = Arc::new(server);
        let point = NewEndpoint {
            socket: Some(send),
            endpoint: crate::quic::endpoint(Some(Arc::clone(&server)), tls),
            server: Some(QuicServer {
                config: server,
                accept: Box::new(accept),
                crowded: Box::new(move || slots.crowded()),
                retried,
            }),
        };
        let new = NewSocket {
            socket,
            stray,
            held: true,
        };
        if !hub.send(Msg::Quic(key, Box::new(new), Box::new(point))) {
            return Err(NetError::Io(io::Error::other(
                "the listener's hub thread has stopped",
            )));
        }
        let handshakes = {
            let common = Arc::clone(&common);
            async move {
                while let Some((link, slot)) = started_rx.recv().await {
                    let task = handshake::quic(Arc::clone(&common), link, slot, tx.clone());
                    tokio::spawn(task);
                }
            }
        };
        let gate = Handle::current().spawn(handshakes).abort_handle();
        Ok(Listener {
            local,
            common,
            ready: tokio::sync::Mutex::new(rx),
            gate,
            listening: None,
            runtime: None,
        })
    }

    /// [`listen`](Self::listen) for programs without a tokio runtime: the
    /// listener gets a small runtime of its own (one `ndr-io` thread), on
    /// which it accepts and runs the handshakes.
    /// The links it accepts need no runtime: their hub drives them.
    ///
    /// ```no_run
    /// use ndr_core::endpoint::Config;
    /// use ndr_core::time::Duration;
    /// use ndr_core::wire::Role;
    /// use ndr_net::{LinkConfig, Listener};
    ///
    /// let mut endpoint = Config::new(Role::Remote).with_width(2);
    /// endpoint.period = Duration::from_millis(10);
    /// // One base at a time: another is told the robot is busy.
    /// let listener = Listener::listen_blocking("127.0.0.1:7300".parse()?, LinkConfig::new(endpoint))?
    ///     .with_max_links(1);
    /// loop {
    ///     let mut link = listener.accept_blocking()?; // one base after another
    ///     while let Ok(command) = link.recv() {
    ///         let state: Vec<f64> = command.values().iter().map(|c| 0.5 * c).collect();
    ///         link.send(&state)?;
    ///     }
    /// }
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn listen_blocking(addr: SocketAddr, config: LinkConfig) -> Result<Listener, NetError> {
        config.checked_transport(config.tls.is_some())?;
        if config.tls.is_none() {
            plain_allowed(addr, &config)?;
        }
        Listener::listen_blocking_with(addr, config)
    }

    fn listen_blocking_with(addr: SocketAddr, config: LinkConfig) -> Result<Listener, NetError> {
        not_in_a_runtime("Listener::listen_blocking", "Listener::listen(..).await")?;
        let rt = own_runtime()?;
        let mut listener = rt.block_on(Listener::listen_with(addr, config))?;
        listener.runtime = Some(rt);
        Ok(listener)
    }

    /// What it accepted and refused so far.
    #[must_use]
    pub fn stats(&self) -> ListenerStats {
        let mut stats = self
            .common
            .ledger
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .stats;
        if let Some(udp) = &self.common.udp {
            stats.datagrams_stray = udp.stray.load(Ordering::Relaxed);
            stats.retried = udp.retried.load(Ordering::Relaxed);
        }
        stats
    }

    /// How its robot was shared: hand-overs of control, the most observers
    /// at once, what the floor refused; `None` unless it shares one
    /// ([`Admission::observers`](crate::Admission::observers)).
    #[must_use]
    pub fn sharing(&self) -> Option<SharingStats> {
        self.common.sharing.as_ref().map(|s| s.stats())
    }

    /// Takes `role` in the links it accepts instead of the remote's (a base
    /// that waits for its robot to dial in). Like the other `with_`
    /// settings, it applies to the handshakes that start after it: set it
    /// right after listening.
    #[must_use]
    pub fn with_role(self, role: Role) -> Listener {
        self.common
            .setup
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .role = role;
        self
    }

    /// Serves at most `n` links at once (at least 1; no limit by default):
    /// a peer whose handshake completes while `n` links this listener
    /// accepted are alive (queued for [`accept`](Self::accept), or taken and
    /// neither dropped nor ended) is refused at once with
    /// [`LinkError::Busy`](ndr_core::endpoint::LinkError::Busy): it gets a
    /// Close with reason `BUSY` right after its handshake, so it can say
    /// the robot is busy rather than wait. Counted in
    /// [`ListenerStats::refused_busy`]. A robot that serves one base at a
    /// time takes 1.
    #[must_use]
    pub fn with_max_links(self, n: usize) -> Listener {
        self.common.seats.set_max(n.max(1));
        self
    }

    /// The address it listens on.
    pub fn local_addr(&self) -> Result<SocketAddr, NetError> {
        Ok(self.local)
    }

    /// The next peer that connected and completed its handshakes, as a
    /// running link (this side is the remote unless
    /// [`with_role`](Self::with_role) said otherwise), waiting until there
    /// is one.
    ///
    /// The handshakes run in the background from [`listen`](Self::listen), side
    /// by side (at most [`TlsConfig::max_pending_handshakes`], or
    /// [`DEFAULT_MAX_PENDING_HANDSHAKES`](crate::tls::DEFAULT_MAX_PENDING_HANDSHAKES)
    /// without TLS): first TLS's, if the listener has it, then ndr's Hello,
    /// both within [`Admission::preauth_timeout`](crate::Admission::preauth_timeout). A peer whose handshake
    /// fails (unknown certificate, another role, other widths or layout, period or
    /// mode, no answer in time…) or that [`Admission`](crate::Admission) turns away is
    /// logged, counted in [`stats`](Self::stats) and dropped: it never
    /// reaches the application, and the listener keeps serving. A link that
    /// ended while it waited here is skipped (counted as
    /// [`unclaimed`](ListenerStats::unclaimed)).
    ///
    /// An error only if the listener stopped listening (its socket failed).
    pub async fn accept(&self) -> Result<Link, NetError> {
        let mut ready = self.ready.lock().await;
        loop {
            let Some(link) = ready.recv().await else {
                let why = self
                    .common
                    .stopped
                    .lock()
                    .unwrap_or_else(PoisonError::into_inner)
                    .clone()
                    .unwrap_or_else(|| "it was shut down".into());
                return Err(NetError::Io(io::Error::other(format!(
                    "the listener on {} stopped listening: {why}; make a new one (Listener::listen)",
                    self.local
                ))));
            };
            if link.stats().is_some_and(|s| s.phase == Phase::Closed) {
                self.common.refuse(
                    Refusal::Unclaimed,
                    link.peer_addr(),
                    &"its link ended while it waited to be accepted",
                );
                continue;
            }
            self.common
                .ledger
                .lock()
                .unwrap_or_else(PoisonError::into_inner)
                .stats
                .accepted += 1;
            return Ok(link);
        }
    }

    /// [`accept`](Self::accept) on the calling thread, for a listener made
    /// by [`listen_blocking`](Self::listen_blocking); one made on a tokio
    /// runtime (by [`listen`](Self::listen)) is refused with an error that
    /// says to `.await` [`accept`](Self::accept) instead.
    pub fn accept_blocking(&self) -> Result<Link, NetError> {
        match &self.runtime {
            Some(rt) => {
                not_in_a_runtime("Listener::accept_blocking", "accept().await")?;
                rt.block_on(self.accept())
            }
            None => Err(NetError::Io(io::Error::other(
                "accept_blocking needs a listener made by Listener::listen_blocking; \
                 this one runs on the caller's tokio runtime: use accept().await",
            ))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn runtime() -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("a runtime")
    }

    #[test]
    fn a_port_another_program_takes_over_tcp_between_the_binds_draws_another() {
        let rt = runtime();
        let _in = rt.enter();
        let loopback = SocketAddr::from(([127, 0, 0, 1], 0));
        // Another program takes TCP at the first number UDP got, in the
        // moment between the two binds, as the listener would (if it cannot,
        // a socket there already keeps the listener off that number too).
        let mut squatted = None;
        let udp = |at| {
            let (socket, local) = bind_udp(at)?;
            if squatted.is_none() {
                squatted = Some((local.port(), tcp_listener(local, 1).ok()));
            }
            Ok((socket, local))
        };
        let (tcp, udp) = bind_both(loopback, 8, udp).expect("binds at another number");
        let taken = squatted.map(|(port, _)| port);
        let port = tcp.local_addr().expect("bound").port();
        assert!(taken.is_some());
        assert_ne!(Some(port), taken);
        assert_eq!(udp.local_addr().expect("bound").port(), port);
    }

    #[test]
    fn a_given_port_taken_over_udp_is_a_clear_error() {
        let rt = runtime();
        let _in = rt.enter();
        let other = std::net::UdpSocket::bind("127.0.0.1:0").expect("binds");
        let at = other.local_addr().expect("bound");
        let e = bind_both(at, 8, bind_udp).expect_err("the port is taken");
        assert_eq!(e.kind(), io::ErrorKind::AddrInUse);
        let msg = e.to_string();
        assert!(
            msg.contains(&format!("listener: cannot listen on {at} over UDP")),
            "{msg}"
        );
    }
}
