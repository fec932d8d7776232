//! The delay relay: a TCP and UDP proxy that gives every frame and every
//! datagram a network delay, and datagrams a loss model.
//!
//! The paper's long-distance runs went through "a relay \[that\] delayed
//! network data with values corresponding to a transmission between Paris
//! and New York". This is that relay, with any [`DelayModel`] of
//! `ndr-netem` (the simulator's): a built-in profile, a netem table or a
//! trace.
//!
//! Put it between the two peers: the base connects to the relay's listening
//! address, and for each client the relay connects to `upstream` (the
//! remote) when the client's first frame is due there, so that the
//! upstream sees the connection arrive with its first message, as across a
//! real path (a client that says nothing for a second gets its upstream
//! connection then, for a protocol whose server speaks first). All the
//! relay's clients share its one address at the upstream: a client that
//! says nothing so takes none of the upstream's handshake slots for that
//! address. Client → upstream is [`Direction::Forward`], upstream → client
//! [`Direction::Backward`]. In each direction of a TCP connection the relay:
//!
//! 1. reads whole frames by their 4-byte length prefix
//!    ([`wire::frame_len`](ndr_core::wire::frame_len)); the rest of a frame
//!    is not decoded, and the bytes go out unchanged. A direction whose
//!    first bytes are a TLS record header (`0x16 0x03 0x01..=0x04`: never a
//!    valid frame prefix, which would claim over 64 KiB) is a TLS link: it
//!    is read as whole TLS records by their 5-byte header instead, each
//!    record delayed as a unit (a chunk of the encrypted stream, which the
//!    relay cannot open), still unchanged and in order; its counters then
//!    count records as frames;
//! 2. gives each frame the delay `sampler.delay(dir, t)`, `t` being the time
//!    the frame arrived, counted from the start of the relay;
//! 3. keeps the stream in order as TCP does, with an
//!    [`InOrderPath`](ndr_netem::InOrderPath):
//!    `release = max(previous release, t + delay)`;
//! 4. writes the frame when its release time comes. tokio's timers round up
//!    to the millisecond, so a frame leaves 0–1.5 ms after its release time
//!    (more on a loaded machine); the regulators downstream absorb it.
//!
//! Each connection draws from a fresh
//! [`DelaySampler`](ndr_netem::DelaySampler) seeded with
//! [`connection_seed`]`(seed, index)`, so a run is reproducible: the same
//! seed and the same send times give the same delays.
//!
//! # Failures
//!
//! - An absurd length prefix in either direction, or a direction whose queue
//!   goes over [`RelayConfig::max_queue_frames`] or
//!   [`RelayConfig::max_queue_bytes`], cuts that connection (both sides),
//!   dropping the frames in flight. An upstream that refuses the connection
//!   (or does not answer within [`RelayConfig::connect_timeout`]) drops the
//!   client. Each is counted in [`RelayStats`], reported as a
//!   [`RelayEvent::Closed`] and logged through `tracing`; the relay keeps
//!   serving other clients.
//! - An end of stream on one side is passed on (as a half-close) once every
//!   frame already in flight in that direction has been delivered; the
//!   connection ends when both directions have ended. A partial frame at an
//!   end of stream is dropped.
//! - A side that fails (a read or a write returns an error: it reset, or
//!   it is gone) ends as a path would end it: what it sent before still
//!   arrives, then its end is passed on as a half-close; the frames still
//!   in flight towards it are dropped (`frames_received −
//!   frames_delivered`), and the other side is no longer read. So a peer
//!   that sends its last frame and closes while the other still sends to
//!   it (its kernel answers with a reset) still has that frame delivered.
//!   Once a side has failed, the rest of the connection has 30 s to
//!   finish (a drain towards a peer that stopped reading), then is cut.
//!   Counted as [`RelayStats::io_errors`], with the first failure as its
//!   [`ConnectionEnd::Io`].
//!
//! # Datagrams
//!
//! A link on the datagram transport sends its samples as UDP datagrams
//! (Bundles, `docs/wire.md` §3.5) and keeps its handshake and control on
//! TCP. The convention: a link's datagrams go to the same port number as
//! its TCP listener, over UDP, and each side learns its peer's datagram
//! address from the source address of the peer's valid datagrams. So the
//! relay also binds a UDP socket at its listening address (given port 0,
//! one number free over both, drawn again if another program takes it
//! meanwhile), and a base that connected to the relay over TCP
//! sends its datagrams there; the relay sends them on to the upstream's
//! address over UDP, and the remote answers to the address it saw them
//! come from: the relay's.
//!
//! A QUIC link (`Transport::Quic`) is all UDP: one flow
//! carries its handshake, its stream and its datagrams, encrypted, which
//! the relay delays and loses as it does any datagram (QUIC resends what
//! its stream lost; the samples' copies make good the rest). No option is
//! needed: the base connects to the relay's port.
//!
//! - **Flows.** Each client address seen on the UDP socket gets a flow: an
//!   upstream UDP socket of its own (an ephemeral port), connected to
//!   `upstream`, so that the upstream's answers on it go back to that
//!   client, from the listening socket. Client → upstream is
//!   [`Direction::Forward`], upstream → client [`Direction::Backward`]. At
//!   most [`RelayConfig::max_flows`] flows are open at once; a flow with no
//!   datagram received or sent for [`RelayConfig::flow_idle_timeout`], and
//!   none waiting, is removed with its socket. A flow holds its place only
//!   once the upstream has answered on it: a datagram from a new client
//!   when all flows are open removes the idle ones at once, else takes the
//!   flow of a client the upstream never answered (the least recently
//!   active), so that one-datagram senders, whose addresses cost nothing
//!   to forge, cannot keep a real peer out for their idle time; it is
//!   dropped and counted only when every flow is answered and active. A
//!   flow is not tied to a TCP connection: the relay cannot tell which
//!   connection a datagram belongs to.
//! - **Loss, then delay.** Each datagram is dropped or kept by
//!   [`RelayConfig::loss`], then held for its delay as a TCP frame is:
//!   flow `k` (counted from 0 on its own: the first flow has the first
//!   connection's seed) draws its delays from
//!   `model.sampler(connection_seed(seed, k))` and its losses from
//!   `loss.sampler(connection_seed(seed, k))`, whose streams are their own
//!   and distinct per direction. So a run is reproducible, and adding loss
//!   changes no delay (a delay is drawn for every datagram, lost or not, as
//!   in the simulator); `t` is when the relay read the datagram. A lost datagram is
//!   gone: the link recovers its samples from the copies in the next ones.
//!   Loss applies to datagrams only: the relay cannot drop TCP bytes without
//!   corrupting the stream (a lossy TCP path is made in the kernel
//!   instead, with nftables as in `docs/benchmarks.md`).
//! - **Order.** A direction of a flow keeps the TCP path's in-order rule,
//!   `release = max(previous release, t + delay)`, though UDP would allow
//!   reordering: the delay models' jitter stands for queueing, which does
//!   not reorder, and with the same rule the relay's datagram and TCP paths
//!   (and the simulator's datagram path, which does the same) see the same
//!   network, apart from the loss. A lost datagram holds nothing back.
//! - **Bounds.** A direction of a flow holds at most
//!   [`RelayConfig::max_queue_frames`] datagrams and
//!   [`RelayConfig::max_queue_bytes`] bytes; a datagram over either bound is
//!   dropped and counted, and the flow goes on. Datagrams of any size UDP
//!   carries (65 507 bytes over IPv4) pass unchanged.
//!
//! Their counters are [`RelayStats::datagrams`]. Flows are not reported as
//! [`RelayEvent`]s; they are logged through `tracing`.
//!
//! # Example
//!
//! ```no_run
//! # async fn run() -> std::io::Result<()> {
//! use ndr_netem::DelayModel;
//! use ndr_net::relay::Relay;
//!
//! let listen = "127.0.0.1:7000".parse().unwrap();
//! let remote = "127.0.0.1:7001".parse().unwrap();
//! let relay = Relay::listen(listen, remote, DelayModel::ParisNewYork, 1).await?;
//! let handle = relay.spawn()?;
//! // ... the base connects to 127.0.0.1:7000 (and sends datagrams to UDP 7000) ...
//! let stats = handle.shutdown().await;
//! println!("{} frames forward", stats.forward.frames_delivered);
//! println!("{} datagrams forward", stats.datagrams.forward.delivered);
//! # Ok(())
//! # }
//! ```
//!
//! Without an async runtime of one's own, [`BlockingRelay`] runs the relay
//! on its own until Ctrl-C or a time limit (this is `ndr relay`).

mod blocking;
mod conn;
mod datagram;
mod stats;

use core::fmt;
use std::io;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Duration as StdDuration;

use crate::ports;
use ndr_core::time::Instant;
use ndr_core::wire::WireError;
use ndr_netem::{DelayModel, Direction, LossModel};
use tokio::net::{TcpListener, UdpSocket};
use tokio::sync::watch;
use tokio::task::{JoinHandle, JoinSet};
use tokio::time::Instant as TokioInstant;

pub use blocking::{BlockingRelay, StopWhen};
pub use stats::{DatagramDirectionStats, DatagramStats, DirectionStats, RelayStats};

/// Default bound on the frames waiting in one direction of one connection.
pub const DEFAULT_MAX_QUEUE_FRAMES: usize = 65_536;
/// Default bound on the bytes waiting in one direction of one connection (32 MiB).
pub const DEFAULT_MAX_QUEUE_BYTES: usize = 32 << 20;
/// Default time allowed to connect to the upstream.
pub const DEFAULT_CONNECT_TIMEOUT: StdDuration = StdDuration::from_secs(5);
/// Default bound on the datagram flows open at once.
pub const DEFAULT_MAX_FLOWS: usize = 1024;
/// Default time after which a datagram flow with no traffic is removed.
pub const DEFAULT_FLOW_IDLE_TIMEOUT: StdDuration = StdDuration::from_secs(30);

/// Release times that cannot be represented are pushed this far away
/// (tokio clamps its own deadlines at about two years anyway).
const FAR_FUTURE: StdDuration = StdDuration::from_secs(365 * 24 * 3600);

/// Pause after a failed `accept` (e.g. out of file descriptors), so that a
/// persistent failure does not spin.
const ACCEPT_BACKOFF: StdDuration = StdDuration::from_millis(100);

/// Limits of a [`Relay`], and the loss of its datagrams.
///
/// The frames in flight in a direction are about its delay times its frame
/// rate (a 1 s delay at 1 kHz holds 1 000 frames); the bounds only stop a
/// connection or a flow from growing without limit when the receiving side
/// stops reading or the delays are absurd. The datagram path holds at most
/// `max_flows × 2` such queues.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub struct RelayConfig {
    /// Most frames waiting in one direction of one connection; one more cuts
    /// the connection ([`ConnectionEnd::QueueFull`]). `0` counts as `1`.
    /// Also the most datagrams waiting in one direction of one flow: one
    /// more is dropped and counted ([`DatagramDirectionStats::queue_full`]).
    pub max_queue_frames: usize,
    /// Most bytes waiting in one direction of one connection; more cuts the
    /// connection ([`ConnectionEnd::QueueFull`]). Also the most bytes
    /// waiting in one direction of one flow: a datagram that would go over
    /// is dropped and counted.
    pub max_queue_bytes: usize,
    /// Time allowed to connect to the upstream for each client.
    pub connect_timeout: StdDuration,
    /// How datagrams are lost, each direction of each flow (default: none).
    /// TCP frames are never dropped: see the module's docs.
    pub loss: LossModel,
    /// Most datagram flows (client addresses) open at once. A datagram
    /// from one more client takes an idle flow's place, else that of a
    /// flow the upstream never answered on
    /// ([`DatagramStats::flows_evicted`]); only when every flow is answered
    /// and active is it dropped and counted
    /// ([`DatagramStats::flows_refused`]). `0` refuses every datagram.
    pub max_flows: usize,
    /// A flow with no datagram received or sent, either way, for this long,
    /// and none waiting, is removed with its upstream socket (checked four
    /// times per timeout, at most every second).
    pub flow_idle_timeout: StdDuration,
}

impl RelayConfig {
    /// The same, losing datagrams as `loss` says.
    #[must_use]
    pub fn with_loss(mut self, loss: LossModel) -> Self {
        self.loss = loss;
        self
    }
}

impl Default for RelayConfig {
    fn default() -> Self {
        RelayConfig {
            max_queue_frames: DEFAULT_MAX_QUEUE_FRAMES,
            max_queue_bytes: DEFAULT_MAX_QUEUE_BYTES,
            connect_timeout: DEFAULT_CONNECT_TIMEOUT,
            loss: LossModel::None,
            max_flows: DEFAULT_MAX_FLOWS,
            flow_idle_timeout: DEFAULT_FLOW_IDLE_TIMEOUT,
        }
    }
}

/// How a relayed connection ended.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum ConnectionEnd {
    /// Both directions reached their end of stream and delivered every
    /// frame in flight.
    Finished,
    /// The upstream refused the connection or did not answer in time.
    UpstreamFailed {
        /// What went wrong, with the upstream's address.
        error: String,
    },
    /// A side sent a length prefix out of the protocol's range: nothing
    /// after it can be framed.
    Framing {
        /// The direction of the bad prefix (forward: from the client).
        dir: Direction,
        /// The refused prefix.
        error: WireError,
    },
    /// A TLS stream (see the module's docs) sent a record header that is
    /// not TLS: nothing after it can be cut into records.
    BadRecord {
        /// The direction of the bad header (forward: from the client).
        dir: Direction,
        /// The refused header.
        header: [u8; 5],
    },
    /// A direction held more frames or bytes than [`RelayConfig`] allows.
    QueueFull {
        /// The direction that overflowed.
        dir: Direction,
        /// Frames waiting when it overflowed.
        frames: usize,
        /// Bytes waiting when it overflowed, the refused frame included.
        bytes: usize,
    },
    /// A read or write failed (a reset, a peer gone): the first failure
    /// (see the module's docs for what still arrives).
    Io {
        /// The direction whose read or write failed.
        dir: Direction,
        /// The error.
        error: String,
    },
    /// The relay was shut down.
    Shutdown,
}

impl ConnectionEnd {
    /// `true` for the ends that cut a connection because something went
    /// wrong (not [`Finished`](Self::Finished) nor [`Shutdown`](Self::Shutdown)).
    #[must_use]
    pub const fn is_error(&self) -> bool {
        !matches!(self, ConnectionEnd::Finished | ConnectionEnd::Shutdown)
    }
}

fn dir_name(dir: Direction) -> &'static str {
    match dir {
        Direction::Forward => "forward (client → upstream)",
        Direction::Backward => "backward (upstream → client)",
    }
}

impl fmt::Display for ConnectionEnd {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ConnectionEnd::Finished => f.write_str("finished"),
            ConnectionEnd::UpstreamFailed { error } => write!(f, "upstream failed: {error}"),
            ConnectionEnd::Framing { dir, error } => {
                write!(f, "bad framing {}: {error}", dir_name(*dir))
            }
            ConnectionEnd::BadRecord { dir, header } => {
                write!(f, "bad TLS record header {}: {header:02x?}", dir_name(*dir))
            }
            ConnectionEnd::QueueFull { dir, frames, bytes } => write!(
                f,
                "queue full {}: {frames} frames, {bytes} bytes waiting",
                dir_name(*dir)
            ),
            ConnectionEnd::Io { dir, error } => write!(f, "{} {error}", dir_name(*dir)),
            ConnectionEnd::Shutdown => f.write_str("relay shut down"),
        }
    }
}

/// What one connection did, reported when it ends.
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct ConnectionSummary {
    /// Index of the connection: 0 for the first client accepted, then 1, 2, …
    pub conn: u64,
    /// The client's address.
    pub peer: SocketAddr,
    /// Client → upstream counters of this connection.
    pub forward: DirectionStats,
    /// Upstream → client counters of this connection.
    pub backward: DirectionStats,
    /// Time from accepting the client to closing both sides.
    pub duration: StdDuration,
    /// How it ended.
    pub end: ConnectionEnd,
}

/// What a relay reports to its observer (see [`Relay::on_event`]).
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum RelayEvent {
    /// A client was accepted; the relay connects to the upstream for it when
    /// its first frame is due there (or after a second without one).
    Opened {
        /// Index of the connection (see [`connection_seed`]).
        conn: u64,
        /// The client's address.
        peer: SocketAddr,
    },
    /// A connection ended: both of its sockets are closed.
    Closed(ConnectionSummary),
}

type Observer = Arc<dyn Fn(&RelayEvent) + Send + Sync>;

/// The seed of the delay sampler of connection `index` of a relay seeded
/// with `seed`: `seed` itself for the first connection (which so draws the
/// same delays as `model.sampler(seed)`), a mix of both for the others.
#[must_use]
pub const fn connection_seed(seed: u64, index: u64) -> u64 {
    if index == 0 {
        seed
    } else {
        splitmix64(seed ^ splitmix64(index))
    }
}

/// SplitMix64's output function: a bijective mix of 64 bits.
const fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The tokio deadline of `release`, a time of the delay models counted from
/// `origin`.
fn deadline(origin: std::time::Instant, release: Instant) -> TokioInstant {
    release
        .to_std(origin)
        .map_or_else(|| TokioInstant::now() + FAR_FUTURE, TokioInstant::from_std)
}

/// What every connection and flow task shares.
struct Ctx {
    upstream: SocketAddr,
    model: DelayModel,
    seed: u64,
    /// `t = 0` of the delay models: when the relay started serving.
    origin: std::time::Instant,
    config: RelayConfig,
    observer: Option<Observer>,
    counters: stats::Counters,
}

impl Ctx {
    fn emit(&self, event: &RelayEvent) {
        if let Some(observer) = &self.observer {
            observer(event);
        }
    }
}

/// A bound delay relay, not yet serving: [`spawn`](Relay::spawn) it.
pub struct Relay {
    listener: TcpListener,
    datagrams: UdpSocket,
    local_addr: SocketAddr,
    upstream: SocketAddr,
    model: DelayModel,
    seed: u64,
    config: RelayConfig,
    observer: Option<Observer>,
}

impl fmt::Debug for Relay {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Relay")
            .field("local_addr", &self.local_addr)
            .field("upstream", &self.upstream)
            .field("model", &self.model.name())
            .field("seed", &self.seed)
            .field("config", &self.config)
            .finish_non_exhaustive()
    }
}

impl Relay {
    /// Listens on `listen` over TCP, and on the same address and port over
    /// UDP for the datagrams (port 0 picks a port free for both: see
    /// [`local_addr`](Self::local_addr)); each client will be relayed to
    /// `upstream` (TCP and UDP) with the delays of `model`, drawn from
    /// `seed`.
    ///
    /// Must be called within a tokio runtime.
    ///
    /// # Errors
    ///
    /// A listening socket cannot be bound (address in use, no
    /// permission…; the UDP one is named as such), or `listen` is not a
    /// loopback address
    /// (`PermissionDenied`): the relay passes plain links through, and
    /// would put a remote that trusts its loopback on the network; use
    /// [`listen_insecure`](Self::listen_insecure) to mean it.
    pub async fn listen(
        listen: SocketAddr,
        upstream: SocketAddr,
        model: DelayModel,
        seed: u64,
    ) -> io::Result<Relay> {
        if !crate::tls::plain_allowed(listen.ip(), false) {
            return Err(io::Error::new(
                io::ErrorKind::PermissionDenied,
                format!(
                    "relay: refusing to listen on {listen}: it is not loopback, and the relay \
                     passes plain links through to the network; listen on 127.0.0.1, or pass \
                     --insecure (Python: insecure=True; Rust: Relay::listen_insecure)"
                ),
            ));
        }
        Relay::listen_insecure(listen, upstream, model, seed).await
    }

    /// [`listen`](Self::listen) on any address, loopback or not.
    ///
    /// # Errors
    ///
    /// A listening socket cannot be bound (address in use, no permission…).
    pub async fn listen_insecure(
        listen: SocketAddr,
        upstream: SocketAddr,
        model: DelayModel,
        seed: u64,
    ) -> io::Result<Relay> {
        let (listener, datagrams, local_addr) = bind_both(listen)?;
        Ok(Relay {
            listener,
            datagrams,
            local_addr,
            upstream,
            model,
            seed,
            config: RelayConfig::default(),
            observer: None,
        })
    }

    /// Replaces the limits (the default is [`RelayConfig::default`]).
    #[must_use]
    pub fn with_config(mut self, config: RelayConfig) -> Self {
        self.config = config;
        self
    }

    /// Calls `observer` on every [`RelayEvent`], from the relay's tasks: it
    /// should return quickly (print a line, send on a channel).
    #[must_use]
    pub fn on_event(mut self, observer: impl Fn(&RelayEvent) + Send + Sync + 'static) -> Self {
        self.observer = Some(Arc::new(observer));
        self
    }

    /// The address the relay listens on, over TCP and UDP alike.
    #[must_use]
    pub const fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// The address each client is relayed to, over TCP and UDP alike.
    #[must_use]
    pub const fn upstream(&self) -> SocketAddr {
        self.upstream
    }

    /// The limits in force.
    #[must_use]
    pub const fn config(&self) -> &RelayConfig {
        &self.config
    }

    /// Starts serving on the current tokio runtime, as a task; the time
    /// origin of the delay models is now. Dropping the returned handle stops
    /// the relay as [`RelayHandle::shutdown`] does, without waiting.
    ///
    /// # Errors
    ///
    /// Called outside a tokio runtime.
    pub fn spawn(self) -> io::Result<RelayHandle> {
        let runtime = tokio::runtime::Handle::try_current()
            .map_err(|e| io::Error::other(format!("relay: spawn needs a tokio runtime: {e}")))?;
        let Relay {
            listener,
            datagrams,
            local_addr,
            upstream,
            model,
            seed,
            config,
            observer,
        } = self;
        let ctx = Arc::new(Ctx {
            upstream,
            model,
            seed,
            origin: std::time::Instant::now(),
            config,
            observer,
            counters: stats::Counters::default(),
        });
        let (stop_tx, stop_rx) = watch::channel(false);
        tracing::info!(
            %local_addr,
            %upstream,
            model = %ctx.model,
            seed,
            datagram_loss = %ctx.config.loss,
            "relay: serving"
        );
        let task = runtime.spawn(serve(listener, datagrams, Arc::clone(&ctx), stop_rx));
        Ok(RelayHandle {
            local_addr,
            ctx,
            stop: stop_tx,
            task,
        })
    }
}

/// Reads a relay's counters from anywhere ([`RelayHandle::stats_reader`]).
#[derive(Clone)]
pub struct RelayStatsReader(Arc<Ctx>);

impl fmt::Debug for RelayStatsReader {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_tuple("RelayStatsReader")
            .field(&self.0.upstream)
            .finish()
    }
}

impl RelayStatsReader {
    /// The counters so far (the final ones once the relay stopped).
    #[must_use]
    pub fn stats(&self) -> RelayStats {
        self.0.counters.snapshot()
    }
}

/// A running relay: its counters, and the way to stop it.
#[must_use = "dropping the handle stops the relay"]
pub struct RelayHandle {
    local_addr: SocketAddr,
    ctx: Arc<Ctx>,
    stop: watch::Sender<bool>,
    task: JoinHandle<()>,
}

impl fmt::Debug for RelayHandle {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("RelayHandle")
            .field("local_addr", &self.local_addr)
            .field("upstream", &self.ctx.upstream)
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

impl RelayHandle {
    /// The address the relay listens on, over TCP and UDP alike.
    #[must_use]
    pub const fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// The counters so far.
    #[must_use]
    pub fn stats(&self) -> RelayStats {
        self.ctx.counters.snapshot()
    }

    /// A reader of the counters that outlives nothing: it keeps them
    /// readable, not the relay running (a metrics exporter holds one).
    #[must_use]
    pub fn stats_reader(&self) -> RelayStatsReader {
        RelayStatsReader(Arc::clone(&self.ctx))
    }

    /// Time since the relay started serving: the `t` its delay models see.
    #[must_use]
    pub fn elapsed(&self) -> StdDuration {
        self.ctx.origin.elapsed()
    }

    /// Stops the relay: closes the listening sockets, every relayed
    /// connection and every datagram flow at once (both sides, dropping the
    /// frames and datagrams in flight, as if the relay were killed), waits
    /// until they are closed, and returns the final counters.
    pub async fn shutdown(self) -> RelayStats {
        // An error means the task is gone already: nothing to stop.
        let _ = self.stop.send(true);
        if let Err(e) = self.task.await {
            tracing::error!("relay: the accept task failed: {e}");
        }
        self.ctx.counters.snapshot()
    }
}

/// Resolves once the relay is told to stop, or its handle is dropped.
async fn stopped(stop: &mut watch::Receiver<bool>) {
    // An error means the sender (the handle) was dropped: stop as well.
    let _ = stop.wait_for(|&stop| stop).await;
}

/// Binds UDP at `listen`, then TCP at the same address and port
/// ([`ports::bind_pair`]).
fn bind_both(listen: SocketAddr) -> io::Result<(TcpListener, UdpSocket, SocketAddr)> {
    let (datagrams, listener, local_addr) = ports::bind_pair(
        listen,
        ports::BIND_ATTEMPTS,
        "relay",
        |at| {
            let socket = std::net::UdpSocket::bind(at)?;
            let local = socket.local_addr()?;
            Ok((socket, local))
        },
        std::net::TcpListener::bind,
    )?;
    datagrams.set_nonblocking(true)?;
    listener.set_nonblocking(true)?;
    Ok((
        TcpListener::from_std(listener)?,
        UdpSocket::from_std(datagrams)?,
        local_addr,
    ))
}

/// Serves both paths until the relay is told to stop.
async fn serve(
    listener: TcpListener,
    datagrams: UdpSocket,
    ctx: Arc<Ctx>,
    stop: watch::Receiver<bool>,
) {
    let datagrams = tokio::spawn(datagram::serve(Arc::clone(&ctx), datagrams, stop.clone()));
    accept_loop(listener, ctx, stop).await;
    if let Err(e) = datagrams.await {
        tracing::error!("relay: the datagram task failed: {e}");
    }
    tracing::info!("relay: stopped");
}

async fn accept_loop(listener: TcpListener, ctx: Arc<Ctx>, mut stop: watch::Receiver<bool>) {
    let mut conns = JoinSet::new();
    let mut next_index = 0u64;
    loop {
        tokio::select! {
            biased;
            () = stopped(&mut stop) => break,
            Some(done) = conns.join_next(), if !conns.is_empty() => {
                if let Err(e) = done {
                    tracing::error!("relay: a connection task failed: {e}");
                }
            }
            accepted = listener.accept() => match accepted {
                Ok((client, peer)) => {
                    let index = next_index;
                    next_index += 1;
                    ctx.counters.connections.fetch_add(1, Ordering::Relaxed);
                    ctx.counters.active.fetch_add(1, Ordering::Relaxed);
                    conns.spawn(conn::connection(
                        Arc::clone(&ctx),
                        index,
                        client,
                        peer,
                        stop.clone(),
                    ));
                }
                Err(e) => {
                    tracing::warn!("relay: accept failed: {e}");
                    tokio::select! {
                        () = stopped(&mut stop) => break,
                        () = tokio::time::sleep(ACCEPT_BACKOFF) => {}
                    }
                }
            },
        }
    }
    drop(listener);
    // Every connection task sees the same stop and closes its sockets.
    while let Some(done) = conns.join_next().await {
        if let Err(e) = done {
            tracing::error!("relay: a connection task failed: {e}");
        }
    }
}
