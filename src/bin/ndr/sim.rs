//! `ndr sim`: the link in deterministic simulated time.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use ndr::core::Regulation;
use ndr::core::endpoint::{Transport, Underflow};
use ndr::core::time::Duration;
use ndr::sim::delay::{DelayModel, LossModel};
use ndr::sim::signal::Signal;
use ndr::sim::{self, Report, Row, SimConfig};

use crate::args::{DelayArgs, millis};

#[derive(clap::Args)]
pub struct SimArgs {
    #[command(flatten)]
    pub net: DelayArgs,
    #[arg(
        long,
        value_name = "NAME",
        help = format!(
            "How both sides regulate the delay: {} (paper-static: the paper's FIFO sized once; \
             paper-dynamic: resized as the network changes; see `ndr compare`)",
            Regulation::names(Some(Regulation::PaperStatic))
        )
    )]
    pub regulation: Option<Regulation>,
    /// What both regulators do at a tick whose sample has not arrived: hold
    /// (the default: repeat the last sample and keep every one) or drop-late
    /// (keep the delay constant: a sample that missed its tick is dropped
    /// and counted).
    #[arg(long, default_value = "hold")]
    pub underflow: Underflow,
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
    /// Simulated time, in seconds (default 600; a recording given to
    /// --trace: until its last sample).
    #[arg(long)]
    pub duration_s: Option<f64>,
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
        let model = self.net.model("lan-75km")?;
        let duration_s = match (self.duration_s, &model) {
            (Some(s), _) => s,
            // A recording replays for as long as it lasted from its first
            // command (the simulator stops there), after a set-up that may
            // take longer than the recorded one.
            (None, DelayModel::Trace(t)) if self.net.is_recording() => {
                2.0 * t.duration().as_secs_f64().max(1.0)
            }
            (None, _) => 600.0,
        };
        let duration = Duration::from_secs_f64(duration_s);
        if !(duration_s.is_finite() && duration_s > 0.0) {
            return Err(format!(
                "--duration-s must be a positive number of seconds, got {duration_s}"
            ));
        }
        let mut cfg = SimConfig::paper(model);
        let regulation = self.regulation.unwrap_or(Regulation::PaperStatic);
        cfg.mode = regulation.mode();
        cfg.playout = regulation.playout();
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
        if let Some(answer) = self.net.recorded_answer()? {
            cfg.answer = answer;
        }
        Ok(cfg)
    }
}

pub fn run(args: &SimArgs) -> Result<(), String> {
    if args.paper {
        return crate::paper::run(args.seed, args.underflow, args.json);
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
