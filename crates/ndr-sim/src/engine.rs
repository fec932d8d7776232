//! The discrete-event loop: two endpoints, two in-order network paths, an
//! operator and a plant. Time jumps from one deadline or arrival to the next.

use std::boxed::Box;
use std::collections::VecDeque;
use std::fmt;
use std::sync::Arc;
use std::vec::Vec;

use ndr_core::Regulation;
use ndr_core::endpoint::{
    Config, ConfigError, Endpoint, Event, LinkError, Mode, Release, Status, Transport, Underflow,
};
use ndr_core::pair::{Pair, World};
use ndr_core::playout::Playout;
use ndr_core::storage::Heap;
use ndr_core::time::{Duration, Instant};
use ndr_core::wire::{Frame, Kind, Payload, Role};
use ndr_core::{ArxError, Tf2, Tf2State};

use super::delay::{
    DelayModel, DelaySampler, Direction, InOrderPath, LossModel, LossSampler, RecordedProbe,
    Recovery, TcpPath, Trace,
};
use super::report::{Collector, Report, Row};
use super::signal::Signal;

/// Most axes a simulated link carries: a command and a state value each,
/// as many as a frame holds.
pub const MAX_SIM_AXES: usize = ndr_core::wire::MAX_CHANNELS;
/// Capacity of the simulated regulators: room for `ns` up to 4095, enough
/// for Paris–New York jitter at a 1 ms period.
pub const SIM_QUEUE: usize = 4096;

pub(crate) type SimEndpoint = Endpoint<Heap>;

/// The remote's plant: per axis, a second-order low-pass system discretized
/// at the link's period by the bilinear transform.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct PlantConfig {
    /// Natural frequency, Hz.
    pub natural_hz: f64,
    /// Damping ratio.
    pub damping: f64,
    /// Static gain.
    pub gain: f64,
}

impl Default for PlantConfig {
    /// 0.5 Hz, damping 0.7, unit gain: a slow arm axis.
    fn default() -> Self {
        PlantConfig {
            natural_hz: 0.5,
            damping: 0.7,
            gain: 1.0,
        }
    }
}

impl PlantConfig {
    pub(crate) fn discretize(&self, period: Duration) -> Result<Tf2, ArxError> {
        Tf2::low_pass(
            core::f64::consts::TAU * self.natural_hz,
            self.damping,
            self.gain,
            period.as_secs_f64(),
        )
    }
}

/// When the simulated remote's application answers a command its link
/// released: its state, sent back, names that command as the one it
/// answers, and the base's GRTT runs from it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub enum Answer {
    /// In the tick that released it: an application run in its driver's
    /// loop (the drive contract), whose state goes out in that tick's frame.
    #[default]
    SameTick,
    /// At the next tick: an application on a thread of its own (`ndr
    /// demo`'s robot), whose state reaches its driver after the tick's
    /// frame went out, so that the next tick's frame carries it.
    NextTick,
}

/// How long after a release the remote's application of
/// [`Answer::NextTick`] hands its state over: a thread's wake-up, well
/// within a period.
const THREAD_ANSWER: Duration = Duration::from_micros(1);

/// One simulation run.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct SimConfig {
    /// The network's delays.
    pub model: DelayModel,
    /// The packets it loses, the same each way: over a stream a lost frame
    /// holds the TCP stream back until it is repaired ([`TcpPath`]); a lost
    /// datagram is gone, its sample recovered from the next ones' copies.
    pub loss: LossModel,
    /// How both endpoints carry their samples: a stream (TCP, the paper's)
    /// or datagrams, each with copies of the samples before it; the
    /// handshake and control then go on a TCP path beside them.
    pub transport: Transport,
    /// Static or dynamic sizing: with `playout`, what a [`Regulation`]
    /// sets ([`SimConfig::with_regulation`]).
    pub mode: Mode,
    /// Both regulators' underflow policy.
    pub underflow: Underflow,
    /// Both regulators' playout policy.
    pub playout: Playout,
    /// The remote's clock runs at `1 + remote_skew_ppm·10⁻⁶` times the
    /// base's (the network's). Each side reads its own clock, so stamps and
    /// delays seen across the link carry the skew.
    pub remote_skew_ppm: f64,
    /// How long after the base's the remote's tick grid starts (on its own
    /// clock): 0 puts both on one grid, the paper's "clock common to the
    /// whole structure"; the two hubs of a real link start anywhere within
    /// a period of each other.
    pub remote_phase: Duration,
    /// The initial period.
    pub period: Duration,
    /// Simulated time.
    pub duration: Duration,
    /// Seed of every random draw.
    pub seed: u64,
    /// Axes, `1..=MAX_SIM_AXES`.
    pub axes: u16,
    /// The operator's command.
    pub signal: Signal,
    /// The remote's plant.
    pub plant: PlantConfig,
    /// When the remote's application answers a released command.
    pub answer: Answer,
    /// Keep one [`Row`] per base tick.
    pub record_series: bool,
    /// Keep every command's timing at the remote ([`SimOutput::forward`]).
    pub record_forward: bool,
}

impl SimConfig {
    /// The paper's setup on `model`: `T = 200 ms`, static, hold, one axis,
    /// ten simulated minutes.
    #[must_use]
    pub fn paper(model: DelayModel) -> Self {
        SimConfig {
            model,
            loss: LossModel::None,
            transport: Transport::Stream,
            mode: Mode::PaperStatic,
            underflow: Underflow::Hold,
            playout: Playout::Fifo,
            remote_skew_ppm: 0.0,
            remote_phase: Duration::ZERO,
            period: Duration::from_millis(200),
            duration: Duration::from_secs(600),
            seed: 1,
            axes: 1,
            signal: Signal::default(),
            plant: PlantConfig::default(),
            answer: Answer::SameTick,
            record_series: false,
            record_forward: false,
        }
    }
}

impl SimConfig {
    /// This run with both sides regulated by `regulation`.
    #[must_use]
    pub fn with_regulation(mut self, regulation: Regulation) -> Self {
        self.mode = regulation.mode();
        self.playout = regulation.playout();
        self
    }
}

/// Why a simulation could not run or ended early.
#[derive(Debug)]
#[non_exhaustive]
pub enum SimError {
    /// More axes than the simulator carries.
    Axes(u16),
    /// An endpoint refused its configuration.
    Config(ConfigError),
    /// The plant parameters are invalid.
    Plant(ArxError),
    /// A controller of a closed loop refused its parameters or an input.
    Control(ndr_core::control::ControlError),
    /// The link ended before the run did.
    Link {
        /// Which side saw it.
        side: &'static str,
        /// When, in seconds.
        at_s: f64,
        /// The error.
        error: LinkError,
    },
}

impl fmt::Display for SimError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SimError::Axes(a) => {
                write!(f, "the simulator carries 1 to {MAX_SIM_AXES} axes, not {a}")
            }
            SimError::Config(e) => write!(f, "{e}"),
            SimError::Plant(e) => write!(f, "plant: {e}"),
            SimError::Control(e) => write!(f, "controller: {e}"),
            SimError::Link { side, at_s, error } => {
                write!(
                    f,
                    "the link failed at t = {at_s:.3} s on the {side} side: {error}"
                )
            }
        }
    }
}

impl std::error::Error for SimError {}

/// What a run gives: the report, and the per-tick series if asked for.
#[derive(Clone, Debug)]
pub struct SimOutput {
    /// Summary statistics.
    pub report: Report,
    /// One row per base tick, when [`SimConfig::record_series`] is set.
    pub series: Vec<Row>,
    /// The commands as the remote saw them, when [`SimConfig::record_forward`] is set.
    pub forward: ForwardLog,
}

/// The commands (base → remote) as the remote saw them, on the remote's clock
/// (send stamps on the base's).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ForwardLog {
    /// Every command that reached the remote, in arrival order.
    pub samples: Vec<CommandTiming>,
    /// The remote's ticks that repeated a command (underflows).
    pub held: Vec<Instant>,
}

/// One command's timing at the remote.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CommandTiming {
    /// Its sequence number.
    pub seq: u64,
    /// Its send stamp (base clock).
    pub sent_at: Instant,
    /// Its arrival (remote clock).
    pub arrived_at: Instant,
    /// Its fresh release (remote clock); `None` if never released fresh.
    pub released_at: Option<Instant>,
}

/// When a command that was lost "arrives" in the [`ForwardLog`]: an hour
/// after it was sent, late for any delay the link could hold.
pub const NEVER: Duration = Duration::from_secs(3600);

/// A clock that runs at `1 + ppb·10⁻⁹` times the simulation's.
#[derive(Clone, Copy, Debug)]
struct SkewedClock {
    ppb: i128,
}

impl SkewedClock {
    fn new(ppm: f64) -> Self {
        let ppb = if ppm.is_finite() {
            (ppm * 1e3).round().clamp(-1e8, 1e8) as i128
        } else {
            0
        };
        SkewedClock { ppb }
    }

    /// The clock's reading at simulation time `t`.
    fn local(self, t: Instant) -> Instant {
        let n = i128::from(t.as_nanos());
        let l = n + (n * self.ppb).div_euclid(1_000_000_000);
        Instant::from_nanos(u64::try_from(l.max(0)).unwrap_or(u64::MAX))
    }

    /// The first simulation time at which the clock reads `l` or later.
    fn global(self, l: Instant) -> Instant {
        if self.ppb == 0 {
            return l;
        }
        let n = i128::from(l.as_nanos());
        let guess = n * 1_000_000_000 / (1_000_000_000 + self.ppb);
        let mut g = Instant::from_nanos(u64::try_from(guess.max(0) - 2).unwrap_or(0));
        while self.local(g) < l {
            g += Duration::from_nanos(1);
        }
        g
    }
}

/// The simulated network: the delays and losses each way, the TCP and
/// datagram paths, and the remote's clock.
pub(crate) struct Network {
    sampler: DelaySampler,
    loss: LossSampler,
    paths: [TcpPath; 2],
    /// The datagrams' way (the datagram transport), beside the TCP path.
    datagram_paths: [InOrderPath; 2],
    /// The period the link runs at: one frame each way per period.
    pub(crate) period: Duration,
    remote_clock: SkewedClock,
    /// A replayed recording's anchor ([`Trace::anchor`](super::delay::Trace::anchor)),
    /// and when this link sent its first command: the trace's time is the
    /// anchor plus the time since then.
    anchor: Option<Instant>,
    first_command: Option<Instant>,
    /// An anchored trace's length from its anchor to its last row.
    replay_len: Duration,
    /// A replayed recording: its probes' delays and its samples' losses.
    replay: Option<Arc<Trace>>,
}

impl Network {
    pub(crate) fn new(cfg: &SimConfig) -> Self {
        Network {
            sampler: cfg.model.sampler(cfg.seed),
            loss: cfg.loss.sampler(cfg.seed),
            paths: [TcpPath::new(), TcpPath::new()],
            datagram_paths: [InOrderPath::new(), InOrderPath::new()],
            period: cfg.period,
            remote_clock: SkewedClock::new(cfg.remote_skew_ppm),
            anchor: match &cfg.model {
                DelayModel::Trace(t) => t.anchor(),
                _ => None,
            },
            first_command: None,
            replay_len: match &cfg.model {
                DelayModel::Trace(t) => t
                    .anchor()
                    .and_then(|a| (Instant::ZERO + t.duration()).checked_duration_since(a))
                    .unwrap_or(Duration::ZERO),
                _ => Duration::ZERO,
            },
            replay: match &cfg.model {
                DelayModel::Trace(t) if t.anchor().is_some() => Some(Arc::clone(t)),
                _ => None,
            },
        }
    }

    /// Whether the run waits for its first command to tie the trace's
    /// time line to its own.
    fn awaits_first_command(&self) -> bool {
        self.anchor.is_some() && self.first_command.is_none()
    }

    /// When an anchored trace's last row comes on this run's time line:
    /// the recording ends there, and so does its replay.
    fn replay_end(&self) -> Option<Instant> {
        self.anchor?;
        Some(self.first_command? + self.replay_len)
    }

    /// The time on the delay model's line of a frame `from` sends at
    /// `sent`: the simulation's, or for an anchored trace the anchor plus
    /// the time since the first command (before it, the anchor: the
    /// set-up meets the delays the recorded link's first samples met).
    fn model_time(&mut self, from: Role, sent: Instant, frame: &[u8]) -> Instant {
        let Some(anchor) = self.anchor else {
            return sent;
        };
        if self.first_command.is_none() && from == Role::Base && carries_sample(frame) {
            self.first_command = Some(sent);
        }
        match self.first_command {
            Some(first) => anchor + sent.checked_duration_since(first).unwrap_or(Duration::ZERO),
            None => anchor,
        }
    }

    /// When what `from` sends at `sent` reaches its peer (a datagram, or a
    /// frame of the TCP stream), or `None` if a datagram is lost.
    pub(crate) fn deliver(&mut self, from: Role, sent: Instant, datagram: bool) -> Option<Instant> {
        self.deliver_at(from, sent, sent, datagram)
    }

    /// [`Network::deliver`], the delay the model's at `model_time`.
    fn deliver_at(
        &mut self,
        from: Role,
        sent: Instant,
        model_time: Instant,
        datagram: bool,
    ) -> Option<Instant> {
        let delay = self.sampler.delay(direction_of(from), model_time);
        self.deliver_after(from, sent, delay, datagram)
    }

    /// [`Network::deliver`], after `delay`.
    fn deliver_after(
        &mut self,
        from: Role,
        sent: Instant,
        delay: Duration,
        datagram: bool,
    ) -> Option<Instant> {
        let direction = direction_of(from);
        let dir = direction.index();
        // A datagram: lost for good, or through the path's queues, which
        // keep their order (the delay models' jitter is queueing, not
        // reordering; a lost datagram holds nothing back).
        if datagram {
            let lost = self.loss.lost(direction);
            return (!lost).then(|| self.datagram_paths[dir].deliver(sent, delay));
        }
        // The frame's own delay, both ways, stands for the round trip the
        // sender's TCP has measured.
        let recovery = Recovery::linux(self.period, delay * 2);
        let loss = &mut self.loss;
        Some(
            self.paths[dir].deliver(sent, delay, recovery, |attempt| match attempt {
                0 => loss.lost(direction),
                _ => loss.lost_again(direction),
            }),
        )
    }

    /// [`Network::deliver`] for an endpoint's frame.
    pub(crate) fn arrival(&mut self, from: Role, sent: Instant, frame: &[u8]) -> Option<Instant> {
        let datagram = frame.get(5) == Some(&(Kind::Bundle as u8));
        let model_time = self.model_time(from, sent, frame);
        if let Some(replay) = &self.replay {
            let direction = direction_of(from);
            // A probe meets the delay of the recorded probe of its number
            // (the recorded set-up's round trips size the queue); the
            // other frames, the delay of the recorded sample sent nearest.
            match probe_seq(frame).map(|seq| replay.probe(direction, seq)) {
                Some(RecordedProbe::Delayed(delay)) => {
                    return self.deliver_after(from, sent, delay, datagram);
                }
                Some(RecordedProbe::Lost) if datagram => return None,
                _ => {}
            }
            // A sample the recorded link never released: lost (a stream's
            // frame meets the delay in-order delivery gave it).
            if datagram && replay.lost(direction, model_time) {
                return None;
            }
        }
        self.deliver_at(from, sent, model_time, datagram)
    }

    /// `side`'s clock at simulation time `t`.
    pub(crate) fn local(&self, side: Role, t: Instant) -> Instant {
        match side {
            Role::Base => t,
            Role::Remote => self.remote_clock.local(t),
        }
    }

    /// The first simulation time at which `side`'s clock reads `t`.
    pub(crate) fn global(&self, side: Role, t: Instant) -> Instant {
        match side {
            Role::Base => t,
            Role::Remote => self.remote_clock.global(t),
        }
    }
}

/// Whether `frame` carries a sample (not a probe or a control frame).
fn direction_of(from: Role) -> Direction {
    match from {
        Role::Base => Direction::Forward,
        Role::Remote => Direction::Backward,
    }
}

/// A probe's sequence number (a Data frame or datagram without values).
fn probe_seq(frame: &[u8]) -> Option<u64> {
    let f = Frame::new_checked(frame).ok()?;
    let probe = match f.payload() {
        Payload::Data(channels) => channels.is_empty(),
        Payload::Bundle(b) => b.width() == 0,
        _ => false,
    };
    probe.then(|| f.seq())
}

fn carries_sample(frame: &[u8]) -> bool {
    Frame::new_checked(frame).is_ok_and(|f| match f.payload() {
        Payload::Data(channels) => !channels.is_empty(),
        Payload::Bundle(b) => b.width() > 0,
        _ => false,
    })
}

/// The [`World`] methods of a simulated world that holds its [`Network`]
/// in `net`: arrivals, the remote's clock, refused frames.
macro_rules! network_world {
    () => {
        fn arrival(&mut self, from: Role, sent: Instant, frame: &[u8]) -> Option<Instant> {
            self.net.arrival(from, sent, frame)
        }

        fn local(&self, side: Role, t: Instant) -> Instant {
            self.net.local(side, t)
        }

        fn wake(&mut self, side: Role, deadline: Instant) -> Instant {
            self.net.global(side, deadline)
        }

        fn failed(
            &mut self,
            side: Role,
            at: Instant,
            error: ndr_core::endpoint::LinkError,
        ) -> Result<(), SimError> {
            Err($crate::engine::link_error(side, at, error))
        }
    };
}
pub(crate) use network_world;

/// Everything around the simulated link's endpoints: the network, the
/// operator, the plant and what is recorded.
struct SimWorld<'a> {
    cfg: &'a SimConfig,
    net: Network,
    plants: Vec<Tf2State>,
    plant_out: Vec<f64>,
    operator: Vec<f64>,
    collect: Collector,
    forward: Option<ForwardLog>,
    /// Whether the last command frame to reach the remote carried a sample.
    last_was_sample: bool,
    /// The remote's states not handed to its endpoint yet
    /// ([`Answer::NextTick`]): when (simulation time) and what.
    answers: VecDeque<(Instant, Vec<f64>)>,
}

/// The two endpoints of a run of `cfg`, `width` values each way.
pub(crate) fn endpoints(
    cfg: &SimConfig,
    width: u16,
) -> Result<(SimEndpoint, SimEndpoint), SimError> {
    let endpoint = |role| -> Result<SimEndpoint, SimError> {
        let mut c = Config::paper(role).with_width(width);
        c.period = cfg.period;
        c.mode = cfg.mode;
        c.underflow = cfg.underflow;
        c.playout = cfg.playout;
        // One clock for the whole structure, as in the paper, unless the
        // remote's grid is set apart.
        c.tick_origin = match role {
            Role::Base => Instant::ZERO,
            Role::Remote => Instant::ZERO + cfg.remote_phase,
        };
        c.transport = cfg.transport;
        if let Transport::Datagram { .. } = cfg.transport {
            // Any tokens will do between two simulated endpoints.
            c.session = (cfg.seed ^ 0x9e37_79b9_7f4a_7c15).rotate_left(role as u32 * 32) | 1;
        }
        SimEndpoint::with_capacity(c, Instant::ZERO, SIM_QUEUE).map_err(SimError::Config)
    };
    Ok((endpoint(Role::Base)?, endpoint(Role::Remote)?))
}

/// Runs one simulation.
pub fn run(cfg: &SimConfig) -> Result<SimOutput, SimError> {
    if cfg.axes == 0 || usize::from(cfg.axes) > MAX_SIM_AXES {
        return Err(SimError::Axes(cfg.axes));
    }
    let plant = cfg.plant.discretize(cfg.period).map_err(SimError::Plant)?;
    let axes = usize::from(cfg.axes);
    let world = SimWorld {
        cfg,
        net: Network::new(cfg),
        plants: (0..axes).map(|_| Tf2State::new(plant)).collect(),
        plant_out: std::vec![0.0; axes],
        operator: std::vec![0.0; axes],
        collect: Collector::new(cfg),
        forward: cfg.record_forward.then(ForwardLog::default),
        last_was_sample: false,
        answers: VecDeque::new(),
    };
    let (base, remote) = endpoints(cfg, cfg.axes)?;
    let mut pair = Pair::new(base, remote, world);
    let end = Instant::ZERO + cfg.duration;
    let stop = |w: &SimWorld<'_>| w.net.replay_end().map_or(end, |e| e.min(end));
    let mut cursor = Instant::ZERO;
    loop {
        let limit = stop(&pair.world);
        // The remote's answers are given between its ticks, as a thread of
        // its own gives them: run to its next deadline (a release gives an
        // answer), to each answer, and hand it over. A replay runs a period
        // at a time until its first command ties the trace to it.
        let step = Duration::from_nanos(1);
        let until = match pair.world.answers.front() {
            Some(&(at, _)) if at <= limit => at,
            _ if cfg.answer == Answer::NextTick => pair
                .remote
                .poll_timeout()
                .map_or(limit, |d| pair.world.net.global(Role::Remote, d))
                .min(cursor + cfg.period)
                .max(cursor + step)
                .min(limit),
            _ if pair.world.net.awaits_first_command() => (cursor + cfg.period).min(limit),
            _ => limit,
        };
        pair.run_until(until)?;
        cursor = cursor.max(until);
        while pair.world.answers.front().is_some_and(|a| a.0 <= until) {
            let Some((_, state)) = pair.world.answers.pop_front() else {
                break;
            };
            let now = pair.world.net.local(Role::Remote, until);
            pair.world
                .set_sample(Role::Remote, &mut pair.remote, now, &state)?;
        }
        if cursor >= stop(&pair.world) {
            break;
        }
    }
    let (base, remote, world) = pair.into_parts();
    // A replay that ended with its recording ran that long.
    let ran = world.net.replay_end().map(|_| SimConfig {
        duration: cursor - Instant::ZERO,
        ..cfg.clone()
    });
    let mut out = world
        .collect
        .finish(ran.as_ref().unwrap_or(cfg), &base, &remote);
    out.forward = world.forward.unwrap_or_default();
    Ok(out)
}

impl World<Heap> for SimWorld<'_> {
    type Error = SimError;

    network_world!();

    fn received(&mut self, side: Role, at: Instant, frame: &[u8]) {
        if side == Role::Remote {
            self.log_command(at, frame);
        }
    }

    fn event(
        &mut self,
        side: Role,
        ep: &mut SimEndpoint,
        now: Instant,
        event: Event<Box<[f64]>>,
    ) -> Result<(), SimError> {
        match event {
            Event::Released(r) => {
                if r.status == Status::Fresh {
                    self.collect.fresh(side, &r);
                }
                if side == Role::Remote {
                    self.log_release(&r);
                    // The plant takes the command released now; its output
                    // is the state sent at this tick.
                    for ((plant, out), &u) in self
                        .plants
                        .iter_mut()
                        .zip(&mut self.plant_out)
                        .zip(r.values())
                    {
                        *out = plant.step(u);
                    }
                    let out = self.plant_out.clone();
                    match self.cfg.answer {
                        Answer::SameTick => self.set_sample(side, ep, now, &out)?,
                        Answer::NextTick => {
                            let at = self.global(side, now) + THREAD_ANSWER;
                            self.answers.push_back((at, out));
                        }
                    }
                }
            }
            Event::Started { period, ns } => {
                self.collect.started(side, now, period, ns);
                self.net.period = period;
                if side == Role::Remote {
                    let model = self.cfg.plant.discretize(period).map_err(SimError::Plant)?;
                    for p in &mut self.plants {
                        p.set_model(model);
                    }
                }
            }
            Event::DelayChanged { .. } if side == Role::Remote => {
                self.collect.delay_events_fwd += 1;
            }
            Event::Closed { error: Some(e) } => {
                return Err(link_error(side, self.global(side, now), e));
            }
            // Paused, Connected, LinkLost, LinkRestored, the base's
            // DelayChanged, a local Closed: counted by the endpoints; the
            // simulated operator carries on.
            _ => {}
        }
        Ok(())
    }

    fn sample(&mut self, side: Role, ep: &mut SimEndpoint, now: Instant) -> Result<(), SimError> {
        if side == Role::Base {
            let t = now.as_secs_f64();
            for (axis, v) in self.operator.iter_mut().enumerate() {
                *v = self.cfg.signal.value(t, axis);
            }
            let cmd = self.operator.clone();
            self.set_sample(side, ep, now, &cmd)?;
        }
        Ok(())
    }

    fn ticked(&mut self, side: Role, at: Instant, base: &SimEndpoint, remote: &SimEndpoint) {
        if side == Role::Base {
            self.collect.base_tick(at, base, remote);
        }
    }
}

impl SimWorld<'_> {
    /// The first simulation time at which `side`'s clock reads `t`.
    fn global(&self, side: Role, t: Instant) -> Instant {
        self.net.global(side, t)
    }

    /// A frame reached the remote at `at` (its clock): keep a command's
    /// timing; of a datagram's bundle, each sample not kept yet, and the
    /// samples it shows lost (a gap between two samples).
    fn log_command(&mut self, at: Instant, bytes: &[u8]) {
        let Some(log) = &mut self.forward else {
            return;
        };
        let Ok(frame) = Frame::new_checked(bytes) else {
            return;
        };
        // Whether the newest frame before this one carried a sample: a gap
        // after a probe may be probes.
        let after_sample = self.last_was_sample;
        let mut came: Vec<(u64, Instant)> = Vec::new();
        let bundle = match frame.payload() {
            Payload::Data(channels) => {
                self.last_was_sample = !channels.is_empty();
                if channels.is_empty() {
                    return;
                }
                came.push((frame.seq(), frame.sent_at()));
                false
            }
            Payload::Bundle(b) => {
                self.last_was_sample = b.width() > 0;
                if b.width() == 0 {
                    return;
                }
                came.extend(b.older().map(|o| (o.seq, o.sent_at)));
                came.push((frame.seq(), frame.sent_at()));
                came.sort_unstable();
                true
            }
            _ => return,
        };
        for (seq, sent_at) in came {
            let last = log.samples.last().map(|c| (c.seq, c.sent_at));
            if last.is_some_and(|(s, _)| seq <= s) {
                continue;
            }
            if let Some((s, t)) = last.filter(|_| bundle && after_sample) {
                // Lost: never arrives; sent on the grid between its neighbours.
                let step = (sent_at - t) / (seq - s);
                for k in 1..seq - s {
                    let sent = t + step * k;
                    log.samples.push(CommandTiming {
                        seq: s + k,
                        sent_at: sent,
                        arrived_at: sent + NEVER,
                        released_at: None,
                    });
                }
            }
            log.samples.push(CommandTiming {
                seq,
                sent_at,
                arrived_at: at,
                released_at: None,
            });
        }
    }

    /// The remote released a command (fresh or held) at `t`.
    fn log_release(&mut self, r: &Release<Box<[f64]>>) {
        let Some(log) = &mut self.forward else {
            return;
        };
        if r.status == Status::Held {
            log.held.push(r.released_at);
            return;
        }
        if let Ok(i) = log.samples.binary_search_by_key(&r.seq, |c| c.seq)
            && let Some(c) = log.samples.get_mut(i)
        {
            c.released_at = Some(r.released_at);
        }
    }

    fn set_sample(
        &self,
        side: Role,
        ep: &mut SimEndpoint,
        now: Instant,
        values: &[f64],
    ) -> Result<(), SimError> {
        ep.set_sample(values)
            .map_err(|e| link_error(side, self.global(side, now), e))
    }
}

pub(crate) fn link_error(side: Role, at: Instant, error: LinkError) -> SimError {
    SimError::Link {
        side: if side == Role::Base { "base" } else { "remote" },
        at_s: at.as_secs_f64(),
        error,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lossy_tcp_path_holds_samples_back_but_loses_none() {
        let run_with = |loss: LossModel| {
            let mut cfg =
                SimConfig::paper(DelayModel::Lan75km).with_regulation(Regulation::ADAPTIVE);
            cfg.period = Duration::from_millis(20);
            cfg.duration = Duration::from_secs(30);
            cfg.loss = loss;
            cfg.record_forward = true;
            run(&cfg).unwrap()
        };
        let clean = run_with(LossModel::None);
        let lossy = run_with(LossModel::Bernoulli { rate: 0.03 });
        // Every command reaches the remote, in order, none twice.
        let seqs: Vec<u64> = lossy.forward.samples.iter().map(|c| c.seq).collect();
        assert!(seqs.len() > 1000);
        assert!(
            seqs.windows(2).all(|w| w[1] == w[0] + 1),
            "a gap or a repeat"
        );
        // But the stalls cost delay: the adaptive playout covers them.
        let (a, b) = (clean.report.grtt_mean_s, lossy.report.grtt_mean_s);
        assert!(b > 2.0 * a, "{a} {b}");
        // No loss is the run without a loss model, draw for draw.
        let none = run_with("0".parse().unwrap());
        assert_eq!(none.forward, clean.forward);
    }

    #[test]
    fn bad_axes_are_refused() {
        let mut cfg = SimConfig::paper(DelayModel::Lan75km);
        for axes in [0, 257] {
            cfg.axes = axes;
            assert!(matches!(run(&cfg), Err(SimError::Axes(a)) if a == axes));
        }
    }
}

#[cfg(test)]
mod answer_tests {
    use super::*;

    #[test]
    fn a_remote_that_answers_at_the_next_tick_adds_a_period_to_each_round_trip() {
        let grtt = |answer| {
            let mut cfg = SimConfig::paper(DelayModel::Constant {
                fwd: Duration::from_millis(100),
                bwd: Duration::from_millis(100),
            })
            .with_regulation("constant:200".parse().unwrap());
            cfg.period = Duration::from_millis(50);
            cfg.duration = Duration::from_secs(10);
            cfg.answer = answer;
            let r = run(&cfg).unwrap().report;
            assert!(r.grtt_count > 150, "{} round trips", r.grtt_count);
            assert!(r.grtt_std_s < 1e-9, "GRTT std {}", r.grtt_std_s);
            r.grtt_mean_s
        };
        // 200 ms of playout each way, and the state sent at the release's
        // tick or at the next one.
        assert!((grtt(Answer::SameTick) - 0.400).abs() < 1e-9);
        assert!((grtt(Answer::NextTick) - 0.450).abs() < 1e-9);
    }
}
