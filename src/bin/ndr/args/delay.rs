//! Where a network's delays come from, on the command line.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use ndr::sim::delay::{DelayModel, DistTable, Trace};

use super::time::millis;

/// Where the network's delays come from; shared by the commands that run a network.
#[derive(clap::Args, Clone, Debug)]
pub struct DelayArgs {
    /// A built-in delay profile: paris-newyork, lan-75km, paper-fig6, constant[:MS].
    #[arg(long)]
    pub profile: Option<String>,
    /// Replay a delay trace: CSV with header `t_s,fwd_ms,bwd_ms`.
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
            let trace = Trace::from_path(path).map_err(|e| with_path(path, &e))?;
            return Ok(DelayModel::Trace(Arc::new(trace)));
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
