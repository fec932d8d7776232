//! The relay's counters: lock-free while it runs, a plain snapshot to read.

use std::sync::atomic::{AtomicU64, Ordering};

use ndr_netem::Direction;

use super::ConnectionEnd;

/// Counters of one direction, for the whole relay or for one connection.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct DirectionStats {
    /// Whole frames read from the sending side.
    pub frames_received: u64,
    /// Frames written to the receiving side (after their delay).
    pub frames_delivered: u64,
    /// Bytes of the delivered frames, length prefixes included.
    pub bytes_delivered: u64,
    /// Frames that left later than their own delay said, held back behind an
    /// earlier, slower frame to keep the stream in order.
    pub held_back: u64,
}

/// Counters of one direction of the datagram path, summed over its flows.
///
/// Each datagram received is counted once more when it leaves: lost,
/// dropped for a full queue, delivered, failed to send, or dropped with its
/// flow when a new client took it; the ones still waiting at a shutdown are
/// dropped uncounted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct DatagramDirectionStats {
    /// Datagrams read from the sending side into a flow.
    pub received: u64,
    /// Dropped by the loss model ([`RelayConfig::loss`](super::RelayConfig::loss)).
    pub lost: u64,
    /// Dropped because the direction's queue held
    /// [`max_queue_frames`](super::RelayConfig::max_queue_frames) datagrams
    /// or would have gone over
    /// [`max_queue_bytes`](super::RelayConfig::max_queue_bytes).
    pub queue_full: u64,
    /// Sent on after their delay.
    pub delivered: u64,
    /// Bytes of the delivered datagrams.
    pub bytes_delivered: u64,
    /// Whose send failed after their delay (the receiving side unreachable,
    /// a datagram too large for its path).
    pub send_failed: u64,
    /// Datagrams that left later than their own delay said, held back behind
    /// an earlier, slower one.
    pub held_back: u64,
    /// Dropped while they waited, their flow evicted for a new client
    /// ([`DatagramStats::flows_evicted`]).
    pub evicted: u64,
}

/// Counters of the datagram path: its flows, and each direction.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct DatagramStats {
    /// Flows opened: client addresses seen, each given an upstream socket.
    pub flows_opened: u64,
    /// Flows open now.
    pub flows_active: u64,
    /// Datagrams from a new client address dropped because
    /// [`max_flows`](super::RelayConfig::max_flows) flows were open, every
    /// one answered by the upstream and active (or its upstream socket
    /// could not be opened): each such datagram counts.
    pub flows_refused: u64,
    /// Flows the upstream never answered on, removed with their socket to
    /// make room for a new client when
    /// [`max_flows`](super::RelayConfig::max_flows) flows were open and
    /// none idle: one-datagram senders (spoofed addresses among them) take
    /// no flow from a real peer.
    pub flows_evicted: u64,
    /// Flows removed, with their socket, after
    /// [`flow_idle_timeout`](super::RelayConfig::flow_idle_timeout) without
    /// a datagram either way (see the config).
    pub flows_expired: u64,
    /// Client → upstream.
    pub forward: DatagramDirectionStats,
    /// Upstream → client.
    pub backward: DatagramDirectionStats,
}

impl DatagramStats {
    /// The counters of one direction.
    #[must_use]
    pub const fn direction(&self, dir: Direction) -> &DatagramDirectionStats {
        match dir {
            Direction::Forward => &self.forward,
            Direction::Backward => &self.backward,
        }
    }
}

/// A snapshot of a relay's counters (see [`RelayHandle::stats`](super::RelayHandle::stats)).
///
/// Each connection that ended is counted once in `finished` or in exactly
/// one of the reasons it was cut. The TCP counters count frames; the
/// datagram path has its own, in [`datagrams`](Self::datagrams).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct RelayStats {
    /// Client connections accepted.
    pub connections: u64,
    /// Connections open now.
    pub active: u64,
    /// Connections that ended normally: both sides closed after every frame
    /// in flight was delivered.
    pub finished: u64,
    /// Connections dropped because the upstream refused them, or did not
    /// answer within the connect timeout.
    pub upstream_failures: u64,
    /// Connections cut because a side sent an absurd length prefix (or a
    /// TLS stream a header that is not TLS).
    pub framing_errors: u64,
    /// Connections cut because a direction's queue went over its bound.
    pub queue_overflows: u64,
    /// Connections ended by a read or write error (a reset, a peer gone);
    /// what the failed side sent before it still arrived.
    pub io_errors: u64,
    /// Connections closed by [`RelayHandle::shutdown`](super::RelayHandle::shutdown)
    /// (or by dropping the handle).
    pub closed_by_shutdown: u64,
    /// Client → upstream.
    pub forward: DirectionStats,
    /// Upstream → client.
    pub backward: DirectionStats,
    /// The datagram (UDP) path.
    pub datagrams: DatagramStats,
}

impl RelayStats {
    /// The counters of one direction.
    #[must_use]
    pub const fn direction(&self, dir: Direction) -> &DirectionStats {
        match dir {
            Direction::Forward => &self.forward,
            Direction::Backward => &self.backward,
        }
    }
}

/// Live counters of one direction.
#[derive(Debug, Default)]
pub(super) struct DirCounters {
    received: AtomicU64,
    delivered: AtomicU64,
    bytes: AtomicU64,
    held_back: AtomicU64,
}

impl DirCounters {
    pub(super) fn snapshot(&self) -> DirectionStats {
        DirectionStats {
            frames_received: self.received.load(Ordering::Relaxed),
            frames_delivered: self.delivered.load(Ordering::Relaxed),
            bytes_delivered: self.bytes.load(Ordering::Relaxed),
            held_back: self.held_back.load(Ordering::Relaxed),
        }
    }
}

/// Live counters of the relay.
#[derive(Debug, Default)]
pub(super) struct Counters {
    pub(super) connections: AtomicU64,
    pub(super) active: AtomicU64,
    finished: AtomicU64,
    upstream_failures: AtomicU64,
    framing_errors: AtomicU64,
    queue_overflows: AtomicU64,
    io_errors: AtomicU64,
    closed_by_shutdown: AtomicU64,
    pub(super) dirs: [DirCounters; 2],
    pub(super) datagrams: DatagramCounters,
}

impl Counters {
    pub(super) fn snapshot(&self) -> RelayStats {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        RelayStats {
            connections: get(&self.connections),
            active: get(&self.active),
            finished: get(&self.finished),
            upstream_failures: get(&self.upstream_failures),
            framing_errors: get(&self.framing_errors),
            queue_overflows: get(&self.queue_overflows),
            io_errors: get(&self.io_errors),
            closed_by_shutdown: get(&self.closed_by_shutdown),
            forward: self.dirs[0].snapshot(),
            backward: self.dirs[1].snapshot(),
            datagrams: self.datagrams.snapshot(),
        }
    }

    /// Counts a connection that ended, by how it ended.
    pub(super) fn ended(&self, end: &ConnectionEnd) {
        let counter = match end {
            ConnectionEnd::Finished => &self.finished,
            ConnectionEnd::UpstreamFailed { .. } => &self.upstream_failures,
            ConnectionEnd::Framing { .. } | ConnectionEnd::BadRecord { .. } => &self.framing_errors,
            ConnectionEnd::QueueFull { .. } => &self.queue_overflows,
            ConnectionEnd::Io { .. } => &self.io_errors,
            ConnectionEnd::Shutdown => &self.closed_by_shutdown,
        };
        counter.fetch_add(1, Ordering::Relaxed);
        self.active.fetch_sub(1, Ordering::Relaxed);
    }
}

/// Counts into the relay's counters and one connection's at once.
#[derive(Clone, Copy)]
pub(super) struct Tally<'a> {
    pub(super) global: &'a DirCounters,
    pub(super) local: &'a DirCounters,
}

impl Tally<'_> {
    fn add(&self, field: impl Fn(&DirCounters) -> &AtomicU64, n: u64) {
        field(self.global).fetch_add(n, Ordering::Relaxed);
        field(self.local).fetch_add(n, Ordering::Relaxed);
    }

    pub(super) fn received(&self, held_back: bool) {
        self.add(|c| &c.received, 1);
        if held_back {
            self.add(|c| &c.held_back, 1);
        }
    }

    pub(super) fn delivered(&self, frames: u64, bytes: u64) {
        self.add(|c| &c.delivered, frames);
        self.add(|c| &c.bytes, bytes);
    }
}

/// Live counters of the datagram path.
#[derive(Debug, Default)]
pub(super) struct DatagramCounters {
    pub(super) flows_opened: AtomicU64,
    pub(super) flows_active: AtomicU64,
    pub(super) flows_refused: AtomicU64,
    pub(super) flows_evicted: AtomicU64,
    pub(super) flows_expired: AtomicU64,
    pub(super) dirs: [DatagramDirCounters; 2],
}

impl DatagramCounters {
    fn snapshot(&self) -> DatagramStats {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        DatagramStats {
            flows_opened: get(&self.flows_opened),
            flows_active: get(&self.flows_active),
            flows_refused: get(&self.flows_refused),
            flows_evicted: get(&self.flows_evicted),
            flows_expired: get(&self.flows_expired),
            forward: self.dirs[0].snapshot(),
            backward: self.dirs[1].snapshot(),
        }
    }
}

/// Live counters of one direction of the datagram path.
#[derive(Debug, Default)]
pub(super) struct DatagramDirCounters {
    pub(super) received: AtomicU64,
    pub(super) lost: AtomicU64,
    pub(super) queue_full: AtomicU64,
    pub(super) delivered: AtomicU64,
    pub(super) bytes_delivered: AtomicU64,
    pub(super) send_failed: AtomicU64,
    pub(super) held_back: AtomicU64,
    pub(super) evicted: AtomicU64,
}

impl DatagramDirCounters {
    fn snapshot(&self) -> DatagramDirectionStats {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        DatagramDirectionStats {
            received: get(&self.received),
            lost: get(&self.lost),
            queue_full: get(&self.queue_full),
            delivered: get(&self.delivered),
            bytes_delivered: get(&self.bytes_delivered),
            send_failed: get(&self.send_failed),
            held_back: get(&self.held_back),
            evicted: get(&self.evicted),
        }
    }
}
