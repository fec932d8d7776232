//! Estimation of the remote's current state and prediction of its state when
//! the command sent now takes effect (the paper's §4.3 and Fig. 10, after
//! Oboe & Fiorini 1998).

use core::fmt;

use crate::arx::{Arx2, ArxError, Tf2};

/// Adaptations needed before an identified model is used: five, the number
/// of parameters; fewer samples cannot determine the model.
pub(crate) const MIN_IDENTIFICATION_UPDATES: u64 = 5;

/// Why the estimator could not be built or stepped.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub enum EstimatorError {
    /// The command history capacity `H` cannot cover the delays: it must be at
    /// least `Df + Db + 3`.
    HistoryTooShort {
        /// Forward delay asked for (ticks).
        delay_fwd: usize,
        /// Backward delay asked for (ticks).
        delay_bwd: usize,
        /// Smallest `H` that works (`usize::MAX` if that overflows).
        needed: usize,
        /// The `H` of this estimator.
        capacity: usize,
    },
    /// The command or the state sample is NaN or infinite.
    NonFiniteInput,
    /// A fixed model has a NaN or infinite coefficient.
    InvalidModel,
    /// The identification rejected the update (numerical overflow).
    Identification(ArxError),
}

impl fmt::Display for EstimatorError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            EstimatorError::HistoryTooShort {
                delay_fwd,
                delay_bwd,
                needed,
                capacity,
            } => write!(
                f,
                "estimator command history H = {capacity} is too short for delays \
                 Df = {delay_fwd}, Db = {delay_bwd} ticks: use Estimator::<{needed}> or larger \
                 (H ≥ Df + Db + 3)"
            ),
            EstimatorError::NonFiniteInput => f.write_str(
                "estimator input (command or state sample) is NaN or infinite: the tick was \
                 ignored and the estimator is unchanged; check the signal source",
            ),
            EstimatorError::InvalidModel => f.write_str(
                "estimator model has a NaN or infinite coefficient: give finite b and a",
            ),
            EstimatorError::Identification(e) => write!(
                f,
                "estimator identification failed, the tick was ignored and the estimator \
                 is unchanged: {e}"
            ),
        }
    }
}

impl core::error::Error for EstimatorError {
    fn source(&self) -> Option<&(dyn core::error::Error + 'static)> {
        match self {
            EstimatorError::Identification(e) => Some(e),
            _ => None,
        }
    }
}

/// The estimator's output for one tick `n`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Estimate {
    /// Estimate of the remote's current state `y[n]`.
    pub x3e: f64,
    /// Prediction of `y[n + Df]`, the state when the command sent at `n`
    /// takes effect.
    pub x3p: f64,
    /// `true` if both come from the model; `false` during warm-up, when both
    /// hold the last received state.
    pub from_model: bool,
}

// Boxing the identifier would need a heap; an estimator holds one model anyway.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq)]
enum Model {
    Identify(Arx2),
    Fixed(Tf2),
}

/// Estimation of the remote's current state and prediction of its state when
/// the command sent now takes effect (the paper's §4.3 and Fig. 10, after
/// Oboe & Fiorini 1998).
///
/// The regulators make both one-way delays constant and whole numbers of
/// ticks, so commands and states can be aligned exactly; the base then runs
/// an identified model of the remote forward from the last received state.
///
/// # Timing contract
///
/// Both peers run the same period, so one tick index `n` serves both.
///
/// - At tick `n` the base sends the command `u[n]`.
/// - The remote's regulator releases it `Df` ticks later, where it becomes the
///   plant's input: `p[m] = u[m − Df]`.
/// - The plant's output at tick `m` is `y[m]` (it may depend on `p[m]`
///   through `b0`). The remote sends `y[m]` at tick `m`; the base's regulator
///   releases it at tick `m + Db`.
///
/// So at base tick `n` the base knows `u[..=n]` and `y[..=n − Db]`, and
/// [`Estimator::step`] returns
///
/// - `x3e[n]`, the estimate of `y[n]`: the remote's current state, `Db` ticks
///   before its feedback arrives;
/// - `x3p[n]`, the estimate of `y[n + Df]`: the state when the command sent
///   now takes effect.
///
/// ```text
/// tick       n−Db−Df−2 … n−Db … n … n+Df
/// u known    ─────────────────────────┤ n
/// y known    ───────────────┤ n−Db                (anchor y[n−Db], y[n−Db−1])
/// simulated                 ├──── x3e ┼──── x3p
/// ```
///
/// # Per tick
///
/// [`Estimator::step`]`(u, y)` records `u[n]`; `y` is the sample released at
/// this tick, `y[n − Db]`, or `None` if none was (queue underflow).
///
/// - With a sample: identification (if enabled) adapts on the pair
///   `(p[n − Db], y[n − Db])`, once the command history reaches back to
///   `u[n − Db − Df]`; the sample becomes the anchor of the simulation.
/// - Without: the model's own one-step output stands in for `y[n − Db]`, and
///   no adaptation uses a regressor that contains it (the next two samples
///   only refill the identification history, see
///   [`Arx2::record_substitute`]).
///
/// Then the model is simulated from the anchor `(y[n − Db], y[n − Db − 1])`
/// with the known inputs `p[m] = u[m − Df]` up to `m = n` (`x3e`) and on to
/// `m = n + Df` (`x3p`): `Db + Df` steps of the difference equation.
///
/// # Warm-up and fallback
///
/// The model is used once (a) the command history reaches `u[n − Db − Df − 1]`
/// (i.e. from tick `Db + Df + 1` on), (b) two consecutive samples anchor the
/// simulation, and (c) when identifying, the RLS has adapted at least
/// 5 times. Until then, and whenever the
/// simulation would not be finite, both outputs hold the last received state
/// (`0.0` before the first one) and [`Estimate::from_model`] is `false`.
///
/// Base-side estimator/predictor of one axis of the remote system, with a
/// command history of capacity `H` (at least `Df + Db + 3`).
///
#[derive(Clone, Debug, PartialEq)]
pub struct Estimator<const H: usize> {
    model: Model,
    delay_fwd: usize,
    delay_bwd: usize,
    /// Ring buffer: `u[j]` lives at `j mod H`.
    commands: [f64; H],
    /// Index `n` of the next tick (= ticks stepped so far).
    next: i64,
    /// Anchor: `y0 = y[anchor_at]`, `y1 = y[anchor_at − 1]`; `anchor_len` of
    /// them (0–2) are valid, measured or substituted.
    y0: f64,
    y1: f64,
    anchor_at: i64,
    anchor_len: u8,
    last_received: Option<f64>,
    /// Output index the identifier's history expects next, if contiguous.
    arx_next: Option<i64>,
}

impl<const H: usize> Estimator<H> {
    /// An estimator that identifies the model online with `arx` (whose current
    /// model, if trained, is kept; its sample history is cleared).
    ///
    /// # Errors
    /// [`EstimatorError::HistoryTooShort`] if `H < delay_fwd + delay_bwd + 3`.
    pub fn new(delay_fwd: usize, delay_bwd: usize, mut arx: Arx2) -> Result<Self, EstimatorError> {
        check_capacity::<H>(delay_fwd, delay_bwd)?;
        arx.clear_history();
        Ok(Estimator::build(delay_fwd, delay_bwd, Model::Identify(arx)))
    }

    /// An estimator with a fixed, known model and no identification.
    ///
    /// # Errors
    /// [`EstimatorError::HistoryTooShort`] if `H < delay_fwd + delay_bwd + 3`;
    /// [`EstimatorError::InvalidModel`] if a coefficient is not finite.
    pub fn with_model(
        delay_fwd: usize,
        delay_bwd: usize,
        model: Tf2,
    ) -> Result<Self, EstimatorError> {
        check_capacity::<H>(delay_fwd, delay_bwd)?;
        if !model.is_finite() {
            return Err(EstimatorError::InvalidModel);
        }
        Ok(Estimator::build(delay_fwd, delay_bwd, Model::Fixed(model)))
    }

    fn build(delay_fwd: usize, delay_bwd: usize, model: Model) -> Self {
        Estimator {
            model,
            delay_fwd,
            delay_bwd,
            commands: [0.0; H],
            next: 0,
            y0: 0.0,
            y1: 0.0,
            anchor_at: 0,
            anchor_len: 0,
            last_received: None,
            arx_next: None,
        }
    }

    /// One base tick: `u` is the command sent now (`u[n]`), `y` the state
    /// sample the regulator released now (`y[n − Db]`), `None` if none was.
    ///
    /// # Errors
    /// [`EstimatorError::NonFiniteInput`] if `u` or `y` is NaN or infinite,
    /// [`EstimatorError::Identification`] if the RLS update overflows; the
    /// estimator is then unchanged (the tick did not happen).
    pub fn step(&mut self, u: f64, y: Option<f64>) -> Result<Estimate, EstimatorError> {
        if !(u.is_finite() && y.is_none_or(f64::is_finite)) {
            return Err(EstimatorError::NonFiniteInput);
        }
        let n = self.next;
        let (df, db) = (self.delay_fwd as i64, self.delay_bwd as i64);
        let m = n - db;
        // p[m] = u[m − Df]; m − Df = n only when both delays are zero.
        let p_m = if m - df == n {
            Some(u)
        } else {
            self.command(m - df)
        };

        // The only fallible part comes first, so an error leaves no trace.
        if let (Model::Identify(arx), Some(y), Some(p_m)) = (&mut self.model, y, p_m) {
            if self.arx_next != Some(m) {
                // A gap (delay change, dropped anchor): only fresh samples may
                // enter a regressor. Recording cannot fail.
                arx.clear_history();
            }
            arx.update(p_m, y).map_err(EstimatorError::Identification)?;
            self.arx_next = Some(m + 1);
        }

        if let Some(cell) = slot::<H>(n).and_then(|i| self.commands.get_mut(i)) {
            *cell = u;
        }
        self.next = n + 1;

        match y {
            Some(y) => {
                if self.anchor_len >= 1 && self.anchor_at == m - 1 {
                    self.y1 = self.y0;
                    self.anchor_len = 2;
                } else {
                    self.anchor_len = 1;
                }
                self.y0 = y;
                self.anchor_at = m;
                self.last_received = Some(y);
            }
            None => self.substitute(m),
        }

        Ok(self.simulate(n, m).unwrap_or_else(|| {
            let held = self.last_received.unwrap_or(0.0);
            Estimate {
                x3e: held,
                x3p: held,
                from_model: false,
            }
        }))
    }

    /// No sample at output index `m`: continue the anchor with the model's
    /// own output, or drop it if that cannot be computed.
    fn substitute(&mut self, m: i64) {
        let df = self.delay_fwd as i64;
        let model = self.model();
        let inputs = (
            self.command(m - df),
            self.command(m - 1 - df),
            self.command(m - 2 - df),
        );
        if let (true, true, (Some(p0), Some(p1), Some(p2))) = (
            self.anchor_len == 2 && self.anchor_at == m - 1,
            self.model_ready(),
            inputs,
        ) {
            let y_hat = model.output(p0, p1, p2, self.y0, self.y1);
            if y_hat.is_finite() {
                self.y1 = self.y0;
                self.y0 = y_hat;
                self.anchor_at = m;
                if let Model::Identify(arx) = &mut self.model
                    && self.arx_next == Some(m)
                {
                    arx.record_substitute(p0, y_hat);
                    self.arx_next = Some(m + 1);
                }
                return;
            }
        }
        self.anchor_len = 0;
    }

    /// Runs the model from the anchor at `m` to `n + Df`; `None` if the
    /// model is not usable yet or the result is not finite.
    fn simulate(&self, n: i64, m: i64) -> Option<Estimate> {
        if !(self.model_ready() && self.anchor_len == 2 && self.anchor_at == m) {
            return None;
        }
        let df = self.delay_fwd as i64;
        let model = self.model();
        let (mut ya, mut yb) = (self.y0, self.y1);
        let (mut u1, mut u2) = (self.command(m - df)?, self.command(m - 1 - df)?);
        let mut x3e = ya;
        for j in (m + 1)..=(n + df) {
            let uj = self.command(j - df)?;
            let yj = model.output(uj, u1, u2, ya, yb);
            (u2, u1, yb, ya) = (u1, uj, ya, yj);
            if j == n {
                x3e = yj;
            }
        }
        (x3e.is_finite() && ya.is_finite()).then_some(Estimate {
            x3e,
            x3p: ya,
            from_model: true,
        })
    }

    /// `u[j]` if it is still in the history.
    fn command(&self, j: i64) -> Option<f64> {
        let newest = self.next - 1;
        if j < 0 || j > newest || newest - j >= H as i64 {
            return None;
        }
        self.commands.get(slot::<H>(j)?).copied()
    }

    fn model_ready(&self) -> bool {
        match &self.model {
            Model::Identify(arx) => arx.updates() >= MIN_IDENTIFICATION_UPDATES,
            Model::Fixed(_) => true,
        }
    }

    /// The model in use: the identified one (all zeros before any
    /// adaptation) or the fixed one.
    #[must_use]
    pub fn model(&self) -> Tf2 {
        match &self.model {
            Model::Identify(arx) => arx.model(),
            Model::Fixed(tf) => *tf,
        }
    }

    /// The identifier, or `None` with a fixed model (the model is
    /// identified online when there is one).
    #[must_use]
    pub fn arx(&self) -> Option<&Arx2> {
        match &self.model {
            Model::Identify(arx) => Some(arx),
            Model::Fixed(_) => None,
        }
    }

    /// The delays `(Df, Db)` in ticks.
    #[must_use]
    pub fn delays(&self) -> (usize, usize) {
        (self.delay_fwd, self.delay_bwd)
    }

    /// Changes the delays (the link adapted its period or queue sizes).
    ///
    /// The command history stays valid, since commands are indexed by tick
    /// and not by delay, as long as `H ≥ Df + Db + 3`, which is checked. If a
    /// delay actually changes, the simulation anchor and the identification
    /// history are dropped: during the change the plant's inputs follow
    /// neither delay. The next two consecutive samples rebuild them; until
    /// then the estimate holds the last received state. The model is kept.
    ///
    /// # Errors
    /// [`EstimatorError::HistoryTooShort`] if `H` cannot cover the new
    /// delays; nothing changes then.
    pub fn set_delays(&mut self, delay_fwd: usize, delay_bwd: usize) -> Result<(), EstimatorError> {
        check_capacity::<H>(delay_fwd, delay_bwd)?;
        if (delay_fwd, delay_bwd) != (self.delay_fwd, self.delay_bwd) {
            self.delay_fwd = delay_fwd;
            self.delay_bwd = delay_bwd;
            self.anchor_len = 0;
            self.arx_next = None;
        }
        Ok(())
    }

    /// Forgets the link's state (command history, anchor, last received
    /// sample, tick count) for a restart at tick 0; keeps the model and its
    /// identification state (the robot has not changed).
    pub fn reset(&mut self) {
        *self = Estimator::build(self.delay_fwd, self.delay_bwd, self.model.clone());
        if let Model::Identify(arx) = &mut self.model {
            arx.clear_history();
        }
    }

    /// Restarts identification from scratch (zero model, covariance `δ·I`);
    /// no effect with a fixed model.
    pub fn reset_identification(&mut self) {
        if let Model::Identify(arx) = &mut self.model {
            arx.reset();
        }
        self.arx_next = None;
    }

    /// Ticks stepped since construction or [`Estimator::reset`]: the index
    /// `n` of the next tick.
    #[must_use]
    pub fn ticks(&self) -> u64 {
        self.next as u64
    }

    /// The last state sample received, if any.
    #[must_use]
    pub fn last_received(&self) -> Option<f64> {
        self.last_received
    }

    #[cfg(test)]
    /// The command history capacity `H`.
    #[must_use]
    pub(crate) const fn capacity(&self) -> usize {
        H
    }
}

fn check_capacity<const H: usize>(
    delay_fwd: usize,
    delay_bwd: usize,
) -> Result<(), EstimatorError> {
    let needed = delay_fwd
        .checked_add(delay_bwd)
        .and_then(|s| s.checked_add(3))
        .unwrap_or(usize::MAX);
    // H ≤ isize::MAX (it is an array length), so the delays then fit in i64.
    if needed > H {
        return Err(EstimatorError::HistoryTooShort {
            delay_fwd,
            delay_bwd,
            needed,
            capacity: H,
        });
    }
    Ok(())
}

/// Ring-buffer slot of tick `j ≥ 0`.
fn slot<const H: usize>(j: i64) -> Option<usize> {
    usize::try_from(j).ok()?.checked_rem(H)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plant() -> Tf2 {
        Tf2::low_pass(2.0, 0.5, 3.0, 0.5).unwrap()
    }

    fn command(n: usize) -> f64 {
        let t = n as f64;
        libm::sin(0.3 * t) + 0.5 * libm::sin(1.1 * t + 0.4) + 0.2 * libm::cos(2.3 * t)
    }

    /// True outputs y[0..len] with p[m] = u[m − df] (zero input before the
    /// first command arrives).
    fn truth(df: usize, len: usize) -> std::vec::Vec<f64> {
        let mut s = crate::arx::Tf2State::new(plant());
        (0..len)
            .map(|m| s.step(if m >= df { command(m - df) } else { 0.0 }))
            .collect()
    }

    #[test]
    fn capacity_is_checked() {
        let arx = Arx2::new(1.0, 1e6).unwrap();
        assert_eq!(
            Estimator::<6>::new(2, 2, arx.clone()).unwrap_err(),
            EstimatorError::HistoryTooShort {
                delay_fwd: 2,
                delay_bwd: 2,
                needed: 7,
                capacity: 6
            }
        );
        let mut est = Estimator::<7>::new(2, 2, arx).unwrap();
        assert_eq!(est.capacity(), 7);
        assert!(matches!(
            est.set_delays(3, 2),
            Err(EstimatorError::HistoryTooShort { needed: 8, .. })
        ));
        assert!(matches!(
            est.set_delays(usize::MAX, 1),
            Err(EstimatorError::HistoryTooShort {
                needed: usize::MAX,
                ..
            })
        ));
        assert_eq!(est.delays(), (2, 2));
        est.set_delays(4, 0).unwrap();
        assert_eq!(est.delays(), (4, 0));
        assert!(Estimator::<0>::with_model(0, 0, plant()).is_err());
        assert_eq!(
            Estimator::<3>::with_model(
                0,
                0,
                Tf2 {
                    b: [f64::NAN, 0.0, 0.0],
                    a: [0.0; 2]
                }
            ),
            Err(EstimatorError::InvalidModel)
        );
        let msg = std::string::ToString::to_string(&EstimatorError::HistoryTooShort {
            delay_fwd: 2,
            delay_bwd: 2,
            needed: 7,
            capacity: 6,
        });
        assert!(msg.contains("Estimator::<7>"), "{msg}");
    }

    #[test]
    fn fixed_model_is_exact_after_warm_up() {
        let (df, db) = (2, 1);
        let y = truth(df, 200);
        let mut est = Estimator::<8>::with_model(df, db, plant()).unwrap();
        assert!(est.arx().is_none());
        for n in 0..190_usize {
            let sample = n.checked_sub(db).map(|m| y[m]);
            let e = est.step(command(n), sample).unwrap();
            // Needs u[n − Db − Df − 1]: from n = Db + Df + 1 = 4 on.
            assert_eq!(e.from_model, n >= 4, "n = {n}");
            if e.from_model {
                assert!((e.x3e - y[n]).abs() < 1e-12, "n = {n}");
                assert!((e.x3p - y[n + df]).abs() < 1e-12, "n = {n}");
            } else {
                let held = sample.unwrap_or(0.0);
                assert_eq!((e.x3e, e.x3p), (held, held));
            }
        }
        assert_eq!(est.ticks(), 190);
        assert_eq!(est.last_received(), Some(y[188]));
    }

    #[test]
    fn missing_samples_are_bridged_by_the_model() {
        let (df, db) = (1, 3);
        let y = truth(df, 300);
        let mut est = Estimator::<8>::with_model(df, db, plant()).unwrap();
        for n in 0..290_usize {
            let lost = (100..103).contains(&n) || n % 17 == 0;
            let sample = n.checked_sub(db).filter(|_| !lost).map(|m| y[m]);
            let e = est.step(command(n), sample).unwrap();
            if n >= 10 {
                assert!(e.from_model, "n = {n}");
                assert!((e.x3e - y[n]).abs() < 1e-12, "n = {n}");
                assert!((e.x3p - y[n + df]).abs() < 1e-12, "n = {n}");
            }
        }
    }

    #[test]
    fn zero_delays_return_the_sample() {
        let y = truth(0, 50);
        let mut est = Estimator::<3>::with_model(0, 0, plant()).unwrap();
        for (n, &yn) in y.iter().enumerate() {
            let e = est.step(command(n), Some(yn)).unwrap();
            assert_eq!((e.x3e, e.x3p), (yn, yn));
        }
    }

    #[test]
    fn bad_input_changes_nothing() {
        let y = truth(1, 40);
        let mut est = Estimator::<6>::new(1, 1, Arx2::new(1.0, 1e6).unwrap()).unwrap();
        for n in 0..30 {
            let _ = est
                .step(command(n), n.checked_sub(1).map(|m| y[m]))
                .unwrap();
        }
        let before = est.clone();
        for (u, s) in [
            (f64::NAN, Some(0.0)),
            (f64::INFINITY, None),
            (0.0, Some(f64::NAN)),
            (0.0, Some(f64::NEG_INFINITY)),
        ] {
            assert_eq!(est.step(u, s), Err(EstimatorError::NonFiniteInput));
            assert_eq!(est, before);
        }
        // A finite but absurd sample is accepted once; as a regressor entry
        // it then overflows inside the RLS, and that tick leaves no trace.
        let _ = est.step(0.0, Some(1e300)).unwrap();
        let before = est.clone();
        assert!(matches!(
            est.step(0.0, Some(1.0)),
            Err(EstimatorError::Identification(ArxError::Rls(_)))
        ));
        assert_eq!(est, before);
    }

    #[test]
    fn reset_keeps_the_model() {
        let (df, db) = (1, 2);
        let y = truth(df, 400);
        let mut est = Estimator::<8>::new(df, db, Arx2::new(1.0, 1e8).unwrap()).unwrap();
        for n in 0..400 {
            let _ = est
                .step(command(n), n.checked_sub(db).map(|m| y[m]))
                .unwrap();
        }
        let model = est.model();
        for (got, want) in model.params().iter().zip(plant().params()) {
            assert!((got - want).abs() < 1e-6, "{model:?}");
        }
        est.reset();
        assert_eq!(est.ticks(), 0);
        assert_eq!(est.last_received(), None);
        assert_eq!(est.model(), model);
        // A restarted link with a known model is exact from warm-up on.
        for n in 0..50 {
            let e = est
                .step(command(n), n.checked_sub(db).map(|m| y[m]))
                .unwrap();
            assert_eq!(e.from_model, n > df + db, "n = {n}");
            if e.from_model {
                assert!((e.x3p - y[n + df]).abs() < 1e-6);
            }
        }
        est.reset_identification();
        assert_eq!(est.model(), Tf2::default());
        assert_eq!(est.arx().map(Arx2::updates), Some(0));
    }
}
