//! Applied commands: what the robot did, told to its observers.
//!
//! A remote's driver hands each command the robot applied to every
//! observer's link ([`Endpoint::send_applied`]); each goes out in an
//! Applied frame on the reliable path, stamped with the command's term,
//! its `seq`, when it was sent and when it was applied (both on the
//! remote's clock). A link holds a few of them: an observer that does not
//! read loses the oldest (counted), and never holds the robot back.

use heapless::{Deque, Vec as HVec};

use super::{Endpoint, Event, LinkError, Phase};
use crate::storage::Storage;
use crate::time::Instant;
use crate::wire::{self, Header, Kind, Message, Role, Seat};

/// Applied commands a link holds for its driver.
pub(super) const APPLIED_QUEUE: usize = 4;

/// A command the robot applied, as an observer's application gets it, its
/// values in `V`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct AppliedCommand<V> {
    /// The control term it was applied in.
    pub term: u16,
    /// Its `seq` on its controller's link.
    pub seq: u64,
    /// When its controller sent it, on the remote's clock.
    pub sent_at: Instant,
    /// When the robot applied it, on the remote's clock.
    pub applied_at: Instant,
    /// When it arrived here, on this side's clock.
    pub arrived_at: Instant,
    len: u16,
    values: V,
}

impl<V: AsRef<[f64]>> AppliedCommand<V> {
    /// The command's values.
    #[must_use]
    pub fn values(&self) -> &[f64] {
        let all = self.values.as_ref();
        all.get(..usize::from(self.len)).unwrap_or(all)
    }
}

#[derive(Clone, Copy, Debug)]
struct Head {
    term: u16,
    seq: u64,
    sent_at: Instant,
    applied_at: Instant,
    buf: usize,
}

/// The applied commands waiting to go to an observer.
#[derive(Clone, Debug)]
pub(super) struct AppliedOut<V> {
    /// Value buffers, made on first use.
    bufs: HVec<V, APPLIED_QUEUE>,
    queue: Deque<Head, APPLIED_QUEUE>,
    next_buf: usize,
}

impl<V> AppliedOut<V> {
    pub(super) fn new() -> Self {
        AppliedOut {
            bufs: HVec::new(),
            queue: Deque::new(),
            next_buf: 0,
        }
    }

    pub(super) fn clear(&mut self) {
        self.queue.clear();
    }
}

impl<S: Storage> Endpoint<S> {
    /// Remote: tells this link's observer that the robot applied a command
    /// of `term` (`seq` on its controller's link, sent at `sent_at` and
    /// applied at `applied_at`, both on this side's clock — see
    /// [`peer_to_local`](Self::peer_to_local)). Goes out with the next
    /// frames; if the observer's driver is behind, the oldest waiting one
    /// is dropped ([`Stats::applied_dropped`](super::Stats)).
    ///
    /// # Errors
    /// [`LinkError::NotController`] on a link that is not an observer's
    /// (a base, or a controller's link); [`LinkError::SampleShape`] and
    /// [`LinkError::NonFinite`] for values that are no command;
    /// [`LinkError::Closed`] on a closed link.
    pub fn send_applied(
        &mut self,
        (term, seq): (u16, u64),
        sent_at: Instant,
        applied_at: Instant,
        values: &[f64],
    ) -> Result<(), LinkError> {
        if self.phase == Phase::Closed {
            return Err(LinkError::Closed);
        }
        if self.config.role != Role::Remote
            || self.seating.held.is_some()
            || self.seating.given != Some(Seat::Observe)
        {
            return Err(LinkError::NotController);
        }
        let width = self.config.command_width;
        super::check_sample(values, width)?;
        let out = &mut self.applied;
        if out.queue.is_full() {
            let _ = out.queue.pop_front();
            self.stats.applied_dropped += 1;
        }
        let buf = out.next_buf;
        out.next_buf = (buf + 1) % APPLIED_QUEUE;
        if out.bufs.len() <= buf {
            let Some(v) = S::values(usize::from(width)) else {
                return Err(LinkError::SampleShape {
                    expected: width,
                    got: values.len(),
                });
            };
            let _ = out.bufs.push(v);
        }
        if let Some(dst) = out
            .bufs
            .get_mut(buf)
            .and_then(|v| v.as_mut().get_mut(..values.len()))
        {
            dst.copy_from_slice(values);
        }
        let _ = out.queue.push_back(Head {
            term,
            seq,
            sent_at,
            applied_at,
            buf,
        });
        Ok(())
    }

    /// Writes the oldest applied command waiting, if any.
    pub(super) fn poll_applied(
        &mut self,
        now: Instant,
        buf: &mut [u8],
    ) -> Result<Option<usize>, wire::WireError> {
        let Some(&head) = self.applied.queue.front() else {
            return Ok(None);
        };
        let header = Header {
            seq: self.out.next_seq,
            sent_at: now,
            echo: self.heard.echo_at(now),
            released: self.rel.released_seq,
            term: head.term,
        };
        let width = usize::from(self.config.command_width);
        let values = self
            .applied
            .bufs
            .get(head.buf)
            .map(|v| v.as_ref())
            .and_then(|v| v.get(..width))
            .unwrap_or_default();
        let msg = Message::Applied {
            seq: head.seq,
            sent_at: head.sent_at,
            applied_at: head.applied_at,
            values,
        };
        let n = wire::encode(&header, &msg, buf)?;
        let _ = self.applied.queue.pop_front();
        self.stats.frames_sent += 1;
        self.stats.applied_sent += 1;
        Ok(Some(n))
    }

    /// Base: an applied command from the remote, for an observer.
    pub(super) fn receive_applied(
        &mut self,
        now: Instant,
        term: u16,
        applied: wire::Applied<'_>,
    ) -> Result<(), LinkError> {
        if self.config.role != Role::Base
            || self.seating.held.is_some()
            || matches!(self.phase, Phase::Handshake)
        {
            return Err(self.unexpected(Kind::Applied));
        }
        let width = self.config.command_width;
        let mismatch = LinkError::ChannelCount {
            expected: width,
            got: applied.values.len(),
        };
        if applied.values.len() != usize::from(width) {
            return Err(mismatch);
        }
        let Some(mut values) = S::values(usize::from(width)) else {
            return Err(mismatch);
        };
        if applied.values.copy_to(values.as_mut()).is_err() {
            return Err(mismatch);
        }
        self.stats.applied_received += 1;
        self.emit(Event::Applied(AppliedCommand {
            term,
            seq: applied.seq,
            sent_at: applied.sent_at,
            applied_at: applied.applied_at,
            arrived_at: now,
            len: width,
            values,
        }));
        Ok(())
    }

    /// `t` on the peer's clock, on this side's, by the current estimate of
    /// the clocks' offset (`t` itself before there is one): a remote maps
    /// its controller's send stamps with it for [`send_applied`](Self::send_applied).
    #[must_use]
    pub fn peer_to_local(&self, t: Instant, now: Instant) -> Instant {
        match self.sync.offset_at(now) {
            Some(theta) => {
                let ns = t.as_nanos() as f64 + theta * 1e9;
                Instant::from_nanos(if ns > 0.0 { ns as u64 } else { 0 })
            }
            None => t,
        }
    }
}
