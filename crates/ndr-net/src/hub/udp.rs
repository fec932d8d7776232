//! The datagram transport's sockets in a hub.
//!
//! A hub has one UDP socket of its own per address family, shared by the
//! links it connects, and one per datagram listener whose links it drives
//! (bound at the listener's port: a link's datagrams go to the port number
//! of its TCP listener). Each socket is read and written in batches
//! (`recvmmsg`, `sendmmsg`), so a tick that serves many links costs a few
//! system calls, not one per link.
//!
//! A datagram goes to the link whose session token it carries (a Bundle
//! names its receiver's token). Once that link's endpoint has taken it (the
//! right session, valid, newer than any before), the address it came from
//! becomes the link's path: a listener's side learns where its peer is
//! from the first datagram, and a peer behind a NAT, or one that moved, is
//! answered where it is now. A datagram without a known token is dropped
//! and counted on its socket.

use std::collections::HashMap;
use std::io;
use std::net::SocketAddr;
use std::ops::Range;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant as StdInstant;

use mio::net::UdpSocket;
use mio::{Interest, Registry, Token};
use ndr_core::endpoint::DatagramError;
use ndr_core::time::Instant;
use ndr_core::wire::{self, HEADER_LEN};

use super::Entry;

/// Datagrams read, or written, per system call.
pub(super) const BATCH: usize = 32;
/// Room for one received datagram: more than the longest Bundle a link
/// sends (one sample of [`wire::MAX_CHANNELS`] values alone); a longer one
/// arrives cut short and its endpoint refuses it.
const SLOT: usize = 4096;
const _: () = assert!(SLOT >= HEADER_LEN + wire::BUNDLE_FIXED_LEN + 8 * wire::MAX_CHANNELS);
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
    /// Where its datagrams go: the peer's newest address; `None` until
    /// the peer's first datagram (a listener's side).
    pub peer: Option<SocketAddr>,
    /// Datagrams not sent: no address for the peer yet, or the socket
    /// refused them (its buffer full, the path unreachable).
    pub unsent: u64,
    /// Times the peer's address changed (a NAT's new mapping, a peer that
    /// moved, or the first datagram of a listener's side).
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

/// The token a datagram names, if it is a Bundle long enough to name one.
fn session_of(bytes: &[u8]) -> Option<u64> {
    if !wire::is_bundle(bytes) {
        return None;
    }
    let token = bytes.get(HEADER_LEN..HEADER_LEN + 8)?;
    Some(u64::from_le_bytes(token.try_into().ok()?))
}

/// What one received datagram was.
#[derive(Clone, Copy, Default)]
struct Meta {
    len: usize,
    from: Option<SocketAddr>,
    at: Option<StdInstant>,
}

/// The hub's datagram sockets and their buffers.
pub(super) struct Udp {
    sockets: HashMap<u64, Sock>,
    pub(super) out: Outgoing,
    slots: Vec<u8>,
    meta: [Meta; BATCH],
}

impl Udp {
    pub(super) fn new() -> Udp {
        Udp {
            sockets: HashMap::new(),
            out: Outgoing::default(),
            slots: Vec::new(),
            meta: [Meta::default(); BATCH],
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
        let mut socket = UdpSocket::from_std(new.socket);
        registry.register(&mut socket, Token(key as usize), Interest::READABLE)?;
        self.sockets.insert(
            key,
            Sock {
                socket,
                sessions: HashMap::new(),
                stray: new.stray,
                held: new.held,
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
        if let Some(sock) = self.sockets.get_mut(&path.socket)
            && sock.sessions.get(&path.session) == Some(&id)
        {
            sock.sessions.remove(&path.session);
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

    /// Reads a batch from socket `key` (for a QUIC endpoint): how many
    /// datagrams, each then read with [`received`](Self::received).
    pub(super) fn read(&mut self, key: u64) -> io::Result<usize> {
        if self.slots.is_empty() {
            self.slots = vec![0; SLOT * BATCH];
        }
        self.read_batch(key)
    }

    /// The `i`th datagram of the last [`read`](Self::read): where it came
    /// from, when it arrived (the kernel's stamp), its bytes.
    pub(super) fn received(
        &self,
        i: usize,
    ) -> Option<(Option<SocketAddr>, Option<StdInstant>, &[u8])> {
        let meta = self.meta.get(i)?;
        let slot = self.slots.chunks_exact(SLOT).nth(i)?;
        Some((meta.from, meta.at, slot.get(..meta.len.min(SLOT))?))
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
            let Some(sock) = self.sockets.get(&key) else {
                return;
            };
            let handled = StdInstant::now();
            for (meta, slot) in self
                .meta
                .iter()
                .zip(self.slots.chunks_exact(SLOT))
                .take(got)
            {
                let bytes = slot.get(..meta.len.min(SLOT)).unwrap_or_default();
                let link = session_of(bytes).and_then(|s| sock.sessions.get(&s).copied());
                let Some(e) = link.and_then(|id| entries.get_mut(&id)) else {
                    sock.stray.fetch_add(1, Ordering::Relaxed);
                    continue;
                };
                let at = meta.at.unwrap_or(handled);
                e.rx_lag
                    .push_duration(handled.saturating_duration_since(at).into());
                let taken = e
                    .endpoint
                    .handle_datagram(Instant::from_std(origin, at), bytes);
                if let (Ok(()), Some(path), Some(from)) = (taken, e.datagram.as_mut(), meta.from)
                    && path.peer != Some(from)
                {
                    tracing::debug!(from = %from, before = ?path.peer, "datagram path changed");
                    path.peer = Some(from);
                    path.path_changes += 1;
                }
                // Refused datagrams are counted by the endpoint; only an
                // ended link needs its hub to act.
                if matches!(taken, Ok(()) | Err(DatagramError::Link(_)))
                    && let Some(id) = link.filter(|id| !touched.contains(id))
                {
                    touched.push(id);
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
        let mut start = 0;
        while start < self.out.queued.len() {
            let key = self.out.queued[start].socket;
            // The run of datagrams for one socket (there is usually one).
            let end = self.out.queued[start..]
                .iter()
                .position(|q| q.socket != key)
                .map_or(self.out.queued.len(), |n| start + n);
            let mut at = start;
            while at < end {
                let chunk = at..end.min(at + BATCH);
                match self.write_batch(key, chunk.clone()) {
                    Ok(n) => at += n.max(1),
                    Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                    Err(_) => {
                        // The first of the chunk was refused (a full buffer,
                        // an unreachable path): it is lost, as on the network.
                        if let Some(e) = entries.get_mut(&self.out.queued[at].link) {
                            if let Some(path) = e.datagram.as_mut() {
                                path.unsent += 1;
                            }
                            if let Some(q) = e.quic.as_deref_mut() {
                                q.dropped += 1;
                            }
                        }
                        at += 1;
                    }
                }
            }
            start = end;
        }
        self.out.queued.clear();
        self.out.arena.clear();
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
            MultiHeaders::preallocate(BATCH, Some(nix::cmsg_space!(nix::sys::time::TimeSpec)));
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
                let stamp = r.cmsgs().ok().and_then(|mut c| {
                    c.find_map(|m| match m {
                        ControlMessageOwned::ScmTimestampns(ts) => Some(ts),
                        _ => None,
                    })
                });
                *meta = Meta {
                    len: r.bytes,
                    from: r.address.and_then(|a| std_addr(&a)),
                    at: stamp.and_then(crate::arrival::kernel_instant),
                };
                got += 1;
            }
            got
        };
        Ok(got)
    }

    #[cfg(target_os = "linux")]
    fn write_batch(&mut self, key: u64, chunk: Range<usize>) -> io::Result<usize> {
        use std::os::fd::AsRawFd;

        use nix::sys::socket::{ControlMessage, MsgFlags, MultiHeaders, SockaddrStorage, sendmmsg};

        let Some(sock) = self.sockets.get(&key) else {
            return Ok(chunk.len());
        };
        let queued = self.out.queued.get(chunk).unwrap_or_default();
        let arena = &self.out.arena;
        let iovs: [[io::IoSlice<'_>; 1]; BATCH] = std::array::from_fn(|i| {
            let bytes = queued
                .get(i)
                .and_then(|q| arena.get(q.bytes.clone()))
                .unwrap_or_default();
            [io::IoSlice::new(bytes)]
        });
        let addrs: [Option<SockaddrStorage>; BATCH] =
            std::array::from_fn(|i| queued.get(i).map(|q| SockaddrStorage::from(q.to)));
        let n = queued.len();
        let none: [ControlMessage<'_>; 0] = [];
        let mut headers = MultiHeaders::preallocate(n, None);
        let sent = sendmmsg(
            sock.socket.as_raw_fd(),
            &mut headers,
            iovs.get(..n).unwrap_or_default(),
            addrs.get(..n).unwrap_or_default(),
            none,
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
    fn write_batch(&mut self, key: u64, chunk: Range<usize>) -> io::Result<usize> {
        let Some(sock) = self.sockets.get(&key) else {
            return Ok(chunk.len());
        };
        let q = self
            .out
            .queued
            .get(chunk.start)
            .ok_or(io::ErrorKind::InvalidInput)?;
        let bytes = self.out.arena.get(q.bytes.clone()).unwrap_or_default();
        sock.socket.send_to(bytes, q.to)?;
        Ok(1)
    }
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

    #[test]
    fn a_datagram_is_routed_by_the_token_of_a_whole_bundle_only() {
        let header = wire::Header::new(7, Instant::ZERO);
        let newest = [1.0, 2.0];
        let msg = wire::Message::Bundle {
            session: 0x1234_5678_9abc_def0,
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
