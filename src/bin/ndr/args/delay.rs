//! Where a network's delays come from, on the command line.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use ndr::core::time::{Duration, Instant};
use ndr::sim::Answer;
use ndr::sim::delay::{DelayModel, Direction, DistTable, OneWay, Trace, one_way_trace};

use super::time::millis;

/// Where the network's delays come from; shared by the commands that run a network.
#[derive(clap::Args, Clone, Debug)]
pub struct DelayArgs {
    /// A built-in delay profile: paris-newyork, lan-75km, paper-fig6, constant[:MS].
    #[arg(long)]
    pub profile: Option<String>,
    /// Replay a delay trace: CSV with header `t_s,fwd_ms,bwd_ms`, or a
    /// link's MCAP recording (`--record`): the one-way delays it measured,
    /// sample by sample, each way (a recording of one side gives its
    /// direction to both).
    #[arg(long, value_name = "FILE")]
    pub trace: Option<PathBuf>,
    /// Draw delays from an iproute2 netem distribution table (`*.dist`),
    /// with --mean-ms and --std-ms.
    #[arg(long, value_name = "FILE", requires_all = ["mean_ms", "std_ms"])]
    pub dist: Option<PathBuf>,
    /// Mean one-way delay for --dist, in ms.
    #[arg(long, requires = "dist")]
    pub mean_ms: Option<f64>,
    /// Standard deviation of the one-way delay for --dist, in ms.
    #[arg(long, requires = "dist")]
    pub std_ms: Option<f64>,
}

impl DelayArgs {
    /// Whether --trace names a recording (MCAP) rather than a CSV trace.
    pub fn is_recording(&self) -> bool {
        self.trace.as_deref().is_some_and(is_mcap)
    }

    /// When the recorded remote answered its commands, if --trace names a
    /// recording that shows it.
    pub fn recorded_answer(&self) -> Result<Option<Answer>, String> {
        match &self.trace {
            Some(path) if is_mcap(path) => answer(path),
            _ => Ok(None),
        }
    }

    /// The delay model these arguments describe; `default` when none is given.
    pub fn model(&self, default: &str) -> Result<DelayModel, String> {
        let given = [
            self.profile.is_some(),
            self.trace.is_some(),
            self.dist.is_some(),
        ];
        if given.iter().filter(|&&g| g).count() > 1 {
            return Err("give one of --profile, --trace and --dist, not several".into());
        }
        if let Some(path) = &self.trace {
            return Ok(DelayModel::Trace(Arc::new(trace(path)?)));
        }
        if let Some(path) = &self.dist {
            let table = DistTable::from_path(path).map_err(|e| with_path(path, &e))?;
            let mean = millis("--mean-ms", self.mean_ms.unwrap_or(0.0))?;
            let std = millis("--std-ms", self.std_ms.unwrap_or(0.0))?;
            return Ok(DelayModel::Dist {
                table: Arc::new(table),
                mean,
                std,
            });
        }
        let name = self.profile.as_deref().unwrap_or(default);
        DelayModel::profile(name).map_err(|e| e.to_string())
    }
}

/// A delay trace from its file: a CSV trace, or an MCAP recording's
/// one-way delays (told apart by the file's first bytes).
pub fn trace(path: &Path) -> Result<Trace, String> {
    if !is_mcap(path) {
        return Trace::from_path(path).map_err(|e| with_path(path, &e));
    }
    let net = ndr::net::record::read_network(path).map_err(|e| e.to_string())?;
    if net.truncated {
        eprintln!(
            "ndr: {} ends inside a record (its writer was killed): replaying what came before",
            path.display()
        );
    }
    // The trace starts when the recording did; its anchor is the first
    // command's send (a recording of the base alone: its first state's),
    // which the simulated link's first command is put on, so that every
    // sample meets the delay its recorded twin met however long the
    // simulated set-up takes (which the recording did not measure).
    let origin = net
        .forward
        .iter()
        .chain(&net.backward)
        .map(|c| c.sent_unix_ns)
        .chain(net.attached_unix_ns)
        .min()
        .unwrap_or(0);
    let first_sent = net
        .forward
        .first()
        .or(net.backward.first())
        .map_or(origin, |c| c.sent_unix_ns);
    let anchor = Instant::from_nanos(first_sent - origin);
    let way = |crossings: &[ndr::net::record::Crossing]| -> Vec<OneWay> {
        crossings
            .iter()
            .map(|c| OneWay {
                sent: Instant::from_nanos(c.sent_unix_ns - origin),
                // A delay measured below zero (the clock estimate's error)
                // is none at all.
                delay: c.one_way_s.map(|s| Duration::from_secs_f64(s.max(0.0))),
            })
            .collect()
    };
    // The set-up's probes, by number: the simulated link's probes meet
    // their delays, so that its initialization pattern measures the
    // recorded round trips and sizes its queue as the recorded one did.
    let probes = |probes: &[ndr::net::record::ProbeCrossing]| -> Vec<(u64, Duration)> {
        probes
            .iter()
            .map(|p| (p.seq, Duration::from_secs_f64(p.one_way_s.max(0.0))))
            .collect()
    };
    // A recording of one side measured its own way: both take it.
    let (fwd, bwd) = match (&net.forward_probes[..], &net.backward_probes[..]) {
        ([], one) | (one, []) => (probes(one), probes(one)),
        (fwd, bwd) => (probes(fwd), probes(bwd)),
    };
    one_way_trace(&way(&net.forward), &way(&net.backward))
        .map(|t| {
            t.with_anchor(anchor)
                .with_probes(Direction::Forward, fwd)
                .with_probes(Direction::Backward, bwd)
        })
        .map_err(|e| with_path(path, &e))
}

/// When the remote of the recording at `path` answered its commands: at
/// the next tick if most states went out half a period or more after the
/// release of the command they answer; `None` if the recording does not
/// hold both sides.
pub fn answer(path: &Path) -> Result<Option<Answer>, String> {
    let net = ndr::net::record::read_network(path).map_err(|e| e.to_string())?;
    let (Some(period), false) = (net.period_s, net.answer_lags_s.is_empty()) else {
        return Ok(None);
    };
    let later = net
        .answer_lags_s
        .iter()
        .filter(|&&lag| lag >= period / 2.0)
        .count();
    Ok(Some(if 2 * later > net.answer_lags_s.len() {
        Answer::NextTick
    } else {
        Answer::SameTick
    }))
}

fn is_mcap(path: &Path) -> bool {
    use std::io::Read;
    let mut magic = [0u8; 8];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut magic))
        .is_ok_and(|()| magic == *b"\x89MCAP0\r\n")
}

/// An error about a file, naming the file once.
fn with_path(path: &Path, e: &dyn std::fmt::Display) -> String {
    let msg = e.to_string();
    let name = path.display().to_string();
    if msg.contains(&name) {
        msg
    } else {
        format!("{name}: {msg}")
    }
}
