//! Queue sizing and the period law: the initialization pattern (paper §4.2.2)
//! and the choice of new parameters (§4.2.4.3).

use core::fmt;

use crate::time::{Duration, Instant};

/// Frames exchanged by the initialization pattern (paper: 10).
pub const INIT_EXCHANGES: usize = 10;
/// The paper's security factor η.
pub(crate) const DEFAULT_ETA: f64 = 1.3;
/// The smallest nominal size the paper permits.
pub(crate) const MIN_NOMINAL_SIZE: usize = 2;
/// The paper's lower bound on the period, `T_min`.
pub(crate) const DEFAULT_MIN_PERIOD: Duration = Duration::from_millis(50);

/// Errors of sizing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum SizingError {
    /// η must be finite and positive.
    BadEta,
    /// The minimum period must be positive.
    ZeroMinPeriod,
    /// An echo arrived before the frame it answers was sent.
    EchoBeforeSend {
        /// When the frame was sent.
        sent_at: Instant,
        /// When its echo was received.
        received_at: Instant,
    },
    /// The pattern already holds its `capacity` samples.
    PatternFull {
        /// The pattern's capacity.
        capacity: usize,
    },
}

impl fmt::Display for SizingError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            SizingError::BadEta => f.write_str(
                "the security factor eta must be finite and positive (the paper uses 1.3)",
            ),
            SizingError::ZeroMinPeriod => {
                f.write_str("the minimum period must be positive (the paper uses 50 ms)")
            }
            SizingError::EchoBeforeSend {
                sent_at,
                received_at,
            } => write!(
                f,
                "echo received at {received_at} for a frame sent at {sent_at}: \
                 both times must come from the same local clock"
            ),
            SizingError::PatternFull { capacity } => write!(
                f,
                "the initialization pattern already holds its {capacity} samples; \
                 read its stats or clear it"
            ),
        }
    }
}

impl core::error::Error for SizingError {}

/// What the initialization pattern measured.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct InitStats {
    /// Number of round trips measured.
    pub samples: usize,
    /// Smallest NRTT.
    pub nrtt_min: Duration,
    /// Largest NRTT.
    pub nrtt_max: Duration,
    /// Mean NRTT (truncated to the nanosecond).
    pub nrtt_mean: Duration,
    /// Largest lag of a reception behind its schedule: `max − min` NRTT.
    pub mt: Duration,
}

/// The NRTT samples of an initialization pattern, `M` at most (default
/// [`INIT_EXCHANGES`]); no allocation.
#[derive(Clone, Debug)]
pub struct InitPattern<const M: usize = INIT_EXCHANGES> {
    nrtt: [Duration; M],
    len: usize,
}

impl<const M: usize> Default for InitPattern<M> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const M: usize> InitPattern<M> {
    /// An empty pattern.
    #[must_use]
    pub const fn new() -> Self {
        InitPattern {
            nrtt: [Duration::ZERO; M],
            len: 0,
        }
    }

    #[cfg(test)]
    /// Records the round trip of a frame sent at `sent_at` whose echo came back
    /// at `received_at` (both on the local clock), less `peer_hold`, the time
    /// the peer held it before echoing.
    pub(crate) fn record(
        &mut self,
        sent_at: Instant,
        received_at: Instant,
        peer_hold: Duration,
    ) -> Result<(), SizingError> {
        let rtt =
            received_at
                .checked_duration_since(sent_at)
                .ok_or(SizingError::EchoBeforeSend {
                    sent_at,
                    received_at,
                })?;
        self.record_nrtt(rtt.saturating_sub(peer_hold))
    }

    /// Records one measured NRTT.
    pub fn record_nrtt(&mut self, nrtt: Duration) -> Result<(), SizingError> {
        let slot = self
            .nrtt
            .get_mut(self.len)
            .ok_or(SizingError::PatternFull { capacity: M })?;
        *slot = nrtt;
        self.len += 1;
        Ok(())
    }

    /// Samples recorded so far.
    #[must_use]
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    #[cfg(test)]
    /// Whether nothing is recorded.
    #[must_use]
    pub(crate) fn is_empty(&self) -> bool {
        self.len == 0
    }

    #[cfg(test)]
    /// Whether all `M` exchanges are recorded.
    #[must_use]
    pub(crate) fn is_complete(&self) -> bool {
        self.len == M
    }

    /// The NRTT samples recorded, in order.
    #[must_use]
    pub(crate) fn samples(&self) -> &[Duration] {
        &self.nrtt[..self.len]
    }

    /// Forgets the samples, for a new pattern.
    pub(crate) fn clear(&mut self) {
        self.len = 0;
    }

    /// Statistics of the samples so far; `None` if there are none.
    #[must_use]
    pub fn stats(&self) -> Option<InitStats> {
        let samples = self.samples();
        let first = *samples.first()?;
        let (mut lo, mut hi, mut sum) = (first, first, 0u128);
        for &d in samples {
            lo = lo.min(d);
            hi = hi.max(d);
            sum += u128::from(d.as_nanos());
        }
        let mean = (sum / samples.len() as u128) as u64;
        Some(InitStats {
            samples: samples.len(),
            nrtt_min: lo,
            nrtt_max: hi,
            nrtt_mean: Duration::from_nanos(mean),
            mt: hi - lo,
        })
    }
}

/// Queue sizing and the period law: the initialization pattern (paper §4.2.2)
/// and the choice of new parameters (§4.2.4.3).
///
/// At start-up, [`INIT_EXCHANGES`] frames are exchanged and their round-trip
/// times (NRTT) recorded in an [`InitPattern`]. From them come `mt`, the largest
/// time by which a reception can lag its schedule, and the nominal queue size
///
/// ```text
/// ns = 2 + floor(η · mt / T)        η = 1.3, never below 2
/// ```
///
/// `ns` is the stock a regulator keeps between releases. It drains by one per
/// period while nothing arrives, so it survives a reception lagging by `mt`
/// with 2 samples to spare. `mt` is the
/// paper's "maximum time between two receptions (ie maximum difference between
/// delays)": frames are sent on a fixed schedule, so a reception lags the
/// schedule by its delay minus the smallest delay — `mt = max(NRTT) − min(NRTT)`.
/// (The raw time between receptions includes the period itself; with it `ns`
/// could never be 2, yet the paper reports `ns = 2` on its 23 ms LAN at 200 ms.)
///
/// The period law, once the mean NRTT is known: `T = max(T_min, NRTT/3)`,
/// `T_min = 50 ms`.
///
/// The paper's laws with their constants: `ns` from `mt` and the period from NRTT.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sizing {
    eta: f64,
    min_period: Duration,
}

impl Default for Sizing {
    /// η = 1.3, `T_min` = 50 ms.
    fn default() -> Self {
        Sizing {
            eta: DEFAULT_ETA,
            min_period: DEFAULT_MIN_PERIOD,
        }
    }
}

impl Sizing {
    /// Laws with security factor `eta` and lower period bound `min_period`.
    pub fn new(eta: f64, min_period: Duration) -> Result<Self, SizingError> {
        if !(eta.is_finite() && eta > 0.0) {
            return Err(SizingError::BadEta);
        }
        if min_period.is_zero() {
            return Err(SizingError::ZeroMinPeriod);
        }
        Ok(Sizing { eta, min_period })
    }

    /// The security factor η.
    #[must_use]
    pub fn eta(&self) -> f64 {
        self.eta
    }

    /// `ns = 2 + floor(η · mt / T)`, saturating; a zero period counts as 1 ns.
    #[must_use]
    pub fn nominal_size(&self, mt: Duration, period: Duration) -> usize {
        let periods = self.eta * mt.as_nanos() as f64 / period.as_nanos().max(1) as f64;
        // `as` saturates: an absurd mt gives usize::MAX, which no queue accepts.
        MIN_NOMINAL_SIZE.saturating_add(libm::floor(periods) as usize)
    }

    /// `T = max(T_min, NRTT / 3)`.
    #[must_use]
    pub fn period(&self, nrtt_mean: Duration) -> Duration {
        self.min_period.max(nrtt_mean / 3)
    }

    /// `ns` for an initialization pattern's statistics at period `period`.
    #[must_use]
    pub(crate) fn nominal_size_for(&self, stats: &InitStats, period: Duration) -> usize {
        self.nominal_size(stats.mt, period)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(nrtt_ms: &[u64]) -> InitPattern {
        let mut p = InitPattern::new();
        for &ms in nrtt_ms {
            p.record_nrtt(Duration::from_millis(ms)).unwrap();
        }
        p
    }

    const T: Duration = Duration::from_millis(200);

    #[test]
    fn paris_new_york_pattern_gives_13() {
        // NRTT mean 610 ms, std 501 ms: range 1980 − 180 = 1800 ms.
        // 1.3 · 1800 / 200 = 11.7 → ns = 2 + 11 = 13, the paper's value.
        let p = pattern(&[180, 320, 1980, 350, 610, 240, 800, 300, 760, 560]);
        let s = p.stats().unwrap();
        assert_eq!(s.mt, Duration::from_millis(1800));
        assert_eq!(s.nrtt_mean, Duration::from_millis(610));
        assert_eq!(Sizing::default().nominal_size_for(&s, T), 13);
    }

    #[test]
    fn lan_pattern_gives_2() {
        // 75 km LAN, NRTT about 23 ms: range 31 − 19 = 12 ms.
        // 1.3 · 12 / 200 = 0.078 → ns = 2.
        let p = pattern(&[23, 19, 25, 22, 31, 21, 24, 20, 23, 22]);
        let s = p.stats().unwrap();
        assert_eq!(s.mt, Duration::from_millis(12));
        assert_eq!(Sizing::default().nominal_size_for(&s, T), 2);
    }

    #[test]
    fn nominal_size_floors_and_never_goes_below_two() {
        let law = Sizing::default();
        assert_eq!(law.nominal_size(Duration::ZERO, T), 2);
        // 1.3 · 400 / 200 = 2.6 → 4.
        assert_eq!(law.nominal_size(Duration::from_millis(400), T), 4);
        // Exactly 1.3 · 1000/200 = 6.5 → 8; η = 1 gives exactly 5 → 7.
        assert_eq!(law.nominal_size(Duration::from_secs(1), T), 8);
        let eta1 = Sizing::new(1.0, DEFAULT_MIN_PERIOD).unwrap();
        assert_eq!(eta1.nominal_size(Duration::from_secs(1), T), 7);
        assert_eq!(law.nominal_size(Duration::MAX, Duration::ZERO), usize::MAX);
    }

    #[test]
    fn period_law() {
        let law = Sizing::default();
        // LAN: 23/3 ms < 50 ms → 50 ms.
        assert_eq!(
            law.period(Duration::from_millis(23)),
            Duration::from_millis(50)
        );
        // Paris–New York: 610/3 ≈ 203.3 ms.
        assert_eq!(
            law.period(Duration::from_millis(610)),
            Duration::from_nanos(203_333_333)
        );
    }

    #[test]
    fn record_takes_out_the_peer_hold_and_checks_order() {
        let mut p: InitPattern<2> = InitPattern::new();
        p.record(
            Instant::from_millis(100),
            Instant::from_millis(130),
            Duration::from_millis(5),
        )
        .unwrap();
        assert_eq!(p.samples(), &[Duration::from_millis(25)]);
        assert!(matches!(
            p.record(
                Instant::from_millis(100),
                Instant::from_millis(90),
                Duration::ZERO
            ),
            Err(SizingError::EchoBeforeSend { .. })
        ));
        p.record_nrtt(Duration::from_millis(1)).unwrap();
        assert!(p.is_complete());
        assert_eq!(
            p.record_nrtt(Duration::from_millis(1)),
            Err(SizingError::PatternFull { capacity: 2 })
        );
        p.clear();
        assert!(p.is_empty() && p.stats().is_none());
    }

    #[test]
    fn bad_parameters_are_refused() {
        assert_eq!(
            Sizing::new(f64::NAN, DEFAULT_MIN_PERIOD),
            Err(SizingError::BadEta)
        );
        assert_eq!(
            Sizing::new(-1.0, DEFAULT_MIN_PERIOD),
            Err(SizingError::BadEta)
        );
        assert_eq!(
            Sizing::new(1.3, Duration::ZERO),
            Err(SizingError::ZeroMinPeriod)
        );
    }
}
