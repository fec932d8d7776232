//! The trace families of the comparison: the paper's profiles, events
//! (step, spikes, stalls), clock skew, and iproute2's netem tables.

use std::path::{Path, PathBuf};
use std::string::{String, ToString};
use std::sync::Arc;
use std::vec::Vec;

use ndr_core::endpoint::Transport;
use ndr_core::time::Duration;

use crate::delay::{
    DelayModel, DistTable, EventKind, EventParams, FIG6_DURATION, FIG6_STEP_AT_S, JitterParams,
    LossModel, Trace,
};

/// One family of traces: a delay model run with several seeds.
#[derive(Clone, Debug)]
pub struct Family {
    /// Its name in reports.
    pub name: String,
    /// What it is, in a few words.
    pub description: String,
    /// The network's delays.
    pub model: DelayModel,
    /// The packets it loses (over TCP: a stall of a retransmission
    /// timeout each).
    pub loss: LossModel,
    /// How the samples cross: a stream (TCP) or datagrams.
    pub transport: Transport,
    /// The remote's clock skew, ppm.
    pub skew_ppm: f64,
    /// Simulated time per run.
    pub duration: Duration,
    /// Onsets of the events whose recovery is measured, s.
    pub events_s: Vec<f64>,
    /// Whether the seed changes the delays (a trace file's do not: one run).
    pub seeded: bool,
}

/// The jitter under the event and skew families: 40 ms plus a gamma of
/// shape 2 and mean 10 ms, capped at 200 ms (one-way 50 ms mean, 7 ms std).
pub const WAN: JitterParams = JitterParams {
    base_s: 0.040,
    mean_s: 0.010,
    shape: 2.0,
    cap_s: 0.2,
};

/// The jitter of the route-flap family: 20 ms plus a gamma of shape 2 and
/// mean 1 ms, capped at 5 ms (one-way 21 ms, 0.7 ms std). Two routes of
/// little jitter are where the delay's step shows: a step of 20 ms over
/// the longer one's 71 ms was most of the delay's excess.
const FLAP_JITTER: JitterParams = JitterParams {
    base_s: 0.020,
    mean_s: 0.001,
    shape: 2.0,
    cap_s: 0.005,
};

/// Simulated time of most families.
pub const FAMILY_DURATION: Duration = Duration::from_secs(120);
/// Simulated time of the skew families: long enough for ±100 ppm to drift
/// the apparent delay by 30 ms.
pub const SKEW_DURATION: Duration = Duration::from_secs(300);

/// The netem tables iproute2 ships, in the order they are compared.
pub const NETEM_TABLES: [&str; 4] = ["normal", "pareto", "paretonormal", "experimental"];
/// netem's `delay MEAN STD` used with each table.
pub const NETEM_MEAN: Duration = Duration::from_millis(100);
/// See [`NETEM_MEAN`].
pub const NETEM_STD: Duration = Duration::from_millis(20);

/// Where iproute2 installs its tables, depending on the distribution.
pub const TC_DIRS: [&str; 6] = [
    "/usr/lib/tc",
    "/lib/tc",
    "/usr/lib/x86_64-linux-gnu/tc",
    "/usr/lib/aarch64-linux-gnu/tc",
    "/usr/lib64/tc",
    "/usr/share/tc",
];

impl Family {
    /// The same family run for `duration` instead: its events (an event
    /// family's, recurring; paper-fig6's step) are those before the end.
    #[must_use]
    pub fn with_duration(mut self, duration: Duration) -> Family {
        let until = duration.as_secs_f64();
        self.events_s = match &self.model {
            DelayModel::Events(p) => p.onsets(until),
            DelayModel::PaperFig6 => [FIG6_STEP_AT_S]
                .into_iter()
                .filter(|&t| t < until)
                .collect(),
            _ => self.events_s.into_iter().filter(|&t| t < until).collect(),
        };
        self.duration = duration;
        self
    }
}

fn family(name: &str, description: &str, model: DelayModel) -> Family {
    Family {
        name: name.to_string(),
        description: description.to_string(),
        model,
        loss: LossModel::None,
        transport: Transport::Stream,
        skew_ppm: 0.0,
        duration: FAMILY_DURATION,
        events_s: Vec::new(),
        seeded: true,
    }
}

fn events(name: &str, description: &str, kind: EventKind, duration: Duration) -> Family {
    events_on(WAN, name, description, kind, duration)
}

fn events_on(
    jitter: JitterParams,
    name: &str,
    description: &str,
    kind: EventKind,
    duration: Duration,
) -> Family {
    let p = EventParams { jitter, kind };
    Family {
        events_s: p.onsets(duration.as_secs_f64()),
        ..family(name, description, DelayModel::Events(p))
    }
}

/// The built-in families that need no file: the paper's profiles, a step,
/// spikes, stalls, clock skew, a route flap and packet loss.
#[must_use]
pub fn builtin() -> Vec<Family> {
    let wan = DelayModel::Events(EventParams {
        jitter: WAN,
        kind: EventKind::Step {
            at_s: f64::INFINITY,
            by_s: 0.0,
        },
    });
    let skew = |ppm: f64| Family {
        skew_ppm: ppm,
        duration: SKEW_DURATION,
        ..family(
            &std::format!("skew{ppm:+}ppm"),
            &std::format!("WAN jitter; the receiver's clock runs {ppm:+} ppm off the sender's"),
            wan.clone(),
        )
    };
    let mut families = std::vec![
        family(
            "paris-newyork",
            "the paper's relay: congestion episodes, NRTT 610/500 ms",
            DelayModel::ParisNewYork,
        ),
        family(
            "lan-75km",
            "the paper's LAN: 11.5 ms one-way, 2.6 ms std",
            DelayModel::Lan75km,
        ),
        Family {
            duration: FIG6_DURATION,
            events_s: std::vec![FIG6_STEP_AT_S],
            ..family(
                "paper-fig6",
                "the paper's Fig. 6: slow sines, +150 ms step at 12 min",
                DelayModel::PaperFig6,
            )
        },
        events(
            "step",
            "WAN jitter (50 ms), +150 ms step at 60 s",
            EventKind::Step {
                at_s: 60.0,
                by_s: 0.150,
            },
            FAMILY_DURATION,
        ),
        events(
            "spikes",
            "WAN jitter, +400 ms spikes falling at 0.5 s/s, every 20 s",
            EventKind::Spikes {
                first_s: 30.0,
                every_s: 20.0,
                height_s: 0.400,
                fall_rate: 0.5,
            },
            FAMILY_DURATION,
        ),
        events(
            "tcp-stall",
            "WAN jitter, a 300 ms head-of-line stall then a burst, every 20 s",
            EventKind::Stalls {
                first_s: 30.0,
                every_s: 20.0,
                stall_s: 0.300,
            },
            FAMILY_DURATION,
        ),
        skew(100.0),
        skew(-100.0),
        events_on(
            FLAP_JITTER,
            "route-flap",
            "21 ms one-way, 0.7 ms std; the route flips to one 50 ms longer and back every 4 s from 20 s",
            EventKind::Flaps {
                first_s: 20.0,
                every_s: 4.0,
                by_s: 0.050,
            },
            FAMILY_DURATION,
        ),
        lossy(
            "lan-75km-loss1",
            "the paper's LAN, 1 % of packets lost (TCP: each loss holds the stream back until repaired)",
            DelayModel::Lan75km,
            LossModel::Bernoulli { rate: 0.01 },
        ),
        lossy(
            "lan-75km-loss3",
            "the paper's LAN, 3 % of packets lost",
            DelayModel::Lan75km,
            LossModel::Bernoulli { rate: 0.03 },
        ),
        lossy(
            "wan-bursts",
            "WAN jitter, 2 % of packets lost in bursts of 4 on average (Gilbert–Elliott)",
            wan,
            LossModel::GilbertElliott {
                p: 0.02 * 0.25 / 0.98,
                r: 0.25,
            },
        ),
    ];
    // The lossy families again on datagrams, beside TCP.
    let datagrams: Vec<Family> = families
        .iter()
        .filter(|f| !f.loss.is_none())
        .map(on_datagrams)
        .collect();
    families.extend(datagrams);
    families
}

fn lossy(name: &str, description: &str, model: DelayModel, loss: LossModel) -> Family {
    Family {
        loss,
        ..family(name, description, model)
    }
}

/// `family` on the datagram transport (three samples a datagram): named
/// `NAME/datagram`.
#[must_use]
pub fn on_datagrams(family: &Family) -> Family {
    Family {
        name: std::format!("{}/datagram", family.name),
        description: std::format!("{}; over datagrams, 3 samples each", family.description),
        transport: Transport::DATAGRAM,
        ..family.clone()
    }
}

/// The netem families, one per table found in the first of `dirs` that
/// holds it; a note for each table missing or unreadable.
#[must_use]
pub fn netem<P: AsRef<Path>>(dirs: &[P]) -> (Vec<Family>, Vec<String>) {
    let mut families = Vec::new();
    let mut notes = Vec::new();
    for table in NETEM_TABLES {
        let file = std::format!("{table}.dist");
        let found: Option<PathBuf> = dirs
            .iter()
            .map(|d| d.as_ref().join(&file))
            .find(|p| p.is_file());
        let Some(path) = found else {
            notes.push(std::format!(
                "netem-{table} skipped: no {file} in {} (install iproute2 for the tables)",
                dirs.iter()
                    .map(|d| d.as_ref().display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
            continue;
        };
        match DistTable::from_path(&path) {
            Ok(t) => families.push(family(
                &std::format!("netem-{table}"),
                &std::format!(
                    "netem delay 100ms 20ms distribution {table} ({})",
                    path.display()
                ),
                DelayModel::Dist {
                    table: Arc::new(t),
                    mean: NETEM_MEAN,
                    std: NETEM_STD,
                },
            )),
            Err(e) => notes.push(std::format!("netem-{table} skipped: {e}")),
        }
    }
    (families, notes)
}

/// A family of one delay trace (CSV, `t_s,fwd_ms,bwd_ms`): one run, as
/// long as the trace plus 10 s, at least 60 s.
#[must_use]
pub fn trace(name: &str, trace: Trace) -> Family {
    let duration = (trace.duration() + Duration::from_secs(10)).max(Duration::from_secs(60));
    Family {
        duration,
        seeded: false,
        ..family(name, "delay trace file", DelayModel::Trace(Arc::new(trace)))
    }
}
