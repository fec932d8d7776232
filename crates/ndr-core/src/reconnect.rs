//! A link that comes back: how long to wait between attempts to reach a
//! peer, and what the application sees across the sessions of one link.
//!
//! A driver that reconnects runs a new [`Endpoint`](crate::endpoint::Endpoint)
//! for each session (a new handshake, a new initialization pattern, sequence
//! numbers from zero again). [`Sessions`] keeps what must outlive them: the
//! outage (from the loss of one session to the start of the next), the
//! counts, and a sequence the application sees rise across sessions, so
//! that no release of an old session can pass for a new one or come after
//! it. It never reads a clock: time is an argument, as everywhere in the core.

use crate::time::{Duration, Instant};

/// Waits between attempts: `first`, doubled at each failed attempt, at
/// most `max`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct Backoff {
    /// The wait after the first failed attempt.
    pub first: Duration,
    /// The longest wait.
    pub max: Duration,
}

impl Default for Backoff {
    /// 100 ms, doubling to 1 s: a restarted peer is reached within a second
    /// of its coming back, at one attempt a second while it is away.
    fn default() -> Self {
        Backoff {
            first: Duration::from_millis(100),
            max: Duration::from_secs(1),
        }
    }
}

impl Backoff {
    /// The wait after the failed attempt `attempt` (0 for the first).
    #[must_use]
    pub fn delay(&self, attempt: u32) -> Duration {
        let factor = 1_u64.checked_shl(attempt.min(63)).unwrap_or(u64::MAX);
        let nanos = self.first.as_nanos().saturating_mul(factor);
        Duration::from_nanos(nanos.min(self.max.as_nanos()))
    }
}

/// What the sessions of one link counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct ReconnectStats {
    /// Sessions after the first that passed their initialization pattern.
    pub reconnects: u64,
    /// Sum of the outages: from each loss to the start of the next session.
    pub outage_total: Duration,
    /// The latest outage, once one ended.
    pub last_outage: Option<Duration>,
    /// The longest outage.
    pub longest_outage: Duration,
    /// Releases refused because they belonged to a session older than the
    /// current one, or did not come after the last release given.
    pub stale: u64,
}

/// The sessions of one link, as its application sees them.
#[derive(Clone, Debug, Default)]
pub struct Sessions {
    /// The current session's number (0 for the first).
    session: u32,
    /// Added to the current session's sequence numbers.
    offset: u64,
    /// The last sequence number given to the application.
    last: Option<u64>,
    /// When the current outage started.
    down_since: Option<Instant>,
    /// A new session runs, its samples not flowing yet.
    pending: bool,
    stats: ReconnectStats,
}

impl Sessions {
    /// The first session, up.
    #[must_use]
    pub fn new() -> Self {
        Self::default()
    }

    /// The current session lost its peer at `now`; `false` if an outage
    /// was already running (it started earlier).
    pub fn lost(&mut self, now: Instant) -> bool {
        if self.down_since.is_some() {
            return false;
        }
        self.down_since = Some(now);
        true
    }

    /// When the current outage started, if the link is down.
    #[must_use]
    pub fn down_since(&self) -> Option<Instant> {
        self.down_since
    }

    /// A new session starts (its handshake done): its sequence numbers
    /// follow the last one given. Returns its number.
    pub fn resumed(&mut self) -> u32 {
        self.session = self.session.wrapping_add(1);
        self.offset = self.last.map_or(0, |l| l.saturating_add(1));
        self.pending = true;
        self.session
    }

    /// The current session's number.
    #[must_use]
    pub fn session(&self) -> u32 {
        self.session
    }

    /// Samples flow again on the new session at `now` (its initialization
    /// pattern is over): the outage, counted, if one was running.
    pub fn restored(&mut self, now: Instant) -> Option<Duration> {
        if !self.pending {
            return None;
        }
        self.pending = false;
        let since = self.down_since.take()?;
        let outage = now.checked_duration_since(since).unwrap_or(Duration::ZERO);
        let s = &mut self.stats;
        s.reconnects += 1;
        s.outage_total = s.outage_total.checked_add(outage).unwrap_or(s.outage_total);
        s.last_outage = Some(outage);
        if outage > s.longest_outage {
            s.longest_outage = outage;
        }
        Some(outage)
    }

    /// The sequence number the application sees for the release `seq` of
    /// session `session`; `None` (counted in [`ReconnectStats::stale`])
    /// for a release of an older session, or a fresh one that does not
    /// come after the last given. A repeat (`fresh` false: the last sample
    /// held at an underflow) keeps the number of the sample it repeats.
    pub fn admit(&mut self, session: u32, seq: u64, fresh: bool) -> Option<u64> {
        let seen = self.offset.saturating_add(seq);
        let behind = match self.last {
            Some(l) if fresh => seen <= l,
            Some(l) => seen > l,
            None => !fresh,
        };
        if session != self.session || behind {
            self.stats.stale += 1;
            return None;
        }
        if fresh {
            self.last = Some(seen);
        }
        Some(seen)
    }

    /// What was counted.
    #[must_use]
    pub fn stats(&self) -> ReconnectStats {
        self.stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_to_its_bound() {
        let b = Backoff::default();
        let ms: alloc::vec::Vec<u64> = (0..6).map(|a| b.delay(a).as_millis()).collect();
        assert_eq!(ms, [100, 200, 400, 800, 1000, 1000]);
        assert_eq!(b.delay(u32::MAX), Duration::from_secs(1));
    }

    #[test]
    fn a_second_session_continues_the_sequence_and_refuses_the_first() {
        let mut s = Sessions::new();
        assert_eq!(s.admit(0, 0, true), Some(0));
        assert_eq!(s.admit(0, 7, true), Some(7));
        // A repeat keeps the number of what it repeats.
        assert_eq!(s.admit(0, 7, false), Some(7));
        assert!(s.lost(Instant::from_millis(1000)));
        assert!(!s.lost(Instant::from_millis(1500)), "one outage");
        let session = s.resumed();
        assert_eq!(session, 1);
        // A late release of the first session is refused and counted.
        assert_eq!(s.admit(0, 8, true), None);
        // The new session counts from zero; the application sees 8 on.
        assert_eq!(s.admit(1, 0, true), Some(8));
        assert_eq!(s.admit(1, 3, true), Some(11));
        // Nothing twice.
        assert_eq!(s.admit(1, 3, true), None);
        assert_eq!(s.stats().stale, 2);
        assert_eq!(
            s.restored(Instant::from_millis(3250)),
            Some(Duration::from_millis(2250))
        );
        assert_eq!(s.restored(Instant::from_millis(4000)), None);
        let st = s.stats();
        assert_eq!(st.reconnects, 1);
        assert_eq!(st.outage_total, Duration::from_millis(2250));
        assert_eq!(st.last_outage, Some(Duration::from_millis(2250)));
    }

    #[test]
    fn a_session_resumed_without_an_outage_counts_none() {
        let mut s = Sessions::new();
        let _ = s.resumed();
        assert_eq!(s.restored(Instant::from_millis(10)), None);
        assert_eq!(s.stats().reconnects, 0);
    }
}
