//! The paper's network predictor (§4.2.4.1): it forecasts, `l` periods ahead,
//! the mean NRTT and `mt`, and from them the period and queue size the paper's
//! laws would choose.

use core::fmt;

use nalgebra::Vector3;

use crate::filters::{DEFAULT_DECAY, Envelope, FilterError, LowPass};
use crate::kalman::{DEFAULT_HORIZON, Kalman3, KalmanError};
use crate::sizing::Sizing;
use crate::time::Duration;

/// Errors of configuring a [`NetworkPredictor`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum PredictorError {
    /// A filter parameter is invalid.
    Filter(FilterError),
    /// A Kalman parameter is invalid.
    Kalman(KalmanError),
}

impl fmt::Display for PredictorError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PredictorError::Filter(e) => write!(f, "network predictor: {e}"),
            PredictorError::Kalman(e) => write!(f, "network predictor: {e}"),
        }
    }
}

impl core::error::Error for PredictorError {}

impl From<FilterError> for PredictorError {
    fn from(e: FilterError) -> Self {
        PredictorError::Filter(e)
    }
}

impl From<KalmanError> for PredictorError {
    fn from(e: KalmanError) -> Self {
        PredictorError::Kalman(e)
    }
}

/// The predictor's constants; [`PredictorConfig::paper`] gives the paper's.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct PredictorConfig {
    /// The period `T` at which [`NetworkPredictor::step`] is called.
    pub period: Duration,
    /// Prediction horizon `l`, in periods (paper: 50).
    pub horizon: u32,
    /// Time constant of the NRTT low-pass, in periods (paper: 250).
    pub nrtt_tau: f64,
    /// Time constant of the envelope's low-pass, in periods (paper: 25).
    pub mt_tau: f64,
    /// Time constant of the low-pass on the horizon predictions, in periods (paper: 50).
    pub ahead_tau: f64,
    /// Envelope decay `vd` (paper: 1.00005).
    pub decay: f64,
    /// The Kalman filters' σQ (the estimates do not depend on it).
    pub sigma_q: f64,
    /// The laws for the suggested period and queue size.
    pub sizing: Sizing,
}

impl PredictorConfig {
    /// The paper's constants at period `period`.
    #[must_use]
    pub fn paper(period: Duration) -> Self {
        PredictorConfig {
            period,
            horizon: DEFAULT_HORIZON,
            nrtt_tau: 250.0,
            mt_tau: 25.0,
            ahead_tau: 50.0,
            decay: DEFAULT_DECAY,
            sigma_q: 1.0,
            sizing: Sizing::default(),
        }
    }
}

/// One step's output. Times in seconds.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Prediction {
    /// Measured mean NRTT (the low-passed samples).
    pub nrtt_mean: f64,
    /// Measured `mt` (the low-passed envelope of the gaps).
    pub mt: f64,
    /// Mean NRTT predicted `horizon` periods ahead, smoothed, never negative.
    pub nrtt_ahead: f64,
    /// `mt` predicted `horizon` periods ahead, smoothed, never negative.
    pub mt_ahead: f64,
    /// The period the paper's law would choose: `max(T_min, nrtt_ahead/3)`.
    pub period: Duration,
    /// The nominal size the paper's law would choose at that period.
    pub ns: usize,
}

#[derive(Clone, Debug, PartialEq)]
struct Channel {
    measured: LowPass,
    kalman: Kalman3,
    ahead: LowPass,
    started: bool,
}

impl Channel {
    fn new(measured_tau: f64, cfg: &PredictorConfig) -> Result<Self, PredictorError> {
        Ok(Channel {
            measured: LowPass::with_periods(measured_tau, cfg.period)?,
            kalman: Kalman3::new(cfg.sigma_q, cfg.period, cfg.horizon)?,
            ahead: LowPass::with_periods(cfg.ahead_tau, cfg.period)?,
            started: false,
        })
    }

    /// One Kalman step on the measured value; returns (measured, smoothed prediction).
    fn step(&mut self) -> Option<(f64, f64)> {
        let z = self.measured.value()?;
        // Measurements are finite by construction (durations), so the filters cannot fail.
        if self.started {
            self.kalman.step(z).ok()?;
        } else {
            // Start at the first measurement rather than climbing from zero.
            let p = *self.kalman.p();
            self.kalman.set_state(Vector3::new(z, 0.0, 0.0), p).ok()?;
            self.started = true;
        }
        let ahead = self.ahead.update(self.kalman.predict_ahead()).ok()?;
        Some((z, ahead.max(0.0)))
    }

    fn set_period(&mut self, period: Duration) -> Result<(), PredictorError> {
        self.measured.set_period(period)?;
        self.ahead.set_period(period)?;
        self.kalman.set_period(period)?;
        Ok(())
    }
}

/// The paper's network predictor (§4.2.4.1): it forecasts, `l` periods ahead,
/// the mean NRTT and `mt`, and from them the period and queue size the paper's
/// laws would choose.
///
/// ```text
/// NRTT samples ──► LowPass τ=250·T ──► Kalman3 ──► A^l·x ──► LowPass τ=50·T ──► nrtt_ahead ─┐
/// reception gaps ─► Envelope vd ─► LowPass τ=25·T ─► Kalman3 ─► A^l·x ─► LowPass τ=50·T ─► mt_ahead ─┤
///                                                         T = max(T_min, nrtt_ahead/3)  ◄────┤
///                                                         ns = 2 + floor(η·mt_ahead/T)  ◄────┘
/// ```
///
/// Measurements come in whenever they happen ([`observe_nrtt`], [`observe_gap`]);
/// [`step`] runs once per period. A "gap" is the time by which a reception
/// lags its schedule relative to the previous one: the time between two
/// successive receptions minus the time between their sendings (see
/// [`Sizing`](crate::Sizing) for why the paper's `mt` must be measured that way).
///
/// [`observe_nrtt`]: NetworkPredictor::observe_nrtt
/// [`observe_gap`]: NetworkPredictor::observe_gap
/// [`step`]: NetworkPredictor::step
///
/// The paper's two-channel network predictor. No allocation; one
/// [`step`](Self::step) per period.
#[derive(Clone, Debug, PartialEq)]
pub struct NetworkPredictor {
    config: PredictorConfig,
    nrtt: Channel,
    envelope: Envelope,
    mt: Channel,
    last: Option<Prediction>,
    steps: u64,
}

impl NetworkPredictor {
    /// A predictor with the given constants.
    pub fn new(config: PredictorConfig) -> Result<Self, PredictorError> {
        Ok(NetworkPredictor {
            nrtt: Channel::new(config.nrtt_tau, &config)?,
            envelope: Envelope::new(config.decay)?,
            mt: Channel::new(config.mt_tau, &config)?,
            config,
            last: None,
            steps: 0,
        })
    }

    /// A round trip was measured.
    pub fn observe_nrtt(&mut self, nrtt: Duration) {
        // Durations are finite: the low-pass cannot refuse them.
        let _ = self.nrtt.measured.update(nrtt.as_secs_f64());
    }

    /// A frame arrived `gap` later than its schedule relative to the previous one.
    pub fn observe_gap(&mut self, gap: Duration) {
        if let Ok(e) = self.envelope.update(gap.as_secs_f64()) {
            let _ = self.mt.measured.update(e);
        }
    }

    /// Runs the Kalman filters one period; `None` until at least one NRTT and
    /// one gap have been observed.
    #[must_use = "the prediction is the point of stepping"]
    pub fn step(&mut self) -> Option<Prediction> {
        let (nrtt_mean, nrtt_ahead) = self.nrtt.step()?;
        let (mt, mt_ahead) = self.mt.step()?;
        self.steps += 1;
        let law = &self.config.sizing;
        let period = law.period(Duration::from_secs_f64(nrtt_ahead));
        let ns = law.nominal_size(Duration::from_secs_f64(mt_ahead), period);
        let p = Prediction {
            nrtt_mean,
            mt,
            nrtt_ahead,
            mt_ahead,
            period,
            ns,
        };
        self.last = Some(p);
        Some(p)
    }

    /// The latest prediction.
    #[must_use]
    pub fn last(&self) -> Option<Prediction> {
        self.last
    }

    /// Periods stepped so far.
    #[must_use]
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// The constants in use.
    #[must_use]
    pub fn config(&self) -> &PredictorConfig {
        &self.config
    }

    /// The Kalman filter of the mean NRTT.
    #[must_use]
    pub fn nrtt_filter(&self) -> &Kalman3 {
        &self.nrtt.kalman
    }

    /// The Kalman filter of `mt`.
    #[must_use]
    pub fn mt_filter(&self) -> &Kalman3 {
        &self.mt.kalman
    }

    /// Adapts to a new period after the link has changed it, keeping what was
    /// learnt; time constants keep their length in seconds.
    pub fn set_period(&mut self, period: Duration) -> Result<(), PredictorError> {
        self.nrtt.set_period(period)?;
        self.mt.set_period(period)?;
        self.config.period = period;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: Duration = Duration::from_millis(200);

    /// Observes then steps: a driver with one of each per period.
    fn update(p: &mut NetworkPredictor, nrtt: Duration, gap: Duration) -> Option<Prediction> {
        p.observe_nrtt(nrtt);
        p.observe_gap(gap);
        p.step()
    }

    #[test]
    fn nothing_before_both_measurements() {
        let mut p = NetworkPredictor::new(PredictorConfig::paper(T)).unwrap();
        assert_eq!(p.step(), None);
        p.observe_nrtt(Duration::from_millis(23));
        assert_eq!(p.step(), None);
        p.observe_gap(Duration::from_millis(5));
        assert!(p.step().is_some());
        assert_eq!(p.steps(), 1);
    }

    #[test]
    fn steady_lan_gives_the_papers_new_parameters() {
        // 23 ms NRTT, gaps up to 12 ms: T = max(50 ms, 23/3 ms) = 50 ms, ns = 2.
        let mut p = NetworkPredictor::new(PredictorConfig::paper(T)).unwrap();
        let mut last = None;
        for k in 0..2000u64 {
            let gap = Duration::from_millis(if k % 10 == 0 { 12 } else { 1 });
            last = update(&mut p, Duration::from_millis(23), gap);
        }
        let last = last.unwrap();
        assert!((last.nrtt_mean - 0.023).abs() < 1e-9);
        assert!(
            (last.nrtt_ahead - 0.023).abs() < 1e-6,
            "{}",
            last.nrtt_ahead
        );
        assert_eq!(last.period, Duration::from_millis(50));
        assert_eq!(last.ns, 2);
        // The envelope holds the 12 ms peaks (decaying by vd between them).
        assert!((last.mt - 0.012).abs() < 1e-5, "{}", last.mt);
    }

    #[test]
    fn a_rising_delay_is_forecast_ahead_of_the_measure() {
        let mut p = NetworkPredictor::new(PredictorConfig::paper(T)).unwrap();
        let mut last = None;
        // NRTT rising 1 ms per second.
        for k in 0..3000u64 {
            let nrtt = Duration::from_micros(600_000 + k * 200);
            last = update(&mut p, nrtt, Duration::from_millis(300));
        }
        let last = last.unwrap();
        assert!(last.nrtt_ahead > last.nrtt_mean, "{last:?}");
        // ns for a 300 ms mt at the new period: T = nrtt_ahead/3 ≈ 0.4 s.
        let law = Sizing::default();
        assert_eq!(
            last.period,
            law.period(Duration::from_secs_f64(last.nrtt_ahead))
        );
        assert!(last.period > Duration::from_millis(200));
        let expected = 2 + libm::floor(1.3 * last.mt_ahead / last.period.as_secs_f64()) as usize;
        assert_eq!(last.ns, expected);
    }

    #[test]
    fn bad_config_is_refused() {
        let mut cfg = PredictorConfig::paper(T);
        cfg.decay = 0.5;
        assert!(matches!(
            NetworkPredictor::new(cfg),
            Err(PredictorError::Filter(_))
        ));
        let mut cfg = PredictorConfig::paper(T);
        cfg.sigma_q = -1.0;
        assert!(matches!(
            NetworkPredictor::new(cfg),
            Err(PredictorError::Kalman(_))
        ));
        assert!(NetworkPredictor::new(PredictorConfig::paper(Duration::ZERO)).is_err());
    }
}
