//! `ndr size`: a regulator's nominal size from an initialization pattern.

use ndr::core::{INIT_EXCHANGES, InitPattern, Sizing};
use serde::Serialize;

use crate::args::millis;

#[derive(clap::Args)]
pub struct SizeArgs {
    /// Round-trip times measured by the initialization pattern, in ms (1 to 10 values).
    #[arg(long, value_delimiter = ',', required = true, num_args = 1..)]
    nrtt_ms: Vec<f64>,
    /// The period the queue is sized for, in ms.
    #[arg(long, default_value_t = 200.0)]
    period_ms: f64,
    /// Security factor eta.
    #[arg(long, default_value_t = Sizing::default().eta())]
    eta: f64,
    /// Lower bound of the period law, in ms.
    #[arg(long, default_value_t = 50.0)]
    min_period_ms: f64,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    json: bool,
}

#[derive(Serialize)]
struct SizeReport {
    samples: usize,
    nrtt_min_s: f64,
    nrtt_max_s: f64,
    nrtt_mean_s: f64,
    mt_s: f64,
    period_s: f64,
    eta: f64,
    ns: usize,
    suggested_period_s: f64,
    suggested_ns: usize,
}

pub fn run(args: &SizeArgs) -> Result<(), String> {
    let law = Sizing::new(args.eta, millis("--min-period-ms", args.min_period_ms)?)
        .map_err(|e| e.to_string())?;
    let period = millis("--period-ms", args.period_ms)?;
    if period.is_zero() {
        return Err("--period-ms must be positive".into());
    }
    let mut pattern: InitPattern = InitPattern::new();
    for &ms in &args.nrtt_ms {
        pattern
            .record_nrtt(millis("--nrtt-ms", ms)?)
            .map_err(|_| format!("--nrtt-ms takes at most {INIT_EXCHANGES} values"))?;
    }
    let stats = pattern
        .stats()
        .ok_or("--nrtt-ms needs at least one value")?;
    let suggested = law.period(stats.nrtt_mean);
    let report = SizeReport {
        samples: stats.samples,
        nrtt_min_s: stats.nrtt_min.as_secs_f64(),
        nrtt_max_s: stats.nrtt_max.as_secs_f64(),
        nrtt_mean_s: stats.nrtt_mean.as_secs_f64(),
        mt_s: stats.mt.as_secs_f64(),
        period_s: period.as_secs_f64(),
        eta: law.eta(),
        ns: law.nominal_size(stats.mt, period),
        suggested_period_s: suggested.as_secs_f64(),
        suggested_ns: law.nominal_size(stats.mt, suggested),
    };
    if args.json {
        println!(
            "{}",
            serde_json::to_string(&report).map_err(|e| e.to_string())?
        );
    } else {
        println!("initialization pattern: {} round trips", report.samples);
        println!(
            "  NRTT min / mean / max  {} / {} / {}",
            stats.nrtt_min, stats.nrtt_mean, stats.nrtt_max
        );
        println!("  mt (max − min NRTT)    {}", stats.mt);
        println!("at T = {period}:            ns = {}", report.ns);
        println!(
            "period law max(T_min, NRTT/3) = {suggested}: ns = {}",
            report.suggested_ns
        );
    }
    Ok(())
}
