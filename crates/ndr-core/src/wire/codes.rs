//! The codes a frame carries in its fields, as enums with a case for the
//! codes this build does not know (the wire accepts them; later versions
//! add codes).

/// An enum of known codes plus `Unknown`, with lossless conversions from
/// and to the wire's integer.
macro_rules! codes {
    (
        $(#[$attr:meta])*
        pub enum $name:ident: $int:ty {
            $( $(#[$vattr:meta])* $variant:ident = $value:literal, )+
        }
    ) => {
        $(#[$attr])*
        ///
        /// Converting from the wire's integer maps each known code to its
        /// variant and only the others to `Unknown`; build values that way
        /// (an `Unknown` holding a known code compares unequal to its variant).
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
        #[non_exhaustive]
        pub enum $name {
            $( $(#[$vattr])* $variant, )+
            /// A code this build does not know.
            Unknown($int),
        }

        impl From<$int> for $name {
            fn from(code: $int) -> $name {
                match code {
                    $( $value => $name::$variant, )+
                    other => $name::Unknown(other),
                }
            }
        }

        impl From<$name> for $int {
            fn from(code: $name) -> $int {
                match code {
                    $( $name::$variant => $value, )+
                    $name::Unknown(other) => other,
                }
            }
        }
    };
}

codes! {
    /// The regulator mode a [`Hello`](super::Hello) announces; the
    /// endpoint decides whether it can work with it
    /// ([`Mode`](crate::Mode) converts to and from it).
    pub enum ModeCode: u8 {
        /// The paper's static regulator: `T` and `ns` fixed after the handshake.
        PaperStatic = 0,
        /// The paper's dynamic regulator: `T` and `ns` re-sized from predicted delays.
        PaperDynamic = 1,
    }
}

codes! {
    /// What the sender of a [`Hello`](super::Hello) releases on an empty
    /// queue ([`Underflow`](crate::Underflow) converts to it).
    pub enum UnderflowCode: u8 {
        /// Release the last sample again.
        Hold = 0,
        /// Release nothing, and drop samples that arrive after their deadline.
        DropLate = 1,
    }
}

codes! {
    /// The operation of a [`Control`](super::Control) frame; code 0 is
    /// invalid on the wire.
    pub enum ControlOp: u8 {
        /// Ask the peer to pause teleoperation (to re-size the link).
        PauseRequest = 1,
        /// Agree to a pause request.
        PauseAck = 2,
        /// Resume with the [`Control`](super::Control)'s `ns` and `period`.
        Resume = 3,
        /// Remote to base: the base holds control from now, in the term the
        /// frame's header carries.
        Grant = 4,
        /// Remote to base: the base no longer holds control (the header's
        /// term is the one it lost); it observes from now.
        Revoke = 5,
        /// Base to remote: the controller gives control up.
        Yield = 6,
        /// Remote to the controller: another base waits for control.
        Request = 7,
    }
}

codes! {
    /// Why a [`Close`](super::Close) ends the session. Every code is valid
    /// on the wire: a closing peer must always be able to say goodbye.
    pub enum CloseReason: u16 {
        /// Orderly end of the session.
        Normal = 0,
        /// The peers speak different wire versions.
        VersionMismatch = 1,
        /// Both peers claim the same role.
        RoleMismatch = 2,
        /// The peers disagree on a sample's width (command or state values).
        WidthMismatch = 3,
        /// The peers disagree on the period.
        PeriodMismatch = 4,
        /// The peers disagree on the regulator mode.
        ModeMismatch = 5,
        /// The peer sent an invalid or unexpected frame.
        ProtocolError = 6,
        /// The peer went silent for too long.
        Timeout = 7,
        /// The sender's application failed (its code on the link's driver
        /// thread panicked, or it dropped the link unclosed).
        Application = 8,
        /// The listener serves as many peers as it may: try again later.
        Busy = 9,
        /// A Data frame that is not the next one in sequence (a repeat, a
        /// gap or a replay).
        Sequence = 10,
        /// A Data frame whose send stamp does not advance as the sender's
        /// clock can: a step back, or a stamp from the future.
        Stamp = 11,
        /// The peers were built for different channel layouts.
        LayoutMismatch = 12,
        /// One peer runs over a stream, the other over datagrams.
        TransportMismatch = 13,
        /// The listener cut the handshake short to make room for a newer
        /// connection from the same address: that address had as many
        /// handshakes pending as one source may have.
        EvictedSource = 14,
        /// The listener cut the handshake short to make room for a newer
        /// connection: every handshake slot was taken.
        Evicted = 15,
        /// The base asked for control, but its identity may only observe.
        ObserverOnly = 16,
        /// The base asked to observe, and the remote serves as many
        /// observers as it may.
        ObserversFull = 17,
    }
}

impl CloseReason {
    /// A short name for the reason, `"unknown"` for codes this build does
    /// not know.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            CloseReason::Normal => "normal",
            CloseReason::VersionMismatch => "version mismatch",
            CloseReason::RoleMismatch => "role mismatch",
            CloseReason::WidthMismatch => "width mismatch",
            CloseReason::PeriodMismatch => "period mismatch",
            CloseReason::ModeMismatch => "mode mismatch",
            CloseReason::ProtocolError => "protocol error",
            CloseReason::Timeout => "timeout",
            CloseReason::Application => "application failure",
            CloseReason::Busy => "busy: serving another peer",
            CloseReason::Sequence => "frame out of sequence",
            CloseReason::Stamp => "send stamp out of time",
            CloseReason::LayoutMismatch => "layout mismatch",
            CloseReason::TransportMismatch => "transport mismatch",
            CloseReason::EvictedSource => "evicted: too many handshakes pending from this address",
            CloseReason::Evicted => "evicted: too many handshakes pending",
            CloseReason::ObserverOnly => {
                "refused control: this identity is allowed to observe only"
            }
            CloseReason::ObserversFull => "busy: serving as many observers as allowed",
            CloseReason::Unknown(_) => "unknown",
        }
    }
}
