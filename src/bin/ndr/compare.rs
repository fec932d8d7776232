//! `ndr compare`: every regulation on the same traces, beside the oracle.

use std::path::PathBuf;
use std::time::Instant as WallClock;

use ndr::core::Regulation;
use ndr::core::endpoint::Underflow;
use ndr::core::time::Duration;
use ndr::sim::compare::{
    self, CompareConfig, CompareReport, Family, Matched, RegulationResult, Stat, TC_DIRS,
};

use crate::args::millis;

/// `--duration-s`'s range: runs measure all but their last 10 s; an hour
/// at most bounds a run's memory, as the simulator logs every command (at
/// T = 1 ms, 3.6 M of them, about 150 MB per run).
const MIN_DURATION_S: f64 = 20.0;
const MAX_DURATION_S: f64 = 3_600.0;

/// The layout of `ndr compare --json`, shown by `ndr compare --help`.
const JSON_HELP: &str = "\
JSON (--json): one object, schema \"ndr-compare/2\":
  { schema, period_s, seeds, epsilon, underflow, window_s, margin_s,
    regulations: [name, ...],
    families: [ { name, description, duration_s, seeds, events_s: [s, ...],
                  regulations: [ { regulation, runs, failed,
                                mean_delay_s, std_delay_s, p99_delay_s, late_rate,
                                underflows, delay_changes, oracle_ratio, piecewise_ratio,
                                hull_ratio: {mean, ci95},
                                recovery_s, split_ratio: {mean, ci95} or null,
                                point: {mean_delay_s, late_rate} } ] } ],
    matched: [ { family, against, seeds, paper_failed, matched, wins, win,
                 paper_delay_s, paper_late_rate, adaptive_delay_s,
                 adaptive_late_rate, epsilon, delay_gain_s: {mean, ci95},
                 paper_split_ratio: {mean, ci95} or null,
                 one_epsilon: { epsilon, adaptive_delay_s, adaptive_late_rate,
                                win } or null,
                 adaptive_runs,
                 runs: [ { seed, paper_delay_s, paper_late_rate,
                           paper_split_ratio (or null), win,
                           adaptive: {epsilon, mean_delay_s, late_rate} or null } ] } ]
             (only with --matched),
    notes: [text, ...] }
Each family lists the regulations asked for, then `oracle` and `oracle-piecewise`
at `epsilon`. `mean` is over seeds, `ci95` the half-width of its 95 % confidence
interval. Delays are end-to-end (release at the remote - send at the base), in
seconds; `late_rate` counts every sample never released fresh; `point` is the
(delay, late rate) point to plot. With --matched, per family and paper mode
asked for: the adaptive policy's lowest delay at a late rate <= the paper run's,
per seed (ε searched on the same seed); `delay_gain_s` = paper delay - adaptive
delay, paired per matched seed; `win` = a match on every seed and a lower mean
delay; `paper_split_ratio` = the paper run's delay / the split oracle's at its
late rate (one constant delay before the family's first event, one after, in
hindsight), the room a policy that learns at the first event has;
`one_epsilon`: one ε for all those seeds, the lowest mean delay at a mean late
rate <= the paper mode's. docs/algorithms.md §9 defines every measure.";

#[derive(clap::Args)]
#[command(after_long_help = JSON_HELP)]
pub struct CompareArgs {
    /// Delay trace files (CSV `t_s,fwd_ms,bwd_ms`, or links' MCAP
    /// recordings: their measured one-way delays) to compare on, each a
    /// family of one run, instead of the built-in families.
    #[arg(long, value_name = "FILES", num_args = 1..)]
    pub traces: Vec<PathBuf>,
    /// Built-in families to run (repeatable; default all): paris-newyork,
    /// lan-75km, paper-fig6, step, spikes, tcp-stall, skew+100ppm,
    /// skew-100ppm, route-flap, lan-75km-loss1, lan-75km-loss3, wan-bursts (and the
    /// three lossy ones over datagrams: NAME/datagram), netem-normal,
    /// netem-pareto, netem-paretonormal, netem-experimental.
    #[arg(long = "family", value_name = "NAME")]
    pub families: Vec<String>,
    #[arg(
        long = "regulation",
        value_name = "NAME",
        help = format!(
            "Regulations to run (repeatable; default each one named without a value): {}",
            Regulation::names(None)
        )
    )]
    pub regulations: Vec<String>,
    /// Seeds per family (1..=N).
    #[arg(long, default_value_t = 10)]
    pub seeds: u64,
    /// The period, in ms.
    #[arg(long, default_value_t = 20.0)]
    pub period_ms: f64,
    /// The oracle rows' late rate.
    #[arg(long, default_value_t = compare::DEFAULT_EPSILON)]
    pub epsilon: f64,
    /// The piecewise oracle's window, in seconds.
    #[arg(long, default_value_t = 10.0)]
    pub window_s: f64,
    /// Simulated time of every family's runs, in seconds (default: each
    /// family's own, 120 s; 300 s for the skew families, 1200 s for
    /// paper-fig6). The event families' events recur until then; the last
    /// 10 s of a run are not measured.
    #[arg(long, value_name = "SECONDS")]
    pub duration_s: Option<f64>,
    /// Where to look for iproute2's netem tables (repeatable; default the
    /// usual places).
    #[arg(long, value_name = "DIR")]
    pub tc_dir: Vec<PathBuf>,
    /// Worker threads (default: the machine's cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Also compare the adaptive policy with each paper mode asked for at an
    /// equal or lower late rate, per seed (ε searched by bisection, up to 16
    /// adaptive runs per paper run; in the steps of the first
    /// `adaptive:PERCENT:QUANTUM_MS` asked for, if any).
    #[arg(long)]
    pub matched: bool,
    /// What every regulator does with a late sample: drop-late (a constant
    /// delay; the sample is lost) or hold (the paper's FIFO: nothing is
    /// lost, the delay stretches; no late rate to match, so not with
    /// --matched).
    #[arg(long, default_value = "drop-late")]
    pub underflow: Underflow,
    /// Print one JSON object instead of the tables.
    #[arg(long)]
    pub json: bool,
}

fn regulation(name: &str) -> Result<Regulation, String> {
    name.parse::<Regulation>()
        .map_err(|e| format!("regulation `{name}`: {e}"))
}

fn families(args: &CompareArgs) -> Result<(Vec<Family>, Vec<String>), String> {
    if !args.traces.is_empty() {
        let mut out = Vec::new();
        for path in &args.traces {
            let t = crate::args::delay::trace(path)?;
            let name = path.file_stem().map_or_else(
                || path.display().to_string(),
                |s| s.to_string_lossy().into(),
            );
            out.push(compare::trace(&name, t));
        }
        return Ok((out, Vec::new()));
    }
    let dirs: Vec<PathBuf> = if args.tc_dir.is_empty() {
        TC_DIRS.iter().map(PathBuf::from).collect()
    } else {
        args.tc_dir.clone()
    };
    let (netem, mut notes) = compare::netem(&dirs);
    let mut all = compare::builtin();
    all.extend(netem);
    if args.families.is_empty() {
        return Ok((all, notes));
    }
    let mut chosen = Vec::new();
    let mut kept = Vec::new();
    for name in &args.families {
        if let Some(f) = all.iter().find(|f| &f.name == name) {
            chosen.push(f.clone());
        } else if let Some(n) = notes.iter().find(|n| n.starts_with(&format!("{name} "))) {
            // A netem table this machine lacks: a note, not an error.
            kept.push(n.clone());
        } else {
            let known: Vec<&str> = all.iter().map(|f| f.name.as_str()).collect();
            return Err(format!(
                "unknown family `{name}`; valid: {}",
                known.join(", ")
            ));
        }
    }
    notes = kept;
    Ok((chosen, notes))
}

pub fn run(args: &CompareArgs) -> Result<(), String> {
    let period = millis("--period-ms", args.period_ms)?;
    if period < ndr::core::endpoint::MIN_PERIOD {
        return Err(format!(
            "--period-ms must be at least {}",
            ndr::core::endpoint::MIN_PERIOD
        ));
    }
    if !(0.0..=1.0).contains(&args.epsilon) {
        return Err(format!(
            "--epsilon must be a late rate in [0, 1], got {}",
            args.epsilon
        ));
    }
    if !(args.window_s.is_finite() && args.window_s > 0.0) {
        return Err(format!(
            "--window-s must be a positive number of seconds, got {}",
            args.window_s
        ));
    }
    if args.seeds == 0 {
        return Err("--seeds must be at least 1".into());
    }
    let duration = match args.duration_s {
        None => None,
        Some(s) if s.is_finite() && (MIN_DURATION_S..=MAX_DURATION_S).contains(&s) => {
            Some(Duration::from_secs_f64(s))
        }
        Some(s) => {
            return Err(format!(
                "--duration-s must be {MIN_DURATION_S} to {MAX_DURATION_S} seconds (the last \
                 10 s of a run are not measured), got {s}"
            ));
        }
    };
    if args.matched && args.underflow == Underflow::Hold {
        return Err(
            "--matched compares late rates, and under --underflow hold no sample is \
                    late (each stretches the delay instead): drop one of the two"
                .into(),
        );
    }
    let (mut families, skipped) = families(args)?;
    if let Some(d) = duration {
        families = families.into_iter().map(|f| f.with_duration(d)).collect();
    }
    let mut cfg = CompareConfig::new(families);
    if !args.regulations.is_empty() {
        cfg.regulations = args
            .regulations
            .iter()
            .map(|r| regulation(r))
            .collect::<Result<_, _>>()?;
    }
    cfg.seeds = args.seeds;
    cfg.period = period;
    cfg.epsilon = args.epsilon;
    cfg.window = Duration::from_secs_f64(args.window_s);
    cfg.matched = args.matched;
    cfg.underflow = args.underflow;
    cfg.threads = args.threads.unwrap_or_else(|| {
        std::thread::available_parallelism().map_or(2, std::num::NonZeroUsize::get)
    });
    let started = WallClock::now();
    let mut report = compare::compare(&cfg);
    let mut notes = skipped;
    notes.append(&mut report.notes);
    report.notes = notes;
    if args.json {
        println!(
            "{}",
            serde_json::to_string(&report).map_err(|e| e.to_string())?
        );
    } else {
        print_tables(&report);
    }
    eprintln!(
        "ndr compare: {} families × {} regulations in {:.1} s ({} threads)",
        report.families.len(),
        report.regulations.len(),
        started.elapsed().as_secs_f64(),
        cfg.threads
    );
    Ok(())
}

/// A ratio's mean ± half-width.
fn ratio(s: Stat) -> String {
    format!("{:.2} ± {:.2}", s.mean, s.ci95)
}

fn ms(s: Stat) -> String {
    format!("{:.0} ± {:.0}", s.mean * 1e3, s.ci95 * 1e3)
}

fn row(p: &RegulationResult) -> String {
    let pct = |s: Stat| format!("{:.2} ± {:.2}", s.mean * 100.0, s.ci95 * 100.0);
    let num = |s: Stat| format!("{:.1} ± {:.1}", s.mean, s.ci95);
    let recovery = p.recovery_s.map_or_else(
        || "–".to_string(),
        |s| format!("{:.2} ± {:.2}", s.mean, s.ci95),
    );
    format!(
        "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
        p.regulation,
        ms(p.mean_delay_s),
        ms(p.std_delay_s),
        ms(p.p99_delay_s),
        pct(p.late_rate),
        num(p.underflows),
        num(p.delay_changes),
        recovery,
        ratio(p.oracle_ratio),
        ratio(p.hull_ratio),
        ratio(p.piecewise_ratio),
        p.split_ratio.map_or_else(|| "–".to_string(), ratio),
    )
}

/// Markdown: one table per family.
pub fn print_tables(r: &CompareReport) {
    println!(
        "T = {:.0} ms · {} seeds · {} · oracle rows at ε = {} · piecewise window {:.0} s · \
         split oracle cut at the first event · mean ± 95 % CI over seeds",
        r.period_s * 1e3,
        r.seeds,
        r.underflow,
        r.epsilon,
        r.window_s
    );
    for f in &r.families {
        println!(
            "\n**{}** — {} ({:.0} s, {} run(s))\n",
            f.name, f.description, f.duration_s, f.seeds
        );
        println!(
            "| regulation | delay ms | std ms | p99 ms | late % | underflows | changes | \
             recovery s | ÷ oracle | ÷ hull | ÷ piecewise | ÷ split |"
        );
        println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
        for p in &f.regulations {
            println!("{}", row(p));
        }
    }
    print_matched(&r.matched);
    for n in &r.notes {
        println!("\nnote: {n}");
    }
}

/// Markdown: the late-rate-matched comparison, one row per family and paper mode.
fn print_matched(matched: &[Matched]) {
    if matched.is_empty() {
        return;
    }
    println!(
        "\n**adaptive at an equal or lower late rate** — per seed, the lowest-delay \
         adaptive run (ε searched) with a late rate ≤ the paper run's; gain = paper − \
         adaptive delay, paired per seed; n.s.: its 95 % interval includes 0; paper ÷ \
         split: the paper run's delay ÷ the best two constants, before and after the \
         first event, in hindsight at its late rate\n"
    );
    println!(
        "| family | against | paper delay ms | paper late % | paper ÷ split | \
         adaptive delay ms | adaptive late % | ε % | gain ms | seeds won | wins |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    let pct = |s: Stat| format!("{:.4} ± {:.4}", s.mean * 100.0, s.ci95 * 100.0);
    for m in matched {
        let unmatched = m.seeds - m.matched;
        let adaptive = |s: String| {
            if unmatched == 0 {
                s
            } else {
                format!("{s} ({unmatched} unmatched)")
            }
        };
        println!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {}/{} | {} |",
            m.family,
            m.against,
            ms(m.paper_delay_s),
            pct(m.paper_late_rate),
            m.paper_split_ratio.map_or_else(|| "–".to_string(), ratio),
            adaptive(ms(m.adaptive_delay_s)),
            pct(m.adaptive_late_rate),
            pct(m.epsilon),
            ms(m.delay_gain_s),
            m.wins,
            m.seeds,
            match (m.win, m.delay_gain_s.mean - m.delay_gain_s.ci95 > 0.0) {
                (false, _) => "no",
                (true, true) => "yes",
                // The paired gain's 95 % interval includes 0.
                (true, false) => "yes (n.s.)",
            },
        );
    }
    println!(
        "\n**adaptive at one ε for all seeds** — the lowest mean delay at a mean late \
         rate ≤ the paper mode's\n"
    );
    println!(
        "| family | against | paper delay ms | paper late % | ε % | adaptive delay ms | adaptive late % | wins |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for m in matched {
        let (eps, delay, late, win) = m.one_epsilon.map_or_else(
            || {
                (
                    "–".to_string(),
                    "–".to_string(),
                    "–".to_string(),
                    "no (no ε)",
                )
            },
            |o| {
                (
                    format!("{:.4}", o.epsilon * 100.0),
                    ms(o.adaptive_delay_s),
                    pct(o.adaptive_late_rate),
                    if o.win { "yes" } else { "no" },
                )
            },
        );
        println!(
            "| {} | {} | {} | {} | {eps} | {delay} | {late} | {win} |",
            m.family,
            m.against,
            ms(m.paper_delay_s),
            pct(m.paper_late_rate),
        );
    }
}
