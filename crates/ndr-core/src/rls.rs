//! Recursive least squares (RLS) with exponential forgetting.

use core::fmt;

use nalgebra::{SMatrix, SVector};

/// Default covariance-trace bound, as a multiple of the initial trace `P·δ`.
///
/// See the [module docs](self) for why a million.
pub(crate) const DEFAULT_TRACE_FACTOR: f64 = 1e6;

/// Why an [`Rls`] could not be built or updated.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum RlsError {
    /// The forgetting factor is not in `(0, 1]` (or is NaN).
    InvalidForgettingFactor(f64),
    /// The initial covariance scale `δ` is not finite and positive.
    InvalidInitialCovariance(f64),
    /// The covariance-trace bound is not finite or not above the initial trace.
    InvalidTraceBound {
        /// The bound that was asked for.
        bound: f64,
        /// The initial trace `P·δ` it must exceed.
        initial_trace: f64,
    },
    /// A regressor entry, a desired value or a weight is NaN or infinite.
    NonFiniteInput,
    /// The update would overflow `f64`; it was skipped.
    Overflow,
}

impl fmt::Display for RlsError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            RlsError::InvalidForgettingFactor(l) => write!(
                f,
                "RLS forgetting factor {l} is outside (0, 1]: use 1.0 for no forgetting \
                 or e.g. 0.98 to track a slowly changing system"
            ),
            RlsError::InvalidInitialCovariance(d) => write!(
                f,
                "RLS initial covariance scale {d} must be finite and > 0: use e.g. 1e3 to 1e6 \
                 (larger trusts the initial weights less)"
            ),
            RlsError::InvalidTraceBound {
                bound,
                initial_trace,
            } => write!(
                f,
                "RLS covariance trace bound {bound} must be finite and above the initial \
                 trace {initial_trace}: use a large multiple of it, e.g. 1e6 times"
            ),
            RlsError::NonFiniteInput => f.write_str(
                "RLS input is NaN or infinite: the sample was ignored and the filter is \
                 unchanged; check the signal source",
            ),
            RlsError::Overflow => f.write_str(
                "RLS update overflowed f64 (regressor or desired value far too large): the \
                 sample was ignored and the filter is unchanged; scale the signals",
            ),
        }
    }
}

impl core::error::Error for RlsError {}

/// Recursive least squares (RLS) with exponential forgetting.
///
/// [`Rls`] fits the linear model `d ≈ wᵀx` one sample at a time. It is the
/// identification engine behind [`crate::arx::Arx2`]. Names map onto
/// padasip's `FilterRLS`: [`Rls::update`]`(x, d)` is `adapt(d, x)`,
/// [`Rls::predict`] is `predict(x)`, [`Rls::weights`] is `w`; the covariance
/// is `P` as in filterpy.
///
/// Per sample, with regressor `x`, desired value `d` and forgetting factor `λ`:
///
/// ```text
/// e = d − wᵀx                  a-priori error (returned)
/// k = P x / (λ + xᵀ P x)       gain
/// w ← w + k e
/// P ← (P − k (P x)ᵀ) / λ       uses P = Pᵀ: k xᵀ P = k (P x)ᵀ
/// ```
///
/// `P` stays exactly symmetric: entry `(i, j)` is computed from
/// `(Px)ᵢ·(Px)ⱼ`, which rounds the same as `(Px)ⱼ·(Px)ᵢ`, so no explicit
/// symmetrization is needed.
///
/// **Covariance wind-up.** With `λ < 1`, directions of `x` that stop being
/// excited have their covariance divided by `λ` every sample, so `P` grows
/// geometrically and the next informative sample moves `w` violently (and
/// eventually `P` overflows). The filter bounds `tr P`: when it exceeds the
/// bound, `P` is reset to `δ·I` and [`Rls::covariance_resets`] counts it. The
/// default bound is `DEFAULT_TRACE_FACTOR · P · δ`, a million times the
/// initial trace: while the input excites every direction, information only
/// accumulates and `tr P` stays at or below its initial value `P·δ`, so a
/// bound this far above it never fires during normal convergence; it fires
/// only after a long stretch without excitation (about 680 samples from `δ·I`
/// at `λ = 0.98`, longer from a converged `P`), and it keeps `P` five or more
/// orders of magnitude away from `f64` overflow and from a condition number
/// near `1/ε`. Rounding that makes `P` lose positive definiteness
/// (`xᵀPx < 0` or a non-positive diagonal entry) resets it in the same way.
///
/// Recursive least squares estimator of `P` weights with forgetting factor
/// `λ` and initial covariance `δ·I`.
///
/// Allocation-free: the weights and covariance are fixed-size `nalgebra`
/// values stored inline.
#[derive(Clone, Debug, PartialEq)]
pub struct Rls<const P: usize> {
    w: SVector<f64, P>,
    p: SMatrix<f64, P, P>,
    lambda: f64,
    inv_lambda: f64,
    delta: f64,
    trace_bound: f64,
    updates: u64,
    covariance_resets: u64,
}

impl<const P: usize> Rls<P> {
    /// A filter with zero weights, covariance `delta·I` and forgetting factor
    /// `lambda`, with the default trace bound
    /// `DEFAULT_TRACE_FACTOR · P · delta`.
    ///
    /// # Errors
    /// [`RlsError::InvalidForgettingFactor`] unless `0 < lambda ≤ 1`;
    /// [`RlsError::InvalidInitialCovariance`] unless `delta` is finite and `> 0`.
    pub fn new(lambda: f64, delta: f64) -> Result<Self, RlsError> {
        if !(lambda > 0.0 && lambda <= 1.0) {
            return Err(RlsError::InvalidForgettingFactor(lambda));
        }
        if !(delta.is_finite() && delta > 0.0) {
            return Err(RlsError::InvalidInitialCovariance(delta));
        }
        // Saturate rather than overflow for absurd δ: the guard then never fires,
        // and the finiteness checks of `update` still protect the state.
        let trace_bound = (DEFAULT_TRACE_FACTOR * P as f64 * delta).min(f64::MAX);
        Ok(Rls {
            w: SVector::zeros(),
            p: SMatrix::identity() * delta,
            lambda,
            inv_lambda: 1.0 / lambda,
            delta,
            trace_bound,
            updates: 0,
            covariance_resets: 0,
        })
    }

    #[cfg(test)]
    /// This filter with its covariance-trace bound set to `bound` (builder form
    /// of [`Rls::set_trace_bound`]).
    ///
    /// # Errors
    /// As [`Rls::set_trace_bound`].
    pub(crate) fn with_trace_bound(mut self, bound: f64) -> Result<Self, RlsError> {
        self.set_trace_bound(bound)?;
        Ok(self)
    }

    /// Sets the bound on `tr P` above which the covariance is reset to `δ·I`.
    /// `f64::MAX` effectively disables the wind-up guard.
    ///
    /// # Errors
    /// [`RlsError::InvalidTraceBound`] unless `bound` is finite and larger
    /// than the initial trace `P·δ` (a smaller bound would reset every sample).
    pub fn set_trace_bound(&mut self, bound: f64) -> Result<(), RlsError> {
        let initial_trace = P as f64 * self.delta;
        if !(bound.is_finite() && bound > initial_trace) {
            return Err(RlsError::InvalidTraceBound {
                bound,
                initial_trace,
            });
        }
        self.trace_bound = bound;
        Ok(())
    }

    /// Sets the forgetting factor; weights and covariance are kept.
    ///
    /// # Errors
    /// [`RlsError::InvalidForgettingFactor`] unless `0 < lambda ≤ 1`.
    pub fn set_lambda(&mut self, lambda: f64) -> Result<(), RlsError> {
        if !(lambda > 0.0 && lambda <= 1.0) {
            return Err(RlsError::InvalidForgettingFactor(lambda));
        }
        self.lambda = lambda;
        self.inv_lambda = 1.0 / lambda;
        Ok(())
    }

    /// Adapts the weights to one sample: regressor `x`, desired output `d`
    /// (padasip's `adapt(d, x)`). Returns the a-priori error `d − wᵀx`.
    ///
    /// # Errors
    /// [`RlsError::NonFiniteInput`] if `d` or an entry of `x` is NaN or
    /// infinite, [`RlsError::Overflow`] if the update would overflow; in both
    /// cases the filter is left exactly as it was.
    pub fn update(&mut self, x: &[f64; P], d: f64) -> Result<f64, RlsError> {
        if !(d.is_finite() && all_finite(x)) {
            return Err(RlsError::NonFiniteInput);
        }
        let x = SVector::<f64, P>::from(*x);
        let e = d - self.w.dot(&x);

        let mut reset = false;
        let mut px = self.p * x;
        let mut xpx = x.dot(&px);
        if xpx < 0.0 {
            // Rounding has made P indefinite: restart from δ·I for this sample.
            reset = true;
            px = x * self.delta;
            xpx = x.dot(&px);
        }
        let denom = self.lambda + xpx;
        if !(denom.is_finite() && e.is_finite()) {
            return Err(RlsError::Overflow);
        }
        let g = 1.0 / denom;

        let w = self.w + px * (g * e);
        let base = if reset {
            SMatrix::<f64, P, P>::identity() * self.delta
        } else {
            self.p
        };
        // (Px)ᵢ(Px)ⱼ·g is bitwise symmetric in i, j, so P stays symmetric.
        let mut p = (base - (px * px.transpose()) * g) * self.inv_lambda;

        // Slices, not nalgebra's strided iterators: this check is on the hot path.
        if !(all_finite(w.as_slice()) && all_finite(p.as_slice())) {
            return Err(RlsError::Overflow);
        }
        let windup = p.trace() > self.trace_bound;
        let indefinite = p.diagonal().iter().any(|&v| v <= 0.0);
        if windup || indefinite {
            p = SMatrix::identity() * self.delta;
            reset = true;
        }

        self.w = w;
        self.p = p;
        self.updates = self.updates.saturating_add(1);
        if reset {
            self.covariance_resets = self.covariance_resets.saturating_add(1);
        }
        Ok(e)
    }

    /// The model's output `wᵀx` for regressor `x` (NaN if `x` holds NaN).
    #[must_use]
    pub fn predict(&self, x: &[f64; P]) -> f64 {
        self.w.dot(&SVector::<f64, P>::from(*x))
    }

    /// The current weights `w`.
    #[must_use]
    pub fn weights(&self) -> &[f64; P] {
        &self.w.data.0[0]
    }

    /// Replaces the weights (e.g. with a prior model); the covariance is kept.
    ///
    /// # Errors
    /// [`RlsError::NonFiniteInput`] if an entry is NaN or infinite; the
    /// weights are then unchanged.
    pub fn set_weights(&mut self, w: &[f64; P]) -> Result<(), RlsError> {
        if !w.iter().all(|v| v.is_finite()) {
            return Err(RlsError::NonFiniteInput);
        }
        self.w = SVector::from(*w);
        Ok(())
    }

    /// The covariance `P` (symmetric).
    #[must_use]
    pub fn covariance(&self) -> &SMatrix<f64, P, P> {
        &self.p
    }

    /// Resets the covariance to `δ·I` and keeps the weights: the filter
    /// re-adapts quickly (e.g. after a known change of the system) without
    /// forgetting its current estimate. Not counted in
    /// [`Rls::covariance_resets`], which counts the automatic ones.
    pub fn reset_covariance(&mut self) {
        self.p = SMatrix::identity() * self.delta;
    }

    /// Back to the state right after [`Rls::new`]: zero weights, covariance
    /// `δ·I`, counters at zero. Forgetting factor and trace bound are kept.
    pub fn reset(&mut self) {
        self.w = SVector::zeros();
        self.reset_covariance();
        self.updates = 0;
        self.covariance_resets = 0;
    }

    /// Number of successful [`Rls::update`] calls.
    #[must_use]
    pub fn updates(&self) -> u64 {
        self.updates
    }

    /// Number of automatic covariance resets (wind-up guard or lost
    /// positive definiteness).
    #[must_use]
    pub fn covariance_resets(&self) -> u64 {
        self.covariance_resets
    }

    /// The forgetting factor `λ`.
    #[must_use]
    pub fn lambda(&self) -> f64 {
        self.lambda
    }

    /// The initial covariance scale `δ` (`P` starts and resets at `δ·I`).
    #[must_use]
    pub fn delta(&self) -> f64 {
        self.delta
    }

    /// The bound on `tr P` above which the covariance is reset.
    #[must_use]
    pub fn trace_bound(&self) -> f64 {
        self.trace_bound
    }
}

/// Whether every entry is finite; branch-free so it vectorizes.
fn all_finite(v: &[f64]) -> bool {
    v.iter().fold(true, |ok, x| ok & x.is_finite())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_parameters() {
        for l in [0.0, -0.5, 1.000_000_1, f64::INFINITY, f64::NEG_INFINITY] {
            assert_eq!(
                Rls::<2>::new(l, 1.0).unwrap_err(),
                RlsError::InvalidForgettingFactor(l)
            );
        }
        assert!(matches!(
            Rls::<2>::new(f64::NAN, 1.0),
            Err(RlsError::InvalidForgettingFactor(_))
        ));
        for d in [0.0, -1.0, f64::INFINITY] {
            assert_eq!(
                Rls::<2>::new(1.0, d).unwrap_err(),
                RlsError::InvalidInitialCovariance(d)
            );
        }
        assert!(matches!(
            Rls::<2>::new(1.0, f64::NAN),
            Err(RlsError::InvalidInitialCovariance(_))
        ));
        let mut rls = Rls::<2>::new(0.99, 10.0).unwrap();
        assert_eq!(rls.trace_bound(), 2e7);
        assert_eq!(
            rls.clone().with_trace_bound(20.0).unwrap_err(),
            RlsError::InvalidTraceBound {
                bound: 20.0,
                initial_trace: 20.0
            }
        );
        assert!(rls.clone().with_trace_bound(f64::NAN).is_err());
        assert!(rls.clone().with_trace_bound(f64::INFINITY).is_err());
        assert_eq!(
            rls.clone().with_trace_bound(20.5).unwrap().trace_bound(),
            20.5
        );
        assert!(rls.set_lambda(1.5).is_err());
        assert_eq!(rls.lambda(), 0.99);
        rls.set_lambda(0.5).unwrap();
        assert_eq!(rls.lambda(), 0.5);
    }

    #[test]
    fn errors_say_what_to_do() {
        use std::string::ToString;
        let msg = RlsError::InvalidForgettingFactor(1.5).to_string();
        assert!(msg.contains("1.5") && msg.contains("(0, 1]"), "{msg}");
        let msg = RlsError::InvalidInitialCovariance(-2.0).to_string();
        assert!(msg.contains("-2") && msg.contains("> 0"), "{msg}");
        assert!(RlsError::NonFiniteInput.to_string().contains("unchanged"));
        assert!(RlsError::Overflow.to_string().contains("scale"));
    }

    /// Weighted, regularized least squares in closed form: RLS started at
    /// `w = 0`, `P = δI` minimizes `λᴺ/δ·|w|² + Σ λᴺ⁻ᵏ (dₖ − wᵀxₖ)²`.
    fn closed_form(xs: &[[f64; 2]], ds: &[f64], lambda: f64, delta: f64) -> SVector<f64, 2> {
        let n = xs.len() as i32;
        let mut a = SMatrix::<f64, 2, 2>::identity() * (lambda.powi(n) / delta);
        let mut b = SVector::<f64, 2>::zeros();
        for (k, (x, d)) in xs.iter().zip(ds).enumerate() {
            let x = SVector::<f64, 2>::from(*x);
            let weight = lambda.powi(n - 1 - k as i32);
            a += x * x.transpose() * weight;
            b += x * (*d * weight);
        }
        a.try_inverse().unwrap() * b
    }

    #[test]
    fn matches_closed_form_least_squares() {
        let xs = [[1.0, 2.0], [3.0, -1.0], [0.5, 4.0], [-2.0, 0.3], [1.5, 1.5]];
        let ds = [2.0, -1.0, 0.7, 3.0, -0.4];
        for (lambda, delta) in [(1.0, 100.0), (0.9, 100.0), (0.8, 0.5)] {
            let mut rls = Rls::<2>::new(lambda, delta).unwrap();
            for (i, (x, d)) in xs.iter().zip(&ds).enumerate() {
                let before = rls.predict(x);
                let e = rls.update(x, *d).unwrap();
                assert!((e - (d - before)).abs() < 1e-15, "a-priori error");
                let want = closed_form(&xs[..=i], &ds[..=i], lambda, delta);
                let w = rls.weights();
                assert!(
                    (w[0] - want[0]).abs() < 1e-9 && (w[1] - want[1]).abs() < 1e-9,
                    "λ={lambda} δ={delta} step {i}: {w:?} vs {want:?}"
                );
            }
            assert_eq!(rls.updates(), 5);
            assert_eq!(rls.covariance_resets(), 0);
        }
    }

    #[test]
    fn covariance_stays_exactly_symmetric() {
        let mut rls = Rls::<4>::new(0.97, 1e3).unwrap();
        let mut s = 0x9e37_79b9_7f4a_7c15_u64;
        for _ in 0..10_000 {
            let mut x = [0.0; 4];
            for v in &mut x {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                *v = (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            }
            let _ = rls.update(&x, x[0] - 2.0 * x[3]).unwrap();
        }
        let p = rls.covariance();
        assert_eq!(*p, p.transpose());
        assert!((rls.weights()[0] - 1.0).abs() < 1e-9);
        assert!((rls.weights()[3] + 2.0).abs() < 1e-9);
    }

    #[test]
    fn non_finite_or_overflowing_input_changes_nothing() {
        let mut rls = Rls::<3>::new(0.95, 10.0).unwrap();
        let _ = rls.update(&[1.0, -2.0, 0.5], 1.0).unwrap();
        let before = rls.clone();
        for (x, d) in [
            ([f64::NAN, 0.0, 0.0], 1.0),
            ([0.0, f64::INFINITY, 0.0], 1.0),
            ([0.0, 0.0, f64::NEG_INFINITY], 1.0),
            ([1.0, 1.0, 1.0], f64::NAN),
            ([1.0, 1.0, 1.0], f64::INFINITY),
        ] {
            assert_eq!(rls.update(&x, d), Err(RlsError::NonFiniteInput));
            assert_eq!(rls, before);
        }
        assert_eq!(
            rls.update(&[1e200, 1e200, 0.0], 0.0),
            Err(RlsError::Overflow)
        );
        assert_eq!(rls, before);
        let mut big = rls.clone();
        big.set_weights(&[1e308, 0.0, 0.0]).unwrap();
        let snapshot = big.clone();
        assert_eq!(
            big.update(&[-1.0, 0.0, 0.0], f64::MAX),
            Err(RlsError::Overflow)
        );
        assert_eq!(big, snapshot);
        assert_eq!(
            rls.set_weights(&[1.0, f64::NAN, 0.0]),
            Err(RlsError::NonFiniteInput)
        );
        assert_eq!(rls, before);
    }

    #[test]
    fn covariance_reset_keeps_weights() {
        let mut rls = Rls::<2>::new(1.0, 1e6).unwrap();
        for k in 0..50 {
            let x = [1.0, (k as f64 * 0.7).sin()];
            let _ = rls.update(&x, 0.5 * x[0] + 3.0 * x[1]).unwrap();
        }
        let w = *rls.weights();
        assert!(
            (w[0] - 0.5).abs() < 1e-5 && (w[1] - 3.0).abs() < 1e-5,
            "{w:?}"
        );
        assert!(rls.covariance().trace() < 1.0);
        rls.reset_covariance();
        assert_eq!(*rls.weights(), w);
        assert_eq!(*rls.covariance(), SMatrix::<f64, 2, 2>::identity() * 1e6);
        assert_eq!(rls.covariance_resets(), 0, "manual resets are not counted");
        assert_eq!(rls.updates(), 50);

        rls.set_weights(&[7.0, 8.0]).unwrap();
        assert_eq!(rls.predict(&[1.0, 2.0]), 23.0);
        rls.reset();
        assert_eq!(*rls.weights(), [0.0, 0.0]);
        assert_eq!(rls.updates(), 0);
    }

    #[test]
    fn windup_guard_fires_under_zero_excitation() {
        // tr P = 2·0.9⁻ⁿ crosses the bound 1e6·2·1 between n = 131 (1.98e6)
        // and n = 132 (2.20e6).
        let mut rls = Rls::<2>::new(0.9, 1.0).unwrap();
        rls.set_weights(&[1.0, 2.0]).unwrap();
        for n in 1..=131 {
            let _ = rls.update(&[0.0, 0.0], 0.0).unwrap();
            assert_eq!(rls.covariance_resets(), 0, "no reset yet at n = {n}");
        }
        assert!(rls.covariance().trace() > 1.9e6);
        let _ = rls.update(&[0.0, 0.0], 0.0).unwrap();
        assert_eq!(rls.covariance_resets(), 1);
        assert_eq!(*rls.covariance(), SMatrix::<f64, 2, 2>::identity());
        assert_eq!(
            *rls.weights(),
            [1.0, 2.0],
            "zero regressors carry no information"
        );

        // Without forgetting, P cannot grow: no reset ever.
        let mut rls = Rls::<2>::new(1.0, 1.0).unwrap();
        for _ in 0..10_000 {
            let _ = rls.update(&[0.0, 0.0], 0.0).unwrap();
        }
        assert_eq!(rls.covariance_resets(), 0);
    }

    #[test]
    fn windup_guard_fires_under_poor_excitation() {
        // Only the first direction is excited: P₂₂ grows as 0.95⁻ⁿ.
        let mut rls = Rls::<2>::new(0.95, 1.0)
            .unwrap()
            .with_trace_bound(1e3)
            .unwrap();
        let mut first = None;
        for n in 0..1000 {
            let _ = rls.update(&[1.0, 0.0], 4.0).unwrap();
            if first.is_none() && rls.covariance_resets() > 0 {
                first = Some(n);
            }
            assert!(rls.covariance().trace() <= 1e3);
        }
        // 0.95⁻ⁿ > 1e3 − P₁₁ first at n + 1 = 135.
        assert_eq!(first, Some(134));
        assert!(rls.covariance_resets() >= 7);
        assert!((rls.weights()[0] - 4.0).abs() < 1e-9);
    }
}
