//! The datagram transport ([`Transport::Datagram`]): samples go in
//! Bundles, each with the newest sample and copies of the few before it,
//! so that the receiver recovers a sample whose own datagram was lost from
//! the next one, and sent again a few times while the peer reports losses;
//! duplicates, reordered and replayed datagrams are dropped by `seq` and
//! counted, and a datagram without this side's session token is dropped
//! and counted. None of them harms the link.
//!
//! A datagram is bound to its path as QUIC binds its packets: its `seq`
//! may run ahead of the last one taken only by the ticks its stamp leaves
//! room for (a forged `seq` of 2⁶⁴ − 2 would make every real datagram
//! stale), and it is taken only from the address the driver has validated
//! ([`Origin::Path`]). A valid datagram from elsewhere is dropped and
//! counted; the driver may then give the peer a new token on the reliable
//! path ([`Endpoint::renew_session`]), and the address the first datagram
//! carrying it comes from becomes the peer's ([`Taken::Validated`]). Only
//! the peer reads the reliable path, so a stranger who saw a token can
//! neither move the stream of samples nor stop it.

use core::fmt;

use heapless::Vec as HVec;

use super::config::{DATAGRAM_BUDGET, REPEAT_HOLD, REPEAT_SPACING, Transport};
use super::event::Head;
use super::{Endpoint, LinkError, Phase, Stats, Tx};
use crate::storage::Storage;
use crate::time::{Duration, Instant};
use crate::wire::Token;
use crate::wire::{
    self, BUNDLE_FIXED_LEN, Control, Frame, HEADER_LEN, Header, Kind, MAX_BUNDLE, Message,
    OLDER_FIELDS_LEN, OlderSample, Payload, WireError,
};

/// One sample sent, kept for the copies in the next datagrams.
#[derive(Clone, Debug)]
struct SentCopy<V> {
    seq: u64,
    sent_at: Instant,
    released: Option<u64>,
    values: V,
}

/// What the datagram transport keeps: the samples sent lately, the peer's
/// session token, and the newest `seq` received.
#[derive(Clone, Debug)]
pub(super) struct Datagrams<V> {
    /// Copies of the last samples sent, oldest first, the newest last, at
    /// most `redundancy`; their buffers are made once.
    sent: HVec<SentCopy<V>, MAX_BUNDLE>,
    /// How many of `sent` hold a sample.
    filled: usize,
    /// Samples per datagram.
    redundancy: usize,
    /// Times each sample's datagram goes again, while repeating.
    repeats: u8,
    /// Until when samples are repeated: [`REPEAT_HOLD`] after the first
    /// sample, then after each report of a loss; `None` before the first.
    repeat_until: Option<Instant>,
    /// The peer's count of this side's samples it missed, as last seen.
    peer_missed: u32,
    /// The newest sample's header, for its repeats (the same samples again).
    newest: Option<Header>,
    /// When the next repeat of it is due, which send it is (1: the first
    /// repeat), the last, and the spacing between them.
    repeat: Option<(Instant, u8, u8, Duration)>,
    /// The peer's token (from its Hello, or its newest Token frame), put
    /// in every datagram to it.
    pub(super) peer_session: u64,
    /// This side's token: what the peer's datagrams carry.
    own: u64,
    /// A token given to the peer and not yet seen in a datagram.
    fresh: Option<u64>,
    /// The newest `seq` taken from the peer.
    highest: Option<u64>,
    /// The `seq` the next datagram should carry and the stamp it follows
    /// (the peer's Hello's, then the newest taken): a `seq` ahead of it by
    /// more ticks than its stamp leaves room for is refused.
    pub(super) anchor: Option<(u64, Instant)>,
    /// Whether it was a sample's (a gap between two samples is samples
    /// lost; one next to a probe may be probes).
    highest_sample: bool,
}

impl<V: AsRef<[f64]> + AsMut<[f64]> + Clone> Datagrams<V> {
    /// For `transport`, with sample buffers from `make`; `None` on a stream,
    /// or if a buffer cannot be made.
    pub(super) fn new(
        transport: Transport,
        own: u64,
        make: impl Fn() -> Option<V>,
    ) -> Option<Self> {
        let Transport::Datagram {
            redundancy,
            repeats,
        } = transport
        else {
            return None;
        };
        let redundancy = usize::from(redundancy).clamp(1, MAX_BUNDLE);
        let mut sent = HVec::new();
        for _ in 0..redundancy {
            let copy = SentCopy {
                seq: 0,
                sent_at: Instant::ZERO,
                released: None,
                values: make()?,
            };
            sent.push(copy).ok()?;
        }
        Some(Datagrams {
            sent,
            filled: 0,
            redundancy,
            repeats,
            repeat_until: None,
            peer_missed: 0,
            newest: None,
            repeat: None,
            peer_session: 0,
            own,
            fresh: None,
            highest: None,
            anchor: None,
            highest_sample: false,
        })
    }

    /// Forgets the samples sent: none of them is copied into a later
    /// datagram (they belong to a control term that ended).
    pub(super) fn forget_sent(&mut self) {
        self.filled = 0;
    }

    /// A sample just sent: the newest copy, the oldest given up.
    fn remember(&mut self, header: &Header, values: &[f64]) {
        self.newest = Some(*header);
        self.sent.rotate_left(1);
        if let Some(last) = self.sent.last_mut() {
            last.seq = header.seq;
            last.sent_at = header.sent_at;
            last.released = header.released;
            if let Some(dst) = last.values.as_mut().get_mut(..values.len()) {
                dst.copy_from_slice(values);
            }
        }
        self.filled = (self.filled + 1).min(self.sent.len());
    }

    /// Writes a bundle of `newest` (empty: a probe, sent alone) and the
    /// copies of the samples before it that fit [`DATAGRAM_BUDGET`]: those
    /// of `sent` but its last `skip` (the newest itself, in a repeat);
    /// `repeat` is which send of `newest` it is, `missed` this side's count
    /// of the peer's samples it missed.
    fn encode(
        &self,
        header: &Header,
        newest: &[f64],
        (skip, repeat): (usize, u8),
        missed: u32,
        buf: &mut [u8],
    ) -> Result<usize, WireError> {
        let width = newest.len();
        let values = 8 * width;
        let room = DATAGRAM_BUDGET.saturating_sub(HEADER_LEN + BUNDLE_FIXED_LEN + values)
            / (OLDER_FIELDS_LEN + values);
        let copies = if width == 0 {
            0
        } else {
            room.min(self.redundancy - 1)
                .min(self.filled.saturating_sub(skip))
        };
        let mut older: HVec<OlderSample<'_>, { MAX_BUNDLE - 1 }> = HVec::new();
        for copy in self.sent.iter().rev().skip(skip).take(copies) {
            let vs = copy.values.as_ref();
            let sample = OlderSample {
                seq: copy.seq,
                sent_at: copy.sent_at,
                released: copy.released,
                values: vs.get(..width).unwrap_or(vs),
            };
            // Never more than `sent` holds.
            let _ = older.push(sample);
        }
        let msg = Message::Bundle {
            session: self.peer_session,
            repeat,
            missed,
            newest,
            older: &older,
        };
        wire::encode(header, &msg, buf)
    }
}

/// Why a datagram was dropped (each counted in [`Stats`](super::Stats));
/// the link carries on, but for [`DatagramError::Link`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum DatagramError {
    /// The link is closed.
    Closed,
    /// This endpoint runs over a stream: give its frames to
    /// [`Endpoint::handle_frame`].
    NotDatagram,
    /// Not a valid frame (`datagrams_refused`).
    Wire(WireError),
    /// A frame of another kind than Bundle: those go on the reliable path
    /// (`datagrams_refused`).
    NotABundle(Kind),
    /// Another session's token: a stray or a spoof (`datagrams_foreign`).
    Foreign {
        /// The token it carried.
        session: u64,
    },
    /// Samples before the handshake is over (`datagrams_refused`).
    BeforeHandshake,
    /// Older than a datagram already taken: repeated by the network,
    /// reordered, or replayed (`datagrams_stale`).
    Stale {
        /// Its newest sample's `seq`.
        seq: u64,
        /// The newest taken.
        newest: u64,
    },
    /// Samples of another width than the peer's (`datagrams_refused`).
    Width {
        /// The width agreed.
        expected: u16,
        /// What it carried.
        got: usize,
    },
    /// A `seq` past any sender's count: 2⁶⁴ − 1, the wire's "none", which
    /// `released` could not name (`datagrams_refused`).
    Sequence {
        /// Its newest sample's `seq`.
        seq: u64,
    },
    /// A `seq` further ahead of the one expected than the ticks its stamp
    /// leaves room for: forged, since an honest sender numbers its ticks
    /// (`datagrams_refused`).
    Ahead {
        /// Its newest sample's `seq`.
        seq: u64,
        /// The `seq` expected next.
        expected: u64,
        /// The most ticks its stamp leaves room for.
        room: u64,
    },
    /// A copy stamped after the newest sample of its bundle, which an
    /// honest sender stamped later (`datagrams_refused`).
    CopyStamp {
        /// The copy's `seq`.
        seq: u64,
    },
    /// A valid datagram from an address the driver has not validated as
    /// the peer's (`datagrams_off_path`): not taken. The driver may
    /// validate the address with [`Endpoint::renew_session`].
    OffPath,
    /// A stamp the receive checks refuse (from the future:
    /// `datagrams_refused`).
    Stamp(LinkError),
    /// The samples were taken, and what they made the endpoint do ended
    /// the link (a Close is queued for the peer).
    Link(LinkError),
}

impl fmt::Display for DatagramError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            DatagramError::Closed => f.write_str("the link is closed"),
            DatagramError::NotDatagram => {
                f.write_str("this endpoint runs over a stream: hand its frames to handle_frame")
            }
            DatagramError::Wire(e) => write!(f, "an invalid datagram, dropped: {e}"),
            DatagramError::NotABundle(kind) => write!(
                f,
                "a {kind:?} frame as a datagram, dropped: only samples (Bundles) come as \
                 datagrams, the rest on the reliable path"
            ),
            DatagramError::Foreign { session } => write!(
                f,
                "a datagram of another session (token {session:#018x}), dropped: a stray or \
                 a spoof"
            ),
            DatagramError::BeforeHandshake => {
                f.write_str("samples before the handshake is over, dropped")
            }
            DatagramError::Stale { seq, newest } => write!(
                f,
                "a datagram with sample {seq} after sample {newest} was taken (repeated, \
                 reordered or replayed), dropped"
            ),
            DatagramError::Width { expected, got } => write!(
                f,
                "a datagram of {got} values per sample where the peer's carry {expected}, \
                 dropped"
            ),
            DatagramError::Sequence { seq } => write!(
                f,
                "a datagram with sample {seq}, past any sender's count (the wire's 'none'), \
                 dropped"
            ),
            DatagramError::Ahead {
                seq,
                expected,
                room,
            } => write!(
                f,
                "a datagram with sample {seq} where {expected} was expected and its stamp \
                 leaves room for {room} ticks (forged: a sender numbers its ticks), dropped"
            ),
            DatagramError::CopyStamp { seq } => write!(
                f,
                "a datagram whose copy of sample {seq} is stamped after its newest sample \
                 (forged: a sender stamps its ticks in order), dropped"
            ),
            DatagramError::OffPath => f.write_str(
                "a datagram from an address not validated as the peer's, dropped (the peer \
                 is given a new token to validate it)",
            ),
            DatagramError::Stamp(e) => write!(f, "a datagram the receive checks refuse: {e}"),
            DatagramError::Link(e) => write!(f, "{e}"),
        }
    }
}

impl core::error::Error for DatagramError {}

/// Where a datagram came from, as its driver sees it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Origin {
    /// The address validated as the peer's, or a transport that validates
    /// its paths itself (QUIC) or has no addresses (a simulator).
    Path,
    /// Any other address: none is validated yet (a listener's side before
    /// the first), or the datagram came from elsewhere.
    Elsewhere,
}

/// What a datagram that was taken means for its driver.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[must_use = "a validated path changes where datagrams go"]
pub enum Taken {
    /// Its samples were taken.
    Samples,
    /// Its samples were taken, and it carried the token given last
    /// ([`Endpoint::renew_session`]): its address is the peer's, where this
    /// side's datagrams go from now on, and the token before, `retired`,
    /// is no longer this link's.
    Validated {
        /// The token the peer's datagrams carried before.
        retired: u64,
    },
}

/// Why [`Endpoint::renew_session`] gave no token.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum RenewError {
    /// This endpoint runs over a stream: it has no datagrams.
    NotDatagram,
    /// Before the handshake is over, or after the link closed: the peer
    /// could not take a token.
    NotRunning,
    /// The token is 0 or the one in use: draw another.
    Token,
}

impl fmt::Display for RenewError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            RenewError::NotDatagram => "this endpoint runs over a stream: it has no datagram token",
            RenewError::NotRunning => {
                "a new datagram token goes to the peer only between the handshake and the close"
            }
            RenewError::Token => "a datagram token is never 0 nor the one in use: draw another",
        })
    }
}

impl core::error::Error for RenewError {}

/// This side's count of the peer's samples it missed, for its bundles.
fn missed(s: &Stats) -> u32 {
    let missed = s.samples_lost + s.samples_recovered + s.samples_from_repeats;
    // Modulo 2³²: the peer looks only for growth.
    missed as u32
}

impl<S: Storage> Endpoint<S> {
    /// A datagram arrived at `now` from `origin` (datagram transport only).
    /// It never ends the link by itself: a datagram that is not this
    /// session's, not valid, older than one taken, too far ahead, or from
    /// an address not validated is dropped, counted, and reported; the
    /// error is fatal only as [`DatagramError::Link`].
    pub fn handle_datagram(
        &mut self,
        now: Instant,
        bytes: &[u8],
        origin: Origin,
    ) -> Result<Taken, DatagramError> {
        if self.phase == Phase::Closed {
            return Err(DatagramError::Closed);
        }
        let Some(d) = self.dgram.as_ref() else {
            return Err(DatagramError::NotDatagram);
        };
        let (highest, after_sample, anchor) = (d.highest, d.highest_sample, d.anchor);
        let (own, fresh) = (d.own, d.fresh);
        let refused = |ep: &mut Self, e: DatagramError| {
            ep.stats.datagrams_refused += 1;
            Err(e)
        };
        let frame = match Frame::new_checked(bytes) {
            Ok(f) => f,
            Err(e) => return refused(self, DatagramError::Wire(e)),
        };
        let Payload::Bundle(bundle) = frame.payload() else {
            return refused(self, DatagramError::NotABundle(frame.kind()));
        };
        let token = bundle.session();
        let validates = fresh == Some(token);
        if token != own && !validates {
            self.stats.datagrams_foreign += 1;
            return Err(DatagramError::Foreign { session: token });
        }
        if self.phase == Phase::Handshake {
            return refused(self, DatagramError::BeforeHandshake);
        }
        let seq = frame.seq();
        if let Some(newest) = highest.filter(|&h| seq <= h) {
            self.stats.datagrams_stale += 1;
            return Err(DatagramError::Stale { seq, newest });
        }
        // Taken, it would be released, and this side's `released` could
        // not name it.
        if seq == u64::MAX {
            return refused(self, DatagramError::Sequence { seq });
        }
        let sent_at = frame.sent_at();
        if let Some((expected, since)) = anchor.filter(|&(e, _)| seq > e) {
            // The ticks from the one before `expected` to this one's, each
            // half the shortest period apart at least.
            let room = self.heard.check.tick_room(since, sent_at);
            if seq - expected >= room {
                return refused(
                    self,
                    DatagramError::Ahead {
                        seq,
                        expected,
                        room,
                    },
                );
            }
        }
        let width = self.config.received_width();
        if bundle.width() != 0 && bundle.width() != usize::from(width) {
            return refused(
                self,
                DatagramError::Width {
                    expected: width,
                    got: bundle.width(),
                },
            );
        }
        let stalled = self.driver_stalled(now);
        if let Err(e) = self.check_stamp(now, sent_at, frame.echo()) {
            return refused(self, DatagramError::Stamp(e));
        }
        // The newest's stamp is checked: its copies' come before it.
        if let Some(o) = bundle.older().find(|o| o.sent_at > sent_at) {
            return refused(self, DatagramError::CopyStamp { seq: o.seq });
        }
        if origin == Origin::Elsewhere && !validates {
            self.stats.datagrams_off_path += 1;
            return Err(DatagramError::OffPath);
        }
        self.stats.frames_received += 1;
        self.stats.datagrams_received += 1;
        let mut taken = Taken::Samples;
        if let Some(d) = &mut self.dgram {
            if validates {
                taken = Taken::Validated { retired: d.own };
                d.own = token;
                d.fresh = None;
                self.stats.paths_validated += 1;
            }
            d.highest = Some(seq);
            d.anchor = Some((seq + 1, sent_at));
            d.highest_sample = bundle.width() > 0;
            // Taken in `seq` order, so the count only grows (modulo 2³²).
            let grew = bundle.missed().wrapping_sub(d.peer_missed);
            if grew != 0 && grew < 1 << 31 {
                d.peer_missed = bundle.missed();
                d.repeat_until = Some(now + REPEAT_HOLD);
                self.stats.loss_reports += 1;
            }
        }
        let counted = highest.filter(|_| after_sample && bundle.width() > 0);
        self.take_bundle(now, &frame, (highest, counted), stalled)
            .map_err(|e| DatagramError::Link(self.fail(e)))?;
        Ok(taken)
    }

    /// Gives the peer `token` for the datagrams it sends here, on the
    /// reliable path, to validate the address a datagram came from
    /// ([`DatagramError::OffPath`]). Until a datagram carrying it is taken
    /// the token before stays good too; the driver routes both to this
    /// link. A token given before and not yet used is replaced (returned:
    /// no longer this link's), for a peer that never used it.
    pub fn renew_session(&mut self, token: u64) -> Result<Option<u64>, RenewError> {
        if matches!(self.phase, Phase::Handshake | Phase::Closed) {
            return Err(if self.dgram.is_some() {
                RenewError::NotRunning
            } else {
                RenewError::NotDatagram
            });
        }
        let Some(d) = &mut self.dgram else {
            return Err(RenewError::NotDatagram);
        };
        if token == 0 || token == d.own {
            return Err(RenewError::Token);
        }
        let replaced = d.fresh.replace(token);
        self.stats.tokens_renewed += 1;
        self.queue_tx(Tx::Token { session: token });
        Ok(replaced)
    }

    /// The peer's Hello, numbered `seq` (what its first Data frame will
    /// carry) and stamped `sent_at`, anchors the window of its first
    /// datagrams: its first ticks may be stamped a little before it.
    pub(super) fn anchor_datagrams(&mut self, seq: u64, sent_at: Instant) {
        let lead = self.period().saturating_mul(2);
        if let Some(d) = &mut self.dgram {
            d.anchor = Some((seq, sent_at.checked_sub(lead).unwrap_or(Instant::ZERO)));
        }
    }

    /// The peer's new token for the datagrams this side sends it.
    pub(super) fn receive_token(&mut self, token: Token) -> Result<(), LinkError> {
        match &mut self.dgram {
            Some(d) if self.phase != Phase::Handshake => {
                d.peer_session = token.session;
                Ok(())
            }
            _ => Err(self.unexpected(Kind::Token)),
        }
    }

    #[cfg(test)]
    /// The token given to the peer and not yet seen in a datagram.
    #[must_use]
    pub(crate) fn pending_session(&self) -> Option<u64> {
        self.dgram.as_ref()?.fresh
    }

    /// A fresh bundle's timing and samples: the copies not taken yet,
    /// oldest first, then the newest. `highest` is the newest `seq` taken
    /// before, and again (`counted`) if a gap from it is samples lost.
    fn take_bundle(
        &mut self,
        now: Instant,
        frame: &Frame<&[u8]>,
        (highest, counted): (Option<u64>, Option<u64>),
        stalled: bool,
    ) -> Result<(), LinkError> {
        let Payload::Bundle(bundle) = frame.payload() else {
            return Ok(());
        };
        self.hear(now, frame.sent_at(), frame.echo())?;
        let mut next = highest.map(|h| h + 1);
        let lost = |next: Option<u64>, seq: u64| {
            if counted.is_some() {
                next.map_or(0, |n| seq - n)
            } else {
                0
            }
        };
        let mut older: HVec<_, { MAX_BUNDLE - 1 }> = HVec::new();
        for o in bundle.older() {
            let _ = older.push(o);
        }
        for o in older.iter().rev() {
            if next.is_some_and(|n| o.seq < n) {
                continue;
            }
            self.stats.samples_lost += lost(next, o.seq);
            next = Some(o.seq + 1);
            self.stats.samples_recovered += 1;
            let head = Head {
                seq: o.seq,
                sent_at: o.sent_at,
                arrived_at: now,
            };
            self.receive_data(head, (o.released, frame.term()), o.values, None)?;
        }
        let seq = frame.seq();
        self.stats.samples_lost += lost(next, seq);
        if bundle.repeat() > 0 && bundle.width() > 0 {
            self.stats.samples_from_repeats += 1;
        }
        let head = Head {
            seq,
            sent_at: frame.sent_at(),
            arrived_at: now,
        };
        self.receive_data(
            head,
            (frame.released(), frame.term()),
            bundle.newest(),
            Some(stalled),
        )
    }

    /// A sample's datagram just went out at `now`: while repeating, its
    /// repeats are due [`repeat_spacing`] apart, as many as fit before the
    /// next sample's (a repeat that would go with it is no use).
    pub(super) fn arm_repeats(&mut self, now: Instant) {
        let period = self.period();
        // A sample queued before the close still goes, without repeats: no
        // deadline is left on a closed endpoint.
        if let Some(d) = self.dgram.as_mut().filter(|_| self.phase != Phase::Closed) {
            // Nothing is known of the path at first: repeat until it shows.
            let until = *d.repeat_until.get_or_insert(now + REPEAT_HOLD);
            let spacing = repeat_spacing(period);
            let room = period.as_nanos() / spacing.as_nanos().max(1);
            let fit = u8::try_from(room.saturating_sub(1)).unwrap_or(u8::MAX);
            let n = if now < until { d.repeats.min(fit) } else { 0 };
            d.repeat = (n > 0).then(|| (now + spacing, 1, n, spacing));
        }
    }

    /// The link closed: the repeats still due never go, and must not stay
    /// a deadline.
    pub(super) fn drop_repeats(&mut self) {
        if let Some(d) = &mut self.dgram {
            d.repeat = None;
        }
    }

    /// When the next repeat is due.
    pub(super) fn repeat_due(&self) -> Option<Instant> {
        self.dgram.as_ref()?.repeat.map(|(at, ..)| at)
    }

    /// Writes the newest sample's datagram again if a repeat is due at `now`.
    pub(super) fn poll_repeat(
        &mut self,
        now: Instant,
        buf: &mut [u8],
    ) -> Result<Option<usize>, LinkError> {
        let Some(d) = self.dgram.as_mut().filter(|_| self.phase != Phase::Closed) else {
            return Ok(None);
        };
        let (Some((at, send, last, spacing)), Some(header)) = (d.repeat, d.newest) else {
            return Ok(None);
        };
        if at > now {
            return Ok(None);
        }
        d.repeat = (send < last).then(|| (at + spacing, send + 1, last, spacing));
        let Some(newest) = d.sent.last().filter(|_| d.filled > 0) else {
            return Ok(None);
        };
        let values = newest.values.as_ref();
        let width = usize::from(self.config.sent_width());
        let values = values.get(..width).unwrap_or(values);
        match d.encode(&header, values, (1, send), missed(&self.stats), buf) {
            Ok(n) => {
                self.stats.datagrams_repeated += 1;
                self.stats.frames_sent += 1;
                Ok(Some(n))
            }
            Err(WireError::BufferTooSmall { needed, got }) => {
                Err(LinkError::BufferTooSmall { needed, got })
            }
            Err(e) => Err(LinkError::Wire(e)),
        }
    }

    /// Writes the frame for `item`: on the datagram transport a sample or a
    /// probe goes in a bundle (and the sample is kept for the next ones'
    /// copies), anything else as a frame of the reliable path.
    pub(super) fn write_item(
        &mut self,
        header: &Header,
        item: Tx,
        buf: &mut [u8],
    ) -> Result<usize, WireError> {
        let width = usize::from(self.config.sent_width());
        let sample = {
            let all = self.out.sample.as_ref();
            all.get(..width).unwrap_or(all)
        };
        let newest: &[f64] = match item {
            Tx::Sample { .. } => sample,
            _ => &[],
        };
        if let (Some(d), Tx::Probe { .. } | Tx::Sample { .. }) = (&mut self.dgram, item) {
            let n = d.encode(header, newest, (0, 0), missed(&self.stats), buf)?;
            if let Tx::Sample { .. } = item {
                d.remember(header, newest);
            }
            return Ok(n);
        }
        let msg = match item {
            Tx::Hello => Message::Hello(self.hello()),
            Tx::Probe { .. } | Tx::Sample { .. } => Message::Data(newest),
            Tx::Control { op, ns, period } => Message::Control(Control { op, ns, period }),
            Tx::Close { reason } => Message::Close(wire::Close { reason }),
            Tx::Token { session } => Message::Token(Token { session }),
        };
        wire::encode(header, &msg, buf)
    }
}

/// Between a sample's datagram and its repeats at `period`: [`REPEAT_SPACING`],
/// or half the period where that is shorter. At a period of a millisecond
/// or less no repeat would fit otherwise, and a lost datagram would wait a
/// whole period for the next one's copies, and be lost when the copies are
/// too (at 1 kHz with one datagram in ten lost, once in 10 000 samples, a
/// tenth of the adaptive playout's default late rate); the repeat half a
/// period later makes it good within the period.
pub(super) fn repeat_spacing(period: Duration) -> Duration {
    REPEAT_SPACING.min(Duration::from_nanos(period.as_nanos() / 2))
}
