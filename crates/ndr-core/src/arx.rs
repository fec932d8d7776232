//! The remote system's per-axis model: a second-order discrete transfer
//! function, its simulator, and its online identification.

use core::fmt;

use crate::rls::{Rls, RlsError};

/// Why a model could not be built or identified.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum ArxError {
    /// The natural frequency is not finite and positive (rad/s).
    InvalidNaturalFrequency(f64),
    /// The damping ratio is not finite and positive.
    InvalidDamping(f64),
    /// The static gain is not finite.
    InvalidGain(f64),
    /// The sampling period is not finite and positive (s).
    InvalidPeriod(f64),
    /// The discretized model is numerically degenerate: a coefficient
    /// overflows or rounding puts a pole on the unit circle (extreme `ωn·T`
    /// or `ζ`).
    Degenerate,
    /// An input or output sample is NaN or infinite.
    NonFiniteInput,
    /// The underlying RLS rejected its parameters or an update.
    Rls(RlsError),
}

impl fmt::Display for ArxError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            ArxError::InvalidNaturalFrequency(w) => write!(
                f,
                "natural frequency {w} rad/s must be finite and > 0 (it is 2π times the \
                 cut-off in Hz)"
            ),
            ArxError::InvalidDamping(z) => write!(
                f,
                "damping ratio {z} must be finite and > 0 (0.7 is a typical well-damped axis)"
            ),
            ArxError::InvalidGain(g) => write!(f, "static gain {g} must be finite"),
            ArxError::InvalidPeriod(t) => write!(
                f,
                "sampling period {t} s must be finite and > 0 (the link period, e.g. 0.2)"
            ),
            ArxError::Degenerate => f.write_str(
                "discretized low-pass is numerically degenerate (a coefficient overflows or a \
                 pole rounds onto the unit circle): ωn·T or ζ is extreme; use a sampling \
                 period comparable to the system's time constants",
            ),
            ArxError::NonFiniteInput => f.write_str(
                "input or output sample is NaN or infinite: it was ignored and the \
                 identification is unchanged; check the signal source",
            ),
            ArxError::Rls(e) => write!(f, "identification: {e}"),
        }
    }
}

impl core::error::Error for ArxError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            ArxError::Rls(e) => Some(e),
            _ => None,
        }
    }
}

impl From<RlsError> for ArxError {
    fn from(e: RlsError) -> Self {
        ArxError::Rls(e)
    }
}

/// A second-order discrete transfer function
/// `(b0 + b1 z⁻¹ + b2 z⁻²) / (1 + a1 z⁻¹ + a2 z⁻²)`; the leading 1 of the
/// denominator is implicit.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Tf2 {
    /// Numerator `[b0, b1, b2]`.
    pub b: [f64; 3],
    /// Denominator without its leading 1: `[a1, a2]`.
    pub a: [f64; 2],
}

impl Tf2 {
    /// The continuous low-pass `gain·ωn² / (s² + 2ζωn s + ωn²)` discretized
    /// with period `period_s` by the bilinear (Tustin) transform
    /// `s = c (1 − z⁻¹)/(1 + z⁻¹)`, `c = 2/T`, without pre-warping (as in the
    /// paper). Multiplying through by `(1 + z⁻¹)²` and dividing by
    /// `a0 = c² + 2ζωn c + ωn²`:
    ///
    /// ```text
    /// b  = gain·ωn²/a0 · [1, 2, 1]
    /// a1 = 2 (ωn² − c²) / a0
    /// a2 = (c² − 2ζωn c + ωn²) / a0
    /// ```
    ///
    /// The result is stable for any `ζ > 0` and its DC gain is `gain`.
    ///
    /// # Errors
    /// [`ArxError::InvalidNaturalFrequency`], [`ArxError::InvalidDamping`],
    /// [`ArxError::InvalidGain`], [`ArxError::InvalidPeriod`] for an invalid
    /// argument; [`ArxError::Degenerate`] if the coefficients overflow or
    /// rounding makes the result not stable.
    pub fn low_pass(wn_rad_s: f64, zeta: f64, gain: f64, period_s: f64) -> Result<Tf2, ArxError> {
        if !(wn_rad_s.is_finite() && wn_rad_s > 0.0) {
            return Err(ArxError::InvalidNaturalFrequency(wn_rad_s));
        }
        if !(zeta.is_finite() && zeta > 0.0) {
            return Err(ArxError::InvalidDamping(zeta));
        }
        if !gain.is_finite() {
            return Err(ArxError::InvalidGain(gain));
        }
        if !(period_s.is_finite() && period_s > 0.0) {
            return Err(ArxError::InvalidPeriod(period_s));
        }
        let c = 2.0 / period_s;
        let wn2 = wn_rad_s * wn_rad_s;
        let c2 = c * c;
        let damp = 2.0 * zeta * wn_rad_s * c;
        let a0 = c2 + damp + wn2;
        let b0 = gain * wn2 / a0;
        let tf = Tf2 {
            b: [b0, 2.0 * b0, b0],
            a: [2.0 * (wn2 - c2) / a0, (c2 - damp + wn2) / a0],
        };
        // Stable in exact arithmetic for ζ > 0; rounding (ωn·T → 0 puts both
        // poles at 1) or overflow (NaN coefficients) can break that.
        if !(tf.is_finite() && tf.is_stable()) {
            return Err(ArxError::Degenerate);
        }
        Ok(tf)
    }

    /// The parameters in RLS order `[b0, b1, b2, a1, a2]`.
    #[must_use]
    pub(crate) const fn params(&self) -> [f64; 5] {
        [self.b[0], self.b[1], self.b[2], self.a[0], self.a[1]]
    }

    /// The transfer function from parameters in RLS order `[b0, b1, b2, a1, a2]`.
    #[must_use]
    pub(crate) const fn from_params(theta: &[f64; 5]) -> Self {
        Tf2 {
            b: [theta[0], theta[1], theta[2]],
            a: [theta[3], theta[4]],
        }
    }

    /// `H(1) = (b0 + b1 + b2)/(1 + a1 + a2)`: the steady-state output per unit
    /// constant input. Infinite or NaN for a model with a pole at `z = 1`.
    #[must_use]
    pub fn dc_gain(&self) -> f64 {
        (self.b[0] + self.b[1] + self.b[2]) / (1.0 + self.a[0] + self.a[1])
    }

    /// Whether both poles lie strictly inside the unit circle (Jury:
    /// `|a2| < 1` and `|a1| < 1 + a2`). False for non-finite coefficients.
    #[must_use]
    pub fn is_stable(&self) -> bool {
        let [a1, a2] = self.a;
        libm::fabs(a2) < 1.0 && libm::fabs(a1) < 1.0 + a2
    }

    /// Whether all five coefficients are finite.
    #[must_use]
    pub fn is_finite(&self) -> bool {
        self.params().iter().all(|v| v.is_finite())
    }

    /// One step of the difference equation: `y[k]` from `u[k]`, `u[k−1]`,
    /// `u[k−2]`, `y[k−1]`, `y[k−2]`.
    #[must_use]
    #[inline]
    pub(crate) fn output(&self, u: f64, u1: f64, u2: f64, y1: f64, y2: f64) -> f64 {
        self.b[0] * u + self.b[1] * u1 + self.b[2] * u2 - self.a[0] * y1 - self.a[1] * y2
    }
}

/// A running simulation of a [`Tf2`]: the model plus its last two inputs and
/// outputs. The simulator uses one per axis as the remote robot's plant.
///
/// Non-finite inputs propagate into the outputs (a plant does not validate
/// its input); [`Tf2State::reset`] recovers.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tf2State {
    model: Tf2,
    u1: f64,
    u2: f64,
    y1: f64,
    y2: f64,
}

impl Tf2State {
    /// The model at rest: past inputs and outputs zero.
    #[must_use]
    pub const fn new(model: Tf2) -> Self {
        Tf2State::with_initial(model, [0.0; 2], [0.0; 2])
    }

    /// The model with past inputs `[u[k−1], u[k−2]]` and past outputs
    /// `[y[k−1], y[k−2]]`.
    #[must_use]
    pub const fn with_initial(model: Tf2, u_past: [f64; 2], y_past: [f64; 2]) -> Self {
        Tf2State {
            model,
            u1: u_past[0],
            u2: u_past[1],
            y1: y_past[0],
            y2: y_past[1],
        }
    }

    /// Feeds input `u[k]` and returns the output `y[k]`.
    #[inline]
    pub fn step(&mut self, u: f64) -> f64 {
        let y = self.model.output(u, self.u1, self.u2, self.y1, self.y2);
        self.u2 = self.u1;
        self.u1 = u;
        self.y2 = self.y1;
        self.y1 = y;
        y
    }

    /// The latest output `y[k−1]` (zero before the first step from rest).
    #[must_use]
    pub fn output(&self) -> f64 {
        self.y1
    }

    /// The simulated model.
    #[must_use]
    pub fn model(&self) -> &Tf2 {
        &self.model
    }

    /// Changes the model and keeps the past inputs and outputs (a plant whose
    /// dynamics change while it runs).
    pub fn set_model(&mut self, model: Tf2) {
        self.model = model;
    }

    /// Back to rest: past inputs and outputs zero, model kept.
    pub fn reset(&mut self) {
        *self = Tf2State::new(self.model);
    }
}

/// The remote system's per-axis model: a second-order discrete transfer
/// function, its simulator, and its online identification.
///
/// The paper (§4.3) models every axis of the remote robot, once linearised by
/// computed torque, as a continuous second-order low-pass system discretized
/// by the bilinear transform:
///
/// ```text
///          b0 + b1 z⁻¹ + b2 z⁻²
/// H(z) = ────────────────────────      y[k] = b0 u[k] + b1 u[k−1] + b2 u[k−2]
///           1 + a1 z⁻¹ + a2 z⁻²                 − a1 y[k−1] − a2 y[k−2]
/// ```
///
/// - [`Tf2`] holds the coefficients ([`Tf2::low_pass`] builds them from
///   `ωn`, `ζ`, gain and period);
/// - [`Tf2State`] simulates one (the simulator's plant, one per axis);
/// - [`Arx2`] identifies one from the input/output stream with an [`Rls<5>`]
///   on the regressor `φ[k] = [u[k], u[k−1], u[k−2], −y[k−1], −y[k−2]]` and
///   the parameters `θ = [b0, b1, b2, a1, a2]`.
///
/// Online identification of a [`Tf2`] from the input/output stream of one
/// axis, by recursive least squares on
/// `φ[k] = [u[k], u[k−1], u[k−2], −y[k−1], −y[k−2]]`,
/// `θ = [b0, b1, b2, a1, a2]`.
///
/// `Arx2` keeps the last two samples itself. It adapts only once it holds two
/// *trusted* past samples: the first two calls of [`Arx2::update`] (and the
/// two after [`Arx2::clear_history`] or [`Arx2::record_substitute`]) only fill
/// the history. Starting from zeros instead would claim the system was at rest
/// with zero input, which is false when identification starts mid-motion, and
/// would bias the first updates.
#[derive(Clone, Debug, PartialEq)]
pub struct Arx2 {
    rls: Rls<5>,
    u1: f64,
    u2: f64,
    y1: f64,
    y2: f64,
    /// How many of the two most recent samples may enter a regressor.
    trusted: u8,
}

impl Arx2 {
    /// An identifier with RLS forgetting factor `lambda` and initial
    /// covariance `delta·I`; the model starts at all-zero coefficients.
    ///
    /// # Errors
    /// [`ArxError::Rls`] as for [`Rls::new`].
    pub fn new(lambda: f64, delta: f64) -> Result<Self, ArxError> {
        Ok(Arx2::from_rls(Rls::new(lambda, delta)?))
    }

    /// An identifier around a configured RLS (e.g. a custom trace bound or
    /// prior weights `[b0, b1, b2, a1, a2]`), with an empty history.
    #[must_use]
    pub(crate) fn from_rls(rls: Rls<5>) -> Self {
        Arx2 {
            rls,
            u1: 0.0,
            u2: 0.0,
            y1: 0.0,
            y2: 0.0,
            trusted: 0,
        }
    }

    /// Feeds `u[k]` and `y[k]`. Adapts the model if the history holds two
    /// trusted samples and returns `Some` a-priori prediction error
    /// `y[k] − φ[k]ᵀθ`; otherwise only records them and returns `None`.
    ///
    /// # Errors
    /// [`ArxError::NonFiniteInput`] if `u` or `y` is NaN or infinite,
    /// [`ArxError::Rls`] if the update overflows; the identifier is then
    /// unchanged.
    pub fn update(&mut self, u: f64, y: f64) -> Result<Option<f64>, ArxError> {
        if !(u.is_finite() && y.is_finite()) {
            return Err(ArxError::NonFiniteInput);
        }
        let e = if self.trusted >= 2 {
            Some(self.rls.update(&self.regressor(u), y)?)
        } else {
            None
        };
        self.push(u, y);
        self.trusted = (self.trusted + 1).min(2);
        Ok(e)
    }

    /// Records a stand-in sample (e.g. the model's own prediction of an output
    /// that was lost) so the history stays contiguous, without ever adapting on
    /// it: the next two [`Arx2::update`] calls only record.
    pub fn record_substitute(&mut self, u: f64, y: f64) {
        self.push(u, y);
        self.trusted = 0;
    }

    /// Forgets the past samples (e.g. after a gap in the stream); the model
    /// is kept and the next two [`Arx2::update`] calls only record.
    pub fn clear_history(&mut self) {
        *self = Arx2::from_rls(self.rls.clone());
    }

    /// The one-step prediction `φ[k]ᵀθ` of `y[k]` for input `u[k]` from the
    /// recorded history, or `None` while the history is not full.
    #[must_use]
    pub fn predict(&self, u: f64) -> Option<f64> {
        (self.trusted >= 2).then(|| self.rls.predict(&self.regressor(u)))
    }

    /// The identified model.
    #[must_use]
    pub fn model(&self) -> Tf2 {
        Tf2::from_params(self.rls.weights())
    }

    /// The RLS engine (weights, covariance, counters).
    #[must_use]
    pub fn rls(&self) -> &Rls<5> {
        &self.rls
    }

    #[cfg(test)]
    /// The RLS engine, mutable: set prior weights, reset the covariance after
    /// a known change, tune the forgetting factor.
    pub(crate) fn rls_mut(&mut self) -> &mut Rls<5> {
        &mut self.rls
    }

    /// Number of adapting updates so far (the [`rls`](Self::rls)'s count).
    #[must_use]
    pub(crate) fn updates(&self) -> u64 {
        self.rls.updates()
    }

    /// How many of the model's 5 directions the data has not determined:
    /// the covariance's eigenvalues still above half the prior `δ`. A
    /// constant input leaves at least two (only `b0 + b1 + b2` is seen), and
    /// the model's coefficients along them are the prior's, not the
    /// system's; `0` once the input excites every direction.
    #[must_use]
    pub fn unexcited(&self) -> usize {
        let half = 0.5 * self.rls.delta();
        self.rls
            .covariance()
            .symmetric_eigenvalues()
            .iter()
            .filter(|&&e| e > half)
            .count()
    }

    /// Back to the state after [`Arx2::new`]: zero model, covariance `δ·I`,
    /// empty history, counters at zero.
    pub fn reset(&mut self) {
        self.rls.reset();
        self.clear_history();
    }

    fn regressor(&self, u: f64) -> [f64; 5] {
        [u, self.u1, self.u2, -self.y1, -self.y2]
    }

    fn push(&mut self, u: f64, y: f64) {
        self.u2 = self.u1;
        self.u1 = u;
        self.y2 = self.y1;
        self.y1 = y;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_constant_input_leaves_the_model_unexcited() {
        let plant = Tf2 {
            b: [0.1, 0.05, 0.0],
            a: [-0.9, 0.2],
        };
        let run = |input: &dyn Fn(u32) -> f64| {
            let mut arx = Arx2::new(1.0, 1e6).unwrap();
            let mut state = Tf2State::new(plant);
            assert_eq!(arx.unexcited(), 5);
            for k in 0..300 {
                let u = input(k);
                arx.update(u, state.step(u)).unwrap();
            }
            arx
        };
        let constant = run(&|_| 1.0);
        assert!(constant.unexcited() >= 2, "{}", constant.unexcited());
        // A pseudo-random input excites every direction and finds the plant.
        let mut noise = [0.0; 300];
        let mut x = 0x2545_f491_4f6c_dd1du64;
        for v in &mut noise {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            *v = (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
        }
        let rich = run(&|k| noise[k as usize]);
        assert_eq!(rich.unexcited(), 0);
        assert!((rich.model().b[0] - 0.1).abs() < 1e-6);
    }

    #[test]
    fn low_pass_validates() {
        assert_eq!(
            Tf2::low_pass(0.0, 0.7, 1.0, 0.1),
            Err(ArxError::InvalidNaturalFrequency(0.0))
        );
        assert_eq!(
            Tf2::low_pass(1.0, -0.1, 1.0, 0.1),
            Err(ArxError::InvalidDamping(-0.1))
        );
        assert_eq!(
            Tf2::low_pass(1.0, 0.0, 1.0, 0.1),
            Err(ArxError::InvalidDamping(0.0))
        );
        assert_eq!(
            Tf2::low_pass(1.0, 0.7, f64::INFINITY, 0.1),
            Err(ArxError::InvalidGain(f64::INFINITY))
        );
        assert_eq!(
            Tf2::low_pass(1.0, 0.7, 1.0, -1.0),
            Err(ArxError::InvalidPeriod(-1.0))
        );
        assert!(matches!(
            Tf2::low_pass(f64::NAN, 0.7, 1.0, 0.1),
            Err(ArxError::InvalidNaturalFrequency(_))
        ));
        assert_eq!(
            Tf2::low_pass(1e300, 0.7, 1.0, 0.1),
            Err(ArxError::Degenerate)
        );
        assert_eq!(
            Tf2::low_pass(1.0, 0.7, 1.0, 1e-300),
            Err(ArxError::Degenerate)
        );
    }

    #[test]
    fn low_pass_hand_computed() {
        // ωn = 2 rad/s, ζ = 0.5, gain 3, T = 0.5 s: c = 2/T = 4, c² = 16,
        // ωn² = 4, 2ζωn c = 8, a0 = 16 + 8 + 4 = 28.
        // b0 = 3·4/28 = 3/7, b = [3/7, 6/7, 3/7];
        // a1 = 2(4 − 16)/28 = −6/7; a2 = (16 − 8 + 4)/28 = 3/7.
        let tf = Tf2::low_pass(2.0, 0.5, 3.0, 0.5).unwrap();
        let want = [3.0 / 7.0, 6.0 / 7.0, 3.0 / 7.0, -6.0 / 7.0, 3.0 / 7.0];
        for (got, want) in tf.params().iter().zip(want) {
            assert!((got - want).abs() < 1e-15, "{tf:?}");
        }
        // DC gain: (12/7)/(1 − 6/7 + 3/7) = (12/7)/(4/7) = 3.
        assert!((tf.dc_gain() - 3.0).abs() < 1e-14);
        assert!(tf.is_stable());
    }

    #[test]
    fn low_pass_dc_gain_and_stability() {
        for &(f_hz, zeta, gain, t) in &[
            (1.0, 0.7, 1.0, 0.01),
            (1.0, 0.7, 2.5, 0.2),
            (0.1, 0.05, -4.0, 0.2),
            (20.0, 3.0, 1e-3, 0.001),
            (5.0, 1.0, 1.0, 1.0),
        ] {
            let tf = Tf2::low_pass(2.0 * core::f64::consts::PI * f_hz, zeta, gain, t).unwrap();
            assert!(tf.is_stable(), "{tf:?}");
            assert!(
                (tf.dc_gain() - gain).abs() <= 1e-9 * gain.abs(),
                "{} vs {gain}",
                tf.dc_gain()
            );
            // Step response settles at the DC gain.
            let mut s = Tf2State::new(tf);
            let mut y = 0.0;
            for _ in 0..200_000 {
                y = s.step(1.0);
            }
            assert!((y - gain).abs() <= 1e-6 * gain.abs(), "{y} vs {gain}");
        }
    }

    #[test]
    fn jury_conditions() {
        assert!(
            Tf2 {
                b: [1.0, 0.0, 0.0],
                a: [0.0, 0.0]
            }
            .is_stable()
        );
        // Poles 0.5 ± 0.5j: a1 = −1, a2 = 0.5.
        assert!(
            Tf2 {
                b: [1.0; 3],
                a: [-1.0, 0.5]
            }
            .is_stable()
        );
        // Double pole at 1: a1 = −2, a2 = 1 (marginal).
        assert!(
            !Tf2 {
                b: [1.0; 3],
                a: [-2.0, 1.0]
            }
            .is_stable()
        );
        // Real poles 1.1 and 0.5: a1 = −1.6, a2 = 0.55.
        assert!(
            !Tf2 {
                b: [1.0; 3],
                a: [-1.6, 0.55]
            }
            .is_stable()
        );
        // Poles −0.95 and 0.9: a1 = 0.05, a2 = −0.855.
        assert!(
            Tf2 {
                b: [1.0; 3],
                a: [0.05, -0.855]
            }
            .is_stable()
        );
        assert!(
            !Tf2 {
                b: [1.0; 3],
                a: [f64::NAN, 0.0]
            }
            .is_stable()
        );
    }

    #[test]
    fn state_follows_difference_equation() {
        let tf = Tf2 {
            b: [0.5, 0.25, 0.125],
            a: [-0.5, 0.25],
        };
        let mut s = Tf2State::with_initial(tf, [1.0, 2.0], [3.0, 4.0]);
        // y = 0.5·2 + 0.25·1 + 0.125·2 + 0.5·3 − 0.25·4 = 2.0
        assert_eq!(s.step(2.0), 2.0);
        assert_eq!(s.output(), 2.0);
        // y = 0.5·0 + 0.25·2 + 0.125·1 + 0.5·2 − 0.25·3 = 0.875
        assert_eq!(s.step(0.0), 0.875);
        s.reset();
        assert_eq!(s.output(), 0.0);
        assert_eq!(s.step(1.0), 0.5);
        assert_eq!(*s.model(), tf);
    }

    #[test]
    fn arx_first_two_updates_only_record() {
        let tf = Tf2::low_pass(3.0, 0.6, 1.5, 0.2).unwrap();
        let mut arx = Arx2::new(1.0, 1e6).unwrap();
        let mut plant = Tf2State::new(tf);
        let u = [1.0, -0.5, 0.25, 2.0, -1.0, 0.3, 0.9, -0.7, 1.1, 0.2];
        for (k, &uk) in u.iter().enumerate() {
            let y = plant.step(uk);
            let e = arx.update(uk, y).unwrap();
            assert_eq!(e.is_some(), k >= 2, "k = {k}");
        }
        assert_eq!(arx.updates(), 8);
        assert!(arx.predict(0.0).is_some());
        arx.record_substitute(0.0, 0.0);
        assert!(arx.predict(0.0).is_none());
        assert_eq!(arx.update(0.0, 0.0), Ok(None));
        assert_eq!(arx.update(0.0, 0.0), Ok(None));
        assert!(arx.update(0.0, 0.0).unwrap().is_some());
        assert_eq!(arx.updates(), 9);
        arx.clear_history();
        assert!(arx.predict(0.0).is_none());
        assert_eq!(arx.updates(), 9);
        let before = arx.clone();
        assert_eq!(arx.update(f64::NAN, 0.0), Err(ArxError::NonFiniteInput));
        assert_eq!(
            arx.update(0.0, f64::INFINITY),
            Err(ArxError::NonFiniteInput)
        );
        assert_eq!(arx, before);
        arx.reset();
        assert_eq!(arx.updates(), 0);
        assert_eq!(arx.model(), Tf2::default());
    }

    #[test]
    fn errors_chain_and_explain() {
        use core::error::Error;
        use std::string::ToString;
        let e = Arx2::new(2.0, 1.0).unwrap_err();
        assert_eq!(e, ArxError::Rls(RlsError::InvalidForgettingFactor(2.0)));
        assert!(e.source().is_some());
        assert!(e.to_string().contains("forgetting factor 2"));
        assert!(ArxError::InvalidPeriod(0.0).to_string().contains("> 0"));
    }
}
