//! The frame codec: ndr wire format version 5.
//!
//! A frame is a fixed 48-byte little-endian header followed by a payload whose
//! layout depends on its [`Kind`]. The byte-exact specification, with test
//! vectors, is `docs/wire.md`; this module is its reference implementation.
//!
//! - Decoding is total and allocation-free: [`Frame::new_checked`] validates
//!   everything once, after which every accessor is infallible.
//! - [`encode`] refuses anything [`Frame::new_checked`] would reject, so a NaN
//!   command never leaves this host.
//! - On a stream (TCP), [`frame_len`] bounds the 4-byte length prefix before
//!   anything is buffered.
//! - After a rejected frame the stream cannot be trusted: send a [`Close`]
//!   with the error's close reason and hang up.
//!
//! ```
//! use ndr_core::time::Instant;
//! use ndr_core::wire::{self, Frame, Header, MAX_FRAME_LEN, Message, Payload};
//!
//! let header = Header { seq: 7, sent_at: Instant::from_millis(1400), echo: None, released: None, term: 0 };
//! let mut buf = [0u8; MAX_FRAME_LEN];
//! let n = wire::encode(&header, &Message::Data(&[0.5, -1.0]), &mut buf)?;
//!
//! // The receiver reads the 4-byte prefix, then the rest of the frame.
//! assert_eq!(wire::frame_len(&buf[..4])?, Some(n));
//! let frame = Frame::new_checked(&buf[..n])?;
//! assert_eq!(frame.header(), header);
//! let Payload::Data(channels) = frame.payload() else { unreachable!() };
//! let mut sample = [0.0; 2];
//! channels.copy_to(&mut sample)?;
//! assert_eq!(sample, [0.5, -1.0]);
//! # Ok::<(), wire::WireError>(())
//! ```

mod bundle;
mod codes;
mod error;
mod payload;
#[cfg(test)]
mod tests;

use core::fmt;

pub use bundle::{BUNDLE_FIXED_LEN, Bundle, MAX_BUNDLE, MAX_DATAGRAM_LEN, Older, OlderSample};
pub(crate) use bundle::{OLDER_FIELDS_LEN, bundle_payload_len};
pub use codes::{CloseReason, ControlOp, ModeCode, UnderflowCode};
pub use error::WireError;
pub use payload::{
    Applied, Channels, ChannelsIter, Close, Control, Hello, Payload, RegulationName, Role, Seat,
    Token,
};

use crate::time::{Duration, Instant};

/// The wire version this build speaks.
pub const VERSION: u8 = 5;
/// Size of the fixed header, in bytes.
pub const HEADER_LEN: usize = 48;
/// Most channels a Data frame carries.
pub const MAX_CHANNELS: usize = 256;
/// Largest valid frame, in bytes (an Applied frame with [`MAX_CHANNELS`]
/// values); a buffer this size can hold any frame.
pub const MAX_FRAME_LEN: usize = HEADER_LEN + Applied::FIXED_LEN + 8 * MAX_CHANNELS;
/// Size of the length prefix a stream reader needs before calling [`frame_len`].
pub const PREFIX_LEN: usize = 4;

/// Wire value of `echo` and `released` meaning "none yet".
const NONE: u64 = u64::MAX;

/// A session token as `Debug` shows it: whether it is set, never its
/// value, which is a bearer secret of the datagram path and must not reach
/// a log.
struct Secret(u64);

impl fmt::Debug for Secret {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(if self.0 == 0 { "0" } else { "<token>" })
    }
}

/// Header field offsets (widths follow from the types read there).
mod field {
    pub(super) const LENGTH: usize = 0;
    pub(super) const VERSION: usize = 4;
    pub(super) const KIND: usize = 5;
    pub(super) const TERM: usize = 6;
    pub(super) const SEQ: usize = 8;
    pub(super) const SENT_AT: usize = 16;
    pub(super) const ECHO: usize = 24;
    pub(super) const ECHO_HOLD: usize = 32;
    pub(super) const RELEASED: usize = 40;
}

/// `N` bytes at `at`, `None` past the end. With constant offsets into a
/// buffer of known length the check folds away.
#[inline(always)]
fn bytes_at<const N: usize>(buf: &[u8], at: usize) -> Option<[u8; N]> {
    buf.get(at..)?.first_chunk::<N>().copied()
}

/// Little-endian `u64` at `at`; the 0 fallback is unreachable where it is
/// used (on buffers already checked to hold the whole header).
#[inline(always)]
fn u64_at(buf: &[u8], at: usize) -> u64 {
    bytes_at(buf, at).map_or(0, u64::from_le_bytes)
}

/// Writes `bytes` at `at`; callers size the buffer first, so nothing is skipped.
#[inline(always)]
fn put<const N: usize>(buf: &mut [u8], at: usize, bytes: [u8; N]) {
    if let Some(dst) = buf.get_mut(at..).and_then(<[u8]>::first_chunk_mut::<N>) {
        *dst = bytes;
    }
}

/// What a frame carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Kind {
    /// One sample: channel values.
    Data = 1,
    /// Handshake.
    Hello = 2,
    /// Pause / resume negotiation.
    Control = 3,
    /// Goodbye.
    Close = 4,
    /// A datagram's samples (the newest and those before it).
    Bundle = 5,
    /// A new session token for the datagrams to the sender (reliable path).
    Token = 6,
    /// A command the robot applied, to an observer.
    Applied = 7,
}

impl Kind {
    /// The exact payload size of this kind, `None` for Data, Bundle and
    /// Applied (they follow their values) and Hello (its regulation's name).
    #[must_use]
    pub(crate) const fn fixed_payload_len(self) -> Option<usize> {
        match self {
            Kind::Data | Kind::Bundle | Kind::Applied | Kind::Hello => None,
            Kind::Control => Some(Control::LEN),
            Kind::Close => Some(Close::LEN),
            Kind::Token => Some(Token::LEN),
        }
    }
}

impl TryFrom<u8> for Kind {
    type Error = WireError;
    fn try_from(code: u8) -> Result<Kind, WireError> {
        match code {
            1 => Ok(Kind::Data),
            2 => Ok(Kind::Hello),
            3 => Ok(Kind::Control),
            4 => Ok(Kind::Close),
            5 => Ok(Kind::Bundle),
            6 => Ok(Kind::Token),
            7 => Ok(Kind::Applied),
            _ => Err(WireError::UnknownKind(code)),
        }
    }
}

impl From<Kind> for u8 {
    fn from(kind: Kind) -> u8 {
        kind as u8
    }
}

/// The echo of the newest frame received from the peer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Echo {
    /// That frame's `sent_at`, on the peer's clock.
    pub sent_at: Instant,
    /// Time between that frame's arrival and the sending of this one, so the
    /// peer can take the dwell time out of its round-trip measurement.
    pub hold: Duration,
}

/// The header fields that are not implied by the payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Header {
    /// The sender's sequence number of this frame.
    pub seq: u64,
    /// The sender's clock at sending.
    pub sent_at: Instant,
    /// The newest frame received from the peer, `None` before the first one.
    /// Its `sent_at` must not be `u64::MAX` ns (the wire's "none").
    pub echo: Option<Echo>,
    /// `seq` of the newest peer Data frame the sender's regulator released to
    /// its application, `None` before the first; must not be `u64::MAX`.
    pub released: Option<u64>,
    /// The control term the sender is in: on a controller's Data frames,
    /// the term its commands belong to; on the remote's frames, the term the
    /// robot is in now; `0` before any term (see `docs/wire.md` §3.8).
    pub term: u16,
}

impl Header {
    /// A header that echoes nothing and names no release: a sender's first
    /// frames (its Hello), or a frame written by hand.
    #[must_use]
    pub const fn new(seq: u64, sent_at: Instant) -> Header {
        Header {
            seq,
            sent_at,
            echo: None,
            released: None,
            term: 0,
        }
    }
}

/// Whether `bytes` (a whole frame, not yet checked) is a Bundle: what a
/// driver of the datagram transport sends as a datagram, and hands to
/// [`Endpoint::handle_datagram`](crate::endpoint::Endpoint::handle_datagram)
/// when it receives one. Every other frame takes the reliable path.
#[must_use]
pub fn is_bundle(bytes: &[u8]) -> bool {
    bytes.get(field::KIND) == Some(&(Kind::Bundle as u8))
}

/// Total length of the frame starting at `prefix`, from its 4-byte length field.
///
/// Returns `Ok(None)` while fewer than [`PREFIX_LEN`] bytes are available.
/// The length is bounded before the caller buffers anything.
///
/// # Errors
/// [`WireError::LengthOutOfRange`] if the field is below [`HEADER_LEN`] or
/// above [`MAX_FRAME_LEN`]: the stream is not (or no longer) ndr frames.
pub fn frame_len(prefix: &[u8]) -> Result<Option<usize>, WireError> {
    let Some(field) = prefix.first_chunk::<PREFIX_LEN>() else {
        return Ok(None);
    };
    let len = u32::from_le_bytes(*field);
    match usize::try_from(len) {
        Ok(n) if (HEADER_LEN..=MAX_FRAME_LEN).contains(&n) => Ok(Some(n)),
        _ => Err(WireError::LengthOutOfRange(len)),
    }
}

/// Validates one whole frame; returns its kind.
fn check(buf: &[u8]) -> Result<Kind, WireError> {
    let got = buf.len();
    let field = buf
        .first_chunk::<PREFIX_LEN>()
        .map(|f| u32::from_le_bytes(*f))
        .ok_or(WireError::Truncated {
            needed: PREFIX_LEN,
            got,
        })?;
    // A Bundle (a datagram) may be longer than any frame of a stream.
    let longest = match buf.get(field::KIND) {
        Some(&k) if k == Kind::Bundle as u8 => MAX_DATAGRAM_LEN,
        _ => MAX_FRAME_LEN,
    };
    let len = match usize::try_from(field) {
        Ok(n) if (HEADER_LEN..=longest).contains(&n) => n,
        _ => return Err(WireError::LengthOutOfRange(field)),
    };
    if got > len {
        return Err(WireError::LengthMismatch {
            field: len,
            actual: got,
        });
    }
    let (head, payload) = buf
        .split_first_chunk::<HEADER_LEN>()
        .filter(|_| got == len)
        .ok_or(WireError::Truncated { needed: len, got })?;
    let [_, _, _, _, version, kind, ..] = *head;
    if version != VERSION {
        return Err(WireError::UnsupportedVersion(version));
    }
    let kind = Kind::try_from(kind)?;
    if u64_at(head, field::ECHO) == NONE && u64_at(head, field::ECHO_HOLD) != 0 {
        return Err(WireError::HoldWithoutEcho);
    }
    match kind {
        Kind::Data => Channels::check(payload).map(drop),
        Kind::Bundle => Bundle::check(payload, u64_at(head, field::SEQ)).map(drop),
        Kind::Hello => Hello::parse(payload).map(drop),
        Kind::Control => Control::parse(payload).map(drop),
        Kind::Close => Close::parse(payload).map(drop),
        Kind::Token => Token::parse(payload).map(drop),
        Kind::Applied => Applied::check(payload).map(drop),
    }?;
    Ok(kind)
}

/// A checked view of one frame, in the style of smoltcp's `Packet`: the
/// buffer is validated once by [`new_checked`](Frame::new_checked), then read
/// in place.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Frame<T: AsRef<[u8]>> {
    buffer: T,
    kind: Kind,
}

impl<T: AsRef<[u8]>> Frame<T> {
    /// Validates `buffer`, which must hold exactly one frame, against every
    /// rule of the spec (length, version, kind, flags, echo, payload size,
    /// reserved bytes, codes, finiteness).
    ///
    /// # Errors
    /// The first rule broken, as a [`WireError`].
    pub fn new_checked(buffer: T) -> Result<Self, WireError> {
        let kind = check(buffer.as_ref())?;
        Ok(Frame { buffer, kind })
    }

    #[cfg(test)]
    /// Gives the buffer back.
    #[must_use]
    pub(crate) fn into_inner(self) -> T {
        self.buffer
    }

    /// The bytes of the frame.
    #[must_use]
    pub fn as_bytes(&self) -> &[u8] {
        self.buffer.as_ref()
    }

    /// What the frame carries.
    #[must_use]
    pub fn kind(&self) -> Kind {
        self.kind
    }

    /// The sender's sequence number of this frame.
    #[must_use]
    pub fn seq(&self) -> u64 {
        u64_at(self.as_bytes(), field::SEQ)
    }

    /// The sender's clock at sending.
    #[must_use]
    pub fn sent_at(&self) -> Instant {
        Instant::from_nanos(u64_at(self.as_bytes(), field::SENT_AT))
    }

    /// The newest frame the sender had received from us, `None` before the first.
    #[must_use]
    pub fn echo(&self) -> Option<Echo> {
        let buf = self.as_bytes();
        match u64_at(buf, field::ECHO) {
            NONE => None,
            sent_at => Some(Echo {
                sent_at: Instant::from_nanos(sent_at),
                hold: Duration::from_nanos(u64_at(buf, field::ECHO_HOLD)),
            }),
        }
    }

    /// `seq` of the newest of our Data frames the sender has released to its
    /// application, `None` before the first.
    #[must_use]
    pub fn released(&self) -> Option<u64> {
        match u64_at(self.as_bytes(), field::RELEASED) {
            NONE => None,
            seq => Some(seq),
        }
    }

    /// The control term the sender is in (`0` before any).
    #[must_use]
    pub fn term(&self) -> u16 {
        bytes_at(self.as_bytes(), field::TERM).map_or(0, u16::from_le_bytes)
    }

    /// All header fields.
    #[must_use]
    pub fn header(&self) -> Header {
        Header {
            seq: self.seq(),
            sent_at: self.sent_at(),
            echo: self.echo(),
            released: self.released(),
            term: self.term(),
        }
    }

    /// The decoded payload.
    #[must_use]
    pub fn payload(&self) -> Payload<'_> {
        let bytes = self.as_bytes().get(HEADER_LEN..).unwrap_or_default();
        // Re-parsing cannot fail on a checked buffer, unless an odd `AsRef`
        // hands out different bytes now: that is a protocol error, not a panic.
        let broken = Payload::Close(Close {
            reason: CloseReason::ProtocolError,
        });
        match self.kind {
            Kind::Data => Payload::Data(Channels::from_checked(bytes)),
            Kind::Bundle => Payload::Bundle(Bundle::from_checked(bytes)),
            Kind::Hello => Hello::parse(bytes).map_or(broken, Payload::Hello),
            Kind::Control => Control::parse(bytes).map_or(broken, Payload::Control),
            Kind::Close => Close::parse(bytes).map_or(broken, Payload::Close),
            Kind::Token => Token::parse(bytes).map_or(broken, Payload::Token),
            Kind::Applied => Applied::check(bytes).map_or(broken, Payload::Applied),
        }
    }
}

impl<T: AsRef<[u8]>> fmt::Debug for Frame<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Frame")
            .field("header", &self.header())
            .field("payload", &self.payload())
            .finish()
    }
}

/// What to send: the payload side of [`encode`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Message<'a> {
    /// One sample: at most [`MAX_CHANNELS`] finite values.
    Data(&'a [f64]),
    /// A datagram's samples: the newest (the header's `seq`, `sent_at`
    /// and `released` are its) and up to [`MAX_BUNDLE`] − 1 older ones,
    /// newest first, all of the newest's width.
    Bundle {
        /// The receiver's session token.
        session: u64,
        /// Which send of the newest sample this is: 0 the first, `r` its
        /// `r`-th repeat.
        repeat: u8,
        /// The sender's count, modulo 2³², of the receiver's samples it saw
        /// lost (see [`Bundle::missed`]).
        missed: u32,
        /// The newest sample's values.
        newest: &'a [f64],
        /// The older samples, newest first.
        older: &'a [OlderSample<'a>],
    },
    /// Handshake.
    Hello(Hello),
    /// Pause / resume negotiation.
    Control(Control),
    /// Goodbye.
    Close(Close),
    /// A new session token for the datagrams to the sender.
    Token(Token),
    /// A command the robot applied, to an observer: the command's `seq`
    /// on its controller's link, its send time and the time it was applied
    /// (both on the remote's clock), its values (at most [`MAX_CHANNELS`],
    /// finite).
    Applied {
        /// The command's `seq`.
        seq: u64,
        /// When its controller sent it, on the remote's clock.
        sent_at: Instant,
        /// When the robot applied it, on the remote's clock.
        applied_at: Instant,
        /// The command.
        values: &'a [f64],
    },
}

impl Message<'_> {
    /// The frame kind carrying this message.
    #[must_use]
    pub const fn kind(&self) -> Kind {
        match self {
            Message::Data(_) => Kind::Data,
            Message::Bundle { .. } => Kind::Bundle,
            Message::Hello(_) => Kind::Hello,
            Message::Control(_) => Kind::Control,
            Message::Close(_) => Kind::Close,
            Message::Token(_) => Kind::Token,
            Message::Applied { .. } => Kind::Applied,
        }
    }
}

/// Size in bytes of the frame carrying `msg` (for a Data message with more
/// than [`MAX_CHANNELS`] values, larger than [`MAX_FRAME_LEN`]: [`encode`]
/// refuses it).
#[must_use]
pub(crate) const fn encoded_len(msg: &Message<'_>) -> usize {
    let payload = match msg {
        Message::Data(values) => values.len().saturating_mul(8),
        Message::Bundle { newest, older, .. } => {
            bundle_payload_len(older.len().saturating_add(1), newest.len())
        }
        Message::Hello(hello) => hello.payload_len(),
        Message::Control(_) => Control::LEN,
        Message::Close(_) => Close::LEN,
        Message::Token(_) => Token::LEN,
        Message::Applied { values, .. } => {
            Applied::FIXED_LEN.saturating_add(values.len().saturating_mul(8))
        }
    };
    HEADER_LEN.saturating_add(payload)
}

/// Writes the frame for `header` and `msg` to the front of `buf` and returns
/// its length. A buffer of [`MAX_FRAME_LEN`] bytes always suffices.
///
/// # Errors
/// Checked in this order: [`TooManyChannels`](WireError::TooManyChannels),
/// [`SentinelValue`](WireError::SentinelValue) (echo or released equal to
/// `u64::MAX`), [`BufferTooSmall`](WireError::BufferTooSmall), then the
/// payload: [`NonFinite`](WireError::NonFinite),
/// [`ZeroPeriod`](WireError::ZeroPeriod) (Hello),
/// [`ZeroControlOp`](WireError::ZeroControlOp),
/// [`ZeroToken`](WireError::ZeroToken). On error the contents of
/// `buf` are unspecified.
pub fn encode(header: &Header, msg: &Message<'_>, buf: &mut [u8]) -> Result<usize, WireError> {
    if let Message::Data(values) | Message::Applied { values, .. } = msg
        && values.len() > MAX_CHANNELS
    {
        return Err(WireError::TooManyChannels(values.len()));
    }
    if let Message::Bundle { newest, older, .. } = msg {
        bundle::check_message(header.seq, newest, older)?;
    }
    let (echo, hold) = match header.echo {
        None => (NONE, 0),
        Some(Echo { sent_at, .. }) if sent_at.as_nanos() == NONE => {
            return Err(WireError::SentinelValue {
                offset: field::ECHO,
            });
        }
        Some(Echo { sent_at, hold }) => (sent_at.as_nanos(), hold.as_nanos()),
    };
    let released = match header.released {
        None => NONE,
        Some(NONE) => {
            return Err(WireError::SentinelValue {
                offset: field::RELEASED,
            });
        }
        Some(seq) => seq,
    };
    let len = encoded_len(msg);
    let got = buf.len();
    let (head, payload) = buf
        .get_mut(..len)
        .and_then(<[u8]>::split_first_chunk_mut::<HEADER_LEN>)
        .ok_or(WireError::BufferTooSmall { needed: len, got })?;
    match *msg {
        Message::Data(values) => {
            // Check first, then copy: two tight loops beat one with an early exit.
            if let Some(index) = values.iter().position(|v| !v.is_finite()) {
                return Err(WireError::NonFinite { index });
            }
            for (dst, v) in payload.chunks_exact_mut(8).zip(values) {
                put(dst, 0, v.to_le_bytes());
            }
        }
        Message::Bundle {
            session,
            repeat,
            missed,
            newest,
            older,
        } => {
            let fixed = bundle::Fixed {
                session,
                repeat,
                missed,
            };
            bundle::write(payload, &fixed, newest, older)?;
        }
        Message::Hello(hello) => hello.write(payload)?,
        Message::Control(control) => put(payload, 0, control.to_bytes()?),
        Message::Close(close) => put(payload, 0, close.to_bytes()),
        Message::Token(token) => put(payload, 0, token.to_bytes()?),
        Message::Applied {
            seq,
            sent_at,
            applied_at,
            values,
        } => {
            if let Some(index) = values.iter().position(|v| !v.is_finite()) {
                return Err(WireError::NonFinite { index });
            }
            put(payload, 0, seq.to_le_bytes());
            put(payload, 8, sent_at.as_nanos().to_le_bytes());
            put(payload, 16, applied_at.as_nanos().to_le_bytes());
            let rest = payload.get_mut(Applied::FIXED_LEN..).unwrap_or_default();
            for (dst, v) in rest.chunks_exact_mut(8).zip(values) {
                put(dst, 0, v.to_le_bytes());
            }
        }
    }
    // len <= MAX_DATAGRAM_LEN here, so the cast is lossless.
    put(head, field::LENGTH, (len as u32).to_le_bytes());
    put(head, field::VERSION, [VERSION]);
    put(head, field::KIND, [msg.kind() as u8]);
    put(head, field::TERM, header.term.to_le_bytes());
    put(head, field::SEQ, header.seq.to_le_bytes());
    put(
        head,
        field::SENT_AT,
        header.sent_at.as_nanos().to_le_bytes(),
    );
    put(head, field::ECHO, echo.to_le_bytes());
    put(head, field::ECHO_HOLD, hold.to_le_bytes());
    put(head, field::RELEASED, released.to_le_bytes());
    Ok(len)
}
