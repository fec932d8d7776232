//! The datagram path: a flow per client address; in each direction a loss
//! model, then a delay in order, then the send.
//!
//! One task, the dispatcher, reads the listening UDP socket: it opens a flow
//! for each new client address and stamps each client datagram itself (lost
//! or kept, release time), so that its `t` is when it came in. Each flow's
//! task owns the flow's upstream socket and runs the rest: the forward
//! writer, the backward reader (which stamps the upstream's datagrams) and
//! the backward writer (which sends them to the client from the listening
//! socket). A writer sleeps until its head is due; release times never
//! decrease within a direction ([`InOrderPath`]), so a FIFO is enough. The
//! dispatcher removes idle flows on a periodic sweep by aborting their
//! task, which closes their socket.
//!
//! A flow holds its place only once the upstream has answered on it: a
//! source address costs nothing to forge, and a flood of one-datagram
//! senders would otherwise keep every flow for its idle time. When a new
//! client comes and every flow is taken, the idle flows go first, then the
//! unanswered flow least recently active (one with nothing waiting before
//! one with datagrams in flight); a new client is refused only when every
//! flow has been answered and is active.

use std::cell::RefCell;
use std::collections::HashMap;
use std::io;
use std::net::{Ipv4Addr, Ipv6Addr, SocketAddr};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::time::Duration as StdDuration;

use ndr_core::time::Instant;
use ndr_netem::{DelaySampler, Direction, InOrderPath, LossSampler};
use tokio::net::UdpSocket;
use tokio::sync::{mpsc, watch};
use tokio::task::{AbortHandle, JoinSet};
use tokio::time::{Instant as TokioInstant, MissedTickBehavior};

use super::{Ctx, RelayConfig, connection_seed, deadline, stopped};

/// Holds any UDP payload (65 507 bytes over IPv4, 65 527 over IPv6), so
/// that no datagram is cut.
const RECV_BUFFER: usize = 1 << 16;
/// Pause after a receive error that is not an ICMP report, so that a
/// persistent failure does not spin.
const RECV_BACKOFF: StdDuration = StdDuration::from_millis(100);
/// The idle sweep runs four times per idle timeout, within these bounds.
const SWEEP_MIN: StdDuration = StdDuration::from_millis(10);
const SWEEP_MAX: StdDuration = StdDuration::from_secs(1);

thread_local! {
    /// The flows' receive buffer: one per worker thread rather than 64 KiB
    /// per flow.
    static SCRATCH: RefCell<Vec<u8>> = RefCell::new(vec![0; RECV_BUFFER]);
}

/// A datagram waiting for its release time.
#[derive(Debug)]
struct Held {
    at: TokioInstant,
    bytes: Vec<u8>,
}

fn count(counter: &AtomicU64) {
    counter.fetch_add(1, Ordering::Relaxed);
}

/// What one direction of a flow holds: queued, or taken by its writer.
#[derive(Debug, Default)]
struct Waiting {
    datagrams: AtomicUsize,
    bytes: AtomicUsize,
}

impl Waiting {
    /// Takes room for a datagram of `len` bytes; `false` if it does not fit.
    fn reserve(&self, len: usize, config: &RelayConfig) -> bool {
        // Only the direction's lane adds and only its writer removes: a
        // check then an add cannot go over the bounds.
        let datagrams = self.datagrams.load(Ordering::Relaxed);
        let bytes = self.bytes.load(Ordering::Relaxed);
        if datagrams >= config.max_queue_frames.max(1)
            || bytes.saturating_add(len) > config.max_queue_bytes
        {
            return false;
        }
        self.datagrams.fetch_add(1, Ordering::Relaxed);
        self.bytes.fetch_add(len, Ordering::Relaxed);
        true
    }

    /// Gives back the room of a datagram of `len` bytes, sent or dropped.
    fn release(&self, len: usize) {
        self.bytes.fetch_sub(len, Ordering::Relaxed);
        // Release: whoever sees the queue empty sees the flow's activity
        // stamped before (see `FlowState::is_idle`).
        self.datagrams.fetch_sub(1, Ordering::Release);
    }

    fn is_empty(&self) -> bool {
        self.datagrams.load(Ordering::Acquire) == 0
    }
}

/// What a flow's dispatcher side and its task both see.
#[derive(Debug)]
struct FlowState {
    /// When a datagram last came in or went out, either way, in
    /// nanoseconds since the relay's origin.
    last_active: AtomicU64,
    /// Per direction.
    waiting: [Waiting; 2],
    /// The upstream has sent a datagram on it: a real peer's flow, which
    /// a newcomer does not evict.
    answered: AtomicBool,
}

fn nanos_since(origin: std::time::Instant, now: std::time::Instant) -> u64 {
    u64::try_from(now.saturating_duration_since(origin).as_nanos()).unwrap_or(u64::MAX)
}

impl FlowState {
    fn new(origin: std::time::Instant, now: std::time::Instant) -> Self {
        FlowState {
            last_active: AtomicU64::new(nanos_since(origin, now)),
            waiting: [Waiting::default(), Waiting::default()],
            answered: AtomicBool::new(false),
        }
    }

    fn answered(&self) -> bool {
        self.answered.load(Ordering::Relaxed)
    }

    fn has_waiting(&self) -> bool {
        !self.waiting.iter().all(Waiting::is_empty)
    }

    fn touch(&self, origin: std::time::Instant, now: std::time::Instant) {
        // Touched from several tasks: the latest wins.
        self.last_active
            .fetch_max(nanos_since(origin, now), Ordering::Relaxed);
    }

    /// No datagram came in or went out for `idle`, and none is waiting.
    fn is_idle(
        &self,
        origin: std::time::Instant,
        now: std::time::Instant,
        idle: StdDuration,
    ) -> bool {
        // The queues first: a writer stamps its send before it empties one.
        if !self.waiting.iter().all(Waiting::is_empty) {
            return false;
        }
        let silent =
            nanos_since(origin, now).saturating_sub(self.last_active.load(Ordering::Relaxed));
        StdDuration::from_nanos(silent) >= idle
    }
}

/// One direction of a flow, up to its queue: loss, delay, order, bounds.
struct Lane {
    dir: Direction,
    delays: DelaySampler,
    loss: LossSampler,
    path: InOrderPath,
    tx: mpsc::UnboundedSender<Held>,
}

impl Lane {
    fn new(
        dir: Direction,
        delays: DelaySampler,
        loss: LossSampler,
        tx: mpsc::UnboundedSender<Held>,
    ) -> Self {
        Lane {
            dir,
            delays,
            loss,
            path: InOrderPath::new(),
            tx,
        }
    }

    /// Takes a datagram that came in now: drops it (lost, or its queue
    /// full) or queues it for its release time. The queue is unbounded as
    /// a channel, bounded by [`Waiting::reserve`].
    fn offer(&mut self, ctx: &Ctx, state: &FlowState, bytes: &[u8]) {
        let i = self.dir.index();
        let counters = &ctx.counters.datagrams.dirs[i];
        count(&counters.received);
        let now = std::time::Instant::now();
        state.touch(ctx.origin, now);
        let sent = Instant::from_std(ctx.origin, now);
        // Drawn for every datagram, lost or not: the loss model draws from
        // streams of its own, so adding loss changes no delay (as in the
        // simulator).
        let delay = self.delays.delay(self.dir, sent);
        if self.loss.lost(self.dir) {
            count(&counters.lost);
            return;
        }
        let waiting = &state.waiting[i];
        if !waiting.reserve(bytes.len(), &ctx.config) {
            count(&counters.queue_full);
            return;
        }
        // Only a datagram that will be sent holds the next ones back.
        let held_before = self.path.held_back();
        let release = self.path.deliver(sent, delay);
        if self.path.held_back() > held_before {
            count(&counters.held_back);
        }
        let held = Held {
            at: deadline(ctx.origin, release),
            bytes: bytes.to_vec(),
        };
        if self.tx.send(held).is_err() {
            // The flow's task is gone (the relay is stopping).
            waiting.release(bytes.len());
        }
    }
}

/// Where a writer sends.
#[derive(Clone, Copy)]
enum Dest<'a> {
    /// The upstream, through the flow's connected socket.
    Upstream(&'a UdpSocket),
    /// The client, from the listening socket.
    Client(&'a UdpSocket, SocketAddr),
}

impl Dest<'_> {
    async fn send(self, bytes: &[u8]) -> io::Result<usize> {
        match self {
            Dest::Upstream(socket) => match socket.send(bytes).await {
                // A connected socket reports an earlier datagram's ICMP
                // error on the next call, which then sends nothing.
                Err(e) if is_icmp_report(&e) => socket.send(bytes).await,
                sent => sent,
            },
            Dest::Client(socket, client) => socket.send_to(bytes, client).await,
        }
    }
}

/// The errors that report an ICMP message about an earlier datagram (the
/// peer not listening, unreachable): nothing is wrong with the socket.
fn is_icmp_report(e: &io::Error) -> bool {
    matches!(
        e.kind(),
        io::ErrorKind::ConnectionRefused
            | io::ErrorKind::ConnectionReset
            | io::ErrorKind::HostUnreachable
            | io::ErrorKind::NetworkUnreachable
    )
}

/// Sends each datagram of `rx` at its release time, for as long as the flow
/// lives.
async fn write_side(
    ctx: &Ctx,
    dir: Direction,
    to: Dest<'_>,
    mut rx: mpsc::UnboundedReceiver<Held>,
    state: &FlowState,
) {
    let counters = &ctx.counters.datagrams.dirs[dir.index()];
    let waiting = &state.waiting[dir.index()];
    while let Some(held) = rx.recv().await {
        tokio::time::sleep_until(held.at).await;
        let len = held.bytes.len();
        match to.send(&held.bytes).await {
            Ok(_) => {
                count(&counters.delivered);
                counters
                    .bytes_delivered
                    .fetch_add(len as u64, Ordering::Relaxed);
            }
            Err(e) => {
                count(&counters.send_failed);
                tracing::debug!(?dir, "relay: datagram not sent: {e}");
            }
        }
        // A flow whose datagram has just gone out is waiting for an answer:
        // not idle.
        state.touch(ctx.origin, std::time::Instant::now());
        waiting.release(len);
    }
}

/// The next datagram of a connected socket, read into this thread's buffer
/// and handed to `take`.
async fn recv_into(socket: &UdpSocket, mut take: impl FnMut(&[u8])) -> io::Result<()> {
    loop {
        socket.readable().await?;
        let got = SCRATCH.with_borrow_mut(|buf| socket.try_recv(buf).map(|n| take(&buf[..n])));
        match got {
            Err(e) if e.kind() == io::ErrorKind::WouldBlock => {}
            got => return got,
        }
    }
}

/// Stamps the upstream's datagrams into the backward lane, for as long as
/// the flow lives.
async fn read_upstream(ctx: &Ctx, upstream: &UdpSocket, mut lane: Lane, state: &FlowState) {
    loop {
        let take = |bytes: &[u8]| {
            state.answered.store(true, Ordering::Relaxed);
            lane.offer(ctx, state, bytes);
        };
        match recv_into(upstream, take).await {
            Ok(()) => {}
            Err(e) if is_icmp_report(&e) => {}
            Err(e) => {
                tracing::warn!("relay: cannot read datagrams from the upstream: {e}");
                tokio::time::sleep(RECV_BACKOFF).await;
            }
        }
    }
}

/// What a flow's task owns.
struct FlowTask {
    ctx: Arc<Ctx>,
    listen: Arc<UdpSocket>,
    client: SocketAddr,
    upstream: UdpSocket,
    state: Arc<FlowState>,
    forward: mpsc::UnboundedReceiver<Held>,
    backward: Lane,
    backward_rx: mpsc::UnboundedReceiver<Held>,
}

impl FlowTask {
    /// Runs until aborted: when the flow expires or the relay stops.
    async fn run(self) {
        let FlowTask {
            ctx,
            listen,
            client,
            upstream,
            state,
            forward,
            backward,
            backward_rx,
        } = self;
        let to_client = Dest::Client(&listen, client);
        tokio::join!(
            write_side(
                &ctx,
                Direction::Forward,
                Dest::Upstream(&upstream),
                forward,
                &state
            ),
            read_upstream(&ctx, &upstream, backward, &state),
            write_side(&ctx, Direction::Backward, to_client, backward_rx, &state),
        );
    }
}

/// A UDP socket on an ephemeral port, of `upstream`'s family, connected
/// to it: it takes only the upstream's datagrams.
fn upstream_socket(upstream: SocketAddr) -> io::Result<UdpSocket> {
    let any = match upstream {
        SocketAddr::V4(_) => SocketAddr::from((Ipv4Addr::UNSPECIFIED, 0)),
        SocketAddr::V6(_) => SocketAddr::from((Ipv6Addr::UNSPECIFIED, 0)),
    };
    let open = || {
        let socket = std::net::UdpSocket::bind(any)?;
        socket.connect(upstream)?;
        socket.set_nonblocking(true)?;
        UdpSocket::from_std(socket)
    };
    open().map_err(|e| {
        io::Error::new(
            e.kind(),
            format!("cannot open a UDP socket to the upstream {upstream}: {e}"),
        )
    })
}

/// A flow, as the dispatcher holds it.
struct Flow {
    index: u64,
    forward: Lane,
    state: Arc<FlowState>,
    task: AbortHandle,
}

/// The dispatcher's flows.
struct Flows {
    ctx: Arc<Ctx>,
    socket: Arc<UdpSocket>,
    map: HashMap<SocketAddr, Flow>,
    tasks: JoinSet<()>,
    next_index: u64,
    /// The refusals at the limit were logged once since a flow last closed.
    warned_full: bool,
}

impl Flows {
    /// Hands a datagram from `client` to its flow, opened if new.
    fn dispatch(&mut self, client: SocketAddr, bytes: &[u8]) {
        if !self.map.contains_key(&client) {
            let opened = self.open(client);
            if let Some(flow) = opened {
                self.map.insert(client, flow);
            }
            // Once, whether a flow was evicted, opened or both.
            self.gauge();
            if !self.map.contains_key(&client) {
                return;
            }
        }
        if let Some(flow) = self.map.get_mut(&client) {
            flow.forward.offer(&self.ctx, &flow.state, bytes);
        }
    }

    fn open(&mut self, client: SocketAddr) -> Option<Flow> {
        if self.map.len() >= self.ctx.config.max_flows && !self.make_room(client) {
            return None;
        }
        let ctx = &self.ctx;
        let counters = &ctx.counters.datagrams;
        let upstream = match upstream_socket(ctx.upstream) {
            Ok(socket) => socket,
            Err(e) => {
                count(&counters.flows_refused);
                tracing::warn!(%client, "relay: datagram flow refused: {e}");
                return None;
            }
        };
        let index = self.next_index;
        self.next_index += 1;
        // As connection `index` draws its delays; the loss streams are
        // distinct from the delays' and per direction.
        let seed = connection_seed(ctx.seed, index);
        let delays = ctx.model.sampler(seed);
        let loss = ctx.config.loss.sampler(seed);
        let (forward_tx, forward_rx) = mpsc::unbounded_channel();
        let (backward_tx, backward_rx) = mpsc::unbounded_channel();
        let state = Arc::new(FlowState::new(ctx.origin, std::time::Instant::now()));
        // Each direction draws from its own streams (delay and loss), and
        // the processes shared by both are functions of (seed, time): a
        // clone per direction draws as one shared sampler would.
        let backward = Lane::new(
            Direction::Backward,
            delays.clone(),
            loss.clone(),
            backward_tx,
        );
        let forward = Lane::new(Direction::Forward, delays, loss, forward_tx);
        let local = upstream.local_addr().ok();
        let task = FlowTask {
            ctx: Arc::clone(ctx),
            listen: Arc::clone(&self.socket),
            client,
            upstream,
            state: Arc::clone(&state),
            forward: forward_rx,
            backward,
            backward_rx,
        };
        let task = self.tasks.spawn(task.run());
        count(&counters.flows_opened);
        tracing::info!(flow = index, %client, ?local, "relay: datagram flow opened");
        Some(Flow {
            index,
            forward,
            state,
            task,
        })
    }

    /// Frees a flow for `client` when all are taken: the idle ones go, else
    /// the unanswered one [`victim`] names; `false` (the datagram refused
    /// and counted) if every flow is answered and active.
    fn make_room(&mut self, client: SocketAddr) -> bool {
        self.expire();
        let ctx = &self.ctx;
        let counters = &ctx.counters.datagrams;
        if self.map.len() < ctx.config.max_flows {
            return true;
        }
        let gone = victim(self.map.iter().map(|(addr, flow)| (*addr, &*flow.state)))
            .and_then(|addr| self.map.remove(&addr).map(|flow| (addr, flow)));
        let Some((addr, flow)) = gone else {
            count(&counters.flows_refused);
            if !self.warned_full {
                self.warned_full = true;
                tracing::warn!(
                    %client,
                    max_flows = ctx.config.max_flows,
                    "relay: datagram flows at their limit, every one answered by the upstream: \
                     datagrams from new clients are dropped"
                );
            }
            return false;
        };
        flow.task.abort();
        count(&counters.flows_evicted);
        // Whatever waited in it is dropped with it.
        for (dir, waiting) in counters.dirs.iter().zip(&flow.state.waiting) {
            let n = waiting.datagrams.load(Ordering::Relaxed) as u64;
            dir.evicted.fetch_add(n, Ordering::Relaxed);
        }
        tracing::debug!(
            flow = flow.index,
            client = %addr,
            "relay: unanswered datagram flow evicted for a new client"
        );
        true
    }

    /// Removes the flows idle for the timeout, with nothing waiting.
    fn expire(&mut self) {
        let (ctx, now) = (&self.ctx, std::time::Instant::now());
        let before = self.map.len();
        self.map.retain(|client, flow| {
            if !flow
                .state
                .is_idle(ctx.origin, now, ctx.config.flow_idle_timeout)
            {
                return true;
            }
            flow.task.abort();
            count(&ctx.counters.datagrams.flows_expired);
            tracing::info!(flow = flow.index, %client, "relay: datagram flow expired");
            false
        });
        if self.map.len() < before {
            self.warned_full = false;
            self.gauge();
        }
    }

    fn gauge(&self) {
        self.ctx
            .counters
            .datagrams
            .flows_active
            .store(self.map.len() as u64, Ordering::Relaxed);
    }

    /// Aborts every flow's task and waits for them: their sockets are
    /// closed on return.
    async fn close(mut self) {
        self.tasks.shutdown().await;
        self.map.clear();
        self.gauge();
    }
}

/// The flow a new client takes when every flow is taken and none is idle:
/// of the flows the upstream has not answered, one with nothing waiting
/// before one with datagrams in flight, then the least recently active.
/// `None` if the upstream has answered on every flow.
fn victim<'a>(flows: impl Iterator<Item = (SocketAddr, &'a FlowState)>) -> Option<SocketAddr> {
    flows
        .filter(|(_, state)| !state.answered())
        .min_by_key(|(_, state)| {
            (
                state.has_waiting(),
                state.last_active.load(Ordering::Relaxed),
            )
        })
        .map(|(addr, _)| addr)
}

fn sweep_period(idle: StdDuration) -> StdDuration {
    (idle / 4).clamp(SWEEP_MIN, SWEEP_MAX)
}

/// Serves the datagram path on `socket` until the relay is told to stop.
pub(super) async fn serve(ctx: Arc<Ctx>, socket: UdpSocket, mut stop: watch::Receiver<bool>) {
    let socket = Arc::new(socket);
    let mut sweep = tokio::time::interval(sweep_period(ctx.config.flow_idle_timeout));
    sweep.set_missed_tick_behavior(MissedTickBehavior::Delay);
    let mut flows = Flows {
        ctx,
        socket: Arc::clone(&socket),
        map: HashMap::new(),
        tasks: JoinSet::new(),
        next_index: 0,
        warned_full: false,
    };
    let mut buf = vec![0u8; RECV_BUFFER];
    loop {
        tokio::select! {
            biased;
            () = stopped(&mut stop) => break,
            Some(done) = flows.tasks.join_next(), if !flows.tasks.is_empty() => {
                if let Err(e) = done
                    && !e.is_cancelled()
                {
                    tracing::error!("relay: a datagram flow task failed: {e}");
                }
            }
            _ = sweep.tick() => flows.expire(),
            received = socket.recv_from(&mut buf) => match received {
                Ok((n, client)) => flows.dispatch(client, &buf[..n]),
                Err(e) if is_icmp_report(&e) => {}
                Err(e) => {
                    tracing::warn!("relay: datagram receive failed: {e}");
                    tokio::select! {
                        () = stopped(&mut stop) => break,
                        () = tokio::time::sleep(RECV_BACKOFF) => {}
                    }
                }
            },
        }
    }
    flows.close().await;
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndr_netem::{DelayModel, LossModel};

    fn ctx(config: RelayConfig) -> Ctx {
        Ctx {
            upstream: "127.0.0.1:9".parse().unwrap(),
            model: DelayModel::profile("constant:5").unwrap(),
            seed: 9,
            origin: std::time::Instant::now(),
            config,
            observer: None,
            counters: super::super::stats::Counters::default(),
        }
    }

    fn lane(ctx: &Ctx, dir: Direction, seed: u64) -> (Lane, mpsc::UnboundedReceiver<Held>) {
        let (tx, rx) = mpsc::unbounded_channel();
        let lane = Lane::new(
            dir,
            ctx.model.sampler(seed),
            ctx.config.loss.sampler(seed),
            tx,
        );
        (lane, rx)
    }

    fn drain(rx: &mut mpsc::UnboundedReceiver<Held>) -> Vec<Vec<u8>> {
        std::iter::from_fn(|| rx.try_recv().ok().map(|h| h.bytes)).collect()
    }

    #[test]
    fn a_lane_drops_what_the_seeded_loss_sampler_draws_and_queues_the_rest() {
        let ctx = ctx(RelayConfig {
            loss: LossModel::Bernoulli { rate: 0.3 },
            ..RelayConfig::default()
        });
        let seed = connection_seed(ctx.seed, 3);
        let n = 1000u32;
        let mut kept_by_dir = Vec::new();
        for dir in [Direction::Forward, Direction::Backward] {
            let state = FlowState::new(ctx.origin, std::time::Instant::now());
            let (mut lane, mut rx) = lane(&ctx, dir, seed);
            for k in 0..n {
                lane.offer(&ctx, &state, &k.to_le_bytes());
            }
            let mut draws = ctx.config.loss.sampler(seed);
            let expected: Vec<Vec<u8>> = (0..n)
                .filter(|_| !draws.lost(dir))
                .map(|k| k.to_le_bytes().to_vec())
                .collect();
            let kept = drain(&mut rx);
            assert_eq!(kept, expected, "{dir:?}");
            let stats = ctx.counters.snapshot().datagrams;
            let d = stats.direction(dir);
            assert_eq!(d.received, u64::from(n));
            assert_eq!(d.lost, u64::from(n) - kept.len() as u64);
            assert_eq!(d.queue_full, 0);
            assert_eq!(
                state.waiting[dir.index()].datagrams.load(Ordering::Relaxed),
                kept.len()
            );
            kept_by_dir.push(kept);
        }
        // Each direction has a stream of its own.
        assert_ne!(kept_by_dir[0], kept_by_dir[1]);
    }

    #[test]
    fn a_full_queue_drops_the_datagram_and_the_flow_goes_on() {
        let ctx = ctx(RelayConfig {
            max_queue_frames: 3,
            max_queue_bytes: 100,
            ..RelayConfig::default()
        });
        let state = FlowState::new(ctx.origin, std::time::Instant::now());
        let (mut lane, mut rx) = lane(&ctx, Direction::Forward, 1);
        for k in 0..5u8 {
            lane.offer(&ctx, &state, &[k; 10]);
        }
        let queued = drain(&mut rx);
        assert_eq!(queued, vec![vec![0; 10], vec![1; 10], vec![2; 10]]);
        let waiting = &state.waiting[0];
        // The writer sends them: room again.
        for q in &queued {
            waiting.release(q.len());
        }
        lane.offer(&ctx, &state, &[5; 60]);
        // 60 + 41 bytes would go over 100.
        lane.offer(&ctx, &state, &[6; 41]);
        lane.offer(&ctx, &state, &[7; 40]);
        assert_eq!(drain(&mut rx), vec![vec![5; 60], vec![7; 40]]);
        let d = ctx.counters.snapshot().datagrams.forward;
        assert_eq!((d.received, d.queue_full, d.lost), (8, 3, 0));
        assert_eq!(waiting.bytes.load(Ordering::Relaxed), 100);
    }

    #[test]
    fn a_flow_is_idle_after_the_timeout_with_nothing_waiting() {
        let origin = std::time::Instant::now();
        let t = |ms| origin + StdDuration::from_millis(ms);
        let idle = StdDuration::from_millis(200);
        let state = FlowState::new(origin, t(100));
        assert!(!state.is_idle(origin, t(299), idle));
        assert!(state.is_idle(origin, t(300), idle));
        // Either direction's datagram keeps it; an earlier touch does not
        // move it back.
        state.touch(origin, t(400));
        state.touch(origin, t(350));
        assert!(!state.is_idle(origin, t(599), idle));
        // A datagram still waiting keeps it too.
        let config = RelayConfig::default();
        assert!(state.waiting[1].reserve(10, &config));
        assert!(!state.is_idle(origin, t(5000), idle));
        state.waiting[1].release(10);
        assert!(state.is_idle(origin, t(5000), idle));
    }

    #[test]
    fn a_new_client_takes_the_flow_of_the_stalest_unanswered_sender_never_an_answered_one() {
        let origin = std::time::Instant::now();
        let t = |ms| origin + StdDuration::from_millis(ms);
        let addr = |port: u16| SocketAddr::from(([127, 0, 0, 1], port));
        // A base's flow, answered by the upstream, quiet for a while.
        let base = FlowState::new(origin, t(0));
        base.answered.store(true, Ordering::Relaxed);
        // One-datagram senders: the first long ago, the second lately.
        let old = FlowState::new(origin, t(10));
        let recent = FlowState::new(origin, t(900));
        let flows = [(addr(1), &base), (addr(2), &old), (addr(3), &recent)];
        assert_eq!(victim(flows.into_iter()), Some(addr(2)));
        // One with a datagram still in flight goes after one without, even
        // a more recent one.
        let config = RelayConfig::default();
        assert!(old.waiting[0].reserve(10, &config));
        assert_eq!(victim(flows.into_iter()), Some(addr(3)));
        old.waiting[0].release(10);
        // A sender that keeps sending stays ahead of one that stopped.
        old.touch(origin, t(1000));
        assert_eq!(victim(flows.into_iter()), Some(addr(3)));
        // Only answered flows: no room.
        assert_eq!(victim([(addr(1), &base)].into_iter()), None);
    }

    #[test]
    fn the_sweep_runs_four_times_per_timeout_within_bounds() {
        assert_eq!(
            sweep_period(StdDuration::from_millis(200)),
            StdDuration::from_millis(50)
        );
        assert_eq!(sweep_period(StdDuration::ZERO), SWEEP_MIN);
        assert_eq!(sweep_period(StdDuration::from_secs(30)), SWEEP_MAX);
    }
}
