//! Classical teleoperation control closed across the link (`ndr control`).
//!
//! Two scenarios, each run over several links with the same gains:
//!
//! - **tracking**: a PID at the base closes a position loop on the remote's
//!   delayed state (the simulator's second-order axis), directly or through
//!   a Smith predictor ([`ndr_core::control::SmithPredictor`]); the
//!   reference is a step sequence, then a sine;
//! - **bilateral**: a master device (a mass the operator holds, modelled as
//!   a spring–damper toward the reference) and a slave (a mass under a
//!   local PD) that meets a stiff wall, coupled by wave variables
//!   ([`ndr_core::control::WaveTransform`]); the force is reflected to the
//!   operator.
//!
//! The links ([`LinkKind`]): the delay-free loop (the design), a plain
//! socket (unregulated: each sample applied the moment it arrives, the
//! Smith predictor given the mean round trip), and the regulated link run
//! through the real endpoints in simulated time (the paper's static and
//! dynamic FIFO, the adaptive playout), where the Smith predictor follows
//! the round trip each base release's GRTT announces.
//!
//! # What is measured
//!
//! Positions are normalised by the reference's amplitude. A state measured
//! at the base answers a known command (the samples carry the tick that
//! sent them, for the measurement only), so the round trip the link
//! actually held is known at every tick.
//!
//! - `rms_vs_reference`: RMS of the position measured at the base less the
//!   reference.
//! - `rms_vs_delayed_design`: RMS of the position measured at the base
//!   less the delay-free loop's position on the command it answers: the
//!   design's output delayed by the round trip held. Zero when the loop
//!   behaves like the design, delayed. `rms_vs_delayed_design_late`: the
//!   same over the run's second half.
//! - `overshoot` (fraction of the step) and `settling_s` (to 2 % of the
//!   step, measured at the base, so the round trip counts): the worst over
//!   the steps; `stable`: the position stayed within
//!   [`STABLE_BOUND`] amplitudes.
//! - bilateral: `energy_generated` (the most the wave channel gave beyond
//!   what it received, over the energy that went through it),
//!   `contact_force_rms_error` (N: the force reflected to the operator
//!   less the contact force at the slave when it sent the wave), and
//!   `position_rms_error` (the slave's position less the master's when it
//!   sent the command the slave applied).
//! - `round_trip_changes`: the round trips the Smith predictor was given;
//!   `announced`: the delay changes the endpoints announced;
//!   `round_trips_announced`: the round trips the base announced;
//!   `unannounced_changes`: round-trip changes with no announcement (of
//!   either kind) within a round trip of them; `announced_late`: those
//!   announced only after the GRTT showed them;
//!   `change_peak`: the largest `rms_vs_delayed_design`-type error in the
//!   [`CHANGE_WINDOW`] ticks after each announced change.

mod apps;
mod links;

use std::string::{String, ToString};
use std::vec::Vec;

use ndr_core::Regulation;
use ndr_core::control::ControlError;
use ndr_core::time::Duration;
use serde::Serialize;

use self::apps::{Bilateral, Record, Tracking};
use crate::{SimConfig, SimError};

/// A position beyond this many reference amplitudes is an unstable loop.
pub const STABLE_BOUND: f64 = 3.0;
/// Ticks after an announced delay change in which the error peak is taken.
pub const CHANGE_WINDOW: u64 = 100;
/// The layout version of `ndr control --json`.
pub const SCHEMA: &str = "ndr-control/1";

/// Which loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum Scenario {
    /// A position loop on the remote's delayed state.
    Tracking,
    /// Master and slave coupled by wave variables, the slave against a wall.
    Bilateral,
}

/// Which controller closes the loop.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum Controller {
    /// A PID through a Smith predictor with the plant's true model.
    Smith,
    /// The same with a model identified online.
    SmithIdentified,
    /// The PID on the measured state.
    Pid,
    /// Wave variables (bilateral).
    Wave,
}

/// Which link the loop is closed across.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
#[non_exhaustive]
pub enum LinkKind {
    /// No delay: the design.
    Ideal,
    /// A plain socket: each sample applied when it arrives.
    Unregulated,
    /// The paper's FIFO, sized once.
    PaperStatic,
    /// The paper's FIFO, resized as the network changes.
    PaperDynamic,
    /// ndr's adaptive playout.
    Adaptive,
}

impl LinkKind {
    /// Every link, in the order of the report.
    pub const ALL: [LinkKind; 5] = [
        LinkKind::Ideal,
        LinkKind::Unregulated,
        LinkKind::PaperStatic,
        LinkKind::PaperDynamic,
        LinkKind::Adaptive,
    ];

    /// Its name on the command line and in reports.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            LinkKind::Ideal => "ideal",
            LinkKind::Unregulated => "unregulated",
            LinkKind::PaperStatic => "paper-static",
            LinkKind::PaperDynamic => "paper-dynamic",
            LinkKind::Adaptive => "adaptive",
        }
    }

    fn regulation(self) -> Option<Regulation> {
        match self {
            LinkKind::PaperStatic => Some(Regulation::PaperStatic),
            LinkKind::PaperDynamic => Some(Regulation::PaperDynamic),
            LinkKind::Adaptive => Some(Regulation::ADAPTIVE),
            LinkKind::Ideal | LinkKind::Unregulated => None,
        }
    }
}

impl core::str::FromStr for LinkKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        LinkKind::ALL
            .into_iter()
            .find(|l| l.name() == s)
            .ok_or_else(|| {
                let names: Vec<&str> = LinkKind::ALL.iter().map(|l| l.name()).collect();
                std::format!("unknown link `{s}`; valid: {}", names.join(", "))
            })
    }
}

/// The reference: steps between 0 and the amplitude, then a sine.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[non_exhaustive]
pub struct Reference {
    /// Amplitude.
    pub amplitude: f64,
    /// Time each step is held, s.
    pub step_s: f64,
    /// Steps before the sine starts.
    pub steps: u32,
    /// The sine's frequency, Hz.
    pub sine_hz: f64,
}

impl Default for Reference {
    /// Four 10 s steps of 1, then a 0.1 Hz sine.
    fn default() -> Self {
        Reference {
            amplitude: 1.0,
            step_s: 10.0,
            steps: 4,
            sine_hz: 0.1,
        }
    }
}

impl Reference {
    /// The reference at `t` seconds.
    #[must_use]
    pub fn value(&self, t: f64) -> f64 {
        let end = self.step_s * f64::from(self.steps);
        if t < end {
            let i = (t / self.step_s) as u32;
            if i.is_multiple_of(2) {
                self.amplitude
            } else {
                0.0
            }
        } else {
            self.amplitude * (core::f64::consts::TAU * self.sine_hz * (t - end)).sin()
        }
    }
}

/// The tracking loop's PID.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[non_exhaustive]
pub struct TrackingGains {
    /// Proportional gain.
    pub kp: f64,
    /// Integral gain, 1/s.
    pub ki: f64,
    /// Derivative gain, s.
    pub kd: f64,
    /// Output limit (±).
    pub u_max: f64,
}

impl Default for TrackingGains {
    /// A PID tuned for the delay-free loop on the default plant.
    fn default() -> Self {
        TrackingGains {
            kp: 4.0,
            ki: 2.0,
            kd: 0.3,
            u_max: 10.0,
        }
    }
}

/// The bilateral loop's masses, operator, slave controller, wall and wave
/// impedance (SI units).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[non_exhaustive]
pub struct BilateralGains {
    /// Wave impedance, N·s/m.
    pub b: f64,
    /// Master mass, kg.
    pub m_master: f64,
    /// Operator stiffness toward the reference, N/m.
    pub k_operator: f64,
    /// Operator damping, N·s/m.
    pub b_operator: f64,
    /// Slave mass, kg.
    pub m_slave: f64,
    /// Slave PD stiffness, N/m.
    pub k_slave: f64,
    /// Slave PD damping, N·s/m.
    pub b_slave: f64,
    /// Wall position, m.
    pub wall: f64,
    /// Wall stiffness, N/m.
    pub k_wall: f64,
    /// Wall damping, N·s/m.
    pub b_wall: f64,
}

impl Default for BilateralGains {
    fn default() -> Self {
        BilateralGains {
            b: 20.0,
            m_master: 1.0,
            k_operator: 100.0,
            b_operator: 20.0,
            m_slave: 1.0,
            k_slave: 400.0,
            b_slave: 40.0,
            wall: 0.5,
            k_wall: 1000.0,
            b_wall: 10.0,
        }
    }
}

/// One closed-loop run.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct LoopConfig {
    /// The network, period, duration, seed and plant (its regulation is
    /// set by `link`).
    pub sim: SimConfig,
    /// The loop.
    pub scenario: Scenario,
    /// The controller: [`Controller::Wave`] for the bilateral loop.
    pub controller: Controller,
    /// The link.
    pub link: LinkKind,
    /// The reference.
    pub reference: Reference,
    /// The tracking PID.
    pub tracking: TrackingGains,
    /// The bilateral loop's parameters.
    pub bilateral: BilateralGains,
}

impl LoopConfig {
    /// `scenario` with its default controller over `link`, on `sim`.
    #[must_use]
    pub fn new(sim: SimConfig, scenario: Scenario, link: LinkKind) -> Self {
        LoopConfig {
            sim,
            scenario,
            controller: match scenario {
                Scenario::Tracking => Controller::Smith,
                Scenario::Bilateral => Controller::Wave,
            },
            link,
            reference: Reference::default(),
            tracking: TrackingGains::default(),
            bilateral: BilateralGains::default(),
        }
    }
}

/// What one run measured (see the [module docs](self)).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
#[non_exhaustive]
pub struct LoopMetrics {
    /// RMS of the measured position less the reference, / amplitude.
    pub rms_vs_reference: f64,
    /// RMS of the measured position less the delayed design's, / amplitude.
    pub rms_vs_delayed_design: f64,
    /// The same over the second half of the run (an identified model has
    /// converged by then).
    pub rms_vs_delayed_design_late: f64,
    /// Largest overshoot of a step, / step.
    pub overshoot: f64,
    /// Longest settling to 2 % of a step, s; `None` if a step never settled.
    pub settling_s: Option<f64>,
    /// The position stayed within [`STABLE_BOUND`] amplitudes.
    pub stable: bool,
    /// The loop diverged to values that are not finite and the run
    /// stopped there (its errors are infinite).
    pub diverged: bool,
    /// Mean round trip held, ticks.
    pub round_trip_mean_ticks: f64,
    /// Round trips the Smith predictor was given after the first.
    pub round_trip_changes: u64,
    /// Remote ticks that applied no new command once commands flowed
    /// (underflows, lost samples; a plain socket's gaps).
    pub repeats: u64,
    /// Delay changes the endpoints announced.
    pub announced: u64,
    /// Round trips the base announced (`Event::RoundTripChanged`), the
    /// first included.
    pub round_trips_announced: u64,
    /// Round-trip changes the Smith predictor saw with neither a delay
    /// change nor a round trip announced within a round trip of them,
    /// before or after.
    pub unannounced_changes: u64,
    /// Round-trip changes announced only after the GRTT showed them
    /// (within a round trip).
    pub announced_late: u64,
    /// Largest error against the delayed design within [`CHANGE_WINDOW`]
    /// ticks after an announced change, / amplitude.
    pub change_peak: Option<f64>,
    /// Each announced change: when (s since the loop started) and the
    /// largest error in the [`CHANGE_WINDOW`] ticks from it, / amplitude
    /// (a seed's own; empty in a mean over seeds).
    pub change_peaks: Vec<ChangePeak>,
    /// Times the link changed its period (paper-dynamic).
    pub period_changes: u64,
    /// Bilateral: energy the channel generated / energy through it.
    pub energy_generated: Option<f64>,
    /// Bilateral: energy through the channel, J.
    pub energy_through: Option<f64>,
    /// Bilateral: RMS of reflected force less contact force, N.
    pub contact_force_rms_error: Option<f64>,
    /// Bilateral: RMS of slave less master position, / amplitude.
    pub position_rms_error: Option<f64>,
}

/// The error after one announced delay change.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
#[non_exhaustive]
pub struct ChangePeak {
    /// When it was announced, s since the loop started.
    pub at_s: f64,
    /// The largest error against the delayed design in the
    /// [`CHANGE_WINDOW`] ticks from it, / amplitude.
    pub peak: f64,
}

/// One run of a loop over its link: what both sides recorded, and what
/// the link did.
fn run_record(cfg: &LoopConfig) -> Result<(Record, links::LinkLog), SimError> {
    let mut sim = cfg.sim.clone();
    let period_s = sim.period.as_secs_f64();
    // Refused here with the plant's own error rather than as a model error.
    cfg.sim
        .plant
        .discretize(sim.period)
        .map_err(SimError::Plant)?;
    // The round trip a Smith predictor is given once: one tick without a
    // link, the mean over a plain socket; the regulated link announces it.
    let fixed = match cfg.link {
        LinkKind::Ideal => Some(1),
        LinkKind::Unregulated => Some(mean_round_trip(&sim)?),
        _ => None,
    };
    let repeat_waves = cfg.link == LinkKind::Unregulated;
    macro_rules! over {
        ($app:expr) => {
            match cfg.link.regulation() {
                Some(r) => {
                    sim = sim.with_regulation(r);
                    links::regulated(&sim, $app)
                }
                None => links::plain(&sim, $app, cfg.link == LinkKind::Ideal),
            }
        };
    }
    match (cfg.scenario, cfg.controller) {
        (
            Scenario::Tracking,
            c @ (Controller::Smith | Controller::SmithIdentified | Controller::Pid),
        ) => {
            let smith = match c {
                Controller::Smith => Some(true),
                Controller::SmithIdentified => Some(false),
                _ => None,
            };
            let mut app = Tracking::new(
                &cfg.tracking,
                cfg.sim.plant,
                cfg.reference,
                period_s,
                smith,
                fixed,
            )
            .map_err(SimError::Control)?;
            let log = over!(&mut app)?;
            Ok((app.record, log))
        }
        (Scenario::Bilateral, Controller::Wave) => {
            let mut app = Bilateral::new(&cfg.bilateral, cfg.reference, period_s, repeat_waves)
                .map_err(SimError::Control)?;
            let log = over!(&mut app)?;
            Ok((app.finish(), log))
        }
        _ => Err(SimError::Control(ControlError::InvalidParameter(
            "the controller for this scenario (tracking: smith, smith-identified or pid; \
             bilateral: wave)",
        ))),
    }
}

/// The mean round trip of a plain socket on `sim`'s network, ticks: what
/// the unregulated link's Smith predictor is given.
fn mean_round_trip(sim: &SimConfig) -> Result<usize, SimError> {
    let mut app = Tracking::new(
        &TrackingGains {
            kp: 0.0,
            ki: 0.0,
            kd: 0.0,
            u_max: 0.0,
        },
        sim.plant,
        Reference::default(),
        sim.period.as_secs_f64(),
        None,
        None,
    )
    .map_err(SimError::Control)?;
    links::plain(sim, &mut app, false)?;
    let held: Vec<f64> = held_round_trips(&app.record).collect();
    let mean = held.iter().sum::<f64>() / held.len().max(1) as f64;
    Ok((mean.round() as usize).max(1))
}

/// The round trip each base tick's state held, ticks.
fn held_round_trips(rec: &Record) -> impl Iterator<Item = f64> + '_ {
    rec.base
        .iter()
        .enumerate()
        .filter(|(_, b)| b.answers >= 0)
        .map(|(k, b)| (k as i64 - b.answers) as f64)
}

/// The metrics of a run (`rec`, `log`) against `design`, the delay-free
/// loop's record on the same configuration.
fn measure(cfg: &LoopConfig, rec: &Record, log: &links::LinkLog, design: &Record) -> LoopMetrics {
    let amp = cfg.reference.amplitude.abs().max(f64::MIN_POSITIVE);
    let period_s = log.start_period.unwrap_or(cfg.sim.period).as_secs_f64();
    // The design's position on each command, by the time it was sent: a
    // run whose period changed is compared with the design at the same
    // times (interpolated); at one period the times are the same floats.
    let mut design_at: Vec<(f64, f64)> = Vec::with_capacity(design.base.len());
    for t in &design.remote {
        if let Some(b) = usize::try_from(t.applied)
            .ok()
            .and_then(|j| design.base.get(j))
            && design_at.last().is_none_or(|&(last, _)| b.t > last)
        {
            design_at.push((b.t, t.x));
        }
    }
    let delayed_design = |b: &apps::BaseTick| -> f64 {
        usize::try_from(b.answers)
            .ok()
            .and_then(|j| rec.base.get(j))
            .map_or(0.0, |sent| interpolate(&design_at, sent.t))
    };
    let n = rec.base.len().max(1) as f64;
    let rms = |f: &dyn Fn(usize, &apps::BaseTick) -> f64| -> f64 {
        (rec.base
            .iter()
            .enumerate()
            .map(|(k, b)| f(k, b).powi(2))
            .sum::<f64>()
            / n)
            .sqrt()
    };
    let rms_vs_reference = rms(&|_, b| b.y - b.r) / amp;
    let rms_vs_delayed_design = rms(&|_, b| b.y - delayed_design(b)) / amp;
    let half = rec.base.len() / 2;
    let rms_vs_delayed_design_late =
        root_mean_square(rec.base.iter().skip(half).map(|b| b.y - delayed_design(b))) / amp;
    let stable = rec
        .base
        .iter()
        .all(|b| b.y.is_finite() && b.y.abs() <= STABLE_BOUND * amp)
        && rec
            .remote
            .iter()
            .all(|t| t.x.is_finite() && t.x.abs() <= STABLE_BOUND * amp);
    // Steps: overshoot and settling of each, the worst.
    let step_ticks = ((cfg.reference.step_s / period_s).round() as usize).max(1);
    let (mut overshoot, mut settling, mut all_settled) = (0.0f64, 0.0f64, true);
    for s in 0..cfg.reference.steps as usize {
        let (start, end) = (s * step_ticks, ((s + 1) * step_ticks).min(rec.base.len()));
        if start >= end || start == 0 && s != 0 {
            continue;
        }
        let window = &rec.base[start..end];
        let target = window[0].r;
        let from = if s == 0 { 0.0 } else { rec.base[start - 1].r };
        let size = target - from;
        if size == 0.0 {
            continue;
        }
        let over = window
            .iter()
            .map(|b| (b.y - target) / size)
            .fold(0.0f64, f64::max);
        overshoot = overshoot.max(over);
        let band = 0.02 * size.abs();
        match window.iter().rposition(|b| (b.y - target).abs() > band) {
            Some(i) if i + 1 == window.len() => all_settled = false,
            Some(i) => settling = settling.max((i + 1) as f64 * period_s),
            None => {}
        }
    }
    let trips: Vec<f64> = held_round_trips(rec).collect();
    let change_peaks: Vec<ChangePeak> = log
        .announced
        .iter()
        .map(|&k| ChangePeak {
            at_s: rec.base.get(k as usize).map_or(f64::NAN, |b| b.t),
            peak: rec
                .base
                .iter()
                .skip(k as usize)
                .take(CHANGE_WINDOW as usize)
                .map(|b| (b.y - delayed_design(b)).abs() / amp)
                .fold(0.0f64, f64::max),
        })
        .collect();
    let change_peak = change_peaks.iter().map(|c| c.peak).reduce(f64::max);
    // Changes of the round trip given to the predictor (after the first)
    // with no announcement `a` such that `near(a, k, window)`.
    let changes = |near: &dyn Fn(u64, u64, u64) -> bool| -> u64 {
        rec.round_trips
            .iter()
            .skip(1)
            .filter(|&&(k, d)| {
                !log.announced
                    .iter()
                    .chain(&log.round_trips_announced)
                    .any(|&a| near(a, k, d as u64 + 2))
            })
            .count() as u64
    };
    let mut m = LoopMetrics {
        rms_vs_reference,
        rms_vs_delayed_design,
        rms_vs_delayed_design_late,
        overshoot,
        settling_s: all_settled.then_some(settling),
        stable,
        round_trip_mean_ticks: trips.iter().sum::<f64>() / trips.len().max(1) as f64,
        round_trip_changes: rec.round_trips.len().saturating_sub(1) as u64,
        repeats: rec.repeats,
        announced: log.announced.len() as u64,
        round_trips_announced: log.round_trips_announced.len() as u64,
        unannounced_changes: changes(&|a, k, w| a + w >= k && a <= k + w),
        announced_late: changes(&|a, k, w| a <= k && a + w >= k)
            .saturating_sub(changes(&|a, k, w| a + w >= k && a <= k + w)),
        change_peak,
        change_peaks,
        period_changes: log.period_changes,
        ..LoopMetrics::default()
    };
    if let Some(e) = rec.energy {
        let through = e.entered();
        m.energy_through = Some(through);
        m.energy_generated = Some(if through > 0.0 {
            e.generated() / through
        } else {
            0.0
        });
        let force = rec.base.iter().map(|b| {
            let contact = usize::try_from(b.from_remote)
                .ok()
                .and_then(|i| rec.remote.get(i))
                .map_or(0.0, |t| t.contact);
            b.force - contact
        });
        m.contact_force_rms_error = Some(root_mean_square(force));
        let position = rec.remote.iter().map(|t| {
            let master = usize::try_from(t.applied)
                .ok()
                .and_then(|j| rec.base.get(j))
                .map_or(0.0, |b| b.master);
            (t.x - master) / amp
        });
        m.position_rms_error = Some(root_mean_square(position));
    }
    m
}

/// The value at `t` of the series `at` (times increasing), linearly
/// interpolated; the end values beyond its ends, zero if it is empty.
fn interpolate(at: &[(f64, f64)], t: f64) -> f64 {
    let i = at.partition_point(|&(ti, _)| ti < t);
    match (i.checked_sub(1).and_then(|p| at.get(p)), at.get(i)) {
        (_, Some(&(ti, x))) if ti == t => x,
        (Some(&(t0, x0)), Some(&(t1, x1))) => x0 + (x1 - x0) * (t - t0) / (t1 - t0),
        (None, Some(&(_, x))) | (Some(&(_, x)), None) => x,
        (None, None) => 0.0,
    }
}

fn root_mean_square(xs: impl Iterator<Item = f64>) -> f64 {
    let (sum, n) = xs.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    (sum / n.max(1) as f64).sqrt()
}

/// Runs `cfg` and the delay-free loop on the same configuration, and
/// measures the first against the second.
///
/// # Errors
/// The simulator's error; [`SimError::Control`] for a controller that
/// does not fit the scenario or refused an input.
pub fn run_loop(cfg: &LoopConfig) -> Result<LoopMetrics, SimError> {
    let (rec, log) = run_record(cfg)?;
    let mut design_cfg = LoopConfig {
        link: LinkKind::Ideal,
        ..cfg.clone()
    };
    // The tracking design is the PID on the plant itself, undelayed.
    if cfg.scenario == Scenario::Tracking {
        design_cfg.controller = Controller::Pid;
    }
    // The design at the period the loop started at (paper-dynamic may
    // size it before the loop starts, and change it while it runs).
    if let Some(p) = log.start_period {
        design_cfg.sim.period = p;
    }
    let (design, _) = run_record(&design_cfg)?;
    Ok(measure(cfg, &rec, &log, &design))
}

/// One link's row of `ndr control`: its metrics over the seeds.
#[derive(Clone, Debug, Serialize)]
#[non_exhaustive]
pub struct LinkRow {
    /// The link's name.
    pub link: String,
    /// Seeds run.
    pub runs: usize,
    /// Runs whose position left the bound.
    pub unstable_runs: usize,
    /// Every run stable.
    pub stable: bool,
    /// Over the seeds: the mean of each error, the sum of each count, the
    /// largest `change_peak`, `stable` if every run was.
    pub mean: LoopMetrics,
    /// The worst seed's `rms_vs_delayed_design`.
    pub max_rms_vs_delayed_design: f64,
    /// The worst seed's `energy_generated` (bilateral).
    pub max_energy_generated: Option<f64>,
    /// Each seed's metrics.
    pub seeds: Vec<LoopMetrics>,
}

/// `ndr control`'s report: one row per link.
#[derive(Clone, Debug, Serialize)]
#[non_exhaustive]
pub struct ControlReport {
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// The loop.
    pub scenario: Scenario,
    /// The controller.
    pub controller: Controller,
    /// The delay model's name.
    pub network: String,
    /// The period, s.
    pub period_s: f64,
    /// Simulated time per run, s.
    pub duration_s: f64,
    /// The reference.
    pub reference: Reference,
    /// One per link, in the order asked.
    pub rows: Vec<LinkRow>,
}

/// What a run that diverged measured: unstable, every error infinite.
fn diverged() -> LoopMetrics {
    LoopMetrics {
        rms_vs_reference: f64::INFINITY,
        rms_vs_delayed_design: f64::INFINITY,
        rms_vs_delayed_design_late: f64::INFINITY,
        overshoot: f64::INFINITY,
        diverged: true,
        ..LoopMetrics::default()
    }
}

/// Whether `e` is a loop that diverged: a controller given a value that
/// is not finite, or an endpoint refusing one.
fn is_divergence(e: &SimError) -> bool {
    matches!(
        e,
        SimError::Control(ControlError::NonFiniteInput)
            | SimError::Link {
                error: ndr_core::endpoint::LinkError::NonFinite { .. },
                ..
            }
    )
}

/// Runs `base` (scenario, controller, network, underflow policy; its link
/// is replaced) over each of `links`, seeds `1..=seeds`. A run that
/// diverges counts as unstable with infinite errors.
///
/// # Errors
/// The first run's error.
pub fn compare_links(
    base: &LoopConfig,
    links: &[LinkKind],
    seeds: u64,
) -> Result<ControlReport, SimError> {
    let mut rows = Vec::new();
    for &link in links {
        let mut runs = Vec::new();
        for seed in 1..=seeds.max(1) {
            let mut cfg = base.clone();
            cfg.link = link;
            cfg.sim.seed = seed;
            runs.push(match run_loop(&cfg) {
                Err(e) if is_divergence(&e) => diverged(),
                other => other?,
            });
        }
        rows.push(summarise(link, runs));
    }
    Ok(ControlReport {
        schema: SCHEMA,
        scenario: base.scenario,
        controller: base.controller,
        network: base.sim.model.name(),
        period_s: base.sim.period.as_secs_f64(),
        duration_s: base.sim.duration.as_secs_f64(),
        reference: base.reference,
        rows,
    })
}

fn summarise(link: LinkKind, runs: Vec<LoopMetrics>) -> LinkRow {
    let n = runs.len().max(1) as f64;
    let mean_of = |f: &dyn Fn(&LoopMetrics) -> f64| runs.iter().map(f).sum::<f64>() / n;
    let mean_opt = |f: &dyn Fn(&LoopMetrics) -> Option<f64>| {
        let v: Vec<f64> = runs.iter().filter_map(f).collect();
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    };
    let settled = runs.iter().all(|r| r.settling_s.is_some());
    let mean = LoopMetrics {
        rms_vs_reference: mean_of(&|r| r.rms_vs_reference),
        rms_vs_delayed_design: mean_of(&|r| r.rms_vs_delayed_design),
        rms_vs_delayed_design_late: mean_of(&|r| r.rms_vs_delayed_design_late),
        overshoot: mean_of(&|r| r.overshoot),
        settling_s: if settled {
            mean_opt(&|r| r.settling_s)
        } else {
            None
        },
        stable: runs.iter().all(|r| r.stable),
        diverged: runs.iter().any(|r| r.diverged),
        round_trip_mean_ticks: mean_of(&|r| r.round_trip_mean_ticks),
        round_trip_changes: runs.iter().map(|r| r.round_trip_changes).sum(),
        repeats: runs.iter().map(|r| r.repeats).sum(),
        announced: runs.iter().map(|r| r.announced).sum(),
        round_trips_announced: runs.iter().map(|r| r.round_trips_announced).sum(),
        unannounced_changes: runs.iter().map(|r| r.unannounced_changes).sum(),
        announced_late: runs.iter().map(|r| r.announced_late).sum(),
        change_peak: runs.iter().filter_map(|r| r.change_peak).reduce(f64::max),
        change_peaks: Vec::new(),
        period_changes: runs.iter().map(|r| r.period_changes).sum(),
        energy_generated: mean_opt(&|r| r.energy_generated),
        energy_through: mean_opt(&|r| r.energy_through),
        contact_force_rms_error: mean_opt(&|r| r.contact_force_rms_error),
        position_rms_error: mean_opt(&|r| r.position_rms_error),
    };
    LinkRow {
        link: link.name().to_string(),
        runs: runs.len(),
        unstable_runs: runs.iter().filter(|r| !r.stable).count(),
        stable: mean.stable,
        mean,
        max_rms_vs_delayed_design: runs
            .iter()
            .map(|r| r.rms_vs_delayed_design)
            .fold(0.0, f64::max),
        max_energy_generated: runs
            .iter()
            .filter_map(|r| r.energy_generated)
            .reduce(f64::max),
        seeds: runs,
    }
}

/// The period of `ndr control`: 20 ms.
pub const CONTROL_PERIOD: Duration = Duration::from_millis(20);
