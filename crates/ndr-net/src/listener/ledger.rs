//! What a listener refused, counted by reason, and logged at most once a
//! second per reason: a flood of refusals must not become a flood of log
//! lines, yet each line says how many it stands for.

use std::fmt;
use std::net::SocketAddr;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr_core::endpoint::LinkError;

use super::ListenerStats;
use crate::error::NetError;
use crate::tls::HandshakeError;

/// Shortest time between two log lines for one reason.
const LOG_EVERY: StdDuration = StdDuration::from_secs(1);

/// Why a connection never became a link the application got: one per
/// counter of [`ListenerStats`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Refusal {
    Certificate,
    NoCertificate,
    TlsVersion,
    Timeout,
    Other,
    Role,
    Layout,
    Settings,
    WireVersion,
    Protocol,
    Transport,
    Evicted,
    PerSource,
    Busy,
    Unclaimed,
    AcceptError,
    ObserverOnly,
    ObserversFull,
}

impl Refusal {
    /// Every reason, in the order of their counters.
    const ALL: [Refusal; 18] = [
        Refusal::Certificate,
        Refusal::NoCertificate,
        Refusal::TlsVersion,
        Refusal::Timeout,
        Refusal::Other,
        Refusal::Role,
        Refusal::Layout,
        Refusal::Settings,
        Refusal::WireVersion,
        Refusal::Protocol,
        Refusal::Transport,
        Refusal::Evicted,
        Refusal::PerSource,
        Refusal::Busy,
        Refusal::Unclaimed,
        Refusal::AcceptError,
        Refusal::ObserverOnly,
        Refusal::ObserversFull,
    ];
    const COUNT: usize = Refusal::ALL.len();

    /// A ndr handshake that failed, by reason.
    pub(crate) fn of_link(e: &NetError) -> Refusal {
        use ndr_core::wire::CloseReason;
        match e {
            NetError::Link(LinkError::RoleMismatch { .. })
            | NetError::Link(LinkError::PeerClosed {
                reason: CloseReason::RoleMismatch,
            }) => Refusal::Role,
            NetError::Link(LinkError::WidthMismatch { .. } | LinkError::LayoutMismatch { .. })
            | NetError::Link(LinkError::PeerClosed {
                reason: CloseReason::WidthMismatch | CloseReason::LayoutMismatch,
            }) => Refusal::Layout,
            NetError::Link(
                LinkError::PeriodMismatch { .. }
                | LinkError::ModeMismatch { .. }
                | LinkError::BadParameters { .. }
                | LinkError::PeerClosed {
                    reason: CloseReason::PeriodMismatch | CloseReason::ModeMismatch,
                },
            ) => Refusal::Settings,
            NetError::Link(
                LinkError::VersionMismatch { .. }
                | LinkError::PeerClosed {
                    reason: CloseReason::VersionMismatch,
                },
            ) => Refusal::WireVersion,
            NetError::Link(
                LinkError::Wire(_) | LinkError::Unexpected { .. } | LinkError::ChannelCount { .. },
            ) => Refusal::Protocol,
            NetError::Link(
                LinkError::TransportMismatch { .. }
                | LinkError::PeerClosed {
                    reason: CloseReason::TransportMismatch,
                },
            ) => Refusal::Transport,
            NetError::Link(LinkError::Timeout) | NetError::Timeout => Refusal::Timeout,
            NetError::Link(LinkError::CertificateRefused | LinkError::PeerCertificateRefused) => {
                Refusal::Certificate
            }
            NetError::Link(LinkError::Busy) => Refusal::Busy,
            NetError::Link(LinkError::ObserverOnly) => Refusal::ObserverOnly,
            NetError::Link(LinkError::ObserversFull) => Refusal::ObserversFull,
            NetError::Handshake(e) => Refusal::of_tls(e),
            _ => Refusal::Other,
        }
    }

    /// A TLS handshake that failed, by reason.
    pub(crate) fn of_tls(e: &HandshakeError) -> Refusal {
        match e {
            HandshakeError::UnknownCertificate(_) => Refusal::Certificate,
            HandshakeError::NoCertificate => Refusal::NoCertificate,
            HandshakeError::Version(_) => Refusal::TlsVersion,
            HandshakeError::Timeout(_) => Refusal::Timeout,
            HandshakeError::Other(_) => Refusal::Other,
        }
    }

    /// Its counter's name in [`ListenerStats`] (and in the logs).
    pub(crate) fn name(self) -> &'static str {
        match self {
            Refusal::Certificate => "refused_certificate",
            Refusal::NoCertificate => "refused_no_certificate",
            Refusal::TlsVersion => "refused_version",
            Refusal::Timeout => "timeouts",
            Refusal::Other => "failed_other",
            Refusal::Role => "refused_role",
            Refusal::Layout => "refused_layout",
            Refusal::Settings => "refused_settings",
            Refusal::WireVersion => "refused_wire_version",
            Refusal::Protocol => "refused_protocol",
            Refusal::Transport => "refused_transport",
            Refusal::Evicted => "evicted",
            Refusal::PerSource => "refused_per_source",
            Refusal::Busy => "refused_busy",
            Refusal::Unclaimed => "unclaimed",
            Refusal::AcceptError => "accept_errors",
            Refusal::ObserverOnly => "refused_observer_only",
            Refusal::ObserversFull => "refused_observers_full",
        }
    }

    fn counter(self, s: &mut ListenerStats) -> &mut u64 {
        match self {
            Refusal::Certificate => &mut s.refused_certificate,
            Refusal::NoCertificate => &mut s.refused_no_certificate,
            Refusal::TlsVersion => &mut s.refused_version,
            Refusal::Timeout => &mut s.timeouts,
            Refusal::Other => &mut s.failed_other,
            Refusal::Role => &mut s.refused_role,
            Refusal::Layout => &mut s.refused_layout,
            Refusal::Settings => &mut s.refused_settings,
            Refusal::WireVersion => &mut s.refused_wire_version,
            Refusal::Protocol => &mut s.refused_protocol,
            Refusal::Transport => &mut s.refused_transport,
            Refusal::Evicted => &mut s.evicted,
            Refusal::PerSource => &mut s.refused_per_source,
            Refusal::Busy => &mut s.refused_busy,
            Refusal::Unclaimed => &mut s.unclaimed,
            Refusal::AcceptError => &mut s.accept_errors,
            Refusal::ObserverOnly => &mut s.refused_observer_only,
            Refusal::ObserversFull => &mut s.refused_observers_full,
        }
    }
}

/// When a reason was last logged, and how many refusals went unlogged since.
#[derive(Clone, Copy, Default)]
struct Gate {
    last: Option<StdInstant>,
    suppressed: u64,
}

/// The counters, and the log's rate limit per reason.
#[derive(Default)]
pub(crate) struct Ledger {
    pub(crate) stats: ListenerStats,
    gates: [Gate; Refusal::COUNT],
}

impl Ledger {
    /// Counts a refusal at `now`; `Some(n)` if it may be logged, `n` being
    /// the refusals for the same reason left unlogged since the last line.
    fn count(&mut self, why: Refusal, now: StdInstant) -> Option<u64> {
        *why.counter(&mut self.stats) += 1;
        let gate = self.gates.get_mut(why as usize)?;
        if gate
            .last
            .is_some_and(|t| now.saturating_duration_since(t) < LOG_EVERY)
        {
            gate.suppressed += 1;
            return None;
        }
        gate.last = Some(now);
        Some(std::mem::take(&mut gate.suppressed))
    }
}

/// Counts a refusal of `peer` (if known) in `ledger` and logs it unless a
/// line for the same reason went out less than a second ago.
pub(crate) fn refuse(
    ledger: &std::sync::Mutex<Ledger>,
    why: Refusal,
    peer: Option<SocketAddr>,
    what: &dyn fmt::Display,
) {
    let logged = ledger
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
        .count(why, StdInstant::now());
    let Some(n) = logged else {
        return;
    };
    let unlogged = Unlogged(n);
    match peer {
        Some(peer) => tracing::warn!(%peer, reason = why.name(), "link refused: {what}{unlogged}"),
        None => tracing::warn!(reason = why.name(), "listener: {what}{unlogged}"),
    }
}

/// How many lines for the same reason were left out before this one.
struct Unlogged(u64);

impl fmt::Display for Unlogged {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.0 {
            0 => Ok(()),
            n => write!(
                f,
                " ({n} more for the same reason since the last such line, not logged)"
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_reason_is_logged_at_most_once_a_second_with_what_it_left_out() {
        let mut ledger = Ledger::default();
        let t0 = StdInstant::now();
        assert_eq!(ledger.count(Refusal::PerSource, t0), Some(0));
        for _ in 0..5 {
            assert_eq!(ledger.count(Refusal::PerSource, t0), None);
        }
        // Another reason has its own allowance.
        assert_eq!(ledger.count(Refusal::Evicted, t0), Some(0));
        let later = t0 + LOG_EVERY;
        assert_eq!(ledger.count(Refusal::PerSource, later), Some(5));
        assert_eq!(ledger.stats.refused_per_source, 7);
        assert_eq!(ledger.stats.evicted, 1);
    }

    #[test]
    fn a_transport_mismatch_is_counted_as_such_from_either_side() {
        let ours = NetError::Link(LinkError::TransportMismatch {
            ours: "stream",
            theirs: "datagram",
        });
        let theirs = NetError::Link(LinkError::PeerClosed {
            reason: ndr_core::wire::CloseReason::TransportMismatch,
        });
        assert_eq!(Refusal::of_link(&ours), Refusal::Transport);
        assert_eq!(Refusal::of_link(&theirs), Refusal::Transport);
        let mut ledger = Ledger::default();
        ledger.count(Refusal::of_link(&ours), StdInstant::now());
        assert_eq!(ledger.stats.refused_transport, 1);
        assert_eq!(ledger.stats.failed_other, 0);
    }

    #[test]
    fn every_reason_has_its_own_counter_and_name() {
        let all = Refusal::ALL;
        let mut ledger = Ledger::default();
        for (i, why) in all.iter().enumerate() {
            assert_eq!(*why as usize, i);
            for _ in 0..=i {
                ledger.count(*why, StdInstant::now());
            }
        }
        let mut names: Vec<&str> = all.iter().map(|w| w.name()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), Refusal::COUNT);
        let mut counts: Vec<u64> = all.iter().map(|w| *w.counter(&mut ledger.stats)).collect();
        counts.dedup();
        assert_eq!(counts.len(), Refusal::COUNT);
    }
}
