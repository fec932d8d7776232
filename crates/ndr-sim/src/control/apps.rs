//! The two closed loops: what runs at the base and at the remote each tick.
//!
//! Every sample carries, beside its payload, the tick that sent it, so
//! that the measurements can pair a state with the command it answers: a
//! command is `[u, k + 1, 0, 0]` (payload, base tick); a state
//! `[y, j + 1, m + 1, x]` (payload, base tick of the command the remote
//! applied, remote tick, the position measured). Ticks count from one so
//! that a zero names the endpoints' samples before the loop started. The controllers use only the payload and what the
//! link announces.

use std::boxed::Box;
use std::vec::Vec;

use ndr_core::control::{ControlError, Pid, PidConfig, SmithPredictor, WaveEnergy, WaveTransform};
use ndr_core::time::Duration;
use ndr_core::wire::Role;
use ndr_core::{Arx2, Tf2, Tf2State};

use super::{BilateralGains, Reference, TrackingGains};
use crate::PlantConfig;

/// Values a sample carries each way.
pub(crate) const WIDTH: usize = 4;

/// The longest round trip the Smith predictor follows, ticks.
pub(crate) const SMITH_HISTORY: usize = 8192;

/// What reached one side at a tick.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Rx {
    /// The newest sample applied; `None` before any.
    pub values: Option<[f64; WIDTH]>,
    /// Whether it is new at this tick (not a repeat).
    pub fresh: bool,
    /// The round trip the link announces at this tick, ticks.
    pub round_trip: Option<usize>,
}

/// One side's application in a closed loop.
pub(crate) trait App {
    /// Base tick: what arrived; the command to send.
    fn base(&mut self, rx: Rx) -> Result<[f64; WIDTH], ControlError>;
    /// Remote tick: the command applied; the state to send.
    fn remote(&mut self, rx: Rx) -> Result<[f64; WIDTH], ControlError>;
    /// `side`'s endpoint changed its period (paper-dynamic): what runs
    /// there is discretized anew.
    fn period(&mut self, side: Role, period_s: f64) -> Result<(), ControlError>;
    /// The remote's samples flow (again): what it sends until its first
    /// release, `None` for its last sample. The endpoint sends the last
    /// sample set at every tick, and after a pause that is one of before
    /// it, which the base takes as fresh.
    fn resume_remote(&self) -> Option<[f64; WIDTH]> {
        None
    }
}

/// One base tick of a run, as measured.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct BaseTick {
    /// When the loop ran it, s since the loop started.
    pub t: f64,
    /// The reference.
    pub r: f64,
    /// The position measured at the base (the newest state's).
    pub y: f64,
    /// The base tick of the command that state answers (−1: none yet).
    pub answers: i64,
    /// The remote tick that sent it (−1: none yet).
    pub from_remote: i64,
    /// The force reflected to the operator (bilateral).
    pub force: f64,
    /// The master's position (bilateral).
    pub master: f64,
}

/// One remote tick of a run.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct RemoteTick {
    /// The plant's (slave's) position.
    pub x: f64,
    /// The base tick of the command applied (−1: none yet).
    pub applied: i64,
    /// The contact force (bilateral).
    pub contact: f64,
}

/// What both sides recorded.
#[derive(Clone, Debug, Default)]
pub(crate) struct Record {
    pub base: Vec<BaseTick>,
    pub remote: Vec<RemoteTick>,
    /// The round trip the controller was given, changes (base tick, ticks).
    pub round_trips: Vec<(u64, usize)>,
    /// The wave channel's account (bilateral).
    pub energy: Option<WaveEnergy>,
    /// Remote ticks, once commands flowed, that applied no new command.
    pub repeats: u64,
}

/// How a tracking loop's controller sees the plant.
pub(crate) enum Feedback {
    /// The measured state itself.
    Plain,
    /// Through a Smith predictor; with `fixed`, told that round trip once
    /// and never the link's.
    Smith {
        predictor: Box<SmithPredictor<SMITH_HISTORY>>,
        fixed: Option<usize>,
    },
}

/// A position loop closed at the base on the remote's delayed state.
pub(crate) struct Tracking {
    feedback: Feedback,
    pid: Pid,
    plant_cfg: PlantConfig,
    plant: Tf2State,
    reference: Reference,
    period_s: f64,
    /// Time at the base since the loop started, s.
    t: f64,
    last: Option<[f64; WIDTH]>,
    /// The loop is closed (an identified model closes it once validated).
    closed: bool,
    /// Fresh states in a row the identified model predicted.
    validated: u32,
    pub record: Record,
}

/// An identified model closes the loop once it has predicted this many
/// fresh states in a row within [`VALIDATION_TOLERANCE`].
const VALIDATION_TICKS: u32 = 50;
/// Of the reference's amplitude.
const VALIDATION_TOLERANCE: f64 = 1e-3;
/// The identifier's forgetting factor: a state paired with the wrong
/// command (the round trip stretched by an underflow, a command applied
/// twice) biases the model for a few thousand ticks instead of for good.
const FORGETTING: f64 = 0.999;

impl Tracking {
    /// `smith`: whether to use a Smith predictor, with the plant's true
    /// model (`Some(true)`) or one identified online; `fixed`: the round
    /// trip it is given once (the unregulated link's mean) instead of the
    /// link's.
    pub(crate) fn new(
        gains: &TrackingGains,
        plant_cfg: PlantConfig,
        reference: Reference,
        period_s: f64,
        smith: Option<bool>,
        fixed: Option<usize>,
    ) -> Result<Self, ControlError> {
        let plant = discretize(&plant_cfg, period_s)?;
        let identifying = smith == Some(false);
        let feedback = match smith {
            None => Feedback::Plain,
            Some(true_model) => {
                let d = fixed.unwrap_or(1).clamp(1, SMITH_HISTORY);
                let predictor = if true_model {
                    SmithPredictor::with_model(plant, d)?
                } else {
                    SmithPredictor::identifying(
                        Arx2::new(FORGETTING, 1e6).map_err(|_| ControlError::InvalidModel)?,
                        d,
                    )?
                };
                Feedback::Smith {
                    predictor: Box::new(predictor),
                    fixed,
                }
            }
        };
        let mut pid_cfg = PidConfig::new(gains.kp, gains.ki, gains.kd, period_s);
        (pid_cfg.out_min, pid_cfg.out_max) = (-gains.u_max, gains.u_max);
        let pid = Pid::new(pid_cfg)?;
        Ok(Tracking {
            feedback,
            pid,
            plant_cfg,
            plant: Tf2State::new(plant),
            reference,
            period_s,
            t: 0.0,
            last: None,
            closed: !identifying,
            validated: 0,
            record: Record::default(),
        })
    }
}

impl App for Tracking {
    fn base(&mut self, rx: Rx) -> Result<[f64; WIDTH], ControlError> {
        let k = self.record.base.len() as u64;
        if rx.values.is_some() {
            self.last = rx.values;
        }
        let y = self.last.map_or(0.0, |v| v[0]);
        let seen = match &mut self.feedback {
            Feedback::Plain => y,
            Feedback::Smith { predictor, fixed } => {
                if let (None, Some(d)) = (*fixed, rx.round_trip)
                    && d != predictor.round_trip()
                    && predictor.set_round_trip(d).is_ok()
                {
                    self.record.round_trips.push((k, d));
                }
                // No correction before the round trip is known: it
                // would compare the state with the wrong command.
                let known = fixed.is_some() || !self.record.round_trips.is_empty();
                let measured = (known && rx.fresh && rx.values.is_some()).then_some(y);
                predictor.feedback(measured)?
            }
        };
        let t = self.t;
        let r = self.reference.value(t);
        self.t += self.period_s;
        // Identify, then close the loop: until the model has predicted the
        // measured state for a while the axis is driven open loop by the
        // reference (a stable position axis of unit static gain), since a
        // loop closed on the plain delayed state, or through a model still
        // wrong, is unstable once the round trip is long.
        if !self.closed
            && let Feedback::Smith { predictor, .. } = &self.feedback
        {
            let tolerance = VALIDATION_TOLERANCE * self.reference.amplitude.abs();
            if !predictor.model_ready() || (rx.fresh && predictor.correction().abs() > tolerance) {
                self.validated = 0;
            } else if rx.fresh {
                self.validated += 1;
            }
            self.closed = self.validated >= VALIDATION_TICKS;
        }
        let u = if self.closed {
            self.pid.step(r, seen)?
        } else {
            self.pid.reset();
            r
        };
        if let Feedback::Smith { predictor, .. } = &mut self.feedback {
            predictor.command(u)?;
        }
        let last = self.last.unwrap_or([0.0; WIDTH]);
        self.record.base.push(BaseTick {
            t,
            r,
            y,
            answers: last[1] as i64 - 1,
            from_remote: last[2] as i64 - 1,
            force: 0.0,
            master: 0.0,
        });
        Ok([u, (k + 1) as f64, 0.0, 0.0])
    }

    fn remote(&mut self, rx: Rx) -> Result<[f64; WIDTH], ControlError> {
        let m = self.record.remote.len();
        let [u, k, ..] = rx.values.unwrap_or([0.0; WIDTH]);
        if k > 0.0 && !rx.fresh {
            self.record.repeats += 1;
        }
        let x = self.plant.step(u);
        self.record.remote.push(RemoteTick {
            x,
            applied: k as i64 - 1,
            contact: 0.0,
        });
        Ok([x, k, (m + 1) as f64, x])
    }

    fn period(&mut self, side: Role, period_s: f64) -> Result<(), ControlError> {
        let tf = discretize(&self.plant_cfg, period_s)?;
        if side == Role::Remote {
            self.plant.set_model(tf);
            return Ok(());
        }
        self.pid.set_period(period_s)?;
        if let Feedback::Smith { predictor, .. } = &mut self.feedback
            && predictor.model_ready()
            && !predictor.is_identifying()
        {
            predictor.set_model(tf)?;
        }
        self.period_s = period_s;
        Ok(())
    }
}

fn discretize(plant: &PlantConfig, period_s: f64) -> Result<Tf2, ControlError> {
    plant
        .discretize(Duration::from_secs_f64(period_s))
        .map_err(|_| ControlError::InvalidModel)
}

/// A master device held by the operator and a slave meeting a wall,
/// coupled by wave variables.
pub(crate) struct Bilateral {
    g: BilateralGains,
    wave: WaveTransform,
    energy: WaveEnergy,
    reference: Reference,
    /// The base's period, s.
    dt: f64,
    /// The remote's period, s.
    dt_remote: f64,
    /// Time at the base since the loop started, s.
    t: f64,
    /// Decode a repeat as the last wave again (a plain socket's receiver)
    /// instead of a zero wave.
    repeat_waves: bool,
    // Master.
    xm: f64,
    vm: f64,
    last_to_base: Option<[f64; WIDTH]>,
    // Slave.
    xs: f64,
    vs: f64,
    xsd: f64,
    last_to_remote: Option<[f64; WIDTH]>,
    pub record: Record,
}

impl Bilateral {
    pub(crate) fn new(
        g: &BilateralGains,
        reference: Reference,
        period_s: f64,
        repeat_waves: bool,
    ) -> Result<Self, ControlError> {
        Ok(Bilateral {
            g: *g,
            wave: WaveTransform::new(g.b)?,
            energy: WaveEnergy::default(),
            reference,
            dt: period_s,
            dt_remote: period_s,
            t: 0.0,
            repeat_waves,
            xm: 0.0,
            vm: 0.0,
            last_to_base: None,
            xs: 0.0,
            vs: 0.0,
            xsd: 0.0,
            last_to_remote: None,
            record: Record::default(),
        })
    }

    /// The wave a side decodes at this tick.
    fn decode(&self, rx: Rx) -> f64 {
        match rx.values {
            Some(v) if rx.fresh || self.repeat_waves => v[0],
            _ => 0.0,
        }
    }

    pub(crate) fn finish(mut self) -> Record {
        self.record.energy = Some(self.energy);
        self.record
    }
}

impl App for Bilateral {
    fn base(&mut self, rx: Rx) -> Result<[f64; WIDTH], ControlError> {
        let k = self.record.base.len();
        if rx.values.is_some() {
            self.last_to_base = rx.values;
        }
        let v = self.decode(rx);
        self.energy.delivered(v, self.dt);
        let t = self.t;
        let r = self.reference.value(t);
        self.t += self.dt;
        // The master's velocity over this tick and the channel's force on
        // it, solved together (implicit in the velocity): the channel's
        // damping `b` and the operator's dissipate, whatever the period.
        let g = &self.g;
        let b = self.wave.impedance();
        let pushed =
            g.m_master * self.vm / self.dt + g.k_operator * (r - self.xm) + (2.0 * b).sqrt() * v;
        self.vm = pushed / (g.m_master / self.dt + b + g.b_operator);
        let port = self.wave.master(self.vm, v)?;
        self.energy.sent(port.wave, self.dt);
        self.xm += self.dt * self.vm;
        let last = self.last_to_base.unwrap_or([0.0; WIDTH]);
        self.record.base.push(BaseTick {
            t,
            r,
            y: last[3],
            answers: last[1] as i64 - 1,
            from_remote: last[2] as i64 - 1,
            force: port.force,
            master: self.xm,
        });
        Ok([port.wave, (k + 1) as f64, 0.0, 0.0])
    }

    fn remote(&mut self, rx: Rx) -> Result<[f64; WIDTH], ControlError> {
        let m = self.record.remote.len();
        if rx.values.is_some() {
            self.last_to_remote = rx.values;
        }
        let u = self.decode(rx);
        self.energy.delivered(u, self.dt_remote);
        // The slave's velocity, its PD force and the velocity the wave
        // commands depend on each other: solved together, implicit in the
        // velocities (backward Euler), so that the port's velocity and
        // force are the pair the wave carries and the stiff wall stays
        // stable at any period. The wall acts while the slave is in it.
        let g = &self.g;
        let dt = self.dt_remote;
        let b = self.wave.impedance();
        let sqrt_2b = (2.0 * b).sqrt();
        let c = g.k_slave * dt + g.b_slave;
        // F = alpha − beta·vs⁺ once the commanded velocity is eliminated.
        let alpha = (g.k_slave * (self.xsd - self.xs) + c * sqrt_2b * u / b) / (1.0 + c / b);
        let beta = c / (1.0 + c / b);
        let touching = self.xs > g.wall;
        let (wall_k, wall_b) = if touching {
            (g.k_wall, g.k_wall * dt + g.b_wall)
        } else {
            (0.0, 0.0)
        };
        self.vs = (g.m_slave * self.vs / dt + alpha - wall_k * (self.xs - g.wall))
            / (g.m_slave / dt + beta + wall_b);
        let force = alpha - beta * self.vs;
        let port = self.wave.slave(u, force)?;
        self.energy.sent(port.wave, dt);
        self.xsd += dt * port.velocity;
        self.xs += dt * self.vs;
        let contact = if touching {
            (g.k_wall * (self.xs - g.wall) + g.b_wall * self.vs).max(0.0)
        } else {
            0.0
        };
        let applied = self.last_to_remote.map_or(0.0, |v| v[1]);
        self.record.remote.push(RemoteTick {
            x: self.xs,
            applied: applied as i64 - 1,
            contact,
        });
        Ok([port.wave, applied, (m + 1) as f64, self.xs])
    }

    fn period(&mut self, side: Role, period_s: f64) -> Result<(), ControlError> {
        match side {
            Role::Base => self.dt = period_s,
            Role::Remote => self.dt_remote = period_s,
        }
        Ok(())
    }

    /// A zero wave (no energy), answering no command.
    fn resume_remote(&self) -> Option<[f64; WIDTH]> {
        Some([0.0, 0.0, 0.0, self.xs])
    }
}
