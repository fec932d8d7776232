//! A Smith predictor for a loop closed across the link.

use crate::arx::{Arx2, Tf2, Tf2State};
use crate::estimator::MIN_IDENTIFICATION_UPDATES;

use super::{ControlError, finite};

// Boxing the identifier would need a heap; a predictor holds one model anyway.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq)]
enum Model {
    Fixed,
    Identify(Arx2),
}

/// A Smith predictor for a loop closed across the link.
///
/// # Timing
///
/// Ticks are the base's. At tick `k` the base releases the measured state
/// `y_m[k]`, the controller computes the command `u[k]`, and the link
/// carries it to the remote; the state the plant reaches on `u[j]` is
/// released back at tick `j + D`, `D` the round trip in ticks (`Df + Db` in
/// the [`Estimator`](crate::Estimator)'s terms). A local model of the plant
/// runs undelayed on the same commands: `ŷ[j]` is its output on `u[j]`.
///
/// At tick `k` the controller is given
///
/// ```text
/// ŷ[k−1] + (y_m[k] − ŷ[k−D])
/// ```
///
/// the model's newest output, corrected by how far the plant was from the
/// model one round trip ago. With the true model the correction is zero
/// and the controller sees `ŷ[k−1]`, exactly what it sees in the delay-free
/// loop (`D = 1`); the plant's state then is the delay-free loop's, delayed
/// by `D − 1` ticks, to the last bit.
///
/// The model's outputs are kept by tick, so a change of `D` (the link
/// announced a new delay) only moves where the correction reads: nothing
/// jumps but what the plant itself did differently. A tick without a fresh
/// measurement (an underflow's repeat) keeps the last correction.
///
/// Before the first command the plant and the model are at rest: a model
/// output before tick 0 is zero.
///
/// A Smith predictor with `H` ticks of history (the round trip can be
/// `1..=H` ticks).
#[derive(Clone, Debug, PartialEq)]
pub struct SmithPredictor<const H: usize> {
    model: Model,
    /// The local model, run undelayed on the commands.
    local: Tf2State,
    /// `ŷ[j]` at `j mod H`.
    outputs: [f64; H],
    /// `u[j]` at `j mod H`.
    commands: [f64; H],
    /// The tick of the next command.
    next: u64,
    round_trip: usize,
    correction: f64,
    /// The last measured state (plain feedback before a model is ready).
    last_measured: f64,
    /// Whether the identifier's history ends at the previous tick.
    contiguous: bool,
}

impl<const H: usize> SmithPredictor<H> {
    /// A predictor with the given model of the plant and a round trip of
    /// `round_trip` ticks.
    ///
    /// # Errors
    /// [`ControlError::InvalidModel`] for a non-finite coefficient,
    /// [`ControlError::RoundTrip`] for a round trip outside `1..=H`.
    pub fn with_model(model: Tf2, round_trip: usize) -> Result<Self, ControlError> {
        if !model.is_finite() {
            return Err(ControlError::InvalidModel);
        }
        Self::build(Model::Fixed, model, round_trip)
    }

    /// A predictor that identifies its model online with `arx` from the
    /// commands and the measured states (the model of `arx` so far, if
    /// trained, is used from the start). Until the identifier has adapted
    /// 5 times, on states that answer a
    /// command (not the first round trip's, the plant at rest), the
    /// controller is given the measured state itself. On a long round trip
    /// a loop closed on that is unstable: drive the plant open loop until
    /// the [`correction`](Self::correction) stays small, then close it.
    ///
    /// # Errors
    /// [`ControlError::RoundTrip`] for a round trip outside `1..=H`.
    pub fn identifying(mut arx: Arx2, round_trip: usize) -> Result<Self, ControlError> {
        arx.clear_history();
        let model = arx.model();
        Self::build(Model::Identify(arx), model, round_trip)
    }

    fn build(model: Model, tf: Tf2, round_trip: usize) -> Result<Self, ControlError> {
        check::<H>(round_trip)?;
        Ok(SmithPredictor {
            model,
            local: Tf2State::new(tf),
            outputs: [0.0; H],
            commands: [0.0; H],
            next: 0,
            round_trip,
            correction: 0.0,
            last_measured: 0.0,
            contiguous: false,
        })
    }

    /// The round trip in ticks.
    #[must_use]
    pub fn round_trip(&self) -> usize {
        self.round_trip
    }

    /// The link announced a new round trip: the correction reads the model
    /// `round_trip` ticks back from now on (the history is kept by tick).
    ///
    /// # Errors
    /// [`ControlError::RoundTrip`] outside `1..=H`; nothing changes then.
    pub fn set_round_trip(&mut self, round_trip: usize) -> Result<(), ControlError> {
        check::<H>(round_trip)?;
        if round_trip != self.round_trip {
            self.round_trip = round_trip;
            // The identifier pairs a command with the state it produced:
            // the pairing moved.
            self.contiguous = false;
        }
        Ok(())
    }

    /// The local model in use.
    #[must_use]
    pub fn model(&self) -> Tf2 {
        *self.local.model()
    }

    /// Gives the local model a new transfer function (the true plant's at
    /// a new period, say), keeping its history.
    ///
    /// # Errors
    /// [`ControlError::InvalidModel`] for a non-finite coefficient.
    pub fn set_model(&mut self, model: Tf2) -> Result<(), ControlError> {
        if !model.is_finite() {
            return Err(ControlError::InvalidModel);
        }
        self.local.set_model(model);
        Ok(())
    }

    /// Whether the model is used: always for a given one, after enough
    /// adaptations for an identified one.
    #[must_use]
    pub fn model_ready(&self) -> bool {
        match &self.model {
            Model::Fixed => true,
            Model::Identify(arx) => arx.updates() >= MIN_IDENTIFICATION_UPDATES,
        }
    }

    /// Whether the model is identified online (not given).
    #[must_use]
    pub fn is_identifying(&self) -> bool {
        matches!(self.model, Model::Identify(_))
    }

    /// The tick of the next [`SmithPredictor::command`]: how many have been given.
    #[must_use]
    pub fn ticks(&self) -> u64 {
        self.next
    }

    /// The last correction `y_m − ŷ[k−D]`.
    #[must_use]
    pub fn correction(&self) -> f64 {
        self.correction
    }

    /// Tick `k`, first half: `measured` is the state released now (`None`
    /// for a repeat or no release); returns what the controller should
    /// take as the plant's state. Call [`SmithPredictor::command`] with the
    /// controller's output next.
    ///
    /// # Errors
    /// [`ControlError::NonFiniteInput`] if `measured` is NaN or infinite;
    /// the predictor is then unchanged.
    pub fn feedback(&mut self, measured: Option<f64>) -> Result<f64, ControlError> {
        let measured = measured.map(finite).transpose()?;
        let d = self.round_trip as u64;
        if let Some(y) = measured {
            let back = self.output(self.next.checked_sub(d));
            self.correction = y - back;
            self.last_measured = y;
            let answered = self.next.checked_sub(d);
            let u = self.command_at(answered);
            // A state that answers no command yet (the plant at rest before
            // tick 0) tells the identifier nothing: it must not count
            // towards the model being ready.
            if let (Model::Identify(arx), Some(_)) = (&mut self.model, answered) {
                if !self.contiguous {
                    arx.clear_history();
                }
                // An overflowing update is skipped: the model stays as it was.
                self.contiguous = arx.update(u, y).is_ok();
                if arx.updates() >= MIN_IDENTIFICATION_UPDATES {
                    let tf = arx.model();
                    if tf.is_finite() {
                        self.local.set_model(tf);
                    }
                }
            }
        } else {
            self.contiguous = false;
        }
        if !self.model_ready() {
            return Ok(self.last_measured);
        }
        Ok(self.local.output() + self.correction)
    }

    /// Tick `k`, second half: the command `u[k]` sent now; the local model
    /// steps on it.
    ///
    /// # Errors
    /// [`ControlError::NonFiniteInput`] if `u` is NaN or infinite; the
    /// predictor is then unchanged.
    pub fn command(&mut self, u: f64) -> Result<(), ControlError> {
        let u = finite(u)?;
        let y = self.local.step(u);
        let i = slot::<H>(self.next);
        if let Some(cell) = self.commands.get_mut(i) {
            *cell = u;
        }
        if let Some(cell) = self.outputs.get_mut(i) {
            *cell = y;
        }
        self.next += 1;
        Ok(())
    }

    /// `ŷ[j]`: zero before tick 0 (at rest) and for a tick not stepped yet.
    fn output(&self, j: Option<u64>) -> f64 {
        self.history(&self.outputs, j)
    }

    fn command_at(&self, j: Option<u64>) -> f64 {
        self.history(&self.commands, j)
    }

    fn history(&self, ring: &[f64; H], j: Option<u64>) -> f64 {
        match j {
            Some(j) if j < self.next && self.next - j <= H as u64 => {
                ring.get(slot::<H>(j)).copied().unwrap_or(0.0)
            }
            _ => 0.0,
        }
    }
}

fn slot<const H: usize>(j: u64) -> usize {
    // H ≥ 1 (checked at construction), and j mod H < H fits in usize.
    (j % (H.max(1) as u64)) as usize
}

fn check<const H: usize>(round_trip: usize) -> Result<(), ControlError> {
    if round_trip == 0 || round_trip > H {
        return Err(ControlError::RoundTrip {
            ticks: round_trip,
            max: H,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::collections::VecDeque;
    use std::vec::Vec;

    use super::*;
    use crate::control::{Pid, PidConfig};

    fn plant() -> Tf2 {
        Tf2::low_pass(core::f64::consts::TAU * 0.5, 0.7, 1.0, 0.02).unwrap()
    }

    fn reference(k: u64) -> f64 {
        if (k / 150).is_multiple_of(2) {
            1.0
        } else {
            -0.5
        }
    }

    fn pid() -> Pid {
        let mut cfg = PidConfig::new(4.0, 2.0, 0.3, 0.02);
        (cfg.out_min, cfg.out_max) = (-20.0, 20.0);
        Pid::new(cfg).unwrap()
    }

    /// The delay-free loop: the controller sees the plant's output on the
    /// previous command.
    fn delay_free(ticks: u64) -> Vec<f64> {
        let (mut p, mut c) = (Tf2State::new(plant()), pid());
        (0..ticks)
            .map(|k| {
                let u = c.step(reference(k), p.output()).unwrap();
                p.step(u);
                p.output()
            })
            .collect()
    }

    /// The loop closed across delays that may change: the command sent at
    /// tick `k` reaches the plant `fwd(k)` ticks later, its state the base
    /// `bwd` ticks after that. `before(k, smith)` runs at each tick before
    /// the predictor. Returns the states measured at the base, tick by tick.
    fn across(
        ticks: u64,
        smith: &mut SmithPredictor<64>,
        mut fwd: impl FnMut(u64) -> u64,
        bwd: u64,
        mut before: impl FnMut(u64, &mut SmithPredictor<64>),
    ) -> Vec<Option<f64>> {
        let (mut p, mut c) = (Tf2State::new(plant()), pid());
        // Commands in flight, by the tick they reach the plant; states by
        // the tick they reach the base.
        let (mut to_plant, mut to_base) = (VecDeque::new(), VecDeque::new());
        let mut last_applied = None;
        let mut measured = Vec::new();
        for k in 0..ticks {
            let mut y_m = None;
            while to_base.front().is_some_and(|&(at, _)| at == k) {
                y_m = to_base.pop_front().map(|(_, y)| y);
            }
            measured.push(y_m);
            before(k, smith);
            let seen = smith.feedback(y_m).unwrap();
            let u = c.step(reference(k), seen).unwrap();
            smith.command(u).unwrap();
            to_plant.push_back((k + fwd(k), u));
            // The plant steps once a tick on the command due (a repeat if
            // none is), the regulated remote's way.
            let mut due = None;
            while to_plant.front().is_some_and(|&(at, _)| at <= k) {
                due = to_plant.pop_front().map(|(_, u)| u);
            }
            if let Some(u) = due.or(last_applied) {
                last_applied = Some(u);
                to_base.push_back((k + bwd, p.step(u)));
            }
        }
        measured
    }

    #[test]
    fn with_the_true_model_the_loop_is_the_delay_free_loop_delayed() {
        for (df, db) in [(0, 1), (1, 1), (3, 4), (10, 7)] {
            let d = (df + db) as usize;
            let mut smith = SmithPredictor::<64>::with_model(plant(), d).unwrap();
            let ideal = delay_free(600);
            let measured = across(600, &mut smith, |_| df, db, |_, _| {});
            for (k, y) in measured.iter().enumerate() {
                // The state measured at k is the plant's on u[k − D]: the
                // delay-free loop's output D − 1 ticks back.
                let want = (k >= d).then(|| ideal[k - d]);
                match (y, want) {
                    (Some(y), Some(w)) => assert_eq!(y.to_bits(), w.to_bits(), "{df}+{db} at {k}"),
                    (Some(y), None) => assert_eq!(*y, 0.0),
                    (None, _) => assert!(k < d, "{df}+{db}: nothing at {k}"),
                }
            }
            assert!(ideal.iter().any(|y| *y > 0.9));
        }
    }

    #[test]
    fn plain_feedback_over_the_same_delay_is_worse() {
        // The loop that would be exact above, without the predictor's
        // correction (the model given zero gain): large error.
        let d = 17;
        let zero = Tf2 {
            b: [0.0; 3],
            a: [0.0; 2],
        };
        let mut plain = SmithPredictor::<64>::with_model(zero, d).unwrap();
        let ideal = delay_free(600);
        let measured = across(600, &mut plain, |_| 10, 7, |_, _| {});
        let err: f64 = measured
            .iter()
            .enumerate()
            .skip(d)
            .map(|(k, y)| (y.unwrap() - ideal[k - d]).abs())
            .fold(0.0, f64::max);
        assert!(err > 0.1, "{err}");
    }

    #[test]
    fn a_delay_change_realigns_without_a_bump_it_does_not_need() {
        // The forward delay rises from 3 to 5 ticks at tick 200: the plant
        // repeats a command twice; the predictor is told at the tick the
        // first state from the longer path arrives.
        let change = 200;
        let fwd = |k: u64| if k < change { 3 } else { 5 };
        let run = |realign: bool| {
            let mut smith = SmithPredictor::<64>::with_model(plant(), 7).unwrap();
            let mut worst = 0.0f64;
            across(800, &mut smith, fwd, 4, |k, smith| {
                if realign && k == change + 5 + 4 {
                    smith.set_round_trip(9).unwrap();
                }
                // The correction of the tick before.
                if k > change + 20 {
                    worst = worst.max(smith.correction().abs());
                }
            });
            worst
        };
        // Realigned, the correction is what the repeated command left:
        // small, and decaying. Not realigned, the model is compared with
        // the plant two ticks apart for ever.
        let (realigned, stale) = (run(true), run(false));
        assert!(realigned < 0.05, "{realigned}");
        assert!(stale > 3.0 * realigned, "{stale} vs {realigned}");
    }

    #[test]
    fn an_identified_model_converges_to_the_plant() {
        let d = 6;
        let mut smith = SmithPredictor::<64>::identifying(Arx2::new(1.0, 1e6).unwrap(), d).unwrap();
        assert!(!smith.model_ready());
        let ideal = delay_free(3000);
        let measured = across(3000, &mut smith, |_| 2, 4, |_, _| {});
        assert!(smith.model_ready());
        let tail: f64 = measured
            .iter()
            .enumerate()
            .skip(2000)
            .map(|(k, y)| (y.unwrap() - ideal[k - d]).abs())
            .fold(0.0, f64::max);
        assert!(tail < 0.02, "{tail}");
    }

    #[test]
    fn bad_round_trips_and_inputs_are_refused() {
        assert!(matches!(
            SmithPredictor::<8>::with_model(plant(), 0),
            Err(ControlError::RoundTrip { ticks: 0, max: 8 })
        ));
        assert!(SmithPredictor::<8>::with_model(plant(), 9).is_err());
        let mut s = SmithPredictor::<8>::with_model(plant(), 8).unwrap();
        assert!(s.set_round_trip(9).is_err());
        assert_eq!(s.round_trip(), 8);
        let before = s.clone();
        assert_eq!(
            s.feedback(Some(f64::NAN)),
            Err(ControlError::NonFiniteInput)
        );
        assert_eq!(s.command(f64::INFINITY), Err(ControlError::NonFiniteInput));
        assert_eq!(s, before);
        let nan = Tf2 {
            b: [f64::NAN, 0.0, 0.0],
            a: [0.0; 2],
        };
        assert_eq!(
            SmithPredictor::<8>::with_model(nan, 1),
            Err(ControlError::InvalidModel)
        );
    }

    #[test]
    fn states_that_answer_no_command_do_not_make_the_model_ready() {
        let mut smith =
            SmithPredictor::<64>::identifying(Arx2::new(1.0, 1e6).unwrap(), 10).unwrap();
        // The first round trip's states are the plant at rest, before any
        // command: nothing to identify from.
        for _ in 0..10 {
            assert_eq!(smith.feedback(Some(0.0)).unwrap(), 0.0);
            smith.command(1.0).unwrap();
        }
        assert!(!smith.model_ready());
        // The identifier's own history fills first (two samples).
        for _ in 0..MIN_IDENTIFICATION_UPDATES + 2 {
            let _ = smith.feedback(Some(0.5)).unwrap();
            smith.command(1.0).unwrap();
        }
        assert!(smith.model_ready());
    }
}
