//! The datagram transport's sockets in a hub.
//!
//! A hub has one UDP socket of its own per address family, shared by the
//! links it connects, and one per datagram listener whose links it drives
//! (bound at the listener's port: a link's datagrams go to the port number
//! of its TCP listener). Each socket is read and written in batches
//! (`recvmmsg`, `sendmmsg`), so a tick that serves many links costs a few
//! system calls, not one per link. On Linux, the datagrams of one length for
//! one address leave as one message the kernel cuts back into them (UDP
//! GSO), and a socket takes such runs whole (UDP GRO): the kernel's work per
//! tick follows the peers' addresses, not the links. Batching never
//! reorders a link's datagrams: a QUIC connection's packets differ in
//! length, and one sent after a newer one arrives stale.
//!
//! A datagram goes to the link whose session token it carries (a Bundle
//! names its receiver's token). Its endpoint takes samples only from the
//! link's path, the address validated as the peer's. A valid datagram from
//! elsewhere (the first ones, on a listener's side; a peer behind a NAT
//! that mapped it anew, or one that moved; a stranger who saw a token) is
//! dropped, and the endpoint gives the peer a new token on the reliable
//! path: the address of the first datagram carrying it becomes the path.
//! Nothing is sent to an address before it is validated. A datagram
//! without a known token is dropped and counted on its socket.

use std::collections::HashMap;
use std::io;
use std::net::SocketAddr;
use std::ops::Range;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant as StdInstant;

use mio::net::UdpSocket;
use mio::{Interest, Registry, Token};
use ndr_core::endpoint::{DatagramError, Origin, Taken};
use ndr_core::time::Instant;
use ndr_core::wire::{self, HEADER_LEN};

use super::Entry;

/// Messages read, or written, per system call.
pub(super) const BATCH: usize = 32;
/// Room for one received message: the longest UDP payload, so that a run
/// of datagrams the kernel coalesced (GRO) arrives whole; a datagram
/// longer than any Bundle is refused by its endpoint.
const SLOT: usize = 1 << 16;
const _: () = assert!(SLOT >= HEADER_LEN + wire::BUNDLE_FIXED_LEN + 8 * wire::MAX_CHANNELS);
/// Datagrams in one segmented message (the kernel's limit is at least this).
const MAX_SEGMENTS: usize = 64;
/// Bytes in one segmented message: under the largest UDP payload over IPv6.
const MAX_SEGMENTED_LEN: usize = 65_000;
/// How long a token given to validate an address may go unused before
/// another replaces it: a peer that got it answers within a round trip,
/// and a stranger's datagrams from elsewhere do not renew it faster.
const RENEWAL_SPACING: std::time::Duration = std::time::Duration::from_secs(1);
/// Kernel buffers asked for each socket (best effort: the kernel caps them
/// at `net.core.rmem_max` / `wmem_max`): a tick of many links sends them
/// all at one instant.
const KERNEL_BUFFER: usize = 4 << 20;

/// Where a link's datagrams go, and what its hub counted of them.
pub(crate) struct DatagramPath {
    /// The hub's key of the socket it uses.
    pub socket: u64,
    /// Its own session token: the datagrams for it carry this.
    pub session: u64,
    /// A new token given to the peer to validate an address, routed to
    /// the link too until the peer uses it; and when it was given.
    pub renewal: Option<(u64, StdInstant)>,
    /// Where its datagrams go: the address validated as the peer's; `None`
    /// until the first is (a listener's side).
    pub peer: Option<SocketAddr>,
    /// Datagrams not sent: no address for the peer yet, or the socket
    /// refused them (its buffer full, the path unreachable).
    pub unsent: u64,
    /// Times the peer's address changed (a NAT's new mapping, a peer that
    /// moved, or the first address validated on a listener's side).
    pub path_changes: u64,
    /// Datagrams to its socket with no link's token (shared by the links on it).
    pub stray: Arc<AtomicU64>,
}

impl DatagramPath {
    /// A path on `socket` for the link whose token is `session`, first
    /// sending to `peer`.
    pub(crate) fn new(socket: u64, session: u64, peer: Option<SocketAddr>) -> DatagramPath {
        DatagramPath {
            socket,
            session,
            renewal: None,
            peer,
            unsent: 0,
            path_changes: 0,
            stray: Arc::default(),
        }
    }
}

/// A socket handed to a hub ([`super::Msg::Socket`]).
pub(crate) struct NewSocket {
    pub socket: std::net::UdpSocket,
    /// Counts datagrams with no link's token (the listener reads it too).
    pub stray: Arc<AtomicU64>,
    /// Kept until released ([`super::Msg::ReleaseSocket`]) even with no
    /// link on it: a listener's, which links it accepts will use.
    pub held: bool,
}

/// Binds a UDP socket for a hub at `addr` (non-blocking, with kernel
/// receive stamps asked for and large buffers).
pub(crate) fn bind(addr: SocketAddr) -> io::Result<std::net::UdpSocket> {
    let socket = std::net::UdpSocket::bind(addr)?;
    socket.set_nonblocking(true)?;
    grow_buffers(&socket);
    Ok(socket)
}

#[cfg(target_os = "linux")]
fn grow_buffers(socket: &std::net::UdpSocket) {
    use nix::sys::socket::{setsockopt, sockopt};
    let _ = setsockopt(socket, sockopt::RcvBuf, &KERNEL_BUFFER);
    let _ = setsockopt(socket, sockopt::SndBuf, &KERNEL_BUFFER);
}

#[cfg(not(target_os = "linux"))]
fn grow_buffers(_: &std::net::UdpSocket) {}

struct Sock {
    socket: UdpSocket,
    /// Session token → link id.
    sessions: HashMap<u64, u64>,
    stray: Arc<AtomicU64>,
    held: bool,
    /// Sends runs of datagrams as one segmented message (UDP GSO); off for
    /// good once the kernel refuses one.
    gso: bool,
}

/// One datagram waiting for the next batched send.
struct Queued {
    socket: u64,
    link: u64,
    to: SocketAddr,
    bytes: Range<usize>,
}

/// Datagrams the endpoints wrote, sent together by [`Udp::send_all`].
#[derive(Default)]
pub(super) struct Outgoing {
    arena: Vec<u8>,
    queued: Vec<Queued>,
    /// `queued`'s indices in sending order (kept for its room).
    order: Vec<usize>,
    /// Each queued datagram's wave (kept for its room): see
    /// [`Outgoing::number_waves`].
    waves: Vec<u32>,
    /// Per socket and link, its last datagram's wave, length and address
    /// (kept for its room).
    last: HashMap<(u64, u64), (u32, usize, SocketAddr)>,
    /// The messages of one socket and length (kept for its room).
    messages: Vec<Message>,
}

/// One message of a batched send: `count` datagrams of one length for one
/// address, `order[first..first + count]`.
#[derive(Clone, Copy)]
struct Message {
    to: SocketAddr,
    first: usize,
    count: usize,
}

/// Messages and datagrams a hub's sockets wrote (what batching saved).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct Sent {
    pub messages: u64,
    pub datagrams: u64,
}

impl Outgoing {
    /// `frame` for the peer on `path`, or counted as unsent if its address
    /// is not known yet.
    pub(super) fn push(&mut self, link: u64, path: &mut DatagramPath, frame: &[u8]) {
        let Some(to) = path.peer else {
            path.unsent += 1;
            return;
        };
        self.push_to(path.socket, link, to, frame);
    }

    /// `bytes` to `to` from socket `socket`, for link `link` (where a
    /// refusal is counted; `u64::MAX`: no link's).
    pub(super) fn push_to(&mut self, socket: u64, link: u64, to: SocketAddr, bytes: &[u8]) {
        let start = self.arena.len();
        self.arena.extend_from_slice(bytes);
        self.queued.push(Queued {
            socket,
            link,
            to,
            bytes: start..self.arena.len(),
        });
    }
}

impl Outgoing {
    /// Numbers each queued datagram with its wave: a link's datagrams on a
    /// socket, in the order queued, split where the length or the address
    /// changes; the first run is wave 0, the next wave 1, and so on. Sent
    /// wave after wave, and within a wave by length and address, a link's
    /// datagrams keep their order, while the runs of one length for one
    /// address of all the links in a wave still leave together.
    fn number_waves(&mut self) {
        self.waves.clear();
        self.last.clear();
        for q in &self.queued {
            let (len, to) = (q.bytes.len(), q.to);
            let wave = match self.last.get(&(q.socket, q.link)) {
                Some(&(w, l, t)) if (l, t) == (len, to) => w,
                Some(&(w, _, _)) => w + 1,
                None => 0,
            };
            self.last.insert((q.socket, q.link), (wave, len, to));
            self.waves.push(wave);
        }
    }
}

/// The token a datagram names, if it is a Bundle long enough to name one.
fn session_of(bytes: &[u8]) -> Option<u64> {
    if !wire::is_bundle(bytes) {
        return None;
    }
    let token = bytes.get(HEADER_LEN..HEADER_LEN + 8)?;
    Some(u64::from_le_bytes(token.try_into().ok()?))
}

/// What one received message was.
#[derive(Clone, Copy, Default)]
struct Meta {
    len: usize,
    from: Option<SocketAddr>,
    at: Option<StdInstant>,
    /// The length of each datagram in it, when the kernel coalesced a run
    /// (GRO): all but the last are this long.
    segment: Option<usize>,
}

/// The datagrams of a received message of `bytes`: cut every `segment`
/// bytes when the kernel coalesced them, else the message itself (an empty
/// datagram too: it is counted like any other).
fn datagrams(bytes: &[u8], segment: Option<usize>) -> impl Iterator<Item = &[u8]> {
    let size = segment.filter(|&s| s > 0).unwrap_or(bytes.len()).max(1);
    let empty = bytes.is_empty().then_some(bytes);
    bytes.chunks(size).chain(empty)
}

/// The hub's datagram sockets and their buffers.
pub(super) struct Udp {
    sockets: HashMap<u64, Sock>,
    pub(super) out: Outgoing,
    slots: Vec<u8>,
    meta: [Meta; BATCH],
    pub(super) sent: Sent,
}

impl Udp {
    pub(super) fn new() -> Udp {
        Udp {
            sockets: HashMap::new(),
            out: Outgoing::default(),
            slots: Vec::new(),
            meta: [Meta::default(); BATCH],
            sent: Sent::default(),
        }
    }

    /// Whether `key` (a poll token) is one of the sockets.
    pub(super) fn has(&self, key: u64) -> bool {
        self.sockets.contains_key(&key)
    }

    /// Takes `new` as the socket `key`, polled under the same token.
    pub(super) fn add(&mut self, registry: &Registry, key: u64, new: NewSocket) -> io::Result<()> {
        // Without the kernel's stamps, a datagram's arrival is its read.
        let _ = crate::arrival::enable(&new.socket);
        // Without GRO, a segmented message is cut by the kernel on receipt.
        enable_gro(&new.socket);
        let mut socket = UdpSocket::from_std(new.socket);
        registry.register(&mut socket, Token(key as usize), Interest::READABLE)?;
        self.sockets.insert(
            key,
            Sock {
                socket,
                sessions: HashMap::new(),
                stray: new.stray,
                held: new.held,
                gso: cfg!(target_os = "linux"),
            },
        );
        Ok(())
    }

    /// The owner of socket `key` lets it go: it closes with its last link.
    pub(super) fn release(&mut self, registry: &Registry, key: u64) {
        if let Some(sock) = self.sockets.get_mut(&key) {
            sock.held = false;
        }
        self.close_if_unused(registry, key);
    }

    /// Routes the datagrams for `path`'s token to link `id`; `false` if its
    /// socket is gone or another link holds the token.
    pub(super) fn attach(&mut self, id: u64, path: &mut DatagramPath) -> bool {
        let Some(sock) = self.sockets.get_mut(&path.socket) else {
            return false;
        };
        if sock.sessions.contains_key(&path.session) {
            return false;
        }
        sock.sessions.insert(path.session, id);
        path.stray = Arc::clone(&sock.stray);
        true
    }

    /// Link `id` has left the hub.
    pub(super) fn detach(&mut self, registry: &Registry, id: u64, path: &DatagramPath) {
        if let Some(sock) = self.sockets.get_mut(&path.socket) {
            let renewal = path.renewal.map(|(token, _)| token);
            for token in [Some(path.session), renewal].into_iter().flatten() {
                if sock.sessions.get(&token) == Some(&id) {
                    sock.sessions.remove(&token);
                }
            }
        }
        self.close_if_unused(registry, path.socket);
    }

    fn close_if_unused(&mut self, registry: &Registry, key: u64) {
        let unused = self
            .sockets
            .get(&key)
            .is_some_and(|s| !s.held && s.sessions.is_empty());
        if unused && let Some(mut sock) = self.sockets.remove(&key) {
            let _ = registry.deregister(&mut sock.socket);
        }
    }

    /// Socket `key`'s count of datagrams no link took.
    pub(super) fn stray(&self, key: u64) -> Option<Arc<AtomicU64>> {
        self.sockets.get(&key).map(|s| Arc::clone(&s.stray))
    }

    /// Reads a batch from socket `key` (for a QUIC endpoint): how many
    /// messages, each then read with [`received`](Self::received).
    pub(super) fn read(&mut self, key: u64) -> io::Result<usize> {
        if self.slots.is_empty() {
            self.slots = vec![0; SLOT * BATCH];
        }
        self.read_batch(key)
    }

    /// The `i`th message of the last [`read`](Self::read): where it came
    /// from, when it arrived (the kernel's stamp), and its datagrams (more
    /// than one when the kernel coalesced a run).
    pub(super) fn received(
        &self,
        i: usize,
    ) -> Option<(
        Option<SocketAddr>,
        Option<StdInstant>,
        impl Iterator<Item = &[u8]>,
    )> {
        let meta = self.meta.get(i)?;
        let slot = self.slots.chunks_exact(SLOT).nth(i)?;
        let message = slot.get(..meta.len.min(SLOT))?;
        Some((meta.from, meta.at, datagrams(message, meta.segment)))
    }

    /// Reads everything socket `key` holds and hands each datagram to its
    /// link's endpoint; the links that took one are added to `touched`.
    pub(super) fn receive(
        &mut self,
        key: u64,
        origin: StdInstant,
        entries: &mut HashMap<u64, Entry>,
        touched: &mut Vec<u64>,
    ) {
        if self.slots.is_empty() {
            self.slots = vec![0; SLOT * BATCH];
        }
        loop {
            let got = match self.read_batch(key) {
                Ok(n) => n,
                Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
                // Nothing left, or an error a later datagram will not have
                // (an ICMP error queued on the socket): nothing is lost by
                // stopping here.
                Err(_) => return,
            };
            let Some(sock) = self.sockets.get_mut(&key) else {
                return;
            };
            let handled = StdInstant::now();
            for (meta, slot) in self
                .meta
                .iter()
                .zip(self.slots.chunks_exact(SLOT))
                .take(got)
            {
                let message = slot.get(..meta.len.min(SLOT)).unwrap_or_default();
                let at = meta.at.unwrap_or(handled);
                for bytes in datagrams(message, meta.segment) {
                    deliver(
                        sock, entries, touched, bytes, meta.from, at, handled, origin,
                    );
                }
            }
            if got < BATCH {
                return;
            }
        }
    }

    /// Sends every queued datagram, counting those the socket refuses on
    /// their links.
    pub(super) fn send_all(&mut self, entries: &mut HashMap<u64, Entry>) {
        self.out.number_waves();
        let mut order = std::mem::take(&mut self.out.order);
        order.clear();
        order.extend(0..self.out.queued.len());
        // Stable, and a link's waves in order: its datagrams keep theirs.
        let (queued, waves) = (&self.out.queued, &self.out.waves);
        order.sort_by_key(|&i| {
            let q = &queued[i];
            (q.socket, waves[i], q.bytes.len(), q.to)
        });
        let mut start = 0;
        while start < order.len() {
            let first = &self.out.queued[order[start]];
            let (key, len) = (first.socket, first.bytes.len());
            // The run of datagrams of one length for one socket.
            let end = order[start..]
                .iter()
                .position(|&i| {
                    let q = &self.out.queued[i];
                    (q.socket, q.bytes.len()) != (key, len)
                })
                .map_or(order.len(), |n| start + n);
            self.send_run(key, len, &order, start..end, entries);
            start = end;
        }
        self.out.order = order;
        self.out.queued.clear();
        self.out.arena.clear();
    }

    /// Sends `order[run]`, datagrams of `len` bytes through socket `key`.
    fn send_run(
        &mut self,
        key: u64,
        len: usize,
        order: &[usize],
        run: Range<usize>,
        entries: &mut HashMap<u64, Entry>,
    ) {
        let mut at = run.start;
        while at < run.end {
            let gso = self.sockets.get(&key).is_some_and(|s| s.gso);
            let per_message = if gso && len > 0 {
                (MAX_SEGMENTED_LEN / len).clamp(1, MAX_SEGMENTS)
            } else {
                1
            };
            let mut messages = std::mem::take(&mut self.out.messages);
            messages.clear();
            let mut next = at;
            while next < run.end && messages.len() < BATCH {
                let to = self.out.queued[order[next]].to;
                let count = order[next..run.end]
                    .iter()
                    .take(per_message)
                    .take_while(|&&i| self.out.queued[i].to == to)
                    .count();
                messages.push(Message {
                    to,
                    first: next,
                    count,
                });
                next += count;
            }
            let result = self.write_batch(key, len, order, &messages, per_message > 1);
            match result {
                Ok(n) => {
                    let n = n.clamp(1, messages.len());
                    let datagrams: usize = messages.iter().take(n).map(|m| m.count).sum();
                    self.sent.messages += n as u64;
                    self.sent.datagrams += datagrams as u64;
                    at += datagrams;
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) if per_message > 1 && gso_refused(&e) => {
                    // This kernel or path does not segment: one by one from now.
                    tracing::debug!(error = %e, "UDP segmentation offload refused");
                    if let Some(sock) = self.sockets.get_mut(&key) {
                        sock.gso = false;
                    }
                }
                Err(_) => {
                    // The first message was refused (a full buffer, an
                    // unreachable path): its datagrams are lost, as on the
                    // network.
                    let first = messages.first().map_or(0, |m| m.count.max(1));
                    for &i in order.get(at..at + first).unwrap_or_default() {
                        if let Some(e) = entries.get_mut(&self.out.queued[i].link) {
                            if let Some(path) = e.path.datagram_mut() {
                                path.unsent += 1;
                            }
                            if let Some(q) = e.path.quic_mut() {
                                q.dropped += 1;
                            }
                        }
                    }
                    at += first;
                }
            }
            self.out.messages = messages;
        }
    }

    #[cfg(target_os = "linux")]
    fn read_batch(&mut self, key: u64) -> io::Result<usize> {
        use std::os::fd::AsRawFd;

        use nix::sys::socket::{ControlMessageOwned, MsgFlags, MultiHeaders, recvmmsg};

        let Some(sock) = self.sockets.get(&key) else {
            return Ok(0);
        };
        let mut slots = self.slots.chunks_exact_mut(SLOT);
        let mut iovs: [[io::IoSliceMut<'_>; 1]; BATCH] =
            std::array::from_fn(|_| [io::IoSliceMut::new(slots.next().unwrap_or_default())]);
        // Headers made for each call, not kept: the kernel shrinks a header's
        // room for control messages to what it used, and they are not Send.
        let mut headers =
            MultiHeaders::preallocate(BATCH, Some(nix::cmsg_space!(nix::sys::time::TimeSpec, i32)));
        let got = {
            let results = recvmmsg(
                sock.socket.as_raw_fd(),
                &mut headers,
                iovs.iter_mut(),
                MsgFlags::MSG_DONTWAIT,
                None,
            )
            .map_err(io::Error::from)?;
            let mut got = 0;
            for (meta, r) in self.meta.iter_mut().zip(results) {
                let (mut stamp, mut segment) = (None, None);
                for m in r.cmsgs().into_iter().flatten() {
                    match m {
                        ControlMessageOwned::ScmTimestampns(ts) => stamp = Some(ts),
                        ControlMessageOwned::UdpGroSegments(size) => {
                            segment = usize::try_from(size).ok();
                        }
                        _ => {}
                    }
                }
                *meta = Meta {
                    len: r.bytes,
                    from: r.address.and_then(|a| std_addr(&a)),
                    at: stamp.and_then(crate::arrival::kernel_instant),
                    segment,
                };
                got += 1;
            }
            got
        };
        Ok(got)
    }

    /// Writes `messages` (of datagrams of `len` bytes, segmented by the
    /// kernel if `segmented`); how many messages went.
    #[cfg(target_os = "linux")]
    fn write_batch(
        &self,
        key: u64,
        len: usize,
        order: &[usize],
        messages: &[Message],
        segmented: bool,
    ) -> io::Result<usize> {
        use std::os::fd::AsRawFd;

        use nix::sys::socket::{ControlMessage, MsgFlags, MultiHeaders, SockaddrStorage, sendmmsg};

        let Some(sock) = self.sockets.get(&key) else {
            return Ok(messages.len());
        };
        let arena = &self.out.arena;
        let iovs: Vec<io::IoSlice<'_>> = messages
            .iter()
            .flat_map(|m| order.get(m.first..m.first + m.count).unwrap_or_default())
            .map(|&i| {
                let bytes = self
                    .out
                    .queued
                    .get(i)
                    .and_then(|q| arena.get(q.bytes.clone()))
                    .unwrap_or_default();
                io::IoSlice::new(bytes)
            })
            .collect();
        let mut parts: Vec<&[io::IoSlice<'_>]> = Vec::with_capacity(messages.len());
        let mut rest = iovs.as_slice();
        for m in messages {
            let (part, tail) = rest.split_at(m.count.min(rest.len()));
            parts.push(part);
            rest = tail;
        }
        let addrs: Vec<Option<SockaddrStorage>> = messages
            .iter()
            .map(|m| Some(SockaddrStorage::from(m.to)))
            .collect();
        let segment = u16::try_from(len).unwrap_or(u16::MAX);
        let gso = [ControlMessage::UdpGsoSegments(&segment)];
        let cmsgs: &[ControlMessage<'_>] = if segmented { &gso } else { &[] };
        let mut headers =
            MultiHeaders::preallocate(messages.len(), segmented.then(|| nix::cmsg_space!(u16)));
        let sent = sendmmsg(
            sock.socket.as_raw_fd(),
            &mut headers,
            &parts,
            &addrs,
            cmsgs,
            MsgFlags::MSG_DONTWAIT,
        )
        .map_err(io::Error::from)?;
        Ok(sent.count())
    }

    #[cfg(not(target_os = "linux"))]
    fn read_batch(&mut self, key: u64) -> io::Result<usize> {
        let Some(sock) = self.sockets.get(&key) else {
            return Ok(0);
        };
        let mut got = 0;
        for (meta, slot) in self.meta.iter_mut().zip(self.slots.chunks_exact_mut(SLOT)) {
            match sock.socket.recv_from(slot) {
                Ok((len, from)) => {
                    *meta = Meta {
                        len,
                        from: Some(from),
                        at: Some(StdInstant::now()),
                        segment: None,
                    };
                    got += 1;
                }
                Err(e) if got > 0 && e.kind() == io::ErrorKind::WouldBlock => break,
                Err(e) => return Err(e),
            }
        }
        Ok(got)
    }

    #[cfg(not(target_os = "linux"))]
    fn write_batch(
        &self,
        key: u64,
        _len: usize,
        order: &[usize],
        messages: &[Message],
        _segmented: bool,
    ) -> io::Result<usize> {
        let Some(sock) = self.sockets.get(&key) else {
            return Ok(messages.len());
        };
        let m = messages.first().ok_or(io::ErrorKind::InvalidInput)?;
        let q = order
            .get(m.first)
            .and_then(|&i| self.out.queued.get(i))
            .ok_or(io::ErrorKind::InvalidInput)?;
        let bytes = self.out.arena.get(q.bytes.clone()).unwrap_or_default();
        sock.socket.send_to(bytes, q.to)?;
        Ok(1)
    }
}

/// Hands one received datagram to the link whose token it names (a stray
/// is counted on its socket); a link whose endpoint took it, ended, or has
/// a Token frame to send is added to `touched`.
#[allow(clippy::too_many_arguments)]
fn deliver(
    sock: &mut Sock,
    entries: &mut HashMap<u64, Entry>,
    touched: &mut Vec<u64>,
    bytes: &[u8],
    from: Option<SocketAddr>,
    at: StdInstant,
    handled: StdInstant,
    origin: StdInstant,
) {
    let link = session_of(bytes).and_then(|s| sock.sessions.get(&s).copied());
    let Some((id, e)) = link.and_then(|id| Some((id, entries.get_mut(&id)?))) else {
        sock.stray.fetch_add(1, Ordering::Relaxed);
        return;
    };
    let Some(path) = e.path.datagram_mut() else {
        return;
    };
    e.rx_lag
        .push_duration(handled.saturating_duration_since(at).into());
    let seen = if from.is_some() && from == path.peer {
        Origin::Path
    } else {
        Origin::Elsewhere
    };
    let taken = e
        .endpoint
        .handle_datagram(Instant::from_std(origin, at), bytes, seen);
    let mut act = matches!(taken, Ok(_) | Err(DatagramError::Link(_)));
    match taken {
        Ok(Taken::Validated { retired }) => {
            sock.sessions.remove(&retired);
            if let Some((token, _)) = path.renewal.take() {
                path.session = token;
            }
            if path.peer != from {
                tracing::debug!(from = ?from, before = ?path.peer, "datagram path validated");
                path.peer = from;
                path.path_changes += 1;
            }
        }
        Err(DatagramError::OffPath) => act = renew(sock, id, e, handled),
        _ => {}
    }
    // Refused datagrams are counted by the endpoint; only a link with
    // something to do needs its hub to act.
    if act && !touched.contains(&id) {
        touched.push(id);
    }
}

/// Gives link `id`'s peer a new token to validate the address of a
/// datagram from elsewhere, unless one given lately is still unused;
/// whether the link has a Token frame to send.
fn renew(sock: &mut Sock, id: u64, e: &mut Entry, now: StdInstant) -> bool {
    let Some(path) = e.path.datagram_mut() else {
        return false;
    };
    if path
        .renewal
        .is_some_and(|(_, given)| now.saturating_duration_since(given) < RENEWAL_SPACING)
    {
        return false;
    }
    let Some(token) = session_token()
        .ok()
        .filter(|t| !sock.sessions.contains_key(t))
    else {
        return false;
    };
    match e.endpoint.renew_session(token) {
        Ok(replaced) => {
            if let Some(old) = replaced {
                sock.sessions.remove(&old);
            }
            sock.sessions.insert(token, id);
            path.renewal = Some((token, now));
            true
        }
        // Before the handshake is over or after the close: the datagram
        // waits for nothing.
        Err(_) => false,
    }
}

/// A datagram session token: random, never 0, so that a datagram of
/// another session (or a guess) is not taken for one of this session.
pub(crate) fn session_token() -> io::Result<u64> {
    use ring::rand::{SecureRandom as _, SystemRandom};
    let rng = SystemRandom::new();
    loop {
        let mut bytes = [0; 8];
        rng.fill(&mut bytes)
            .map_err(|_| io::Error::other("no randomness for a datagram session token"))?;
        let token = u64::from_le_bytes(bytes);
        if token != 0 {
            return Ok(token);
        }
    }
}

/// Asks the kernel to hand runs of datagrams over as one message (best
/// effort: without it they arrive one by one).
#[cfg(target_os = "linux")]
fn enable_gro(socket: &std::net::UdpSocket) {
    use nix::sys::socket::{setsockopt, sockopt};
    let _ = setsockopt(socket, sockopt::UdpGroSegment, &true);
}

#[cfg(not(target_os = "linux"))]
fn enable_gro(_: &std::net::UdpSocket) {}

/// Whether a segmented send failed because the kernel or the path cannot
/// segment (an old kernel, a device without checksum offload), so that
/// sending one by one would succeed.
fn gso_refused(e: &io::Error) -> bool {
    matches!(
        e.raw_os_error(),
        Some(code) if code == nix::libc::EIO || code == nix::libc::EINVAL || code == nix::libc::EOPNOTSUPP
    )
}

#[cfg(target_os = "linux")]
fn std_addr(a: &nix::sys::socket::SockaddrStorage) -> Option<SocketAddr> {
    if let Some(v4) = a.as_sockaddr_in() {
        return Some(SocketAddr::V4((*v4).into()));
    }
    a.as_sockaddr_in6().map(|v6| SocketAddr::V6((*v6).into()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn loopback() -> std::net::UdpSocket {
        bind("127.0.0.1:0".parse().expect("an address")).expect("binds on loopback")
    }

    /// Ten datagrams of one length for one address, and one of another.
    fn queue_eleven(udp: &mut Udp, key: u64, to: SocketAddr) {
        let mut path = DatagramPath::new(key, 1, Some(to));
        for i in 0..10u8 {
            udp.out.push(u64::from(i), &mut path, &[i; 100]);
        }
        udp.out.push(10, &mut path, &[10; 60]);
    }

    #[test]
    fn datagrams_of_one_length_for_one_address_leave_in_one_message() {
        let (_poll, mut udp, peer) = sender_and_peer();
        queue_eleven(&mut udp, 1, peer.local_addr().expect("an address"));
        udp.send_all(&mut HashMap::new());
        assert_eq!(
            udp.sent,
            Sent {
                messages: if cfg!(target_os = "linux") { 2 } else { 11 },
                datagrams: 11
            }
        );
        // The peer, without GRO, gets each datagram whole and in order.
        let mut got = Vec::new();
        let mut buf = [0; 256];
        while got.len() < 11 {
            let n = peer.recv(&mut buf).expect("a datagram");
            got.push(buf[..n].to_vec());
        }
        got.sort_by_key(|d| d[0]);
        for (i, d) in got.iter().enumerate() {
            let len = if i < 10 { 100 } else { 60 };
            assert_eq!(d, &vec![i as u8; len]);
        }
    }

    /// A hub with socket 1 on loopback, and a peer socket (without GRO)
    /// that reads what it sends.
    fn sender_and_peer() -> (mio::Poll, Udp, std::net::UdpSocket) {
        let poll = mio::Poll::new().expect("a poll");
        let mut udp = Udp::new();
        let new = NewSocket {
            socket: loopback(),
            stray: Arc::default(),
            held: true,
        };
        udp.add(poll.registry(), 1, new).expect("takes the socket");
        let peer = std::net::UdpSocket::bind("127.0.0.1:0").expect("binds");
        peer.set_read_timeout(Some(std::time::Duration::from_secs(5)))
            .expect("a timeout");
        (poll, udp, peer)
    }

    /// The first `n` datagrams `peer` gets, in the order it gets them.
    fn read_n(peer: &std::net::UdpSocket, n: usize) -> Vec<Vec<u8>> {
        let mut buf = [0; 256];
        (0..n)
            .map(|_| {
                let got = peer.recv(&mut buf).expect("a datagram");
                buf[..got].to_vec()
            })
            .collect()
    }

    #[test]
    fn a_links_datagrams_of_several_lengths_leave_in_the_order_written() {
        // As a QUIC connection's packets after a hold: each a length of its
        // own, the older ones longer or shorter than the newer.
        let (_poll, mut udp, peer) = sender_and_peer();
        let to = peer.local_addr().expect("an address");
        let mut path = DatagramPath::new(1, 1, Some(to));
        let lengths = [120, 60, 120, 120, 90, 60];
        for (i, &len) in (0u8..).zip(&lengths) {
            udp.out.push(7, &mut path, &vec![i; len]);
        }
        udp.send_all(&mut HashMap::new());
        let got = read_n(&peer, lengths.len());
        let firsts: Vec<u8> = got.iter().map(|d| d[0]).collect();
        assert_eq!(firsts, [0, 1, 2, 3, 4, 5], "in the order written");
        // The run of two of one length still left as one message.
        assert_eq!(udp.sent.datagrams, 6);
        if cfg!(target_os = "linux") {
            assert_eq!(udp.sent.messages, 5);
        }
    }

    #[test]
    fn links_keep_their_order_and_their_runs_of_one_length_leave_together() {
        // Ten links to one peer, each a datagram of 100 bytes then one of
        // 60: two messages, every link's 100 before its 60.
        let (_poll, mut udp, peer) = sender_and_peer();
        let to = peer.local_addr().expect("an address");
        for link in 0..10u8 {
            let mut path = DatagramPath::new(1, 1, Some(to));
            udp.out.push(u64::from(link), &mut path, &[link; 100]);
            udp.out.push(u64::from(link), &mut path, &[link; 60]);
        }
        udp.send_all(&mut HashMap::new());
        assert_eq!(udp.sent.datagrams, 20);
        if cfg!(target_os = "linux") {
            assert_eq!(udp.sent.messages, 2);
        }
        let got = read_n(&peer, 20);
        for link in 0..10u8 {
            let lengths: Vec<usize> = got.iter().filter(|d| d[0] == link).map(Vec::len).collect();
            assert_eq!(lengths, [100, 60], "link {link}");
        }
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn a_coalesced_run_is_read_whole_and_cut_back_into_its_datagrams() {
        let poll = mio::Poll::new().expect("a poll");
        let mut udp = Udp::new();
        for key in [1, 2] {
            let new = NewSocket {
                socket: loopback(),
                stray: Arc::default(),
                held: true,
            };
            udp.add(poll.registry(), key, new)
                .expect("takes the socket");
        }
        let to = udp.sockets[&2].socket.local_addr().expect("an address");
        queue_eleven(&mut udp, 1, to);
        udp.send_all(&mut HashMap::new());
        udp.slots = vec![0; SLOT * BATCH];
        let (mut got, mut messages) = (Vec::new(), 0);
        let deadline = StdInstant::now() + std::time::Duration::from_secs(5);
        while got.len() < 11 && StdInstant::now() < deadline {
            let n = match udp.read_batch(2) {
                Ok(n) => n,
                Err(e) if e.kind() == io::ErrorKind::WouldBlock => continue,
                Err(e) => panic!("reads: {e}"),
            };
            for (meta, slot) in udp.meta.iter().zip(udp.slots.chunks_exact(SLOT)).take(n) {
                assert_eq!(
                    meta.from,
                    Some(udp.sockets[&1].socket.local_addr().expect("bound"))
                );
                got.extend(datagrams(&slot[..meta.len], meta.segment).map(<[u8]>::to_vec));
                messages += 1;
            }
        }
        assert_eq!(got.len(), 11, "every datagram, once");
        assert_eq!(messages, 2, "the run of ten arrives as one message");
        got.sort_by_key(|d| d[0]);
        for (i, d) in got.iter().enumerate() {
            let len = if i < 10 { 100 } else { 60 };
            assert_eq!(d, &vec![i as u8; len]);
        }
    }

    #[test]
    fn a_message_is_cut_at_its_segment_length_only() {
        let bytes = [1, 1, 2, 2, 3];
        let cut: Vec<&[u8]> = datagrams(&bytes, Some(2)).collect();
        assert_eq!(cut, [&[1, 1][..], &[2, 2], &[3]]);
        assert_eq!(datagrams(&bytes, None).count(), 1);
        assert_eq!(datagrams(&bytes, Some(0)).count(), 1);
        let empty: Vec<&[u8]> = datagrams(&[], None).collect();
        assert_eq!(empty, [&[0u8; 0][..]]);
    }

    #[test]
    fn a_datagram_is_routed_by_the_token_of_a_whole_bundle_only() {
        let header = wire::Header::new(7, Instant::ZERO);
        let newest = [1.0, 2.0];
        let msg = wire::Message::Bundle {
            session: 0x1234_5678_9abc_def0,
            repeat: 0,
            missed: 0,
            newest: &newest,
            older: &[],
        };
        let mut buf = [0; 256];
        let n = wire::encode(&header, &msg, &mut buf).expect("encodes");
        assert_eq!(session_of(&buf[..n]), Some(0x1234_5678_9abc_def0));
        // Cut before its token ends: no token, a stray.
        assert_eq!(session_of(&buf[..HEADER_LEN + 7]), None);
        // Another kind of frame names no token, whatever its bytes there.
        let data = wire::Message::Data(&newest);
        let n = wire::encode(&header, &data, &mut buf).expect("encodes");
        assert_eq!(session_of(&buf[..n]), None);
    }
}
