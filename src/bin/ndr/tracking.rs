//! `ndr demo --controller` and `ndr base --controller`: the base closes a
//! position loop on the remote's delayed state over the real link, with
//! the gains, plant and reference of `ndr control --scenario tracking`, so
//! that the two can be compared.
//!
//! Each release is a base tick `k`: the controller takes its state, and
//! the command it computes is sent at the link's next tick. The round trip
//! in ticks is the link's, from each release's GRTT ([`link_round_trip`]);
//! the Smith predictor follows it as the simulator's does. The design (the
//! same PID on the same plant, no link) runs alongside, so that each state
//! can be compared with the design's on the command it answers, one round
//! trip before: the report's `rms_vs_delayed_design`.

use std::str::FromStr;

use ndr::core::Tf2State;
use ndr::core::control::{ControlError, Pid, PidConfig, SmithPredictor, round_trip_ticks};
use ndr::core::time::Duration;
use ndr::sim::control::{Reference, TrackingGains};
use serde::Serialize;

use crate::robot::{StateLayout, plant_model};

/// The longest round trip the controller follows, ticks (the simulator's).
const HISTORY: usize = 8192;

/// Which controller closes the loop at the base.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ControllerKind {
    /// None: the operator's open-loop signal.
    #[default]
    None,
    /// The PID through a Smith predictor with the plant's true model.
    Smith,
    /// The PID on the measured state.
    Pid,
}

impl ControllerKind {
    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            ControllerKind::None => "none",
            ControllerKind::Smith => "smith",
            ControllerKind::Pid => "pid",
        }
    }
}

impl FromStr for ControllerKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s.trim() {
            "none" => Ok(ControllerKind::None),
            "smith" => Ok(ControllerKind::Smith),
            "pid" => Ok(ControllerKind::Pid),
            other => Err(format!(
                "unknown controller `{other}`; valid: none, smith (a PID through a Smith \
                 predictor), pid"
            )),
        }
    }
}

/// Refuses a controller the state layout cannot serve: the loop reads the
/// first axis's position, the first value of a state.
pub fn check_layout(kind: ControllerKind, layout: &StateLayout) -> Result<(), String> {
    if kind == ControllerKind::None || layout.leads_with_positions() {
        Ok(())
    } else {
        Err(format!(
            "--controller {} closes the loop on the first axis's position: give a --state that \
             starts with positions (e.g. positions,velocities), not {layout}",
            kind.name()
        ))
    }
}

/// What the tracking loop measured (positions over the reference's
/// amplitude, as `ndr control`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct TrackingSummary {
    /// Base ticks the loop ran.
    pub ticks: u64,
    /// RMS of the position measured at the base less the reference.
    pub rms_vs_reference: f64,
    /// RMS of the position measured at the base less the design's position
    /// on the command sent one round trip before.
    pub rms_vs_delayed_design: f64,
    /// The mean round trip the controller was given, ticks.
    pub round_trip_mean_ticks: f64,
    /// Changes of that round trip after the first.
    pub round_trip_changes: u64,
}

/// The base's controller and its measurement.
pub struct Tracker {
    pid: Pid,
    smith: Option<Box<SmithPredictor<HISTORY>>>,
    /// The round trip from the link, once one is known.
    round_trip: Option<usize>,
    changes: u64,
    reference: Reference,
    period_s: f64,
    k: u64,
    /// The design: the PID on the plant, undelayed.
    design_pid: Pid,
    design_plant: Tf2State,
    /// The design's position on the command of tick `j`, at `j mod HISTORY`.
    design: Vec<f64>,
    sum_ref: f64,
    sum_design: f64,
    sum_trip: f64,
    trips: u64,
}

fn pid(g: &TrackingGains, period_s: f64) -> Result<Pid, ControlError> {
    let mut cfg = PidConfig::new(g.kp, g.ki, g.kd, period_s);
    (cfg.out_min, cfg.out_max) = (-g.u_max, g.u_max);
    Pid::new(cfg)
}

/// The round trip in base ticks that a release's GRTT is, at `period`,
/// for this loop: it answers each release at once, and its command leaves
/// at the link's next tick, one more tick before the GRTT starts counting.
/// A release the host served a little late (by up to a tenth of a period)
/// is still on its tick: that lateness is not a longer round trip.
pub fn link_round_trip(grtt: Duration, period: Duration) -> Option<usize> {
    let slack = Duration::from_nanos(period.as_nanos() / 10);
    round_trip_ticks(grtt.saturating_sub(slack), period).map(|d| d + 1)
}

fn control_error(e: ControlError) -> String {
    format!("the tracking controller refused a value: {e}")
}

impl Tracker {
    /// The loop for `kind` at `period`; `None` for [`ControllerKind::None`].
    pub fn new(kind: ControllerKind, period: Duration) -> Result<Option<Tracker>, String> {
        if kind == ControllerKind::None {
            return Ok(None);
        }
        let period_s = period.as_secs_f64();
        let gains = TrackingGains::default();
        let model = plant_model(period)?;
        let smith = match kind {
            // One tick until the link says its round trip, as the simulator.
            ControllerKind::Smith => Some(Box::new(
                SmithPredictor::with_model(model, 1).map_err(control_error)?,
            )),
            _ => None,
        };
        Ok(Some(Tracker {
            pid: pid(&gains, period_s).map_err(control_error)?,
            smith,
            round_trip: None,
            changes: 0,
            reference: Reference::default(),
            period_s,
            k: 0,
            design_pid: pid(&gains, period_s).map_err(control_error)?,
            design_plant: Tf2State::new(model),
            design: vec![0.0; HISTORY],
            sum_ref: 0.0,
            sum_design: 0.0,
            sum_trip: 0.0,
            trips: 0,
        }))
    }

    /// The link started again at a new period (paper-dynamic): the plant's
    /// model and the PIDs are discretized anew.
    pub fn set_period(&mut self, period: Duration) -> Result<(), String> {
        let period_s = period.as_secs_f64();
        let model = plant_model(period)?;
        self.pid.set_period(period_s).map_err(control_error)?;
        self.design_pid
            .set_period(period_s)
            .map_err(control_error)?;
        self.design_plant.set_model(model);
        if let Some(s) = &mut self.smith {
            s.set_model(model).map_err(control_error)?;
        }
        self.period_s = period_s;
        Ok(())
    }

    /// One base tick: the state `y` released now (`fresh`: not a held
    /// repeat), the GRTT it closes, if any; returns the command to send.
    pub fn tick(&mut self, y: f64, fresh: bool, grtt: Option<Duration>) -> Result<f64, String> {
        let k = self.k;
        if let Some(d) =
            grtt.and_then(|g| link_round_trip(g, Duration::from_secs_f64(self.period_s)))
            && (1..=HISTORY).contains(&d)
            && self.round_trip != Some(d)
        {
            if self.round_trip.is_some() {
                self.changes += 1;
            }
            self.round_trip = Some(d);
            if let Some(s) = &mut self.smith {
                s.set_round_trip(d).map_err(control_error)?;
            }
        }
        let seen = match &mut self.smith {
            // No correction before the round trip is known: it would
            // compare the state with the wrong command.
            Some(s) => {
                let measured = (self.round_trip.is_some() && fresh).then_some(y);
                s.feedback(measured).map_err(control_error)?
            }
            None => y,
        };
        let r = self.reference.value(k as f64 * self.period_s);
        let u = self.pid.step(r, seen).map_err(control_error)?;
        if let Some(s) = &mut self.smith {
            s.command(u).map_err(control_error)?;
        }
        // The design on this tick's reference, and the measurement.
        let design_u = self
            .design_pid
            .step(r, self.design_plant.output())
            .map_err(control_error)?;
        let x = self.design_plant.step(design_u);
        let slot = |j: u64| (j % HISTORY as u64) as usize;
        let amp = self.reference.amplitude.abs().max(f64::MIN_POSITIVE);
        let delayed = match self.round_trip {
            Some(d) if k >= d as u64 => self.design[slot(k - d as u64)],
            _ => 0.0,
        };
        self.design[slot(k)] = x;
        self.sum_ref += ((y - r) / amp).powi(2);
        self.sum_design += ((y - delayed) / amp).powi(2);
        if let Some(d) = self.round_trip {
            self.sum_trip += d as f64;
            self.trips += 1;
        }
        self.k += 1;
        Ok(u)
    }

    /// What the loop measured so far.
    pub fn summary(&self) -> TrackingSummary {
        let n = self.k.max(1) as f64;
        TrackingSummary {
            ticks: self.k,
            rms_vs_reference: (self.sum_ref / n).sqrt(),
            rms_vs_delayed_design: (self.sum_design / n).sqrt(),
            round_trip_mean_ticks: self.sum_trip / self.trips.max(1) as f64,
            round_trip_changes: self.changes,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A link of `d` ticks in front of the plant, the state of command `j`
    /// released at tick `j + d`, a GRTT of `d` periods on each release.
    fn run(kind: ControllerKind, d: usize, ticks: usize) -> TrackingSummary {
        let period = Duration::from_millis(10);
        let mut t = Tracker::new(kind, period).unwrap().unwrap();
        let mut p = Tf2State::new(plant_model(period).unwrap());
        let mut x = vec![0.0; ticks];
        for k in 0..ticks {
            let y = if k >= d { x[k - d] } else { 0.0 };
            // The command leaves a tick after it is computed.
            let grtt = Duration::from_millis(10 * (d as u64 - 1));
            let u = t.tick(y, true, (k >= d).then_some(grtt)).unwrap();
            x[k] = p.step(u);
        }
        t.summary()
    }

    #[test]
    fn the_smith_loop_is_the_design_delayed_and_the_pid_alone_is_not() {
        let smith = run(ControllerKind::Smith, 12, 6000);
        assert!(smith.rms_vs_delayed_design < 1e-9, "{smith:?}");
        assert_eq!(smith.round_trip_mean_ticks, 12.0);
        assert_eq!(smith.round_trip_changes, 0);
        assert!(smith.rms_vs_reference > 0.05, "{smith:?}");
        let pid = run(ControllerKind::Pid, 12, 6000);
        assert!(
            pid.rms_vs_delayed_design > 100.0 * smith.rms_vs_delayed_design.max(1e-6),
            "{pid:?}"
        );
    }

    #[test]
    fn the_round_trip_counts_the_tick_the_command_waits_not_a_late_release() {
        let t = Duration::from_millis(10);
        assert_eq!(link_round_trip(Duration::from_millis(30), t), Some(4));
        assert_eq!(link_round_trip(Duration::from_micros(30_150), t), Some(4));
        assert_eq!(link_round_trip(Duration::from_micros(31_500), t), Some(5));
        assert_eq!(
            link_round_trip(Duration::from_millis(30), Duration::ZERO),
            None
        );
    }

    #[test]
    fn no_controller_is_no_tracker_and_names_parse() {
        assert!(
            Tracker::new(ControllerKind::None, Duration::from_millis(10))
                .unwrap()
                .is_none()
        );
        for k in [
            ControllerKind::None,
            ControllerKind::Smith,
            ControllerKind::Pid,
        ] {
            assert_eq!(k.name().parse::<ControllerKind>(), Ok(k));
        }
        assert!(
            "wave"
                .parse::<ControllerKind>()
                .unwrap_err()
                .contains("smith")
        );
    }
}
