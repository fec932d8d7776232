//! Time as integers: an [`Instant`] and a [`Duration`] counted in nanoseconds.
//!
//! The state machine never reads a clock: its driver passes `now` in. Integer
//! nanoseconds keep release deadlines exact (`t0 + k·T` never drifts the way a
//! sum of floats does) and cover 584 years, more than any link lives.
//! Floating seconds appear only at the edges, in filters and reports.

use core::fmt;
use core::ops::{Add, AddAssign, Div, Mul, Sub, SubAssign};

/// A point in time: nanoseconds since an origin chosen by the driver
/// (for a link, usually the moment it started).
///
/// Instants of two different hosts are not comparable: each peer has its own
/// origin and its own oscillator.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Instant {
    nanos: u64,
}

/// A non-negative span of time in nanoseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Duration {
    nanos: u64,
}

impl Instant {
    /// The origin.
    pub const ZERO: Instant = Instant { nanos: 0 };

    /// The instant `nanos` nanoseconds after the origin.
    #[must_use]
    pub const fn from_nanos(nanos: u64) -> Self {
        Instant { nanos }
    }

    /// The instant `millis` milliseconds after the origin (saturating).
    #[must_use]
    pub const fn from_millis(millis: u64) -> Self {
        Instant::from_nanos(millis.saturating_mul(1_000_000))
    }

    /// The instant `secs` seconds after the origin, rounded to the nanosecond;
    /// negative or NaN gives the origin, too large saturates.
    #[must_use]
    pub fn from_secs_f64(secs: f64) -> Self {
        Instant::ZERO + Duration::from_secs_f64(secs)
    }

    /// Nanoseconds since the origin.
    #[must_use]
    pub const fn as_nanos(self) -> u64 {
        self.nanos
    }

    /// Seconds since the origin, as a float (for reports and filters).
    #[must_use]
    pub fn as_secs_f64(self) -> f64 {
        self.nanos as f64 * 1e-9
    }

    /// The time from `earlier` to `self`, or `None` if `earlier` is later.
    #[must_use]
    pub const fn checked_duration_since(self, earlier: Instant) -> Option<Duration> {
        match self.nanos.checked_sub(earlier.nanos) {
            Some(nanos) => Some(Duration { nanos }),
            None => None,
        }
    }

    /// The time from `earlier` to `self`, zero if `earlier` is later.
    #[must_use]
    pub(crate) const fn saturating_duration_since(self, earlier: Instant) -> Duration {
        Duration {
            nanos: self.nanos.saturating_sub(earlier.nanos),
        }
    }

    /// `self − other` in signed nanoseconds (saturating at the `i64` range);
    /// what clock-offset arithmetic between two hosts needs.
    #[must_use]
    pub const fn signed_nanos_since(self, other: Instant) -> i64 {
        let diff = self.nanos as i128 - other.nanos as i128;
        if diff > i64::MAX as i128 {
            i64::MAX
        } else if diff < i64::MIN as i128 {
            i64::MIN
        } else {
            diff as i64
        }
    }

    /// `self + d`, or `None` on overflow.
    #[must_use]
    pub const fn checked_add(self, d: Duration) -> Option<Instant> {
        match self.nanos.checked_add(d.nanos) {
            Some(nanos) => Some(Instant { nanos }),
            None => None,
        }
    }

    /// `self − d`, or `None` before the origin.
    #[must_use]
    pub const fn checked_sub(self, d: Duration) -> Option<Instant> {
        match self.nanos.checked_sub(d.nanos) {
            Some(nanos) => Some(Instant { nanos }),
            None => None,
        }
    }
}

impl Duration {
    /// No time at all.
    pub const ZERO: Duration = Duration { nanos: 0 };
    /// The longest representable span.
    pub const MAX: Duration = Duration { nanos: u64::MAX };

    /// A span of `nanos` nanoseconds.
    #[must_use]
    pub const fn from_nanos(nanos: u64) -> Self {
        Duration { nanos }
    }

    /// A span of `micros` microseconds (saturating).
    #[must_use]
    pub const fn from_micros(micros: u64) -> Self {
        Duration::from_nanos(micros.saturating_mul(1_000))
    }

    /// A span of `millis` milliseconds (saturating).
    #[must_use]
    pub const fn from_millis(millis: u64) -> Self {
        Duration::from_nanos(millis.saturating_mul(1_000_000))
    }

    /// A span of `secs` whole seconds (saturating).
    #[must_use]
    pub const fn from_secs(secs: u64) -> Self {
        Duration::from_nanos(secs.saturating_mul(1_000_000_000))
    }

    /// A span of `secs` seconds rounded to the nanosecond; negative or NaN gives
    /// zero, too large or infinite saturates at [`Duration::MAX`].
    #[must_use]
    pub fn from_secs_f64(secs: f64) -> Self {
        let nanos = libm::round(secs * 1e9);
        // NaN fails both comparisons and lands on zero.
        if nanos >= u64::MAX as f64 {
            Duration::MAX
        } else if nanos > 0.0 {
            Duration {
                nanos: nanos as u64,
            }
        } else {
            Duration::ZERO
        }
    }

    /// The span in nanoseconds.
    #[must_use]
    pub const fn as_nanos(self) -> u64 {
        self.nanos
    }

    /// The span in whole microseconds (truncated).
    #[must_use]
    pub const fn as_micros(self) -> u64 {
        self.nanos / 1_000
    }

    /// The span in whole milliseconds (truncated).
    #[must_use]
    pub const fn as_millis(self) -> u64 {
        self.nanos / 1_000_000
    }

    /// The span in seconds, as a float (for reports and filters).
    #[must_use]
    pub fn as_secs_f64(self) -> f64 {
        self.nanos as f64 * 1e-9
    }

    /// Whether the span is zero.
    #[must_use]
    pub const fn is_zero(self) -> bool {
        self.nanos == 0
    }

    /// `self + other`, or `None` on overflow.
    #[must_use]
    pub const fn checked_add(self, other: Duration) -> Option<Duration> {
        match self.nanos.checked_add(other.nanos) {
            Some(nanos) => Some(Duration { nanos }),
            None => None,
        }
    }

    /// `self − other`, or `None` if `other` is longer.
    #[must_use]
    pub const fn checked_sub(self, other: Duration) -> Option<Duration> {
        match self.nanos.checked_sub(other.nanos) {
            Some(nanos) => Some(Duration { nanos }),
            None => None,
        }
    }

    /// `self − other`, zero if `other` is longer.
    #[must_use]
    pub const fn saturating_sub(self, other: Duration) -> Duration {
        Duration {
            nanos: self.nanos.saturating_sub(other.nanos),
        }
    }

    /// `self · k`, saturating.
    #[must_use]
    pub(crate) const fn saturating_mul(self, k: u64) -> Duration {
        Duration {
            nanos: self.nanos.saturating_mul(k),
        }
    }
}

impl Add<Duration> for Instant {
    type Output = Instant;
    /// Saturates at the end of time rather than wrapping into the past.
    fn add(self, d: Duration) -> Instant {
        Instant {
            nanos: self.nanos.saturating_add(d.nanos),
        }
    }
}

impl AddAssign<Duration> for Instant {
    fn add_assign(&mut self, d: Duration) {
        *self = *self + d;
    }
}

impl Sub<Duration> for Instant {
    type Output = Instant;
    /// Saturates at the origin.
    fn sub(self, d: Duration) -> Instant {
        Instant {
            nanos: self.nanos.saturating_sub(d.nanos),
        }
    }
}

impl SubAssign<Duration> for Instant {
    fn sub_assign(&mut self, d: Duration) {
        *self = *self - d;
    }
}

impl Sub<Instant> for Instant {
    type Output = Duration;
    /// Saturates at zero when `rhs` is later; use
    /// [`Instant::checked_duration_since`] to tell the cases apart.
    fn sub(self, rhs: Instant) -> Duration {
        self.saturating_duration_since(rhs)
    }
}

impl Add for Duration {
    type Output = Duration;
    /// Saturating.
    fn add(self, rhs: Duration) -> Duration {
        Duration {
            nanos: self.nanos.saturating_add(rhs.nanos),
        }
    }
}

impl AddAssign for Duration {
    fn add_assign(&mut self, rhs: Duration) {
        *self = *self + rhs;
    }
}

impl Sub for Duration {
    type Output = Duration;
    /// Saturating at zero.
    fn sub(self, rhs: Duration) -> Duration {
        self.saturating_sub(rhs)
    }
}

impl Mul<u64> for Duration {
    type Output = Duration;
    /// Saturating.
    fn mul(self, k: u64) -> Duration {
        self.saturating_mul(k)
    }
}

impl Div<u64> for Duration {
    type Output = Duration;
    /// Truncating; dividing by zero gives [`Duration::MAX`] instead of a panic.
    fn div(self, k: u64) -> Duration {
        match self.nanos.checked_div(k) {
            Some(nanos) => Duration { nanos },
            None => Duration::MAX,
        }
    }
}

impl fmt::Display for Duration {
    /// Picks a readable unit: `850ns`, `12.500µs`, `3.250ms`, `1.200s`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let n = self.nanos;
        if n < 1_000 {
            write!(f, "{n}ns")
        } else if n < 1_000_000 {
            write!(f, "{}.{:03}µs", n / 1_000, n % 1_000)
        } else if n < 1_000_000_000 {
            write!(f, "{}.{:03}ms", n / 1_000_000, (n / 1_000) % 1_000)
        } else {
            write!(f, "{}.{:03}s", n / 1_000_000_000, (n / 1_000_000) % 1_000)
        }
    }
}

impl fmt::Display for Instant {
    /// Seconds since the origin, e.g. `t+1.200s`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "t+{}", Duration::from_nanos(self.nanos))
    }
}

/// Seconds, as an `f64`: the unit every binding and report shows (the stats'
/// durations among them), not the integer nanoseconds it holds.
#[cfg(feature = "serde")]
impl serde::Serialize for Duration {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_f64(self.as_secs_f64())
    }
}

#[cfg(feature = "std")]
mod std_conv {
    use super::{Duration, Instant};

    impl From<std::time::Duration> for Duration {
        /// Saturates at [`Duration::MAX`] (584 years).
        fn from(d: std::time::Duration) -> Self {
            Duration::from_nanos(u64::try_from(d.as_nanos()).unwrap_or(u64::MAX))
        }
    }

    impl From<Duration> for std::time::Duration {
        fn from(d: Duration) -> Self {
            std::time::Duration::from_nanos(d.as_nanos())
        }
    }

    impl Instant {
        /// Maps a `std` instant onto this clock, counting from `origin`
        /// (instants before the origin map to the origin).
        #[must_use]
        pub fn from_std(origin: std::time::Instant, t: std::time::Instant) -> Self {
            Instant::ZERO + Duration::from(t.saturating_duration_since(origin))
        }

        /// The `std` instant this instant stands for, given the same `origin`
        /// that [`Instant::from_std`] used; `None` if it cannot be represented.
        #[must_use]
        pub fn to_std(self, origin: std::time::Instant) -> Option<std::time::Instant> {
            origin.checked_add(std::time::Duration::from_nanos(self.as_nanos()))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arithmetic_saturates_instead_of_wrapping() {
        let t = Instant::from_millis(5);
        assert_eq!(t - Duration::from_millis(10), Instant::ZERO);
        assert_eq!(
            Instant::from_nanos(u64::MAX) + Duration::from_nanos(1),
            Instant::from_nanos(u64::MAX)
        );
        assert_eq!(
            Instant::from_millis(1) - Instant::from_millis(2),
            Duration::ZERO
        );
        assert_eq!(
            Instant::from_millis(1).checked_duration_since(Instant::from_millis(2)),
            None
        );
        assert_eq!(Duration::from_secs(1) / 0, Duration::MAX);
    }

    #[test]
    fn signed_difference_has_a_sign() {
        let a = Instant::from_millis(3);
        let b = Instant::from_millis(5);
        assert_eq!(a.signed_nanos_since(b), -2_000_000);
        assert_eq!(b.signed_nanos_since(a), 2_000_000);
        assert_eq!(
            Instant::from_nanos(u64::MAX).signed_nanos_since(Instant::ZERO),
            i64::MAX
        );
    }

    #[test]
    fn float_conversions_round_and_clamp() {
        assert_eq!(Duration::from_secs_f64(0.2), Duration::from_millis(200));
        assert_eq!(Duration::from_secs_f64(1.5e-9), Duration::from_nanos(2));
        assert_eq!(Duration::from_secs_f64(-1.0), Duration::ZERO);
        assert_eq!(Duration::from_secs_f64(f64::NAN), Duration::ZERO);
        assert_eq!(Duration::from_secs_f64(f64::INFINITY), Duration::MAX);
        assert!((Duration::from_millis(610).as_secs_f64() - 0.61).abs() < 1e-15);
        assert_eq!(Instant::from_secs_f64(1.25), Instant::from_millis(1250));
    }

    #[test]
    fn display_picks_a_unit() {
        extern crate std;
        use std::string::ToString;
        assert_eq!(Duration::from_nanos(850).to_string(), "850ns");
        assert_eq!(Duration::from_nanos(12_500).to_string(), "12.500µs");
        assert_eq!(Duration::from_micros(3_250).to_string(), "3.250ms");
        assert_eq!(Duration::from_millis(1_200).to_string(), "1.200s");
        assert_eq!(Instant::from_millis(1_200).to_string(), "t+1.200s");
    }

    #[cfg(feature = "std")]
    #[test]
    fn std_round_trip() {
        let origin = std::time::Instant::now();
        let later = origin + std::time::Duration::from_micros(1234);
        let t = Instant::from_std(origin, later);
        assert_eq!(t, Instant::from_nanos(1_234_000));
        assert_eq!(t.to_std(origin), Some(later));
        assert_eq!(Instant::from_std(later, origin), Instant::ZERO);
        let d: std::time::Duration = Duration::from_millis(7).into();
        assert_eq!(Duration::from(d), Duration::from_millis(7));
    }
}
