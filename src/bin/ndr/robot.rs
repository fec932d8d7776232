//! The remote's robot: a simulated drive per axis, moved by the commands the
//! link releases, whose state goes back to the base; and how each session
//! with a base ended.

use std::fmt;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration as StdDuration;

use ndr::core::arx::{Tf2, Tf2State};
use ndr::core::endpoint::{Event, LinkError};
use ndr::core::time::Duration;
use ndr::core::wire::close_reason;
use ndr::net::{Link, LinkStats, NetError};
use ndr::sim::PlantConfig;

/// The simulated drive's limits, for `demo` and `remote`.
#[derive(clap::Args, Clone, Debug)]
pub struct PlantArgs {
    /// The largest command the simulated drive takes on each axis, either
    /// way: larger ones are saturated to ±this value, as a real drive
    /// saturates.
    #[arg(long, value_name = "U", default_value_t = 1000.0)]
    pub max_command: f64,
}

impl PlantArgs {
    /// The saturation, checked.
    pub fn max_command(&self) -> Result<f64, String> {
        if self.max_command.is_finite() && self.max_command > 0.0 {
            Ok(self.max_command)
        } else {
            Err(format!(
                "--max-command must be a positive number, got {}",
                self.max_command
            ))
        }
    }
}

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
                    reason: close_reason::NORMAL
                })
        )
    }
}

impl fmt::Display for SessionEnd {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SessionEnd::Stopped => f.write_str("stopped by this side, link closed in order"),
            SessionEnd::Ended(LinkError::PeerClosed {
                reason: close_reason::NORMAL,
            }) => f.write_str("closed in order by the base"),
            SessionEnd::Ended(
                e @ LinkError::PeerClosed {
                    reason: close_reason::APPLICATION,
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

/// One second-order drive per axis, with its command saturated and its
/// state checked.
struct Drive {
    plants: Vec<Tf2State>,
    state: Vec<f64>,
    max_command: f64,
    /// After a `LinkLost`, until `LinkRestored`: the commands are stale, so
    /// each axis is held where it is instead of following them.
    holding: bool,
}

impl Drive {
    fn model(period: Duration) -> Result<Tf2, String> {
        let c = PlantConfig::default();
        Tf2::low_pass(
            std::f64::consts::TAU * c.natural_hz,
            c.damping,
            c.gain,
            period.as_secs_f64(),
        )
        .map_err(|e| format!("the simulated plant cannot run at a period of {period}: {e}"))
    }

    /// One step on the released `commands`; the new state, or why it must
    /// not be sent.
    fn step(&mut self, commands: &[f64]) -> Result<&[f64], String> {
        let axes = self.plants.iter_mut().zip(&mut self.state).zip(commands);
        for (axis, ((plant, y), &u)) in axes.enumerate() {
            let u = if self.holding {
                // The command whose steady state is the present position
                // (the plant's static gain is one).
                plant.output()
            } else if u.is_nan() {
                return Err(format!("the command on axis {axis} is NaN"));
            } else {
                u.clamp(-self.max_command, self.max_command)
            };
            *y = plant.step(u);
            if !y.is_finite() {
                return Err(format!(
                    "the simulated plant's state on axis {axis} became {y} (command {u}); \
                     it was not sent"
                ));
            }
        }
        Ok(&self.state)
    }
}

/// The remote's session with one base: each released command moves the
/// drive, whose state goes back. Returns how the session ended; `stats`
/// holds the link's latest counters (the final ones at the end).
pub fn robot(
    mut link: Link,
    axes: usize,
    period: Duration,
    max_command: f64,
    stop: &AtomicBool,
    stats: &Mutex<Option<LinkStats>>,
) -> SessionEnd {
    let set_stats = |s: Option<LinkStats>| {
        *stats
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = s;
    };
    let mut drive = match Drive::model(period) {
        Ok(model) => Drive {
            plants: (0..axes).map(|_| Tf2State::new(model)).collect(),
            state: vec![0.0; axes],
            max_command,
            holding: false,
        },
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
                Event::Started { period, .. } => match Drive::model(period) {
                    Ok(m) => drive.plants.iter_mut().for_each(|p| p.set_model(m)),
                    Err(why) => failed = Some(why),
                },
                Event::LinkLost { .. } => drive.holding = true,
                Event::LinkRestored => drive.holding = false,
                _ => {}
            }
        }
        if let Some(why) = failed {
            break Some(SessionEnd::AppFailure(why));
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
