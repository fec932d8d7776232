//! Payloads: the decoded views of what follows the header, and the small
//! fixed-size messages with their known codes.

use core::fmt;
use core::iter::FusedIterator;
use core::slice::ChunksExact;

use super::{
    CloseReason, ControlOp, HEADER_LEN, Kind, MAX_CHANNELS, ModeCode, UnderflowCode, WireError,
    bytes_at,
};
use crate::time::Duration;

/// The decoded payload of a valid [`Frame`](super::Frame).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Payload<'a> {
    /// Channel values of one sample.
    Data(Channels<'a>),
    /// A datagram's samples: the newest and those before it.
    Bundle(super::Bundle<'a>),
    /// Handshake.
    Hello(Hello),
    /// Pause / resume negotiation.
    Control(Control),
    /// Goodbye.
    Close(Close),
    /// A new session token for the datagrams to the sender.
    Token(Token),
    /// A command the robot applied, to an observer.
    Applied(Applied<'a>),
}

impl Payload<'_> {
    #[cfg(test)]
    /// The frame kind carrying this payload.
    #[must_use]
    pub(crate) const fn kind(&self) -> Kind {
        match self {
            Payload::Data(_) => Kind::Data,
            Payload::Bundle(_) => Kind::Bundle,
            Payload::Hello(_) => Kind::Hello,
            Payload::Control(_) => Kind::Control,
            Payload::Close(_) => Kind::Close,
            Payload::Token(_) => Kind::Token,
            Payload::Applied(_) => Kind::Applied,
        }
    }
}

/// Zero-copy view of the channel values of a Data frame (little-endian `f64`s,
/// all finite once the frame has been checked).
///
/// Equality is bitwise: `0.0` and `-0.0` differ, as they do on the wire.
#[derive(Clone, Copy, PartialEq, Eq, Default)]
pub struct Channels<'a> {
    bytes: &'a [u8],
}

impl<'a> Channels<'a> {
    /// Validates a Data payload: whole `f64`s, at most [`MAX_CHANNELS`], all finite.
    pub(super) fn check(bytes: &'a [u8]) -> Result<Self, WireError> {
        if !bytes.len().is_multiple_of(8) {
            return Err(WireError::BadPayloadLength {
                kind: Kind::Data,
                len: bytes.len(),
            });
        }
        let channels = Channels { bytes };
        if channels.len() > MAX_CHANNELS {
            return Err(WireError::TooManyChannels(channels.len()));
        }
        match channels.first_non_finite() {
            Some(index) => Err(WireError::NonFinite { index }),
            None => Ok(channels),
        }
    }

    /// The index of the first NaN or infinite value.
    pub(super) fn first_non_finite(&self) -> Option<usize> {
        // One pass on the raw bits: a non-finite f64 has all exponent bits set.
        const EXP: u64 = 0x7ff0_0000_0000_0000;
        self.bytes
            .chunks_exact(8)
            .position(|chunk| u64_of(chunk) & EXP == EXP)
    }

    /// A view over bytes already checked (a trailing partial value is ignored).
    pub(super) const fn from_checked(bytes: &'a [u8]) -> Self {
        Channels { bytes }
    }

    /// Number of channels.
    #[must_use]
    pub(crate) const fn len(&self) -> usize {
        self.bytes.len() / 8
    }

    /// Whether the frame carries no channel (a heartbeat).
    #[must_use]
    pub const fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Channel `i`, or `None` past the end.
    #[must_use]
    pub fn get(&self, i: usize) -> Option<f64> {
        bytes_at::<8>(self.bytes, i.checked_mul(8)?).map(f64::from_le_bytes)
    }

    /// The values in channel order.
    #[must_use]
    pub fn iter(&self) -> ChannelsIter<'a> {
        ChannelsIter {
            chunks: self.bytes.chunks_exact(8),
        }
    }

    /// Copies the values to the front of `dst` and returns how many there are.
    ///
    /// # Errors
    /// [`WireError::DestinationTooSmall`] if `dst` is shorter than the channel count;
    /// `dst` is then left untouched.
    pub fn copy_to(&self, dst: &mut [f64]) -> Result<usize, WireError> {
        let n = self.len();
        let got = dst.len();
        let dst = dst
            .get_mut(..n)
            .ok_or(WireError::DestinationTooSmall { needed: n, got })?;
        for (d, chunk) in dst.iter_mut().zip(self.bytes.chunks_exact(8)) {
            *d = f64::from_bits(u64_of(chunk));
        }
        Ok(n)
    }

    #[cfg(test)]
    /// The raw little-endian bytes of the values.
    #[must_use]
    pub(crate) const fn as_bytes(&self) -> &'a [u8] {
        self.bytes
    }
}

impl fmt::Debug for Channels<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

impl<'a> IntoIterator for Channels<'a> {
    type Item = f64;
    type IntoIter = ChannelsIter<'a>;
    fn into_iter(self) -> ChannelsIter<'a> {
        self.iter()
    }
}

impl<'a> IntoIterator for &Channels<'a> {
    type Item = f64;
    type IntoIter = ChannelsIter<'a>;
    fn into_iter(self) -> ChannelsIter<'a> {
        self.iter()
    }
}

/// Iterator over the values of [`Channels`].
#[derive(Debug, Clone)]
pub struct ChannelsIter<'a> {
    chunks: ChunksExact<'a, u8>,
}

impl Iterator for ChannelsIter<'_> {
    type Item = f64;

    fn next(&mut self) -> Option<f64> {
        self.chunks.next().map(|c| f64::from_bits(u64_of(c)))
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        self.chunks.size_hint()
    }

    fn nth(&mut self, n: usize) -> Option<f64> {
        self.chunks.nth(n).map(|c| f64::from_bits(u64_of(c)))
    }
}

impl DoubleEndedIterator for ChannelsIter<'_> {
    fn next_back(&mut self) -> Option<f64> {
        self.chunks.next_back().map(|c| f64::from_bits(u64_of(c)))
    }
}

impl ExactSizeIterator for ChannelsIter<'_> {}

impl FusedIterator for ChannelsIter<'_> {}

/// An 8-byte chunk as a little-endian `u64` (chunks come from `chunks_exact(8)`,
/// so the fallback never happens; it keeps the function panic-free).
#[inline(always)]
fn u64_of(chunk: &[u8]) -> u64 {
    chunk
        .first_chunk::<8>()
        .map_or(0, |b| u64::from_le_bytes(*b))
}

/// Fails with the offset (in the frame) of the first non-zero byte of a reserved field.
fn reserved_zero(bytes: &[u8], offset: usize) -> Result<(), WireError> {
    match bytes.iter().position(|&b| b != 0) {
        None => Ok(()),
        Some(i) => Err(WireError::ReservedNotZero { offset: offset + i }),
    }
}

/// The sender's side of the link, announced in [`Hello`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum Role {
    /// Operator and controller side.
    Base = 0,
    /// Robot side.
    Remote = 1,
}

impl Role {
    /// The role at the other end of the link.
    #[must_use]
    pub const fn peer(self) -> Role {
        match self {
            Role::Base => Role::Remote,
            Role::Remote => Role::Base,
        }
    }
}

impl TryFrom<u8> for Role {
    type Error = WireError;
    fn try_from(code: u8) -> Result<Role, WireError> {
        match code {
            0 => Ok(Role::Base),
            1 => Ok(Role::Remote),
            _ => Err(WireError::BadRole(code)),
        }
    }
}

impl From<Role> for u8 {
    fn from(role: Role) -> u8 {
        role as u8
    }
}

/// What a base asks for in its Hello, and what the remote's Hello gives it:
/// the seat it holds on the link.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
#[repr(u8)]
pub enum Seat {
    /// The base sends commands (asked: refused with Close `busy` while
    /// another base holds control). The remote's Hello says so when it
    /// grants control at once.
    #[default]
    Control = 0,
    /// The base watches: it receives states and the applied commands, and
    /// sends no command. The remote's Hello says so to every observer,
    /// a base waiting for control included.
    Observe = 1,
    /// Asked only by a base: control if free, else observe until control
    /// frees and is granted (Control op `grant`).
    WaitForControl = 2,
}

impl Seat {
    /// `"control"`, `"observe"` or `"wait_for_control"`.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Seat::Control => "control",
            Seat::Observe => "observe",
            Seat::WaitForControl => "wait_for_control",
        }
    }

    /// The seat a remote gives a base that asks for this one, offering
    /// `offer` (control while it is free, observe while another base holds
    /// it); `None`: refused, control being held.
    #[must_use]
    pub const fn given(self, offer: Seat) -> Option<Seat> {
        match (self, offer) {
            (Seat::Observe, _) => Some(Seat::Observe),
            (Seat::Control | Seat::WaitForControl, Seat::Control) => Some(Seat::Control),
            (Seat::WaitForControl, _) => Some(Seat::Observe),
            (Seat::Control, _) => None,
        }
    }
}

impl TryFrom<u8> for Seat {
    type Error = WireError;
    fn try_from(code: u8) -> Result<Seat, WireError> {
        match code {
            0 => Ok(Seat::Control),
            1 => Ok(Seat::Observe),
            2 => Ok(Seat::WaitForControl),
            _ => Err(WireError::BadSeat(code)),
        }
    }
}

/// The name of the sender's regulation (`adaptive`, `paper-static`,
/// `fixed:200`, …, as `--regulation` spells it), carried by its
/// [`Hello`] so that a peer that refuses it can say what it runs: the
/// Hello's mode code says only whether a side resizes its FIFO. Printable
/// ASCII, at most [`RegulationName::MAX_LEN`] bytes; empty when the sender
/// does not say.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct RegulationName {
    len: u8,
    bytes: [u8; RegulationName::MAX_LEN],
}

impl RegulationName {
    /// Most bytes a name takes on the wire.
    pub const MAX_LEN: usize = 32;

    /// No name: the sender does not say.
    pub const NONE: RegulationName = RegulationName {
        len: 0,
        bytes: [0; RegulationName::MAX_LEN],
    };

    /// `name` as the wire carries it.
    ///
    /// # Errors
    /// [`WireError::BadRegulationName`] for a byte that is not printable
    /// ASCII (its offset in a Hello frame), [`WireError::BadPayloadLength`]
    /// for a name longer than [`RegulationName::MAX_LEN`].
    pub fn new(name: &str) -> Result<RegulationName, WireError> {
        Self::from_wire(name.as_bytes())
    }

    /// The name `name` displays, made fit for the wire: a character that is
    /// not printable ASCII becomes `?`, and what passes
    /// [`RegulationName::MAX_LEN`] bytes is cut (an application's own
    /// playout may name itself anyhow).
    #[must_use]
    pub fn lossy(name: impl fmt::Display) -> RegulationName {
        let mut out = RegulationName::NONE;
        let _ = fmt::write(&mut out, format_args!("{name}"));
        out
    }

    /// The name; empty when the sender does not say.
    #[must_use]
    pub fn as_str(&self) -> &str {
        let bytes = self.bytes.get(..usize::from(self.len)).unwrap_or_default();
        // Printable ASCII by construction.
        core::str::from_utf8(bytes).unwrap_or_default()
    }

    /// Whether the sender does not say.
    #[must_use]
    pub const fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Its bytes on the wire.
    fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or_default()
    }

    fn from_wire(bytes: &[u8]) -> Result<RegulationName, WireError> {
        if bytes.len() > Self::MAX_LEN {
            return Err(WireError::BadPayloadLength {
                kind: Kind::Hello,
                len: Hello::LEN + bytes.len(),
            });
        }
        if let Some(i) = bytes.iter().position(|b| !printable(*b)) {
            return Err(WireError::BadRegulationName {
                offset: HEADER_LEN + Hello::LEN + i,
            });
        }
        let mut out = RegulationName::NONE;
        if let Some(dst) = out.bytes.get_mut(..bytes.len()) {
            dst.copy_from_slice(bytes);
        }
        // At most MAX_LEN, checked above.
        out.len = bytes.len() as u8;
        Ok(out)
    }
}

/// A byte a name may hold: printable ASCII, space included (the name goes
/// into messages and logs as it is).
const fn printable(b: u8) -> bool {
    matches!(b, 0x20..=0x7e)
}

impl Default for RegulationName {
    /// [`RegulationName::NONE`].
    fn default() -> Self {
        RegulationName::NONE
    }
}

impl fmt::Write for RegulationName {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        for c in s.chars() {
            let at = usize::from(self.len);
            let Some(slot) = self.bytes.get_mut(at) else {
                return Err(fmt::Error);
            };
            *slot = u8::try_from(c)
                .ok()
                .filter(|b| printable(*b))
                .unwrap_or(b'?');
            self.len += 1;
        }
        Ok(())
    }
}

impl fmt::Display for RegulationName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl fmt::Debug for RegulationName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Debug::fmt(self.as_str(), f)
    }
}

/// Handshake: what the sender is and how it wants the link run. Its
/// `Debug` form leaves the session token out.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Hello {
    /// The sender's role.
    pub role: Role,
    /// Regulator mode.
    pub mode: ModeCode,
    /// Underflow policy.
    pub underflow: UnderflowCode,
    /// Values in each command sample (base → remote), 1 to
    /// [`MAX_CHANNELS`].
    pub command_width: u16,
    /// Values in each state sample (remote → base), 1 to [`MAX_CHANNELS`].
    pub state_width: u16,
    /// Sampling period `T`; must be positive.
    pub period: Duration,
    /// The fingerprint of the application's channel layout (its channel
    /// names, see [`fingerprint`](crate::fingerprint)); `0` when none is given.
    pub layout: u64,
    /// What the peer puts in every datagram it sends to this sender, so
    /// that this sender can tell them from strays and spoofs; `0` on a
    /// stream (TCP, TLS), which needs none.
    pub session: u64,
    /// The seat a base asks for, or the seat the remote gives it.
    pub seat: Seat,
    /// The sender's regulation by name (its playout and that playout's
    /// values), for messages only: what must agree is `mode`.
    /// [`RegulationName::NONE`] when the sender does not say.
    pub regulation: RegulationName,
}

impl Hello {
    /// Size in bytes of the payload's fixed part; the regulation's name
    /// follows it, up to [`Hello::MAX_LEN`] in all.
    pub const LEN: usize = 32;
    /// Largest payload size in bytes: the fixed part and the longest name.
    pub const MAX_LEN: usize = Self::LEN + RegulationName::MAX_LEN;

    /// Payload size in bytes of this Hello.
    #[must_use]
    pub const fn payload_len(&self) -> usize {
        Self::LEN + self.regulation.len as usize
    }

    pub(super) fn parse(bytes: &[u8]) -> Result<Hello, WireError> {
        let bad_len = WireError::BadPayloadLength {
            kind: Kind::Hello,
            len: bytes.len(),
        };
        if bytes.len() > Self::MAX_LEN {
            return Err(bad_len);
        }
        let (b, name) = bytes.split_first_chunk::<{ Self::LEN }>().ok_or(bad_len)?;
        let [role, mode, underflow, seat, c0, c1, s0, s1, rest @ ..] = *b;
        let role = Role::try_from(role)?;
        let seat = Seat::try_from(seat)?;
        let [command_width, state_width] = [[c0, c1], [s0, s1]].map(u16::from_le_bytes);
        for (width, offset) in [(command_width, 4), (state_width, 6)] {
            if width == 0 || usize::from(width) > MAX_CHANNELS {
                return Err(WireError::WidthOutOfRange {
                    width,
                    offset: HEADER_LEN + offset,
                });
            }
        }
        let [period, layout, session] =
            [0, 8, 16].map(|at| bytes_at::<8>(&rest, at).map_or(0, u64::from_le_bytes));
        if period == 0 {
            return Err(WireError::ZeroPeriod);
        }
        Ok(Hello {
            role,
            mode: ModeCode::from(mode),
            underflow: UnderflowCode::from(underflow),
            command_width,
            state_width,
            period: Duration::from_nanos(period),
            layout,
            session,
            seat,
            regulation: RegulationName::from_wire(name)?,
        })
    }

    /// Writes the payload to the front of `b` (sized by the caller to
    /// [`Hello::payload_len`]).
    pub(super) fn write(self, b: &mut [u8]) -> Result<(), WireError> {
        if self.period.is_zero() {
            return Err(WireError::ZeroPeriod);
        }
        for (width, offset) in [(self.command_width, 4), (self.state_width, 6)] {
            if width == 0 || usize::from(width) > MAX_CHANNELS {
                return Err(WireError::WidthOutOfRange {
                    width,
                    offset: HEADER_LEN + offset,
                });
            }
        }
        super::put(
            b,
            0,
            [
                self.role as u8,
                self.mode.into(),
                self.underflow.into(),
                self.seat as u8,
            ],
        );
        super::put(b, 4, self.command_width.to_le_bytes());
        super::put(b, 6, self.state_width.to_le_bytes());
        super::put(b, 8, self.period.as_nanos().to_le_bytes());
        super::put(b, 16, self.layout.to_le_bytes());
        super::put(b, 24, self.session.to_le_bytes());
        let name = self.regulation.as_bytes();
        if let Some(dst) = b.get_mut(Self::LEN..Self::LEN + name.len()) {
            dst.copy_from_slice(name);
        }
        Ok(())
    }
}

impl fmt::Debug for Hello {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Hello")
            .field("role", &self.role)
            .field("mode", &self.mode)
            .field("underflow", &self.underflow)
            .field("command_width", &self.command_width)
            .field("state_width", &self.state_width)
            .field("period", &self.period)
            .field("layout", &self.layout)
            .field("session", &super::Secret(self.session))
            .field("seat", &self.seat)
            .field("regulation", &self.regulation)
            .finish()
    }
}

/// Pause / resume negotiation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Control {
    /// Operation; never `Unknown(0)`.
    pub op: ControlOp,
    /// Nominal queue size to use after resume; 0 when irrelevant.
    pub ns: u16,
    /// Period to use after resume; zero when irrelevant.
    pub period: Duration,
}

impl Control {
    /// Payload size in bytes.
    pub const LEN: usize = 16;

    pub(super) fn parse(bytes: &[u8]) -> Result<Control, WireError> {
        let b: &[u8; Self::LEN] = bytes.try_into().map_err(|_| WireError::BadPayloadLength {
            kind: Kind::Control,
            len: bytes.len(),
        })?;
        let [op, r0, n0, n1, r1, r2, r3, r4, period @ ..] = *b;
        if op == 0 {
            return Err(WireError::ZeroControlOp);
        }
        reserved_zero(&[r0], HEADER_LEN + 1)?;
        reserved_zero(&[r1, r2, r3, r4], HEADER_LEN + 4)?;
        Ok(Control {
            op: ControlOp::from(op),
            ns: u16::from_le_bytes([n0, n1]),
            period: Duration::from_nanos(u64::from_le_bytes(period)),
        })
    }

    pub(super) fn to_bytes(self) -> Result<[u8; Self::LEN], WireError> {
        let op = u8::from(self.op);
        if op == 0 {
            return Err(WireError::ZeroControlOp);
        }
        let [n0, n1] = self.ns.to_le_bytes();
        let [p0, p1, p2, p3, p4, p5, p6, p7] = self.period.as_nanos().to_le_bytes();
        Ok([op, 0, n0, n1, 0, 0, 0, 0, p0, p1, p2, p3, p4, p5, p6, p7])
    }
}

/// Goodbye, with a reason.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Close {
    /// Why; any code is valid.
    pub reason: CloseReason,
}

impl Close {
    /// Payload size in bytes.
    pub(crate) const LEN: usize = 8;

    pub(super) fn parse(bytes: &[u8]) -> Result<Close, WireError> {
        let b: &[u8; Self::LEN] = bytes.try_into().map_err(|_| WireError::BadPayloadLength {
            kind: Kind::Close,
            len: bytes.len(),
        })?;
        let [c0, c1, reserved @ ..] = *b;
        reserved_zero(&reserved, HEADER_LEN + 2)?;
        Ok(Close {
            reason: CloseReason::from(u16::from_le_bytes([c0, c1])),
        })
    }

    pub(super) fn to_bytes(self) -> [u8; Self::LEN] {
        let [c0, c1] = u16::from(self.reason).to_le_bytes();
        [c0, c1, 0, 0, 0, 0, 0, 0]
    }
}

impl fmt::Display for Close {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ({})", self.reason.name(), u16::from(self.reason))
    }
}

/// A new session token (datagram transport, on the reliable path): from
/// now on the receiver puts `session` in the datagrams it sends to the
/// sender, and the address the first of them comes from becomes the one
/// the sender's datagrams go to. Only someone who reads the reliable path
/// learns it before it is used, so a datagram carrying it proves that its
/// address is the peer's (path validation). Its `Debug` form leaves the
/// token out.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct Token {
    /// The token; never 0 (a stream's "no datagrams").
    pub session: u64,
}

impl Token {
    /// Payload size in bytes.
    pub(crate) const LEN: usize = 8;

    pub(super) fn parse(bytes: &[u8]) -> Result<Token, WireError> {
        let b: &[u8; Self::LEN] = bytes.try_into().map_err(|_| WireError::BadPayloadLength {
            kind: Kind::Token,
            len: bytes.len(),
        })?;
        match u64::from_le_bytes(*b) {
            0 => Err(WireError::ZeroToken),
            session => Ok(Token { session }),
        }
    }

    pub(super) fn to_bytes(self) -> Result<[u8; Self::LEN], WireError> {
        match self.session {
            0 => Err(WireError::ZeroToken),
            session => Ok(session.to_le_bytes()),
        }
    }
}

impl fmt::Debug for Token {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Token")
            .field("session", &super::Secret(self.session))
            .finish()
    }
}

/// A command the robot applied, as an observer receives it (zero-copy
/// over its values).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Applied<'a> {
    /// The command's `seq` on its controller's link.
    pub seq: u64,
    /// When its controller sent it, on the remote's clock.
    pub sent_at: crate::time::Instant,
    /// When the robot applied it, on the remote's clock.
    pub applied_at: crate::time::Instant,
    /// The command.
    pub values: Channels<'a>,
}

impl<'a> Applied<'a> {
    /// Bytes before the values.
    pub const FIXED_LEN: usize = 24;

    pub(super) fn check(bytes: &'a [u8]) -> Result<Self, WireError> {
        let bad = WireError::BadPayloadLength {
            kind: Kind::Applied,
            len: bytes.len(),
        };
        let (fixed, rest) = bytes.split_first_chunk::<24>().ok_or(bad)?;
        if !rest.len().is_multiple_of(8) {
            return Err(bad);
        }
        let values = Channels::check(rest)?;
        let at = |i: usize| bytes_at::<8>(fixed, i).map_or(0, u64::from_le_bytes);
        Ok(Applied {
            seq: at(0),
            sent_at: crate::time::Instant::from_nanos(at(8)),
            applied_at: crate::time::Instant::from_nanos(at(16)),
            values,
        })
    }
}
