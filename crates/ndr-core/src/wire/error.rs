//! The one error type of the codec.

use core::fmt;

use super::{CloseReason, HEADER_LEN, Kind, MAX_CHANNELS, MAX_FRAME_LEN, VERSION, field};

/// Why a byte string is not a valid frame, or why a frame cannot be encoded.
///
/// Every variant is a distinct rule of `docs/wire.md`; offsets are counted
/// from the first byte of the frame (the length prefix).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum WireError {
    /// Fewer bytes than the frame needs: `needed` in all, `got` available.
    Truncated {
        /// Bytes the frame needs.
        needed: usize,
        /// Bytes available.
        got: usize,
    },
    /// The length field is below [`HEADER_LEN`] or above [`MAX_FRAME_LEN`]
    /// ([`MAX_DATAGRAM_LEN`](super::MAX_DATAGRAM_LEN) for a Bundle).
    LengthOutOfRange(u32),
    /// The buffer holds more bytes than the length field announces.
    LengthMismatch {
        /// Frame length announced by the length field.
        field: usize,
        /// Bytes in the buffer.
        actual: usize,
    },
    /// The version byte is not [`VERSION`].
    UnsupportedVersion(u8),
    /// The kind byte names no known frame kind.
    UnknownKind(u8),
    /// The seat byte of a Hello is not 0 (control), 1 (observe) or 2
    /// (control, waiting as an observer while another base holds it).
    BadSeat(u8),
    /// A reserved byte (at `offset` in the frame) is not zero.
    ReservedNotZero {
        /// Offset of the first non-zero reserved byte.
        offset: usize,
    },
    /// The payload size does not fit the frame kind.
    BadPayloadLength {
        /// Kind of the frame.
        kind: Kind,
        /// Payload size in bytes.
        len: usize,
    },
    /// More than [`MAX_CHANNELS`] values in a Data message.
    TooManyChannels(usize),
    /// Channel `index` is NaN or infinite.
    NonFinite {
        /// Index of the first offending channel.
        index: usize,
    },
    /// The role byte of a Hello is neither 0 (base) nor 1 (remote).
    BadRole(u8),
    /// A Hello announces a zero period.
    ZeroPeriod,
    /// A Bundle's count is 0 or above [`MAX_BUNDLE`](super::MAX_BUNDLE).
    BadBundleCount(usize),
    /// A Bundle's sample `index` (1: the first older one) does not come
    /// before the one ahead of it (its `seq` is not lower).
    BundleOrder {
        /// The sample's place, newest first.
        index: usize,
    },
    /// A Bundle to encode whose sample `index` has `len` values, not the
    /// newest's `width`.
    BundleWidth {
        /// The sample's place, newest first.
        index: usize,
        /// Its values.
        len: usize,
        /// The newest sample's.
        width: usize,
    },
    /// A Hello announces a sample width of 0 or above [`MAX_CHANNELS`]
    /// (field at `offset`: 52 command, 54 state).
    WidthOutOfRange {
        /// The width announced.
        width: u16,
        /// Offset of the field in the frame.
        offset: usize,
    },
    /// A Hello's regulation name holds a byte that is not printable ASCII
    /// (at `offset` in the frame).
    BadRegulationName {
        /// Offset of the first such byte.
        offset: usize,
    },
    /// A Control frame has op code 0.
    ZeroControlOp,
    /// A Token frame carries the token 0 (a stream's "no datagrams").
    ZeroToken,
    /// `echo_hold` is non-zero although `echo` says nothing was received yet.
    HoldWithoutEcho,
    /// A header value equals `u64::MAX`, which the wire reserves for "none"
    /// (field at `offset`: 24 echo, 40 released).
    SentinelValue {
        /// Offset of the field in the header.
        offset: usize,
    },
    /// The output buffer of [`encode`](super::encode) is too small.
    BufferTooSmall {
        /// Bytes the frame needs.
        needed: usize,
        /// Bytes in the buffer.
        got: usize,
    },
    /// The destination of [`Channels::copy_to`](super::Channels::copy_to) is too short.
    DestinationTooSmall {
        /// Channels in the frame.
        needed: usize,
        /// Slots in the destination.
        got: usize,
    },
}

impl WireError {
    /// The [`CloseReason`] a peer should send before hanging up on a frame
    /// that failed with this error.
    #[must_use]
    pub(crate) const fn close_reason(&self) -> CloseReason {
        match self {
            WireError::UnsupportedVersion(_) => CloseReason::VersionMismatch,
            _ => CloseReason::ProtocolError,
        }
    }
}

impl fmt::Display for WireError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            WireError::Truncated { needed, got } => write!(
                f,
                "truncated frame: {got} bytes, the frame needs {needed}; read the rest from the stream before decoding"
            ),
            WireError::LengthOutOfRange(len) if looks_like_tls(len) => write!(
                f,
                "these bytes start a TLS record, not an ndr frame: the peer speaks TLS, \
                 configure TLS on this side too (read as a frame, their length field is {len}, \
                 valid is {HEADER_LEN}..={MAX_FRAME_LEN})"
            ),
            WireError::LengthOutOfRange(len) => write!(
                f,
                "frame length field is {len}, valid is {HEADER_LEN}..={MAX_FRAME_LEN}; the stream is corrupt or not ndr, close the connection"
            ),
            WireError::LengthMismatch { field, actual } => write!(
                f,
                "frame length field says {field} bytes but the buffer holds {actual}; pass exactly one frame (split the stream with frame_len)"
            ),
            WireError::UnsupportedVersion(v) => write!(
                f,
                "peer speaks ndr wire version {v}, this build speaks {VERSION}; upgrade the older side (version 5 came with the regulation's name in the Hello, version 4 with observers and control terms)"
            ),
            WireError::UnknownKind(k) => write!(
                f,
                "unknown frame kind {k} (known: 1 Data, 2 Hello, 3 Control, 4 Close, 5 Bundle, 6 Token, 7 Applied)"
            ),
            WireError::BadSeat(seat) => write!(
                f,
                "Hello seat {seat} is not 0 (control), 1 (observe) or 2 (wait for control)"
            ),
            WireError::ReservedNotZero { offset } => {
                write!(f, "reserved byte at offset {offset} is not zero")
            }
            WireError::BadPayloadLength { kind, len } => match kind {
                Kind::Data => write!(
                    f,
                    "Data payload is {len} bytes, not a multiple of 8 (one f64 per channel)"
                ),
                Kind::Applied => write!(
                    f,
                    "Applied payload is {len} bytes; it must be 24 (seq, sent_at, applied_at) \
                     and a multiple of 8 (one f64 per channel)"
                ),
                Kind::Hello => write!(
                    f,
                    "Hello payload is {len} bytes; it must be {} to {} ({} fixed, then the \
                     regulation's name, at most {} bytes)",
                    super::Hello::LEN,
                    super::Hello::MAX_LEN,
                    super::Hello::LEN,
                    super::RegulationName::MAX_LEN
                ),
                _ => write!(
                    f,
                    "{kind:?} payload is {len} bytes, it must be exactly {}",
                    kind.fixed_payload_len().unwrap_or(0)
                ),
            },
            WireError::TooManyChannels(n) => write!(
                f,
                "{n} channels, a frame carries at most {MAX_CHANNELS}; split the sample"
            ),
            WireError::NonFinite { index } => write!(
                f,
                "channel {index} is NaN or infinite; only finite values may cross the link"
            ),
            WireError::BadRole(r) => {
                write!(f, "Hello role {r} is neither 0 (base) nor 1 (remote)")
            }
            WireError::ZeroPeriod => write!(f, "Hello period is zero; it must be positive"),
            WireError::BadBundleCount(n) => write!(
                f,
                "a Bundle of {n} samples; it carries 1 to {}",
                super::MAX_BUNDLE
            ),
            WireError::BundleOrder { index } => write!(
                f,
                "a Bundle's sample {index} is not older than the one before it (its seq is \
                 not lower); the samples go newest first"
            ),
            WireError::BundleWidth { index, len, width } => write!(
                f,
                "a Bundle's sample {index} has {len} values, the newest {width}; every sample \
                 of a bundle has the link's width"
            ),
            WireError::WidthOutOfRange { width, offset } => write!(
                f,
                "Hello {} width is {width}; a sample carries 1 to {MAX_CHANNELS} values",
                if offset == HEADER_LEN + 4 {
                    "command"
                } else {
                    "state"
                }
            ),
            WireError::BadRegulationName { offset } => write!(
                f,
                "Hello regulation name has a byte at offset {offset} that is not printable \
                 ASCII (0x20 to 0x7e)"
            ),
            WireError::ZeroControlOp => write!(f, "Control op code 0 is invalid"),
            WireError::ZeroToken => write!(
                f,
                "Token frame carries the token 0; a session token is never 0"
            ),
            WireError::HoldWithoutEcho => write!(
                f,
                "echo_hold is non-zero but echo says nothing was received yet (u64::MAX)"
            ),
            WireError::SentinelValue { offset } => write!(
                f,
                "{} is u64::MAX, which the wire reserves for 'none'; use None instead",
                if offset == field::ECHO {
                    "echo sent_at"
                } else {
                    "released"
                }
            ),
            WireError::BufferTooSmall { needed, got } => write!(
                f,
                "output buffer is {got} bytes, the frame needs {needed}; pass a buffer of MAX_FRAME_LEN bytes"
            ),
            WireError::DestinationTooSmall { needed, got } => write!(
                f,
                "destination holds {got} values, the frame carries {needed} channels"
            ),
        }
    }
}

impl WireError {
    /// Whether the bytes refused start a TLS record (a TLS peer read by a
    /// plain side).
    #[must_use]
    pub(crate) fn starts_a_tls_record(&self) -> bool {
        matches!(*self, WireError::LengthOutOfRange(len) if looks_like_tls(len))
    }
}

impl core::error::Error for WireError {}

/// Whether a length field's bytes are a TLS record's header: a content type
/// (20–23), then version 3.x.
fn looks_like_tls(field: u32) -> bool {
    let [kind, major, minor, _] = field.to_le_bytes();
    (20..=23).contains(&kind) && major == 3 && minor <= 4
}
