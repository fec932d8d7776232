//! A discrete PID with output limits and anti-windup.

use super::{ControlError, finite};

/// A [`Pid`]'s gains, limits and period.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct PidConfig {
    /// Proportional gain.
    pub kp: f64,
    /// Integral gain, per second (0: a PD).
    pub ki: f64,
    /// Derivative gain, seconds.
    pub kd: f64,
    /// Time constant of the derivative's low-pass, seconds (0: unfiltered).
    pub derivative_filter_s: f64,
    /// Lowest output.
    pub out_min: f64,
    /// Highest output.
    pub out_max: f64,
    /// The period between steps, seconds.
    pub period_s: f64,
}

impl PidConfig {
    /// A PID without limits and without a derivative filter; set the
    /// fields for those.
    #[must_use]
    pub const fn new(kp: f64, ki: f64, kd: f64, period_s: f64) -> Self {
        PidConfig {
            kp,
            ki,
            kd,
            derivative_filter_s: 0.0,
            out_min: f64::NEG_INFINITY,
            out_max: f64::INFINITY,
            period_s,
        }
    }
}

/// A discrete PID with output limits and anti-windup.
///
/// `u = kp·e + ki·∫e + kd·d(−y)/dt` with `e = r − y`: the derivative acts on
/// the measurement, so a step of the reference does not kick the output,
/// and is low-passed with time constant `derivative_filter_s` (0: none).
/// The integral is clamped (conditional integration): while the output is
/// saturated, the error that would push it further is not integrated, so
/// the loop leaves a limit as soon as the error turns.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pid {
    cfg: PidConfig,
    integral: f64,
    derivative: f64,
    last_y: Option<f64>,
}

impl Pid {
    /// A PID at rest.
    ///
    /// # Errors
    /// [`ControlError::InvalidParameter`] for a gain that is not finite, a
    /// period that is not finite and positive, a negative filter constant;
    /// [`ControlError::InvalidLimits`] if `out_min > out_max` or a limit is
    /// NaN.
    pub fn new(cfg: PidConfig) -> Result<Self, ControlError> {
        for (v, what) in [(cfg.kp, "kp"), (cfg.ki, "ki"), (cfg.kd, "kd")] {
            if !v.is_finite() {
                return Err(ControlError::InvalidParameter(what));
            }
        }
        if !(cfg.period_s.is_finite() && cfg.period_s > 0.0) {
            return Err(ControlError::InvalidParameter("the period (s, > 0)"));
        }
        if !(cfg.derivative_filter_s.is_finite() && cfg.derivative_filter_s >= 0.0) {
            return Err(ControlError::InvalidParameter("the derivative filter (s)"));
        }
        // NaN limits compare as neither: refused with the empty range.
        if cfg
            .out_min
            .partial_cmp(&cfg.out_max)
            .is_none_or(|o| o.is_gt())
        {
            return Err(ControlError::InvalidLimits {
                min: cfg.out_min,
                max: cfg.out_max,
            });
        }
        Ok(Pid {
            cfg,
            integral: 0.0,
            derivative: 0.0,
            last_y: None,
        })
    }

    /// The configuration.
    #[must_use]
    pub fn config(&self) -> &PidConfig {
        &self.cfg
    }

    /// Changes the period (the link resized), keeping the state.
    ///
    /// # Errors
    /// [`ControlError::InvalidParameter`] if `period_s` is not finite and
    /// positive.
    pub fn set_period(&mut self, period_s: f64) -> Result<(), ControlError> {
        if !(period_s.is_finite() && period_s > 0.0) {
            return Err(ControlError::InvalidParameter("the period (s, > 0)"));
        }
        self.cfg.period_s = period_s;
        Ok(())
    }

    /// One step: the output for reference `r` and measurement `y`.
    ///
    /// # Errors
    /// [`ControlError::NonFiniteInput`] if `r` or `y` is NaN or infinite;
    /// the controller is then unchanged.
    pub fn step(&mut self, r: f64, y: f64) -> Result<f64, ControlError> {
        let (r, y) = (finite(r)?, finite(y)?);
        let c = &self.cfg;
        let dt = c.period_s;
        let e = r - y;
        // Derivative of −y: no kick on a reference step.
        let raw = self.last_y.map_or(0.0, |last| (last - y) / dt);
        let alpha = dt / (c.derivative_filter_s + dt);
        let derivative = self.derivative + alpha * (raw - self.derivative);
        let unsat = c.kp * e + c.ki * self.integral + c.kd * derivative;
        let integral = self.integral + e * dt;
        let candidate = c.kp * e + c.ki * integral + c.kd * derivative;
        let out = candidate.clamp(c.out_min, c.out_max);
        // Integrate unless saturated and the error pushes further out.
        let winds_up =
            (candidate > c.out_max && c.ki * e > 0.0) || (candidate < c.out_min && c.ki * e < 0.0);
        if !winds_up {
            self.integral = integral;
        }
        self.derivative = derivative;
        self.last_y = Some(y);
        Ok(if winds_up {
            unsat.clamp(c.out_min, c.out_max)
        } else {
            out
        })
    }

    /// Back to rest (integral, derivative and last measurement cleared).
    pub fn reset(&mut self) {
        self.integral = 0.0;
        self.derivative = 0.0;
        self.last_y = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pd_is_proportional_and_damps_on_the_measurement() {
        let mut pd = Pid::new(PidConfig::new(2.0, 0.0, 0.5, 0.1)).unwrap();
        assert_eq!(pd.step(1.0, 0.0).unwrap(), 2.0);
        // The measurement rose by 0.2 in 0.1 s: −0.5·2 from the derivative.
        let u = pd.step(1.0, 0.2).unwrap();
        assert!((u - (2.0 * 0.8 - 1.0)).abs() < 1e-12, "{u}");
        // A reference step alone kicks nothing but kp.
        let u = pd.step(2.0, 0.2).unwrap();
        assert!((u - 3.6).abs() < 1e-12, "{u}");
    }

    #[test]
    fn the_output_stays_in_its_limits_and_the_integral_does_not_wind_up() {
        let mut cfg = PidConfig::new(1.0, 5.0, 0.0, 0.01);
        (cfg.out_min, cfg.out_max) = (-1.0, 1.0);
        let mut pi = Pid::new(cfg).unwrap();
        // A long saturation: the error is large, the output pinned.
        for _ in 0..1000 {
            assert_eq!(pi.step(10.0, 0.0).unwrap(), 1.0);
        }
        // Without anti-windup the integral would be 100 and hold the output
        // at the limit for many steps; clamped, it leaves at once.
        let u = pi.step(-0.5, 0.0).unwrap();
        assert!(u < 1.0, "{u}");
        // An unlimited PI integrates everything.
        let mut free = Pid::new(PidConfig::new(1.0, 5.0, 0.0, 0.01)).unwrap();
        for _ in 0..1000 {
            free.step(10.0, 0.0).unwrap();
        }
        assert!(free.step(-0.5, 0.0).unwrap() > 400.0);
    }

    #[test]
    fn bad_configurations_and_inputs_are_refused() {
        assert!(Pid::new(PidConfig::new(f64::NAN, 0.0, 0.0, 0.1)).is_err());
        assert!(Pid::new(PidConfig::new(1.0, 0.0, 0.0, 0.0)).is_err());
        assert_eq!(
            Pid::new(PidConfig {
                out_min: 1.0,
                out_max: -1.0,
                ..PidConfig::new(1.0, 0.0, 0.0, 0.1)
            }),
            Err(ControlError::InvalidLimits {
                min: 1.0,
                max: -1.0
            })
        );
        let mut p = Pid::new(PidConfig::new(1.0, 1.0, 0.0, 0.1)).unwrap();
        let before = p;
        assert_eq!(
            p.step(f64::INFINITY, 0.0),
            Err(ControlError::NonFiniteInput)
        );
        assert_eq!(p, before);
    }
}
