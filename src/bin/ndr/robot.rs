//! The remote's robot: a simulated drive per axis, moved by the commands the
//! link releases, whose state goes back to the base; and how each session
//! with a base ended.

use std::fmt;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration as StdDuration;

use ndr::core::endpoint::{Event, LinkError};
use ndr::core::time::Duration;
use ndr::core::wire::CloseReason;
use ndr::core::{Tf2, Tf2State};
use ndr::net::{Link, LinkStats, NetError};
use ndr::sim::PlantConfig;

use crate::pauses::LateTicks;

/// How a session of the robot with a base ended.
#[derive(Clone, Debug, PartialEq)]
pub enum SessionEnd {
    /// This side stopped (the demo's end, a signal) and closed the link in order.
    Stopped,
    /// The link ended: closed by the base, lost, silent…
    Ended(LinkError),
    /// This side's application failed; the link was ended with Close code
    /// 8, "application failure".
    AppFailure(String),
}

impl SessionEnd {
    /// Whether the session ended as it should: stopped here, or closed in
    /// order by the base.
    pub fn ok(&self) -> bool {
        matches!(
            self,
            SessionEnd::Stopped
                | SessionEnd::Ended(LinkError::PeerClosed {
                    reason: CloseReason::Normal
                })
        )
    }
}

impl fmt::Display for SessionEnd {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SessionEnd::Stopped => f.write_str("stopped by this side, link closed in order"),
            SessionEnd::Ended(LinkError::PeerClosed {
                reason: CloseReason::Normal,
            }) => f.write_str("closed in order by the base"),
            SessionEnd::Ended(
                e @ LinkError::PeerClosed {
                    reason: CloseReason::Application,
                },
            ) => write!(f, "the base's application failed ({e})"),
            SessionEnd::Ended(e @ LinkError::PeerClosed { .. }) => {
                write!(f, "closed by the base: {e}")
            }
            SessionEnd::Ended(e @ LinkError::Disconnected) => write!(f, "link lost: {e}"),
            SessionEnd::Ended(e @ LinkError::PeerSilent { .. }) => write!(f, "peer silent: {e}"),
            SessionEnd::Ended(e @ LinkError::Timeout) => write!(f, "timed out: {e}"),
            SessionEnd::Ended(e) => write!(f, "link failed: {e}"),
            SessionEnd::AppFailure(why) => write!(
                f,
                "application failure: {why}; the base was told (Close code 8)"
            ),
        }
    }
}

/// The remote's line for a session's end: a session that released no
/// command says it never linked and, over udp, whether any datagram of the
/// base reached `port`.
pub fn session_line(
    end: &SessionEnd,
    stats: Option<&LinkStats>,
    transport: ndr::net::Transport,
    port: u16,
) -> String {
    let linked = stats.is_some_and(|s| s.endpoint.released_fresh > 0);
    if linked || matches!(end, SessionEnd::AppFailure(_)) {
        return end.to_string();
    }
    let heard = stats.is_some_and(|s| s.datagram_peer.is_some());
    let udp = if transport.datagrams() && !transport.is_quic() && !heard {
        format!(
            "; no datagram of the base reached UDP port {port} (a firewall may let TCP \
             through and drop UDP: open UDP port {port} both ways)"
        )
    } else {
        String::new()
    };
    format!("never linked (its initialization pattern did not finish): {end}{udp}")
}

/// What the robot's state sample holds for each axis, in order
/// (`--state`): the state is `quantities × axes` values, the first
/// quantity's value for every axis, then the next's.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct StateLayout(Vec<Quantity>);

/// One quantity of a state sample, per axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Quantity {
    /// Where the axis is.
    Positions,
    /// How fast it moves (the position's change over the last period).
    Velocities,
    /// The command it was driven with (after saturation).
    Efforts,
}

impl Quantity {
    fn name(self) -> &'static str {
        match self {
            Quantity::Positions => "positions",
            Quantity::Velocities => "velocities",
            Quantity::Efforts => "efforts",
        }
    }
}

impl StateLayout {
    /// Whether a state sample starts with the first axis's position.
    pub fn leads_with_positions(&self) -> bool {
        self.0.first() == Some(&Quantity::Positions)
    }

    /// Values in a state sample for `axes` axes.
    pub fn width(&self, axes: u16) -> Result<u16, String> {
        u16::try_from(self.0.len())
            .ok()
            .and_then(|n| n.checked_mul(axes))
            .filter(|&w| usize::from(w) <= ndr::core::wire::MAX_CHANNELS)
            .ok_or_else(|| {
                format!(
                    "a state of {} for {axes} axes is {} values, over the {} a sample can carry",
                    self,
                    self.0.len() * usize::from(axes),
                    ndr::core::wire::MAX_CHANNELS
                )
            })
    }

    /// The layout's fingerprint for the handshake, so that a base built for
    /// another layout is refused; `0` (none) for positions alone, the
    /// layout of a peer that names none.
    pub fn fingerprint(&self, axes: u16) -> u64 {
        if self.0 == [Quantity::Positions] {
            return 0;
        }
        let (commands, states) = self.channel_names(axes);
        let commands: Vec<&str> = commands.iter().map(String::as_str).collect();
        let states: Vec<&str> = states.iter().map(String::as_str).collect();
        ndr::core::fingerprint(&commands, &states)
    }
}

impl StateLayout {
    /// The names of a command's values and of a state's, in their order
    /// (`command0…`; `positions0…`, then the next quantity's).
    pub fn channel_names(&self, axes: u16) -> (Vec<String>, Vec<String>) {
        let commands = (0..axes).map(|a| format!("command{a}")).collect();
        let states = self
            .0
            .iter()
            .flat_map(|q| (0..axes).map(move |a| format!("{}{a}", q.name())))
            .collect();
        (commands, states)
    }
}

impl Default for StateLayout {
    fn default() -> Self {
        StateLayout(vec![Quantity::Positions])
    }
}

impl std::fmt::Display for StateLayout {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names: Vec<&str> = self.0.iter().map(|q| q.name()).collect();
        f.write_str(&names.join(","))
    }
}

impl std::str::FromStr for StateLayout {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let mut quantities = Vec::new();
        for part in s.split(',').map(str::trim) {
            let q = match part {
                "positions" => Quantity::Positions,
                "velocities" => Quantity::Velocities,
                "efforts" => Quantity::Efforts,
                other => {
                    return Err(format!(
                        "unknown state quantity {other:?}: give a comma-separated list of \
                         positions, velocities and efforts (e.g. positions,velocities)"
                    ));
                }
            };
            if quantities.contains(&q) {
                return Err(format!("{part} is given twice in --state {s:?}"));
            }
            quantities.push(q);
        }
        Ok(StateLayout(quantities))
    }
}

/// One second-order drive per axis, with its command saturated and its
/// state checked.
pub struct Drive {
    plants: Vec<Tf2State>,
    /// Each axis's position, and the one before (for its velocity).
    position: Vec<f64>,
    previous: Vec<f64>,
    /// The command each axis was driven with at the last step.
    effort: Vec<f64>,
    /// The state sample, laid out as `layout` says.
    state: Vec<f64>,
    layout: StateLayout,
    period_s: f64,
    max_command: f64,
    /// After a `LinkLost`, until `LinkRestored` (or, on a shared robot,
    /// while no base holds control): the commands are stale, so each axis
    /// is held where it is instead of following them.
    pub holding: bool,
}

/// The simulated plant (the simulator's default axis) at `period`: the
/// robot's drive, and the model of the base's tracking loop.
pub fn plant_model(period: Duration) -> Result<Tf2, String> {
    let c = PlantConfig::default();
    Tf2::low_pass(
        std::f64::consts::TAU * c.natural_hz,
        c.damping,
        c.gain,
        period.as_secs_f64(),
    )
    .map_err(|e| format!("the simulated plant cannot run at a period of {period}: {e}"))
}

impl Drive {
    /// The drive `spec` describes, at rest.
    pub fn new(spec: DriveSpec) -> Result<Drive, String> {
        let DriveSpec {
            axes,
            layout,
            period,
            max_command,
        } = spec;
        let model = plant_model(period)?;
        Ok(Drive {
            plants: (0..axes).map(|_| Tf2State::new(model)).collect(),
            position: vec![0.0; axes],
            previous: vec![0.0; axes],
            effort: vec![0.0; axes],
            state: vec![0.0; axes * layout.0.len()],
            layout,
            period_s: period.as_secs_f64(),
            max_command,
            holding: false,
        })
    }

    /// Its axes: values in a command.
    pub fn axes(&self) -> usize {
        self.plants.len()
    }

    /// Runs the drive at `period` from now on.
    pub fn set_period(&mut self, period: Duration) -> Result<(), String> {
        let m = plant_model(period)?;
        self.plants.iter_mut().for_each(|p| p.set_model(m));
        self.period_s = period.as_secs_f64();
        Ok(())
    }

    /// One step on the released `commands`; the new state, or why it must
    /// not be sent.
    pub fn step(&mut self, commands: &[f64]) -> Result<&[f64], String> {
        self.previous.clone_from(&self.position);
        let axes = self
            .plants
            .iter_mut()
            .zip(&mut self.position)
            .zip(&mut self.effort)
            .zip(commands);
        for (axis, (((plant, y), effort), &u)) in axes.enumerate() {
            let u = if self.holding {
                // The command whose steady state is the present position
                // (the plant's static gain is one).
                plant.output()
            } else if u.is_nan() {
                return Err(format!("the command on axis {axis} is NaN"));
            } else {
                u.clamp(-self.max_command, self.max_command)
            };
            *effort = u;
            *y = plant.step(u);
            if !y.is_finite() {
                return Err(format!(
                    "the simulated plant's state on axis {axis} became {y} (command {u}); \
                     it was not sent"
                ));
            }
        }
        let axes = self.position.len();
        for (q, out) in self
            .layout
            .0
            .iter()
            .zip(self.state.chunks_exact_mut(axes.max(1)))
        {
            match q {
                Quantity::Positions => out.copy_from_slice(&self.position),
                Quantity::Efforts => out.copy_from_slice(&self.effort),
                Quantity::Velocities => {
                    for ((v, y), y0) in out.iter_mut().zip(&self.position).zip(&self.previous) {
                        *v = (y - y0) / self.period_s;
                    }
                }
            }
        }
        Ok(&self.state)
    }
}

/// The simulated drive a remote runs: its axes, what its state holds, the
/// period it starts at, and the largest command it takes.
#[derive(Clone)]
pub struct DriveSpec {
    pub axes: usize,
    pub layout: StateLayout,
    pub period: Duration,
    pub max_command: f64,
}

/// The remote's session with one base: each released command moves the
/// drive, whose state goes back. Returns how the session ended; `stats`
/// holds the link's latest counters (the final ones at the end), `late`
/// (if given) when ticks went without their command.
pub fn robot(
    mut link: Link,
    spec: DriveSpec,
    stop: &AtomicBool,
    stats: &Mutex<Option<LinkStats>>,
    late: Option<&Mutex<LateTicks>>,
) -> SessionEnd {
    let set_stats = |s: Option<LinkStats>| {
        *stats
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = s;
    };
    let mut drive = match Drive::new(spec) {
        Ok(d) => d,
        Err(why) => return fail(link, why, set_stats),
    };
    let end = loop {
        if stop.load(Ordering::Relaxed) {
            break None;
        }
        let received = link.recv_timeout(StdDuration::from_millis(200));
        // Before the command: a LinkLost queued ahead of it says it is stale.
        let mut failed = None;
        for event in link.drain_events() {
            crate::logging::event("remote", &event);
            match event {
                Event::Started { period, .. } => {
                    if let Err(why) = drive.set_period(period) {
                        failed = Some(why);
                    }
                }
                Event::LinkLost { .. } => drive.holding = true,
                Event::LinkRestored { .. } => drive.holding = false,
                _ => {}
            }
        }
        if let Some(why) = failed {
            break Some(SessionEnd::AppFailure(why));
        }
        if let Ok(command) = &received {
            crate::pauses::note(late, &link, command);
        }
        match received {
            Ok(command) => match drive.step(command.values()) {
                Ok(state) => match link.send(state) {
                    Ok(()) => {}
                    Err(NetError::Link(e)) if e.is_fatal() => break Some(SessionEnd::Ended(e)),
                    Err(e) => {
                        break Some(SessionEnd::AppFailure(format!(
                            "the link refused the robot's state: {e}"
                        )));
                    }
                },
                Err(why) => break Some(SessionEnd::AppFailure(why)),
            },
            Err(NetError::Timeout) => {}
            Err(NetError::Link(e)) => break Some(SessionEnd::Ended(e)),
            Err(e) => {
                break Some(SessionEnd::AppFailure(format!(
                    "receiving a command failed: {e}"
                )));
            }
        }
        set_stats(link.stats());
    };
    match end {
        None => {
            set_stats(link.close());
            SessionEnd::Stopped
        }
        Some(SessionEnd::AppFailure(why)) => fail(link, why, set_stats),
        Some(end) => {
            set_stats(link.close());
            end
        }
    }
}

/// Ends the session as an application failure, logged.
fn fail(mut link: Link, why: String, set_stats: impl Fn(Option<LinkStats>)) -> SessionEnd {
    tracing::error!(peer = %link.peer_addr(), "robot: {why}; ending the link as an application failure");
    link.abort();
    set_stats(link.close());
    SessionEnd::AppFailure(why)
}
