//! The Bundle (kind 5): a datagram's samples. The newest sample and up to
//! [`MAX_BUNDLE`] − 1 before it, each with its own `seq`, stamp and
//! `released`, so that a receiver recovers a sample whose own datagram was
//! lost from the next one; the receiver's session token, so that it
//! drops a datagram that does not belong to the session; and what the
//! sender saw of the loss the other way, so that its peer repeats its
//! datagrams only while they are lost.

use core::fmt;

use super::payload::Channels;
use super::{Kind, NONE, WireError, bytes_at, put};
use crate::time::Instant;

/// Most samples a Bundle carries.
pub const MAX_BUNDLE: usize = 8;
/// Largest valid Bundle, in bytes: a UDP datagram's largest payload over
/// IPv4. A sender keeps its datagrams far smaller (one path MTU).
pub const MAX_DATAGRAM_LEN: usize = 65_507;
/// Size of a Bundle's fixed part (session, count, repeat, width, missed), in bytes.
pub const BUNDLE_FIXED_LEN: usize = 16;
/// Size of an older sample's own fields (seq, sent_at, released), in bytes.
pub(crate) const OLDER_FIELDS_LEN: usize = 24;

/// Bytes of a Bundle's payload for `count` samples of `width` values.
#[must_use]
pub(crate) const fn bundle_payload_len(count: usize, width: usize) -> usize {
    let values = width.saturating_mul(8);
    BUNDLE_FIXED_LEN.saturating_add(values).saturating_add(
        count
            .saturating_sub(1)
            .saturating_mul(OLDER_FIELDS_LEN.saturating_add(values)),
    )
}

/// A decoded Bundle payload: the newest sample's values (its `seq`, stamp
/// and `released` are the frame header's) and the older samples'.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Bundle<'a> {
    bytes: &'a [u8],
}

impl<'a> Bundle<'a> {
    /// Validates a Bundle payload, `seq` being the header's.
    pub(super) fn check(bytes: &'a [u8], seq: u64) -> Result<Self, WireError> {
        let bad_len = WireError::BadPayloadLength {
            kind: Kind::Bundle,
            len: bytes.len(),
        };
        let fixed = bytes_at::<BUNDLE_FIXED_LEN>(bytes, 0).ok_or(bad_len)?;
        // `repeat` and `missed` take any value.
        let [_, _, _, _, _, _, _, _, count, _, w0, w1, _, _, _, _] = fixed;
        let count = usize::from(count);
        if count == 0 || count > MAX_BUNDLE {
            return Err(WireError::BadBundleCount(count));
        }
        let width = usize::from(u16::from_le_bytes([w0, w1]));
        if width > super::MAX_CHANNELS {
            return Err(WireError::TooManyChannels(width));
        }
        if bytes.len() != bundle_payload_len(count, width) {
            return Err(bad_len);
        }
        let bundle = Bundle { bytes };
        let mut flat = 0;
        let mut above = seq;
        for (i, sample) in bundle.samples().enumerate() {
            // The newest's seq is the header's.
            if i > 0 {
                if sample.seq >= above {
                    return Err(WireError::BundleOrder { index: i });
                }
                above = sample.seq;
            }
            if let Some(k) = sample.values.first_non_finite() {
                return Err(WireError::NonFinite { index: flat + k });
            }
            flat += width;
        }
        Ok(bundle)
    }

    /// A view over bytes already checked.
    pub(super) const fn from_checked(bytes: &'a [u8]) -> Self {
        Bundle { bytes }
    }

    /// The receiver's session token.
    #[must_use]
    pub fn session(&self) -> u64 {
        bytes_at(self.bytes, 0).map_or(0, u64::from_le_bytes)
    }

    /// Samples in the bundle, 1 to [`MAX_BUNDLE`].
    #[must_use]
    pub fn count(&self) -> usize {
        usize::from(self.bytes.get(8).copied().unwrap_or(0))
    }

    /// Which send of the newest sample this datagram is: 0 the first, `r`
    /// its `r`-th repeat (the same samples again).
    #[must_use]
    pub fn repeat(&self) -> u8 {
        self.bytes.get(9).copied().unwrap_or(0)
    }

    /// The sender's count, modulo 2³², of the receiver's samples it saw
    /// lost on the way: taken from a copy or from a repeat, or lost (see
    /// `docs/wire.md` §3.5). A receiver that sees it grow repeats its own
    /// datagrams for a while.
    #[must_use]
    pub fn missed(&self) -> u32 {
        bytes_at(self.bytes, 12).map_or(0, u32::from_le_bytes)
    }

    /// Values per sample (0: probes).
    #[must_use]
    pub fn width(&self) -> usize {
        usize::from(bytes_at(self.bytes, 10).map_or(0, u16::from_le_bytes))
    }

    /// The newest sample's values.
    #[must_use]
    pub fn newest(&self) -> Channels<'a> {
        let end = BUNDLE_FIXED_LEN + 8 * self.width();
        Channels::from_checked(self.bytes.get(BUNDLE_FIXED_LEN..end).unwrap_or_default())
    }

    /// The samples, newest first; the newest's fields are the frame
    /// header's, so its `seq`, `sent_at` and `released` here are read from
    /// the first older sample's place only for the older ones: use
    /// [`Frame::header`](super::Frame::header) for the newest.
    pub(super) fn samples(&self) -> Samples<'a> {
        Samples {
            bytes: self.bytes,
            width: self.width(),
            index: 0,
            count: self.count(),
        }
    }

    /// The older samples, newest first.
    pub fn older(&self) -> impl Iterator<Item = Older<'a>> + use<'a> {
        self.samples().skip(1)
    }
}

impl fmt::Debug for Bundle<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Bundle")
            .field("session", &super::Secret(self.session()))
            .field("repeat", &self.repeat())
            .field("missed", &self.missed())
            .field("newest", &self.newest())
            .field(
                "older",
                &self.older().collect::<heapless::Vec<_, MAX_BUNDLE>>(),
            )
            .finish()
    }
}

/// One older sample of a [`Bundle`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Older<'a> {
    /// Its sequence number.
    pub seq: u64,
    /// Its send stamp.
    pub sent_at: Instant,
    /// What it answers (the sender's newest release when it was set).
    pub released: Option<u64>,
    /// Its values.
    pub values: Channels<'a>,
}

/// The samples of a checked bundle; the newest's fields are zero here.
pub(super) struct Samples<'a> {
    bytes: &'a [u8],
    width: usize,
    index: usize,
    count: usize,
}

impl<'a> Iterator for Samples<'a> {
    type Item = Older<'a>;

    fn next(&mut self) -> Option<Older<'a>> {
        if self.index >= self.count {
            return None;
        }
        let values = 8 * self.width;
        let (fields, at) = match self.index {
            0 => (None, BUNDLE_FIXED_LEN),
            i => {
                let at = BUNDLE_FIXED_LEN + values + (i - 1) * (OLDER_FIELDS_LEN + values);
                (Some(at), at + OLDER_FIELDS_LEN)
            }
        };
        self.index += 1;
        let u64_at = |at: usize| bytes_at(self.bytes, at).map_or(0, u64::from_le_bytes);
        let (seq, sent_at, released) = match fields {
            None => (u64::MAX, 0, NONE),
            Some(f) => (u64_at(f), u64_at(f + 8), u64_at(f + 16)),
        };
        Some(Older {
            seq,
            sent_at: Instant::from_nanos(sent_at),
            released: (released != NONE).then_some(released),
            values: Channels::from_checked(self.bytes.get(at..at + values).unwrap_or_default()),
        })
    }
}

/// An older sample to send in a Bundle ([`Message::Bundle`](super::Message::Bundle)).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OlderSample<'a> {
    /// Its sequence number.
    pub seq: u64,
    /// Its send stamp.
    pub sent_at: Instant,
    /// What it answers.
    pub released: Option<u64>,
    /// Its values: as many as the newest sample's.
    pub values: &'a [f64],
}

/// The fixed fields of a Bundle, as [`write`] takes them.
pub(super) struct Fixed {
    pub(super) session: u64,
    pub(super) repeat: u8,
    pub(super) missed: u32,
}

/// Writes a Bundle payload into `payload` (exactly its length).
pub(super) fn write(
    payload: &mut [u8],
    fixed: &Fixed,
    newest: &[f64],
    older: &[OlderSample<'_>],
) -> Result<(), WireError> {
    let width = newest.len();
    let count = older.len() + 1;
    let mut flat = 0;
    for (i, values) in core::iter::once(newest)
        .chain(older.iter().map(|o| o.values))
        .enumerate()
    {
        if values.len() != width {
            return Err(WireError::BundleWidth {
                index: i,
                len: values.len(),
                width,
            });
        }
        if let Some(k) = values.iter().position(|v| !v.is_finite()) {
            return Err(WireError::NonFinite { index: flat + k });
        }
        flat += width;
    }
    put(payload, 0, fixed.session.to_le_bytes());
    // count <= MAX_BUNDLE and width <= MAX_CHANNELS: checked by the caller.
    put(payload, 8, [count as u8, fixed.repeat]);
    put(payload, 10, (width as u16).to_le_bytes());
    put(payload, 12, fixed.missed.to_le_bytes());
    let mut at = put_values(payload, BUNDLE_FIXED_LEN, newest);
    for o in older {
        put(payload, at, o.seq.to_le_bytes());
        put(payload, at + 8, o.sent_at.as_nanos().to_le_bytes());
        put(payload, at + 16, o.released.unwrap_or(NONE).to_le_bytes());
        at = put_values(payload, at + OLDER_FIELDS_LEN, o.values);
    }
    Ok(())
}

/// Writes `values` at `at`; returns the offset after them.
fn put_values(payload: &mut [u8], mut at: usize, values: &[f64]) -> usize {
    for v in values {
        put(payload, at, v.to_le_bytes());
        at += 8;
    }
    at
}

/// What [`encode`](super::encode) checks of a Bundle before writing it:
/// its count, its width, that no `released` is the wire's "none" and that
/// the older samples' `seq` go down from the header's.
pub(super) fn check_message(
    seq: u64,
    newest: &[f64],
    older: &[OlderSample<'_>],
) -> Result<(), WireError> {
    if older.len() + 1 > MAX_BUNDLE {
        return Err(WireError::BadBundleCount(older.len() + 1));
    }
    if newest.len() > super::MAX_CHANNELS {
        return Err(WireError::TooManyChannels(newest.len()));
    }
    let mut above = seq;
    for (i, o) in older.iter().enumerate() {
        if o.released == Some(NONE) {
            return Err(WireError::SentinelValue {
                offset: super::field::RELEASED,
            });
        }
        if o.seq >= above {
            return Err(WireError::BundleOrder { index: i + 1 });
        }
        above = o.seq;
    }
    Ok(())
}
