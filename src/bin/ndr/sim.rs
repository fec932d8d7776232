//! `ndr sim`: the link in deterministic simulated time.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use ndr::core::endpoint::{Mode, Transport, Underflow};
use ndr::core::playout::Playout;
use ndr::core::time::Duration;
use ndr::core::{Regulation, RegulationNames};
use ndr::sim::delay::{DelayModel, DistTable, LossModel, Trace};
use ndr::sim::signal::Signal;
use ndr::sim::{self, Report, Row, SimConfig};

use crate::size::millis;

/// Where the network's delays come from; shared by the commands that run a network.
#[derive(clap::Args, Clone, Debug)]
pub struct NetArgs {
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

impl NetArgs {
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

#[derive(clap::Args)]
pub struct SimArgs {
    #[command(flatten)]
    pub net: NetArgs,
    #[arg(
        long,
        value_name = "NAME",
        help = format!(
            "How both sides regulate the delay: {} (paper-static: the paper's FIFO sized once; \
             paper-dynamic: resized as the network changes; see `ndr compare`)",
            RegulationNames::with_default(Regulation::PaperStatic)
        )
    )]
    pub regulation: Option<Regulation>,
    /// Deprecated: --regulation (paper-static or paper-dynamic).
    #[arg(long, hide = true)]
    pub mode: Option<Mode>,
    /// What both regulators do at a tick whose sample has not arrived: hold
    /// (the default: repeat the last sample and keep every one) or drop-late
    /// (keep the delay constant: a sample that missed its tick is dropped
    /// and counted).
    #[arg(long, default_value = "hold")]
    pub underflow: Underflow,
    /// Deprecated: --regulation (the same names; fifo is paper-static).
    #[arg(long, hide = true)]
    pub playout: Option<Playout>,
    /// The remote's clock runs this many ppm fast (negative: slow).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    pub remote_skew_ppm: f64,
    /// Packets lost each way: none, PERCENT (each independently, e.g. 1) or
    /// ge:PERCENT:BURST (in bursts of BURST packets on average, e.g.
    /// ge:2:4). Over TCP a lost frame holds the stream back for a
    /// retransmission timeout (200 ms at least, doubled at each repeat).
    #[arg(long, default_value = "none")]
    pub loss: LossModel,
    /// How samples cross: stream (TCP, the paper's: a loss holds the stream
    /// back until repaired) or datagram[:K[:R]] (each datagram carries the
    /// newest sample and copies of the K − 1 before it, default 4, and is
    /// sent R more times 1 ms apart, default 3, as many as fit before the
    /// next sample, while the peer reports losses; the handshake stays on
    /// TCP). quic[:K[:R]] is simulated as datagram[:K[:R]]: QUIC's
    /// datagrams are not retransmitted either.
    #[arg(long, default_value = "stream", value_parser = crate::transport::simulated)]
    pub transport: Transport,
    /// Sampling period, in ms (the paper's 200).
    #[arg(long, default_value_t = 200.0)]
    pub period_ms: f64,
    /// Simulated time, in seconds.
    #[arg(long, default_value_t = 600.0)]
    pub duration_s: f64,
    /// Seed of every random draw: the same seed gives the same run.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Axes of the teleoperated system (1 to 256).
    #[arg(long, default_value_t = 1)]
    pub axes: u16,
    /// The operator's command: sine[:amp=A,freq=F], steps[:low=L,high=H,period=P], constant:V.
    #[arg(long, default_value = "sine")]
    pub signal: Signal,
    /// Write the per-tick series (for plots) to this CSV file.
    #[arg(long, value_name = "FILE.csv")]
    pub out: Option<PathBuf>,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Run the paper's scenarios and print them beside the paper's numbers.
    #[arg(long)]
    pub paper: bool,
}

impl SimArgs {
    pub fn config(&self) -> Result<SimConfig, String> {
        let period = millis("--period-ms", self.period_ms)?;
        if period.is_zero() {
            return Err("--period-ms must be positive".into());
        }
        let duration = Duration::from_secs_f64(self.duration_s);
        if !(self.duration_s.is_finite() && self.duration_s > 0.0) {
            return Err(format!(
                "--duration-s must be a positive number of seconds, got {}",
                self.duration_s
            ));
        }
        let mut cfg = SimConfig::paper(self.net.model("lan-75km")?);
        (cfg.mode, cfg.playout) = match (self.regulation, self.mode, self.playout) {
            (Some(_), Some(_), _) | (Some(_), _, Some(_)) => {
                return Err(
                    "--regulation replaces --mode and --playout: give --regulation alone".into(),
                );
            }
            (Some(r), None, None) => (r.mode(), r.playout()),
            (None, None, None) => (Mode::PaperStatic, Playout::Fifo),
            (None, mode, playout) => {
                let (mode, playout) = (mode.unwrap_or_default(), playout.unwrap_or_default());
                crate::logging::deprecated_mode_playout(mode, playout);
                (mode, playout)
            }
        };
        cfg.underflow = self.underflow;
        if !(self.remote_skew_ppm.is_finite() && self.remote_skew_ppm.abs() <= 1e5) {
            return Err(format!(
                "--remote-skew-ppm must be within ±100000, got {}",
                self.remote_skew_ppm
            ));
        }
        cfg.remote_skew_ppm = self.remote_skew_ppm;
        cfg.loss = self.loss;
        cfg.transport = self.transport;
        cfg.period = period;
        cfg.duration = duration;
        cfg.seed = self.seed;
        cfg.axes = self.axes;
        cfg.signal = self.signal.clone();
        cfg.record_series = self.out.is_some();
        Ok(cfg)
    }
}

pub fn run(args: &SimArgs) -> Result<(), String> {
    if args.paper {
        return crate::paper::run(args);
    }
    let cfg = args.config()?;
    let out = sim::run(&cfg).map_err(|e| e.to_string())?;
    if let Some(path) = &args.out {
        write_series(path, &out.series)?;
    }
    if args.json {
        println!(
            "{}",
            serde_json::to_string(&out.report).map_err(|e| e.to_string())?
        );
    } else {
        print_report(&out.report);
        if let Some(path) = &args.out {
            println!("series: {} rows in {}", out.series.len(), path.display());
        }
    }
    Ok(())
}

pub fn write_series(path: &Path, rows: &[Row]) -> Result<(), String> {
    let err = |e: std::io::Error| format!("cannot write {}: {e}", path.display());
    let mut w = BufWriter::new(File::create(path).map_err(err)?);
    writeln!(w, "{}", Row::CSV_HEADER).map_err(err)?;
    for row in rows {
        writeln!(w, "{}", row.csv()).map_err(err)?;
    }
    w.flush().map_err(err)
}

fn ms(s: f64) -> String {
    format!("{:.1} ms", s * 1e3)
}

pub fn print_report(r: &Report) {
    println!(
        "{} · {} · {} · seed {} · {:.0} s simulated · {} axis(es)",
        r.profile, r.regulation, r.underflow, r.seed, r.duration_s, r.axes
    );
    println!("                      mean        std         p99");
    println!(
        "  NRTT           {:>11} {:>11}",
        ms(r.nrtt_mean_s),
        ms(r.nrtt_std_s)
    );
    println!(
        "  GRTT           {:>11} {:>11} {:>11}   ({} round trips)",
        ms(r.grtt_mean_s),
        ms(r.grtt_std_s),
        ms(r.grtt_p99_s),
        r.grtt_count
    );
    println!(
        "  e2e commands   {:>11} {:>11}",
        ms(r.e2e_fwd_mean_s),
        ms(r.e2e_fwd_std_s)
    );
    println!(
        "  e2e states     {:>11} {:>11}",
        ms(r.e2e_bwd_mean_s),
        ms(r.e2e_bwd_std_s)
    );
    println!(
        "  period {} · ns {} (first {}) · queue base {}–{} remote {}–{} (before release)",
        ms(r.period_s),
        r.ns,
        r.initial_ns,
        r.queue_base_min,
        r.queue_base_max,
        r.queue_remote_min,
        r.queue_remote_max
    );
    println!(
        "  late rate fwd {:.4} bwd {:.4} · underflows {} · late {} · rejected {} · discarded {} · pauses {} · resizes {}",
        r.late_rate_fwd,
        r.late_rate_bwd,
        r.underflows,
        r.late_samples,
        r.rejected,
        r.discarded,
        r.pauses,
        r.resizes
    );
    println!(
        "  GRTT {} (settled) vs 2·s·T + NRTT: {} with max(s) (error {}), {} with mean(s) (error {})",
        ms(r.settled_grtt_mean_s),
        ms(r.relation_grtt_s),
        ms(r.relation_error_s),
        ms(r.relation_mean_grtt_s),
        ms(r.relation_mean_error_s)
    );
    println!(
        "  predictor {:.0} s ahead: mean NRTT MAE {} RMSE {} · mt MAE {} RMSE {} ({} forecasts)",
        r.pred_horizon_s,
        ms(r.pred_nrtt_mae_s),
        ms(r.pred_nrtt_rmse_s),
        ms(r.pred_mt_mae_s),
        ms(r.pred_mt_rmse_s),
        r.pred_count
    );
}
