//! The paper's discrete Kalman filter on a triple-integrator model (§4.2.4.1).

use core::fmt;

use nalgebra::{Matrix3, RowVector3, Vector3};

use crate::time::Duration;

/// The paper's prediction horizon in periods: 50 (10 s at 200 ms).
pub(crate) const DEFAULT_HORIZON: u32 = 50;

/// Errors of [`Kalman3`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum KalmanError {
    /// σQ must be finite and positive.
    BadSigma(f64),
    /// The period must be positive.
    ZeroPeriod,
    /// A measurement or state was NaN or infinite; the filter is unchanged.
    NonFinite(f64),
    /// `R` must be finite and positive.
    BadR(f64),
    /// The innovation's variance `H·P·Hᵀ + R` was not finite and positive (a `P` set
    /// that is not a covariance); the filter is unchanged.
    NotPositive(f64),
}

impl fmt::Display for KalmanError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            KalmanError::BadSigma(s) => write!(f, "sigma_q {s} must be finite and positive"),
            KalmanError::ZeroPeriod => f.write_str("the Kalman filter's period must be positive"),
            KalmanError::NonFinite(z) => {
                write!(f, "Kalman input {z} is not finite; the filter is unchanged")
            }
            KalmanError::BadR(r) => write!(f, "R = {r} must be finite and positive"),
            KalmanError::NotPositive(s) => write!(
                f,
                "the innovation variance H·P·Hᵀ + R is {s}; it must be finite and positive: P must be a \
                 covariance (symmetric, positive semi-definite); the filter is unchanged"
            ),
        }
    }
}

impl core::error::Error for KalmanError {}

/// The paper's discrete Kalman filter on a triple-integrator model (§4.2.4.1).
///
/// State `x = [value, rate, acceleration]`, sampled every `T`:
///
/// ```text
///     ┌ 1  T  T²/2 ┐                      ┌ 0 0 0  ┐
/// A = │ 0  1  T    │   H = [1 0 0]   Q =  │ 0 0 0  │   R = σQ²   P0 = σQ²·I   B = 0
///     └ 0  0  1    ┘                      └ 0 0 σQ²┘
/// ```
///
/// `A^l` is `A` with `T` replaced by `l·T` (the model is exact for a parabola),
/// so the `l`-step prediction costs one matrix–vector product.
///
/// Q, R and P0 all scale with σQ², so the gains — and hence the estimates — do
/// not depend on σQ; only the reported covariance does.
///
/// The model ([`KalmanModel`]) and the state can be set, as in filterpy, to
/// tune the filter away from the paper's; [`Kalman3::set_period`] goes back
/// to the triple integrator's `A`.
///
/// Triple-integrator Kalman filter with an `l`-step-ahead prediction.
#[derive(Clone, Debug, PartialEq)]
pub struct Kalman3 {
    x: Vector3<f64>,
    p: Matrix3<f64>,
    model: KalmanModel,
    a_ahead: Matrix3<f64>,
    sigma_q2: f64,
    period: Duration,
    horizon: u32,
}

/// What a [`Kalman3`] filters with (filterpy's `F`, `H`, `Q`, `R`): the
/// paper's triple integrator unless set with [`Kalman3::set_model`].
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct KalmanModel {
    /// The transition matrix `A` (filterpy's `F`).
    pub a: Matrix3<f64>,
    /// The measurement matrix `H`, `[1 0 0]` in the paper's model.
    pub h: RowVector3<f64>,
    /// The process noise `Q`, `diag(0, 0, σQ²)` in the paper's model.
    pub q: Matrix3<f64>,
    /// The measurement noise `R` (finite and positive), `σQ²` in the paper's model.
    pub r: f64,
}

/// `A` for a step of `dt` seconds.
fn transition(dt: f64) -> Matrix3<f64> {
    Matrix3::new(1.0, dt, 0.5 * dt * dt, 0.0, 1.0, dt, 0.0, 0.0, 1.0)
}

/// `m` to the power `n`, by squaring.
fn power(m: &Matrix3<f64>, mut n: u32) -> Matrix3<f64> {
    let (mut out, mut base) = (Matrix3::identity(), *m);
    while n > 0 {
        if n & 1 == 1 {
            out *= base;
        }
        base *= base;
        n >>= 1;
    }
    out
}

/// The first value that is NaN or infinite, as an error.
fn all_finite<'a>(values: impl IntoIterator<Item = &'a f64>) -> Result<(), KalmanError> {
    match values.into_iter().find(|v| !v.is_finite()) {
        Some(&bad) => Err(KalmanError::NonFinite(bad)),
        None => Ok(()),
    }
}

impl Kalman3 {
    /// A filter with noise level `sigma_q`, period `period` and prediction
    /// horizon `horizon` periods; state zero, `P0 = σQ²·I`.
    pub fn new(sigma_q: f64, period: Duration, horizon: u32) -> Result<Self, KalmanError> {
        if !(sigma_q.is_finite() && sigma_q > 0.0) {
            return Err(KalmanError::BadSigma(sigma_q));
        }
        if period.is_zero() {
            return Err(KalmanError::ZeroPeriod);
        }
        let sigma_q2 = sigma_q * sigma_q;
        let dt = period.as_secs_f64();
        Ok(Kalman3 {
            x: Vector3::zeros(),
            p: Matrix3::identity() * sigma_q2,
            model: KalmanModel {
                a: transition(dt),
                h: RowVector3::new(1.0, 0.0, 0.0),
                q: Matrix3::from_diagonal(&Vector3::new(0.0, 0.0, sigma_q2)),
                r: sigma_q2,
            },
            a_ahead: transition(dt * f64::from(horizon)),
            sigma_q2,
            period,
            horizon,
        })
    }

    /// Time update: `x ← A·x`, `P ← A·P·Aᵀ + Q`.
    pub fn predict(&mut self) {
        let m = &self.model;
        self.x = m.a * self.x;
        self.p = m.a * self.p * m.a.transpose() + m.q;
    }

    /// Measurement update with `z`; returns the innovation `z − H·x`.
    pub fn update(&mut self, z: f64) -> Result<f64, KalmanError> {
        if !z.is_finite() {
            return Err(KalmanError::NonFinite(z));
        }
        // One measurement: S is a scalar (with the paper's H, P·Hᵀ is the
        // first column of P).
        let (h, r) = (self.model.h, self.model.r);
        let innovation = z - (h * self.x)[0];
        let ph: Vector3<f64> = self.p * h.transpose();
        let s = (h * ph)[0] + r;
        if !(s.is_finite() && s > 0.0) {
            return Err(KalmanError::NotPositive(s));
        }
        let gain = ph / s;
        self.x += gain * innovation;
        self.p -= gain * ph.transpose();
        // Keep P symmetric against rounding.
        self.p = (self.p + self.p.transpose()) * 0.5;
        Ok(innovation)
    }

    /// [`predict`](Self::predict) then [`update`](Self::update); returns the filtered value.
    pub fn step(&mut self, z: f64) -> Result<f64, KalmanError> {
        if !z.is_finite() {
            return Err(KalmanError::NonFinite(z));
        }
        let before = (self.x, self.p);
        self.predict();
        if let Err(e) = self.update(z) {
            (self.x, self.p) = before;
            return Err(e);
        }
        Ok(self.value())
    }

    /// The value predicted `horizon` periods ahead, `H·A^l·x`.
    #[must_use]
    pub fn predict_ahead(&self) -> f64 {
        (self.model.h * self.a_ahead * self.x)[0]
    }

    /// The state estimate `[value, rate, acceleration]`.
    #[must_use]
    pub fn x(&self) -> &Vector3<f64> {
        &self.x
    }

    /// The filtered value, `H·x`.
    #[must_use]
    pub fn value(&self) -> f64 {
        (self.model.h * self.x)[0]
    }

    /// Sets the state `x` and its covariance `P`, e.g. `[first measurement,
    /// 0, 0]` to start without a transient. Both must be finite, or nothing
    /// changes; a `P` that is no covariance is refused by the next update.
    pub fn set_state(&mut self, x: Vector3<f64>, p: Matrix3<f64>) -> Result<(), KalmanError> {
        all_finite(x.iter().chain(p.iter()))?;
        (self.x, self.p) = (x, p);
        Ok(())
    }

    /// The state covariance `P`.
    #[must_use]
    pub fn p(&self) -> &Matrix3<f64> {
        &self.p
    }

    /// The model in use: the triple integrator's unless set.
    #[must_use]
    pub fn model(&self) -> &KalmanModel {
        &self.model
    }

    /// Replaces the model, e.g. to tune the filter away from the paper's
    /// (as filterpy's `F`, `H`, `Q`, `R` are set); `A^l` follows. Every
    /// entry must be finite and `R` positive, or nothing changes.
    pub fn set_model(&mut self, model: KalmanModel) -> Result<(), KalmanError> {
        let KalmanModel { a, h, q, r } = model;
        all_finite(a.iter().chain(h.iter()).chain(q.iter()))?;
        if !(r.is_finite() && r > 0.0) {
            return Err(KalmanError::BadR(r));
        }
        self.a_ahead = power(&a, self.horizon);
        self.model = model;
        Ok(())
    }

    /// `A^l`, the horizon transition: `a_ahead() * x()` is the whole state
    /// predicted `horizon` periods ahead.
    #[must_use]
    pub fn a_ahead(&self) -> &Matrix3<f64> {
        &self.a_ahead
    }

    /// The noise level σQ given to [`new`](Self::new) (`P0 = σQ²·I`).
    #[must_use]
    pub fn sigma_q(&self) -> f64 {
        libm::sqrt(self.sigma_q2)
    }

    /// The sampling period `T`.
    #[must_use]
    pub fn period(&self) -> Duration {
        self.period
    }

    /// The prediction horizon `l`, in periods.
    #[must_use]
    pub fn horizon(&self) -> u32 {
        self.horizon
    }

    /// Changes `T` (the horizon stays `l` periods) keeping the estimate: the
    /// state is in units per second, so it stays valid. `A` is the triple
    /// integrator's again (an `A` set by [`set_model`](Self::set_model) is replaced).
    pub fn set_period(&mut self, period: Duration) -> Result<(), KalmanError> {
        if period.is_zero() {
            return Err(KalmanError::ZeroPeriod);
        }
        let dt = period.as_secs_f64();
        self.period = period;
        self.model.a = transition(dt);
        self.a_ahead = transition(dt * f64::from(self.horizon));
        Ok(())
    }

    /// Back to state zero and `P0 = σQ²·I`.
    pub fn reset(&mut self) {
        self.x = Vector3::zeros();
        self.p = Matrix3::identity() * self.sigma_q2;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: Duration = Duration::from_millis(200);

    fn run(k: &mut Kalman3, f: impl Fn(f64) -> f64, steps: u32) {
        for i in 1..=steps {
            k.step(f(f64::from(i) * 0.2)).unwrap();
        }
    }

    #[test]
    fn tracks_a_constant() {
        let mut k = Kalman3::new(1.0, T, DEFAULT_HORIZON).unwrap();
        run(&mut k, |_| 0.61, 400);
        assert!((k.value() - 0.61).abs() < 1e-9, "{}", k.value());
        assert!(k.x()[1].abs() < 1e-9 && k.x()[2].abs() < 1e-9);
        assert!((k.predict_ahead() - 0.61).abs() < 1e-9);
    }

    #[test]
    fn tracks_a_ramp_and_predicts_it_exactly() {
        let mut k = Kalman3::new(1.0, T, DEFAULT_HORIZON).unwrap();
        let ramp = |t: f64| 0.5 + 0.03 * t;
        run(&mut k, ramp, 600);
        let t_now = 600.0 * 0.2;
        assert!((k.value() - ramp(t_now)).abs() < 1e-9);
        assert!((k.x()[1] - 0.03).abs() < 1e-9);
        // 50 steps of 200 ms ahead.
        assert!(
            (k.predict_ahead() - ramp(t_now + 10.0)).abs() < 1e-8,
            "{}",
            k.predict_ahead()
        );
    }

    #[test]
    fn tracks_a_parabola() {
        let mut k = Kalman3::new(0.1, T, DEFAULT_HORIZON).unwrap();
        let parabola = |t: f64| 1.0 + 0.2 * t - 0.004 * t * t;
        run(&mut k, parabola, 800);
        let t_now = 800.0 * 0.2;
        assert!((k.value() - parabola(t_now)).abs() < 1e-7, "{}", k.value());
        assert!((k.x()[2] - (-0.008)).abs() < 1e-8);
        assert!((k.predict_ahead() - parabola(t_now + 10.0)).abs() < 1e-6);
    }

    #[test]
    fn the_horizon_matrix_is_a_to_the_l() {
        let k = Kalman3::new(1.0, T, 50).unwrap();
        let mut pow = Matrix3::identity();
        for _ in 0..50 {
            pow *= k.model().a;
        }
        assert!((pow - k.a_ahead()).abs().max() < 1e-9);
    }

    #[test]
    fn estimates_do_not_depend_on_sigma_q() {
        let mut a = Kalman3::new(1.0, T, 50).unwrap();
        let mut b = Kalman3::new(0.01, T, 50).unwrap();
        for i in 0..200 {
            let z = libm::sin(f64::from(i) * 0.1) + 0.2;
            a.step(z).unwrap();
            b.step(z).unwrap();
        }
        assert!((a.x() - b.x()).abs().max() < 1e-9);
        assert!((a.p() - b.p() * 1e4).abs().max() < 1e-6 * a.p().abs().max());
    }

    #[test]
    fn rejects_bad_input_without_changing() {
        assert!(Kalman3::new(0.0, T, 50).is_err());
        assert!(Kalman3::new(f64::NAN, T, 50).is_err());
        assert_eq!(
            Kalman3::new(1.0, Duration::ZERO, 50),
            Err(KalmanError::ZeroPeriod)
        );
        let mut k = Kalman3::new(1.0, T, 50).unwrap();
        k.step(1.0).unwrap();
        let before = k.clone();
        assert!(k.step(f64::NAN).is_err());
        assert!(k.update(f64::INFINITY).is_err());
        assert!(
            k.set_state(Vector3::new(0.0, f64::NAN, 0.0), *k.p())
                .is_err()
        );
        assert_eq!(k, before);
    }

    #[test]
    fn a_tuned_filter_uses_what_was_set() {
        let mut k = Kalman3::new(1.0, T, 4).unwrap();
        // A constant-velocity model on the first two states, H reading the rate.
        let f = Matrix3::new(1.0, 0.2, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0);
        let tuned = KalmanModel {
            a: f,
            h: RowVector3::new(0.0, 1.0, 0.0),
            q: Matrix3::identity() * 1e-3,
            r: 0.5,
        };
        k.set_model(tuned).unwrap();
        assert!((k.a_ahead() - f * f * f * f).abs().max() < 1e-12);
        k.set_state(Vector3::new(1.0, 2.0, 0.0), *k.p()).unwrap();
        assert_eq!(k.value(), 2.0);
        assert!((k.predict_ahead() - 2.0).abs() < 1e-12);
        // By hand: P = F·I·Fᵀ + Q, S = P[1,1] + R, K = P[:,1] / S.
        k.predict();
        let p = f * f.transpose() + Matrix3::identity() * 1e-3;
        let s = p[(1, 1)] + 0.5;
        let e = k.update(3.0).unwrap();
        assert!((e - 1.0).abs() < 1e-12);
        assert!((k.x()[1] - (2.0 + p[(1, 1)] / s)).abs() < 1e-12);
        assert!((k.x()[0] - (1.4 + p[(0, 1)] / s)).abs() < 1e-12);
        assert_eq!(
            k.set_model(KalmanModel { r: 0.0, ..tuned }),
            Err(KalmanError::BadR(0.0))
        );
        let nan_q = KalmanModel {
            q: Matrix3::from_element(f64::NAN),
            ..tuned
        };
        assert!(k.set_model(nan_q).is_err());
        assert_eq!(*k.model(), tuned);
        // A P that is no covariance is refused at the update, unchanged.
        k.set_state(*k.x(), -Matrix3::identity()).unwrap();
        let before = k.clone();
        assert!(matches!(k.step(1.0), Err(KalmanError::NotPositive(_))));
        assert_eq!(k, before);
        // set_period goes back to the paper's A.
        k.set_period(T).unwrap();
        assert_eq!(k.model().a, transition(0.2));
    }

    #[test]
    fn period_change_keeps_the_estimate() {
        let mut k = Kalman3::new(1.0, T, 50).unwrap();
        run(&mut k, |t| 2.0 * t, 400);
        let x = *k.x();
        k.set_period(Duration::from_millis(50)).unwrap();
        assert_eq!(*k.x(), x);
        // Horizon now 50 · 50 ms = 2.5 s.
        assert!((k.predict_ahead() - (x[0] + 2.0 * 2.5)).abs() < 1e-8);
    }
}
