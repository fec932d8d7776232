//! Why a link ends, or why a call on it is refused.

use core::fmt;

use crate::time::{Duration, Instant};
use crate::wire::{self, CloseReason, Kind, ModeCode, RegulationName, Role, WireError};

use super::config::Mode;

/// An error of the link. The variants that end the link say so; the endpoint
/// then sends a Close frame with [`LinkError::close_reason`] and stops.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum LinkError {
    /// The peer sent bytes that are not a valid frame (ends the link).
    Wire(WireError),
    /// The peer speaks another wire version (ends the link).
    VersionMismatch {
        /// The peer's version.
        peer: u8,
    },
    /// The peer claims our role: two bases or two remotes (ends the link).
    RoleMismatch {
        /// The role both claim.
        role: Role,
    },
    /// The peers disagree on a sample's width (ends the link).
    WidthMismatch {
        /// `"command"` or `"state"`.
        which: &'static str,
        /// Ours.
        ours: u16,
        /// The peer's.
        theirs: u16,
    },
    /// One peer runs over a stream, the other over datagrams (ends the
    /// link).
    TransportMismatch {
        /// Ours: `stream` or `datagram`.
        ours: &'static str,
        /// The peer's.
        theirs: &'static str,
    },
    /// The peers were built for different channel layouts (ends the link).
    LayoutMismatch {
        /// Our layout's fingerprint (`0`: none given).
        ours: u64,
        /// The peer's.
        theirs: u64,
    },
    /// The peers disagree on the period (ends the link).
    PeriodMismatch {
        /// Ours.
        ours: Duration,
        /// The peer's.
        theirs: Duration,
    },
    /// The peers disagree on the regulation mode (ends the link).
    ModeMismatch {
        /// Ours.
        ours: Mode,
        /// The peer's mode (it may be one this build does not know).
        theirs: ModeCode,
        /// Our regulation by name.
        ours_named: RegulationName,
        /// The peer's regulation as its Hello names it; empty when it
        /// does not say (the message then names only its mode).
        theirs_named: RegulationName,
    },
    /// A frame that is valid but makes no sense now (ends the link).
    Unexpected {
        /// Its kind.
        kind: Kind,
        /// What the endpoint was doing.
        phase: &'static str,
    },
    /// A sample with the wrong number of channels (ends the link).
    ChannelCount {
        /// The agreed width of the peer's samples.
        expected: u16,
        /// What the frame carried.
        got: usize,
    },
    /// The peer asked for parameters this endpoint cannot take (ends the link).
    BadParameters {
        /// The queue size asked for.
        ns: u16,
        /// The period asked for.
        period: Duration,
    },
    /// The handshake or an initialization pattern did not finish in time (ends the link).
    Timeout,
    /// Nothing came from the peer for [`Config::liveness`](super::Config::liveness)
    /// after the handshake: a hung peer or a half-open connection (ends
    /// the link; [`Event::LinkLost`](super::Event::LinkLost) came first).
    PeerSilent {
        /// How long nothing came.
        silent_for: Duration,
    },
    /// This side serves as many peers as it may: the peer was refused
    /// after its handshake (sent by a listener; ends the link).
    Busy,
    /// The peer asked for control, but its identity may only observe
    /// (sent by a listener; ends the link).
    ObserverOnly,
    /// The peer asked to observe, and this side serves as many observers
    /// as it may (sent by a listener; ends the link).
    ObserversFull,
    /// A call that needs this side to hold control (base) or the link to
    /// serve a controller (remote), or a grant before the link passed its
    /// initialization pattern (the call is refused).
    NotController,
    /// This side (a listener) cut the peer's handshake short to make room
    /// for a newer connection: from the same source, which had as many
    /// handshakes pending as one may have (`per_source`), or when every
    /// handshake slot was taken (ends the link; the peer gets Close
    /// [`CloseReason::EvictedSource`] or [`CloseReason::Evicted`]).
    Evicted {
        /// The source's cap, rather than the listener's, was reached.
        per_source: bool,
    },
    /// A Data frame that is not the next one (ends the link): over a
    /// stream every frame is the one after the previous, so a repeated,
    /// skipped or replayed sequence number is an error, never a release.
    OutOfSequence {
        /// The sequence number due.
        expected: u64,
        /// The one the frame carried.
        got: u64,
    },
    /// A Data frame stamped less than half a period after the previous one
    /// (a repeat or a step back of the peer's clock; ends the link).
    StampBehind {
        /// The earliest stamp the frame could carry.
        earliest: Instant,
        /// The stamp it carried.
        got: Instant,
    },
    /// A Data frame stamped after it arrived, by more than the clocks
    /// allow (ends the link): its stamp would freeze the release schedule.
    StampAhead {
        /// How far past its arrival, on the peer's clock as estimated.
        ahead: Duration,
    },
    /// A frame stamped at or past 2⁶³ ns from its sender's origin, 292
    /// years, which no clock reads (ends the link): the clock arithmetic
    /// takes stamps as signed nanoseconds.
    StampOutOfRange {
        /// The stamp it carried.
        got: Instant,
    },
    /// The peer closed the link, with its reason code.
    PeerClosed {
        /// Why.
        reason: CloseReason,
    },
    /// The connection to the peer ended without a Close frame (reported by
    /// the driver through [`Endpoint::abort`](super::Endpoint::abort)).
    Disconnected,
    /// The link is closed; nothing more can be sent or received.
    Closed,
    /// The application's code run by the driver for this link (a release
    /// handler on the driver's thread) panicked: the driver ended the link
    /// and kept the others it drives.
    HandlerPanicked,
    /// This side's application ended the link without closing it: it was
    /// dropped during a panic, or abandoned (an exception, a handle dropped
    /// unclosed). The peer gets Close code [`CloseReason::Application`],
    /// not a normal end.
    Abandoned,
    /// The peer's TLS refused this side's certificate (an alert after the
    /// handshake, as TLS 1.3 checks the client's last): the peer neither pins
    /// it nor trusts its CA (reported by the driver).
    CertificateRefused,
    /// This side's TLS refused the peer's certificate (reported by the
    /// driver where the refusal comes after the link was set up, as over
    /// QUIC): the peer's certificate matches no pin given here and does not
    /// chain to the CA.
    PeerCertificateRefused,
    /// The application's sample does not have this side's width (the call
    /// is refused).
    SampleShape {
        /// The width of what this side sends.
        expected: u16,
        /// What was given.
        got: usize,
    },
    /// The application's sample holds NaN or infinity (the call is refused).
    NonFinite {
        /// The first bad channel.
        index: usize,
    },
    /// The transmit buffer is too small (the frame stays queued).
    BufferTooSmall {
        /// Bytes needed.
        needed: usize,
        /// Bytes given.
        got: usize,
    },
}

impl LinkError {
    /// The reason code to send in a Close frame for this error.
    #[must_use]
    pub const fn close_reason(&self) -> CloseReason {
        match self {
            LinkError::Wire(e) => e.close_reason(),
            LinkError::VersionMismatch { .. } => CloseReason::VersionMismatch,
            LinkError::RoleMismatch { .. } => CloseReason::RoleMismatch,
            LinkError::WidthMismatch { .. } => CloseReason::WidthMismatch,
            LinkError::LayoutMismatch { .. } => CloseReason::LayoutMismatch,
            LinkError::TransportMismatch { .. } => CloseReason::TransportMismatch,
            LinkError::PeriodMismatch { .. } => CloseReason::PeriodMismatch,
            LinkError::ModeMismatch { .. } => CloseReason::ModeMismatch,
            LinkError::Timeout | LinkError::PeerSilent { .. } => CloseReason::Timeout,
            LinkError::Busy => CloseReason::Busy,
            LinkError::ObserverOnly => CloseReason::ObserverOnly,
            LinkError::ObserversFull => CloseReason::ObserversFull,
            LinkError::Evicted { per_source: true } => CloseReason::EvictedSource,
            LinkError::Evicted { per_source: false } => CloseReason::Evicted,
            LinkError::OutOfSequence { .. } => CloseReason::Sequence,
            LinkError::StampBehind { .. }
            | LinkError::StampAhead { .. }
            | LinkError::StampOutOfRange { .. } => CloseReason::Stamp,
            LinkError::PeerClosed { reason } => *reason,
            LinkError::Closed => CloseReason::Normal,
            LinkError::HandlerPanicked | LinkError::Abandoned => CloseReason::Application,
            _ => CloseReason::ProtocolError,
        }
    }

    /// Whether the error ends the link (otherwise only the call was refused).
    #[must_use]
    pub const fn is_fatal(&self) -> bool {
        !matches!(
            self,
            LinkError::SampleShape { .. }
                | LinkError::NonFinite { .. }
                | LinkError::BufferTooSmall { .. }
                | LinkError::NotController
        )
    }

    pub(crate) fn from_wire(e: WireError) -> Self {
        match e {
            WireError::UnsupportedVersion(peer) => LinkError::VersionMismatch { peer },
            e => LinkError::Wire(e),
        }
    }
}

impl From<WireError> for LinkError {
    fn from(e: WireError) -> Self {
        LinkError::from_wire(e)
    }
}

fn role_name(r: Role) -> &'static str {
    match r {
        Role::Base => "base",
        Role::Remote => "remote",
    }
}

/// A Hello's mode code in words: what the side does, and the regulations
/// that send it (the Hello carries the mode, not the playout).
struct ModeWords(u8);

impl fmt::Display for ModeWords {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match ModeCode::from(self.0) {
            ModeCode::PaperStatic => f.write_str(
                "sizes its regulator once, at the handshake (paper-static, adaptive or \
                 another target-delay playout: they all link with each other)",
            ),
            ModeCode::PaperDynamic => f.write_str(
                "runs paper-dynamic (its FIFO resized, with a pause, as the network changes)",
            ),
            _ => f.write_str("runs a regulation mode this build does not know"),
        }
    }
}

/// What a Hello's mode code makes a side do, for a regulation named
/// beside it.
struct ModeWhat(u8);

impl fmt::Display for ModeWhat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match ModeCode::from(self.0) {
            ModeCode::PaperStatic => f.write_str("its regulator sized once, at the handshake"),
            ModeCode::PaperDynamic => {
                f.write_str("its FIFO resized, with a pause, as the network changes")
            }
            _ => write!(f, "mode code {}, which this build does not know", self.0),
        }
    }
}

/// A layout fingerprint as the errors show it: hexadecimal, or "none".
struct LayoutName(u64);

impl fmt::Display for LayoutName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            0 => f.write_str("none (no channel names given)"),
            n => write!(f, "{n:#018x}"),
        }
    }
}

impl fmt::Display for LinkError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            // A plain side's first read of a TLS peer: the fix comes first.
            LinkError::Wire(e) if e.starts_a_tls_record() => f.write_str(
                "the peer speaks TLS and this side does not: configure TLS on this side too \
                 (its certificate and key, and the peer's certificate or pin); the peer's \
                 first bytes are a TLS record, not an ndr frame",
            ),
            LinkError::Wire(e) => write!(f, "invalid frame from the peer: {e}"),
            LinkError::VersionMismatch { peer } => write!(
                f,
                "the peer speaks ndr wire version {peer}, this build speaks {}; upgrade the older side",
                wire::VERSION
            ),
            LinkError::RoleMismatch { role } => write!(
                f,
                "both peers are configured as {}; one side must be the base and the other the remote",
                role_name(role)
            ),
            LinkError::WidthMismatch {
                which,
                ours,
                theirs,
            } => write!(
                f,
                "width mismatch: this side's {which}s carry {ours} values, the peer's {theirs}; \
                 configure both with the same command and state widths (on the command \
                 line: the same --axes and --state)"
            ),
            LinkError::TransportMismatch { ours, theirs } => write!(
                f,
                "transport mismatch: this side carries samples over a {ours}, the peer over a \
                 {theirs}; give both the same transport"
            ),
            LinkError::LayoutMismatch { ours, theirs } => write!(
                f,
                "layout mismatch: this side was built for channel layout {}, the peer for {}; \
                 the two ends name their channels differently (another robot, or another \
                 version of it): give both the same channel names (on the command line: \
                 the same --state)",
                LayoutName(ours),
                LayoutName(theirs)
            ),
            LinkError::PeriodMismatch { ours, theirs } => write!(
                f,
                "period mismatch: this side runs at {ours}, the peer at {theirs}; configure both with the same period"
            ),
            LinkError::ModeMismatch {
                ours,
                theirs,
                ours_named,
                theirs_named,
            } if !theirs_named.is_empty() => write!(
                f,
                "mode mismatch: the peer runs {theirs_named} ({}), this side {} ({}), and \
                 paper-dynamic links only with paper-dynamic: run both with the same \
                 --regulation (in Python, regulation=)",
                ModeWhat(u8::from(theirs)),
                if ours_named.is_empty() {
                    ours.name()
                } else {
                    ours_named.as_str()
                },
                ModeWhat(u8::from(ModeCode::from(ours))),
            ),
            LinkError::ModeMismatch { ours, theirs, .. } => write!(
                f,
                "mode mismatch: this side {}, the peer {} (its Hello's mode code {}); \
                 paper-dynamic links only with paper-dynamic: give both sides the regulation \
                 paper-dynamic, or neither",
                ModeWords(u8::from(ModeCode::from(ours))),
                ModeWords(u8::from(theirs)),
                u8::from(theirs)
            ),
            LinkError::Unexpected { kind, phase } => {
                write!(f, "protocol error: the peer sent a {kind:?} frame during {phase}")
            }
            LinkError::ChannelCount { expected, got } => write!(
                f,
                "protocol error: a sample of {got} values where the peer's samples carry {expected}"
            ),
            LinkError::BadParameters { ns, period } => write!(
                f,
                "the peer asked for queue size {ns} at period {period}, which this endpoint cannot hold; \
                 give it a larger queue capacity or bound the period"
            ),
            LinkError::Timeout => f.write_str(
                "the handshake or an initialization pattern did not finish in time: check that \
                 the peer is reachable, speaks ndr and takes the other role (one base, one \
                 remote); over udp or quic, that UDP to the peer's port passes both ways (a \
                 firewall may let TCP through and drop UDP); on a slow network raise the \
                 handshake timeout (a pause of the dynamic mode also gets three times its \
                 probes and slowest round trip)",
            ),
            LinkError::PeerSilent { silent_for } => write!(
                f,
                "nothing came from the peer for {silent_for}: it hung, or the connection is \
                 half-open (its host or network went away); the link was closed so that \
                 another peer can be served"
            ),
            LinkError::Busy => f.write_str(
                "the listener serves as many peers as it may (a robot serves one base at a \
                 time): try again once the other peer is done",
            ),
            LinkError::ObserverOnly => f.write_str(
                "this peer's identity may only observe (it is on the observers' allow-list, not \
                 the controllers'): connect as an observer, or with a controller's certificate",
            ),
            LinkError::ObserversFull => f.write_str(
                "the listener serves as many observers as it may: try again later, or raise its \
                 observers limit",
            ),
            LinkError::NotController => f.write_str(
                "control is not held on this link: a base sends commands only once granted \
                 control, and a remote grants it only to a base that asked for it, once its \
                 link passed the initialization pattern",
            ),
            LinkError::Evicted { per_source: true } => f.write_str(
                "the peer's handshake was cut short to make room for a newer connection from \
                 its address, which had as many handshakes pending as one address may have",
            ),
            LinkError::Evicted { per_source: false } => f.write_str(
                "the peer's handshake was cut short to make room for a newer connection: every \
                 handshake slot was taken",
            ),
            LinkError::OutOfSequence { expected, got } => write!(
                f,
                "protocol error: a Data frame with sequence number {got} where {expected} was due \
                 (a repeated, lost or replayed frame); nothing of it was released"
            ),
            LinkError::StampBehind { earliest, got } => write!(
                f,
                "protocol error: a Data frame stamped {got} where {earliest} or later was due \
                 (a repeat or a step back of the peer's clock); nothing of it was released"
            ),
            LinkError::StampAhead { ahead } => write!(
                f,
                "protocol error: a Data frame stamped {ahead} after it arrived (a stamp from the \
                 future); nothing of it was released"
            ),
            LinkError::StampOutOfRange { got } => write!(
                f,
                "protocol error: a frame stamped {got}, 2^63 ns (292 years) or more from its \
                 sender's origin, which no clock reads; nothing of it was used"
            ),
            LinkError::PeerClosed {
                reason: CloseReason::ObserverOnly,
            } => f.write_str(
                "the peer refused control: this side's identity is on its observers' \
                 allow-list only; connect as an observer (--observe), or with a controller's \
                 certificate",
            ),
            LinkError::PeerClosed {
                reason: CloseReason::ObserversFull,
            } => f.write_str(
                "the peer serves as many observers as it may: try again later",
            ),
            LinkError::PeerClosed {
                reason: CloseReason::Busy,
            } => f.write_str(
                "the peer is busy serving another peer (a robot serves one base at a time): \
                 try again once it is done",
            ),
            LinkError::PeerClosed { reason: reason @ CloseReason::EvictedSource } => {
                write!(
                    f,
                    "the peer refused this connection: too many handshakes pending from this \
                     side's address (code {reason}): something else at the same address (behind \
                     the same NAT or relay) opens connections that do not complete their \
                     handshake; try again (a peer that completes its handshake promptly gets \
                     in), and find what else connects from this address",
                    reason = u16::from(reason)
                )
            }
            LinkError::PeerClosed { reason: reason @ CloseReason::Evicted } => write!(
                f,
                "the peer refused this connection: every handshake slot was taken (code \
                 {reason}), a flood of connections that do not complete their handshake; try \
                 again (a peer that completes its handshake promptly gets in)",
                reason = u16::from(reason)
            ),
            LinkError::PeerClosed { reason: reason @ CloseReason::VersionMismatch } => write!(
                f,
                "the peer refused this side's wire version (code {reason}): it speaks another \
                 version of ndr's wire format than ndr wire version {}; upgrade the older side",
                wire::VERSION,
                reason = u16::from(reason)
            ),
            LinkError::PeerClosed { reason: reason @ CloseReason::TransportMismatch } => {
                write!(
                    f,
                    "transport mismatch: the peer carries samples over another transport than \
                     this side (code {reason}: one over a stream, the other over datagrams); \
                     give both the same transport",
                    reason = u16::from(reason)
                )
            }
            LinkError::PeerClosed {
                reason: CloseReason::Normal,
            } => f.write_str(
                "the peer ended the link in order (Close code 0, a normal end): it was \
                 stopped, or its program closed the link (not a network fault); start it \
                 again to link again",
            ),
            LinkError::PeerClosed {
                reason: CloseReason::Timeout,
            } => f.write_str(
                "the peer gave up on the link (Close code 7, timeout): its handshake or \
                 initialization pattern did not finish in time, or nothing came from this \
                 side for its liveness time; check that this side's frames reach it (over \
                 udp or quic: that UDP to its port passes both ways)",
            ),
            LinkError::PeerClosed { reason } => write!(
                f,
                "the peer closed the link: {} (code {})",
                reason.name(),
                u16::from(reason)
            ),
            LinkError::Disconnected => f.write_str(
                "the connection to the peer was lost (no Close frame): the peer or a relay on the path died",
            ),
            LinkError::Closed => f.write_str("the link is closed"),
            LinkError::HandlerPanicked => f.write_str(
                "the release handler panicked, so the link was closed; a handler runs on the link's \
                 driver thread and must return normally (handle errors inside it)",
            ),
            LinkError::Abandoned => f.write_str(
                "the application ended the link without closing it (a panic or an exception, or \
                 its handle dropped unclosed); the peer was told: application failure",
            ),
            LinkError::CertificateRefused => f.write_str(
                "the peer refused this side's TLS certificate: it neither pins it nor trusts its \
                 CA; give the peer this side's certificate (its peer certificate) or its SHA-256 pin",
            ),
            LinkError::PeerCertificateRefused => f.write_str(
                "this side refused the peer's TLS certificate: it matches no pin or peer \
                 certificate given here and does not chain to the CA given here; give this \
                 side the peer's certificate (its peer certificate) or its SHA-256 pin, as \
                 `ndr keygen` printed it on the peer",
            ),
            LinkError::SampleShape { expected, got } => write!(
                f,
                "a sample this side sends must have {expected} values (its width), got {got}"
            ),
            LinkError::NonFinite { index } => write!(
                f,
                "sample value {index} is NaN or infinite; it was not sent (the previous sample stays)"
            ),
            LinkError::BufferTooSmall { needed, got } => write!(
                f,
                "transmit buffer of {got} bytes is too small for a {needed}-byte frame; use wire::MAX_FRAME_LEN"
            ),
        }
    }
}

impl core::error::Error for LinkError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            LinkError::Wire(e) => Some(e),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use std::string::ToString;
    use std::vec::Vec;

    use super::*;

    /// One error of each variant, and of each message a variant words
    /// apart (the Close reasons with words of their own).
    fn every_message() -> Vec<LinkError> {
        let t = Duration::from_millis(20);
        let at = Instant::from_millis(5);
        let tls = u32::from_le_bytes([0x16, 0x03, 0x01, 0x02]);
        let mut errors = std::vec![
            LinkError::Wire(WireError::LengthOutOfRange(tls)),
            LinkError::Wire(WireError::LengthOutOfRange(9)),
            LinkError::VersionMismatch { peer: 9 },
            LinkError::RoleMismatch { role: Role::Base },
            LinkError::WidthMismatch {
                which: "state",
                ours: 1,
                theirs: 2,
            },
            LinkError::TransportMismatch {
                ours: "stream",
                theirs: "datagram",
            },
            LinkError::LayoutMismatch { ours: 0, theirs: 7 },
            LinkError::PeriodMismatch { ours: t, theirs: t },
            LinkError::ModeMismatch {
                ours: Mode::PaperDynamic,
                theirs: ModeCode::PaperStatic,
                ours_named: RegulationName::lossy("paper-dynamic"),
                theirs_named: RegulationName::NONE,
            },
            LinkError::ModeMismatch {
                ours: Mode::PaperDynamic,
                theirs: ModeCode::PaperStatic,
                ours_named: RegulationName::lossy("paper-dynamic"),
                theirs_named: RegulationName::lossy("adaptive"),
            },
            LinkError::Unexpected {
                kind: Kind::Data,
                phase: "the handshake",
            },
            LinkError::ChannelCount {
                expected: 2,
                got: 3,
            },
            LinkError::BadParameters { ns: 9, period: t },
            LinkError::Timeout,
            LinkError::PeerSilent { silent_for: t },
            LinkError::Busy,
            LinkError::ObserverOnly,
            LinkError::ObserversFull,
            LinkError::NotController,
            LinkError::Evicted { per_source: true },
            LinkError::Evicted { per_source: false },
            LinkError::OutOfSequence {
                expected: 2,
                got: 3,
            },
            LinkError::StampBehind {
                earliest: at,
                got: at,
            },
            LinkError::StampAhead { ahead: t },
            LinkError::StampOutOfRange { got: at },
            LinkError::Disconnected,
            LinkError::Closed,
            LinkError::HandlerPanicked,
            LinkError::Abandoned,
            LinkError::CertificateRefused,
            LinkError::PeerCertificateRefused,
            LinkError::SampleShape {
                expected: 2,
                got: 3,
            },
            LinkError::NonFinite { index: 1 },
            LinkError::BufferTooSmall { needed: 9, got: 3 },
        ];
        errors.extend((0..=u16::from(CloseReason::ObserversFull) + 1).map(|code| {
            LinkError::PeerClosed {
                reason: CloseReason::from(code),
            }
        }));
        for e in &errors {
            // No wildcard: a new variant fails to compile here until it
            // has its sample above (and its entry in the page).
            match e {
                LinkError::Wire(_)
                | LinkError::VersionMismatch { .. }
                | LinkError::RoleMismatch { .. }
                | LinkError::WidthMismatch { .. }
                | LinkError::TransportMismatch { .. }
                | LinkError::LayoutMismatch { .. }
                | LinkError::PeriodMismatch { .. }
                | LinkError::ModeMismatch { .. }
                | LinkError::Unexpected { .. }
                | LinkError::ChannelCount { .. }
                | LinkError::BadParameters { .. }
                | LinkError::Timeout
                | LinkError::PeerSilent { .. }
                | LinkError::Busy
                | LinkError::ObserverOnly
                | LinkError::ObserversFull
                | LinkError::NotController
                | LinkError::Evicted { .. }
                | LinkError::OutOfSequence { .. }
                | LinkError::StampBehind { .. }
                | LinkError::StampAhead { .. }
                | LinkError::StampOutOfRange { .. }
                | LinkError::PeerClosed { .. }
                | LinkError::Disconnected
                | LinkError::Closed
                | LinkError::HandlerPanicked
                | LinkError::Abandoned
                | LinkError::CertificateRefused
                | LinkError::PeerCertificateRefused
                | LinkError::SampleShape { .. }
                | LinkError::NonFinite { .. }
                | LinkError::BufferTooSmall { .. } => {}
            }
        }
        errors
    }

    include!(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/support/troubleshooting_page.rs"
    ));

    #[test]
    fn every_message_is_in_the_troubleshooting_page() {
        troubleshooting_page::assert_listed(
            concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/../../docs/guide/troubleshooting.md"
            ),
            every_message().iter().map(ToString::to_string),
        );
    }

    #[test]
    fn a_peer_that_closes_in_order_is_not_a_failure() {
        let msg = LinkError::PeerClosed {
            reason: CloseReason::Normal,
        }
        .to_string();
        assert!(msg.starts_with("the peer ended the link in order"), "{msg}");
        assert!(!msg.contains("fail"), "{msg}");
    }

    #[test]
    fn a_peer_that_timed_out_names_udp() {
        for e in [
            LinkError::PeerClosed {
                reason: CloseReason::Timeout,
            },
            LinkError::Timeout,
        ] {
            let msg = e.to_string();
            assert!(msg.contains("UDP to"), "{msg}");
        }
    }

    #[test]
    fn a_layout_mismatch_names_the_command_lines_option() {
        let msg = LinkError::LayoutMismatch { ours: 1, theirs: 2 }.to_string();
        assert!(msg.contains("the same --state"), "{msg}");
        let msg = LinkError::WidthMismatch {
            which: "state",
            ours: 1,
            theirs: 2,
        }
        .to_string();
        assert!(msg.contains("the same --axes and --state"), "{msg}");
    }

    #[test]
    fn a_mode_mismatch_names_the_peer_s_regulation() {
        let msg = LinkError::ModeMismatch {
            ours: Mode::PaperDynamic,
            theirs: ModeCode::PaperStatic,
            ours_named: RegulationName::lossy("paper-dynamic"),
            theirs_named: RegulationName::lossy("fixed:200"),
        }
        .to_string();
        assert!(
            msg.starts_with(
                "mode mismatch: the peer runs fixed:200 (its regulator sized once, at the \
                 handshake), this side paper-dynamic (its FIFO resized"
            ),
            "{msg}"
        );
        assert!(msg.ends_with("run both with the same --regulation (in Python, regulation=)"));
        let msg = LinkError::ModeMismatch {
            ours: Mode::PaperStatic,
            theirs: ModeCode::Unknown(9),
            ours_named: RegulationName::lossy("adaptive"),
            theirs_named: RegulationName::lossy("later-one"),
        }
        .to_string();
        assert!(
            msg.contains("the peer runs later-one (mode code 9, which this build does not know), this side adaptive (its regulator sized once"),
            "{msg}"
        );
    }

    #[test]
    fn a_mode_mismatch_with_a_peer_that_does_not_name_its_regulation_names_what_it_may_run() {
        // A Hello without the regulation's name carries the mode alone: an
        // adaptive peer sends the static mode's code, and the message says so.
        let msg = LinkError::ModeMismatch {
            ours: Mode::PaperDynamic,
            theirs: ModeCode::PaperStatic,
            ours_named: RegulationName::lossy("paper-dynamic"),
            theirs_named: RegulationName::NONE,
        }
        .to_string();
        assert!(msg.contains("this side runs paper-dynamic"), "{msg}");
        assert!(
            msg.contains("the peer sizes its regulator once") && msg.contains("adaptive"),
            "{msg}"
        );
        assert!(!msg.contains("the peer paper-static"), "{msg}");
        let msg = LinkError::ModeMismatch {
            ours: Mode::PaperStatic,
            theirs: ModeCode::PaperDynamic,
            ours_named: RegulationName::lossy("adaptive"),
            theirs_named: RegulationName::NONE,
        }
        .to_string();
        assert!(msg.contains("the peer runs paper-dynamic"), "{msg}");
    }

    #[test]
    fn a_tls_peer_read_as_frames_says_tls_first() {
        // A TLS 1.2 record header (handshake, 3.1) read as a length field.
        let tls = u32::from_le_bytes([0x16, 0x03, 0x01, 0x02]);
        let msg = LinkError::Wire(WireError::LengthOutOfRange(tls)).to_string();
        assert!(msg.starts_with("the peer speaks TLS"), "{msg}");
        let msg = WireError::LengthOutOfRange(tls).to_string();
        assert!(msg.starts_with("these bytes start a TLS record"), "{msg}");
        let msg = LinkError::Wire(WireError::LengthOutOfRange(9)).to_string();
        assert!(msg.starts_with("invalid frame from the peer"), "{msg}");
    }

    #[test]
    fn a_certificate_refusal_names_the_side_that_refused() {
        let ours = LinkError::CertificateRefused.to_string();
        assert!(ours.starts_with("the peer refused this side's"), "{ours}");
        let theirs = LinkError::PeerCertificateRefused.to_string();
        assert!(
            theirs.starts_with("this side refused the peer's"),
            "{theirs}"
        );
    }
}
