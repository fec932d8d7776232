//! The operator's run on the command line.

use std::path::PathBuf;

use ndr::sim::signal::Signal;

use crate::tracking::ControllerKind;

/// The operator's run, shared by `demo` and `base`.
#[derive(clap::Args, Clone, Debug)]
pub struct RunArgs {
    /// How long to run, in seconds.
    #[arg(long, default_value_t = 20.0)]
    pub duration_s: f64,
    /// The operator's command: sine[:amp=A,freq=F], steps[:low=L,high=H,period=P], constant:V.
    #[arg(long, default_value = "sine")]
    pub signal: Signal,
    /// Where to write the base's per-tick series (CSV), row by row as the
    /// states are released; written however the run ends.
    #[arg(long, value_name = "FILE.csv", default_value = "ndr-demo.csv")]
    pub out: PathBuf,
    /// Print one JSON object instead of the live line and the table; it
    /// says how the run ended (`ok`, `end`) and is printed whatever the end.
    #[arg(long)]
    pub json: bool,
    /// Close a position loop at the base on the remote's state instead of
    /// following --signal: smith (a PID through a Smith predictor with the
    /// plant's model, following the round trip the link announces) or pid
    /// (the PID on the delayed state), with the gains, plant and
    /// reference of `ndr control --scenario tracking`, on the first axis;
    /// the report gains the tracking errors. none (the default): the
    /// open-loop operator.
    #[arg(long, default_value = "none")]
    pub controller: ControllerKind,
}

impl RunArgs {
    /// `--duration-s`, checked.
    pub fn check_duration(&self) -> Result<(), String> {
        if self.duration_s.is_finite() && self.duration_s > 0.0 {
            Ok(())
        } else {
            Err(format!(
                "--duration-s must be positive, got {}",
                self.duration_s
            ))
        }
    }
}
