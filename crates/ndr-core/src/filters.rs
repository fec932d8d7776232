//! The small filters of the network predictor: a first-order [`LowPass`] and
//! the decaying upper [`Envelope`] (paper §4.2.4.1).

use core::fmt;

use crate::time::Duration;

/// The paper's envelope decay `vd`.
pub(crate) const DEFAULT_DECAY: f64 = 1.00005;

/// Errors of the filters.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum FilterError {
    /// An input was NaN or infinite; the filter state is unchanged.
    NonFinite(f64),
    /// The envelope decay must be finite and at least 1.
    BadDecay(f64),
    /// The smoothing factor must lie in (0, 1].
    BadAlpha(f64),
    /// The period must be positive.
    ZeroPeriod,
}

impl fmt::Display for FilterError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            FilterError::NonFinite(x) => {
                write!(
                    f,
                    "filter input {x} is not finite; the filter state is unchanged"
                )
            }
            FilterError::BadDecay(vd) => write!(
                f,
                "envelope decay {vd} must be finite and >= 1 (the paper uses 1.00005)"
            ),
            FilterError::BadAlpha(a) => write!(f, "smoothing factor {a} must lie in (0, 1]"),
            FilterError::ZeroPeriod => f.write_str("the sampling period must be positive"),
        }
    }
}

impl core::error::Error for FilterError {}

/// First-order discrete low-pass filter, `y[k] = y[k−1] + α·(x[k] − y[k−1])`.
///
/// Built from a time constant τ and the sampling period T with the exact
/// (zero-order-hold) discretization `α = 1 − e^(−T/τ)`. The first input sets
/// the output, so the filter does not crawl up from zero.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LowPass {
    tau: Duration,
    alpha: f64,
    y: Option<f64>,
}

impl LowPass {
    /// A filter of time constant `tau` sampled every `period`; `tau = 0` passes
    /// the input through.
    pub fn new(tau: Duration, period: Duration) -> Result<Self, FilterError> {
        Ok(LowPass {
            tau,
            alpha: alpha_for(tau, period)?,
            y: None,
        })
    }

    /// A filter of time constant `periods · T`, the way the paper states them
    /// (`τ = 250·T` and so on).
    pub(crate) fn with_periods(periods: f64, period: Duration) -> Result<Self, FilterError> {
        if !periods.is_finite() {
            return Err(FilterError::NonFinite(periods));
        }
        Self::new(
            Duration::from_secs_f64(periods * period.as_secs_f64()),
            period,
        )
    }

    /// A filter with the smoothing factor `alpha` given directly.
    pub fn from_alpha(alpha: f64) -> Result<Self, FilterError> {
        if !(alpha > 0.0 && alpha <= 1.0) {
            return Err(FilterError::BadAlpha(alpha));
        }
        Ok(LowPass {
            tau: Duration::ZERO,
            alpha,
            y: None,
        })
    }

    /// Feeds one sample and returns the new output.
    pub fn update(&mut self, x: f64) -> Result<f64, FilterError> {
        if !x.is_finite() {
            return Err(FilterError::NonFinite(x));
        }
        let y = match self.y {
            Some(y) => y + self.alpha * (x - y),
            None => x,
        };
        self.y = Some(y);
        Ok(y)
    }

    /// The current output, `None` before the first sample.
    #[must_use]
    pub fn value(&self) -> Option<f64> {
        self.y
    }

    /// The smoothing factor α.
    #[must_use]
    pub fn alpha(&self) -> f64 {
        self.alpha
    }

    /// Keeps τ and the output, adapts α to a new sampling period.
    pub fn set_period(&mut self, period: Duration) -> Result<(), FilterError> {
        self.alpha = alpha_for(self.tau, period)?;
        Ok(())
    }

    /// Forgets the output; the next sample sets it.
    pub fn reset(&mut self) {
        self.y = None;
    }
}

fn alpha_for(tau: Duration, period: Duration) -> Result<f64, FilterError> {
    if period.is_zero() {
        return Err(FilterError::ZeroPeriod);
    }
    if tau.is_zero() {
        return Ok(1.0);
    }
    Ok(1.0 - libm::exp(-(period.as_nanos() as f64) / tau.as_nanos() as f64))
}

/// Upper envelope with slow decay:
/// `e[k] = x[k]` if `x[k] > e[k−1]`, else `e[k−1] / vd`.
///
/// The paper keeps the envelope of the time between successive frames to
/// measure `mt`; with `vd = 1.00005` it forgets a peak with a half-life of
/// about 13 900 samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Envelope {
    inv_decay: f64,
    e: Option<f64>,
}

impl Default for Envelope {
    /// `vd = 1.00005`.
    fn default() -> Self {
        Envelope {
            inv_decay: 1.0 / DEFAULT_DECAY,
            e: None,
        }
    }
}

impl Envelope {
    /// An envelope decaying by `vd` (≥ 1) per sample.
    pub fn new(vd: f64) -> Result<Self, FilterError> {
        if !(vd.is_finite() && vd >= 1.0) {
            return Err(FilterError::BadDecay(vd));
        }
        Ok(Envelope {
            inv_decay: 1.0 / vd,
            e: None,
        })
    }

    /// Feeds one sample and returns the envelope.
    pub fn update(&mut self, x: f64) -> Result<f64, FilterError> {
        if !x.is_finite() {
            return Err(FilterError::NonFinite(x));
        }
        let e = match self.e {
            Some(prev) if x <= prev => prev * self.inv_decay,
            _ => x,
        };
        self.e = Some(e);
        Ok(e)
    }

    /// The current envelope, `None` before the first sample.
    #[must_use]
    pub fn value(&self) -> Option<f64> {
        self.e
    }

    /// The decay `vd`.
    #[must_use]
    pub fn decay(&self) -> f64 {
        1.0 / self.inv_decay
    }

    /// Forgets the envelope.
    pub fn reset(&mut self) {
        self.e = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn low_pass_step_response_matches_the_exponential() {
        let t = Duration::from_millis(200);
        let mut lp = LowPass::with_periods(25.0, t).unwrap();
        assert_eq!(lp.update(0.0).unwrap(), 0.0);
        let mut y = 0.0;
        for _ in 0..25 {
            y = lp.update(1.0).unwrap();
        }
        // After one time constant: 1 − e^(−1).
        assert!((y - (1.0 - libm::exp(-1.0))).abs() < 1e-12, "{y}");
    }

    #[test]
    fn low_pass_starts_at_the_first_sample_and_rejects_nan() {
        let mut lp = LowPass::new(Duration::from_secs(50), Duration::from_millis(200)).unwrap();
        assert_eq!(lp.value(), None);
        assert_eq!(lp.update(0.61).unwrap(), 0.61);
        assert!(matches!(lp.update(f64::NAN), Err(FilterError::NonFinite(x)) if x.is_nan()));
        assert_eq!(lp.value(), Some(0.61));
        assert_eq!(
            LowPass::new(Duration::ZERO, Duration::from_millis(1))
                .unwrap()
                .alpha(),
            1.0
        );
        assert_eq!(
            LowPass::new(Duration::from_secs(1), Duration::ZERO),
            Err(FilterError::ZeroPeriod)
        );
        assert!(LowPass::from_alpha(0.0).is_err() && LowPass::from_alpha(1.5).is_err());
    }

    #[test]
    fn low_pass_keeps_tau_across_a_period_change() {
        let mut lp = LowPass::new(Duration::from_secs(10), Duration::from_millis(200)).unwrap();
        lp.update(1.0).unwrap();
        lp.set_period(Duration::from_millis(50)).unwrap();
        assert!((lp.alpha() - (1.0 - libm::exp(-0.005))).abs() < 1e-15);
        assert_eq!(lp.value(), Some(1.0));
    }

    #[test]
    fn envelope_follows_peaks_and_decays() {
        let mut env = Envelope::new(2.0).unwrap();
        assert_eq!(env.update(1.0).unwrap(), 1.0);
        assert_eq!(env.update(4.0).unwrap(), 4.0);
        assert_eq!(env.update(3.0).unwrap(), 2.0);
        assert_eq!(env.update(0.5).unwrap(), 1.0);
        assert_eq!(env.update(1.5).unwrap(), 1.5);
        assert!(env.update(f64::INFINITY).is_err());
        assert_eq!(env.value(), Some(1.5));
        assert!(Envelope::new(0.9).is_err());
        assert!((Envelope::default().decay() - DEFAULT_DECAY).abs() < 1e-12);
    }
}
