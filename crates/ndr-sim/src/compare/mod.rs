//! The comparison harness: playout policies side by side on the same traces,
//! beside the oracle (`ndr compare`).
//!
//! Every policy runs in the full simulator (both endpoints, the protocol,
//! in-order delivery) on every family of traces, with the same seeds: all
//! policies of a family see the same forward delays (the paper's dynamic
//! mode changes the period, and so its send times). Every regulator drops
//! late samples ([`Underflow::DropLate`]): a tick whose sample is missing
//! repeats the last one; [`CompareConfig::underflow`] can hold them
//! instead, as the paper's NDR does (nothing is late, the delay
//! stretches). The commands (base → remote) are measured, on the remote's
//! clock against the base's send stamps.
//!
//! Per run: the commands sent until [`MARGIN`] before the end (so that each
//! has had its chance to be released) are the run's samples. Their
//! end-to-end delay (release − send) gives the mean, standard deviation and
//! 99th percentile; `late_rate` is the share never released fresh (late,
//! skipped when a target fell, or discarded by a pause); `underflows` counts
//! the remote's repeat ticks; `delay_changes` the releases whose delay
//! differs from the previous release's by more than half a period;
//! `recovery_s` the mean, over the family's events, of the time from an
//! onset to the send time of the last sample lost within
//! [`RECOVERY_HORIZON`] (or the next onset), plus one period (0 when none is
//! lost). The oracle's ratio is the run's mean delay over the
//! [`Oracle::constant`] mean delay at the run's own late rate, on the run's
//! own trace, on the grid of the steps its delay can take ([`oracle_grid`]);
//! the piecewise ratio the same over [`Oracle::piecewise`], the hull ratio
//! over [`Oracle::hull`] (two constant targets time-shared).
//!
//! Across seeds: the mean and the half-width of its 95 % confidence interval
//! (Student's t).

mod families;
mod matched;

use std::string::{String, ToString};
use std::vec::Vec;

use ndr_core::Regulation;
use ndr_core::endpoint::{Mode, Underflow};
use ndr_core::playout::{Playout, delay_quantum};
use ndr_core::time::{Duration, Instant};
use serde::Serialize;

pub use families::{
    FAMILY_DURATION, Family, NETEM_MEAN, NETEM_STD, NETEM_TABLES, SKEW_DURATION, TC_DIRS, WAN,
    builtin, netem, trace,
};
pub use matched::{
    BRACKET, MATCH_PROBES, Matched, MatchedSeed, OneEpsilon, Probe, Runs, STRIDE, SeedMatches,
    match_seed, matched_quantum, search,
};

use super::engine::{ForwardLog, SimConfig, run};
use super::oracle::{Arrival, Oracle, OraclePoint};
use super::percentile;

/// The period of the comparison: 20 ms (50 Hz).
pub const COMPARE_PERIOD: Duration = Duration::from_millis(20);
/// Commands sent in the last `MARGIN` of a run are not measured.
pub const MARGIN: Duration = Duration::from_secs(10);
/// Longest time after an event in which a loss counts towards its recovery.
pub const RECOVERY_HORIZON: f64 = 30.0;
/// The oracle rows' late rate.
pub const DEFAULT_EPSILON: f64 = 0.01;
/// The piecewise oracle's window.
pub const DEFAULT_WINDOW: Duration = Duration::from_secs(10);
/// The version of the JSON report's layout.
pub const SCHEMA: &str = "ndr-compare/2";

/// The regulations `ndr compare` runs by default: every one the playout
/// registry names by a bare name ([`Regulation::every`]): the paper's two
/// modes, the classic target-delay playouts, and ndr's adaptive one.
#[must_use]
pub fn default_regulations() -> Vec<Regulation> {
    Regulation::every().collect()
}

/// What to compare.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct CompareConfig {
    /// The families of traces.
    pub families: Vec<Family>,
    /// The regulations, in the order of the report.
    pub regulations: Vec<Regulation>,
    /// Seeds `1..=seeds` for seeded families.
    pub seeds: u64,
    /// The period.
    pub period: Duration,
    /// The oracle rows' late rate.
    pub epsilon: f64,
    /// The piecewise oracle's window.
    pub window: Duration,
    /// Worker threads.
    pub threads: usize,
    /// Also match the adaptive policy's late rate to each paper mode's
    /// (the report's `matched`; costs up to [`MATCH_PROBES`] adaptive runs
    /// per paper run).
    pub matched: bool,
    /// What every regulator does with a late sample: [`Underflow::DropLate`]
    /// by default (a constant delay, a late sample lost); under
    /// [`Underflow::Hold`] nothing is lost and the delay stretches instead,
    /// so late rates are not comparable and `matched` is not run.
    pub underflow: Underflow,
}

impl CompareConfig {
    /// Every default regulation on `families`, 10 seeds, `T = 20 ms`, two threads.
    #[must_use]
    pub fn new(families: Vec<Family>) -> Self {
        CompareConfig {
            families,
            regulations: default_regulations(),
            seeds: 10,
            period: COMPARE_PERIOD,
            epsilon: DEFAULT_EPSILON,
            window: DEFAULT_WINDOW,
            threads: 2,
            matched: false,
            underflow: Underflow::DropLate,
        }
    }
}

/// A mean over runs and the half-width of its 95 % confidence interval.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Stat {
    /// The mean.
    pub mean: f64,
    /// Half-width of the 95 % confidence interval (0 for a single run).
    pub ci95: f64,
}

/// Student's t quantile 0.975 for 1..=30 degrees of freedom.
const T975: [f64; 30] = [
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
    2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
    2.052, 2.048, 2.045, 2.042,
];

impl Stat {
    /// Mean and 95 % half-width of `xs` (zeros when empty).
    #[must_use]
    pub fn of(xs: &[f64]) -> Stat {
        let n = xs.len();
        if n == 0 {
            return Stat {
                mean: 0.0,
                ci95: 0.0,
            };
        }
        let mean = xs.iter().sum::<f64>() / n as f64;
        if n == 1 {
            return Stat { mean, ci95: 0.0 };
        }
        let var = xs.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / (n - 1) as f64;
        let t = T975.get(n - 2).copied().unwrap_or(1.96);
        Stat {
            mean,
            ci95: t * (var / n as f64).sqrt(),
        }
    }

    /// [`Stat::of`] a measure every run has; `None` if one lacks it or
    /// there is no run.
    #[must_use]
    pub fn of_all(xs: impl IntoIterator<Item = Option<f64>>) -> Option<Stat> {
        let xs: Vec<f64> = xs.into_iter().collect::<Option<_>>()?;
        (!xs.is_empty()).then(|| Stat::of(&xs))
    }
}

/// One run's measures (see the module docs). Times in seconds.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RunMetrics {
    /// Samples measured.
    pub samples: usize,
    /// Mean end-to-end delay of the samples released fresh.
    pub mean_delay_s: f64,
    /// Their standard deviation.
    pub std_delay_s: f64,
    /// Their 99th percentile.
    pub p99_delay_s: f64,
    /// Samples never released fresh / samples.
    pub late_rate: f64,
    /// Repeat ticks.
    pub underflows: f64,
    /// Releases whose delay changed by more than half a period.
    pub delay_changes: f64,
    /// Mean recovery time after the family's events; `None` without events.
    pub recovery_s: Option<f64>,
    /// Mean delay / the constant oracle's at the same late rate.
    pub oracle_ratio: f64,
    /// Mean delay / the piecewise oracle's at the same late rate.
    pub piecewise_ratio: f64,
    /// Mean delay / the constant oracle's convex envelope (time-sharing two
    /// constant targets) at the same late rate.
    pub hull_ratio: f64,
    /// Mean delay / the split oracle's ([`Oracle::split`], one constant
    /// before the family's first event, another after) at the same late
    /// rate; `None` without events.
    pub split_ratio: Option<f64>,
}

/// One sample's fate: its send time and, if released fresh, its delay (s).
type Fate = (f64, Option<f64>);

fn metrics(fates: &[Fate], underflows: usize, period_s: f64, events: &[f64]) -> RunMetrics {
    let delays: Vec<f64> = fates.iter().filter_map(|f| f.1).collect();
    let n = fates.len();
    let mean = if delays.is_empty() {
        0.0
    } else {
        delays.iter().sum::<f64>() / delays.len() as f64
    };
    let var = if delays.is_empty() {
        0.0
    } else {
        delays.iter().map(|d| (d - mean) * (d - mean)).sum::<f64>() / delays.len() as f64
    };
    let changes = delays
        .windows(2)
        .filter(|w| matches!(w, [a, b] if (b - a).abs() > period_s / 2.0))
        .count();
    let recovery = (!events.is_empty()).then(|| {
        let total: f64 = events
            .iter()
            .enumerate()
            .map(|(i, &onset)| {
                let next = events.get(i + 1).copied().unwrap_or(f64::INFINITY);
                let end = next.min(onset + RECOVERY_HORIZON);
                fates
                    .iter()
                    .filter(|(s, d)| d.is_none() && *s >= onset && *s < end)
                    .map(|(s, _)| s - onset + period_s)
                    .fold(0.0, f64::max)
            })
            .sum();
        total / events.len() as f64
    });
    RunMetrics {
        samples: n,
        mean_delay_s: mean,
        std_delay_s: var.sqrt(),
        p99_delay_s: percentile(&delays, 0.99),
        late_rate: if n == 0 {
            0.0
        } else {
            (n - delays.len()) as f64 / n as f64
        },
        underflows: underflows as f64,
        delay_changes: changes as f64,
        recovery_s: recovery,
        oracle_ratio: 1.0,
        piecewise_ratio: 1.0,
        hull_ratio: 1.0,
        split_ratio: (!events.is_empty()).then_some(1.0),
    }
}

fn ratio(a: f64, b: f64) -> f64 {
    if b > 0.0 { a / b } else { 1.0 }
}

/// A run measured: the regulation's metrics, and the trace's oracle.
#[derive(Clone, Debug)]
pub struct Measured {
    /// The regulation's metrics.
    pub metrics: RunMetrics,
    /// The oracle of the run's own trace.
    pub oracle: Oracle,
    /// Fresh releases among the measured samples.
    pub released: usize,
}

/// The grid of the target-delay and paper policies' oracle: the period up
/// to 20 ms, a fraction of it beyond.
const ORACLE_GRID: Duration = Duration::from_millis(20);

/// The grid the oracle of `regulation`'s runs is computed on: the step its
/// delay can take. The adaptive playout's quantum (it releases between
/// ticks, its delay in steps of a millisecond by default), else
/// `T/⌈T/20 ms⌉`.
#[must_use]
pub fn oracle_grid(regulation: Regulation, period: Duration) -> Duration {
    match regulation.playout() {
        Playout::Adaptive { quantum, .. } => delay_quantum(period, quantum),
        _ => delay_quantum(period, Some(ORACLE_GRID)),
    }
}

/// Measures a run from its log of commands, the oracle on the grid
/// `T/⌈T/20 ms⌉` (see [`oracle_grid`]).
#[must_use]
pub fn measure(
    log: &ForwardLog,
    end: Instant,
    times: (Duration, Duration),
    family: &Family,
) -> Measured {
    let grid = delay_quantum(times.0, Some(ORACLE_GRID));
    measure_on(log, end, times, family, grid)
}

fn measure_on(
    log: &ForwardLog,
    end: Instant,
    (period, window): (Duration, Duration),
    family: &Family,
    grid: Duration,
) -> Measured {
    let until = end - MARGIN;
    let kept: Vec<_> = log.samples.iter().filter(|c| c.sent_at <= until).collect();
    let fates: Vec<Fate> = kept
        .iter()
        .map(|c| {
            let delay = c.released_at.map(|r| (r - c.sent_at).as_secs_f64());
            (c.sent_at.as_secs_f64(), delay)
        })
        .collect();
    let first = kept.first().map_or(Instant::ZERO, |c| c.sent_at);
    let underflows = log
        .held
        .iter()
        .filter(|&&t| t >= first && t <= until)
        .count();
    let period_s = period.as_secs_f64();
    let mut m = metrics(&fates, underflows, period_s, &family.events_s);
    let arrivals: Vec<Arrival> = kept
        .iter()
        .map(|c| Arrival {
            sent_at: c.sent_at,
            arrived_at: c.arrived_at,
        })
        .collect();
    let oracle = Oracle::new(&arrivals, Instant::ZERO, grid);
    m.oracle_ratio = ratio(m.mean_delay_s, oracle.constant(m.late_rate).mean_delay_s);
    m.piecewise_ratio = ratio(
        m.mean_delay_s,
        oracle.piecewise(m.late_rate, window).mean_delay_s,
    );
    m.hull_ratio = ratio(m.mean_delay_s, oracle.hull(m.late_rate));
    m.split_ratio = family.events_s.first().map(|&first| {
        let at = Instant::from_secs_f64(first);
        ratio(m.mean_delay_s, oracle.split(m.late_rate, at).mean_delay_s)
    });
    let released = fates.iter().filter(|f| f.1.is_some()).count();
    Measured {
        metrics: m,
        oracle,
        released,
    }
}

/// The metrics of an oracle's point on a trace (as a regulation's row).
fn oracle_metrics(o: &OraclePoint, samples: usize, family: &Family) -> RunMetrics {
    let lost = (o.late_rate * samples as f64).round();
    RunMetrics {
        samples,
        mean_delay_s: o.mean_delay_s,
        std_delay_s: 0.0,
        p99_delay_s: o.mean_delay_s,
        late_rate: o.late_rate,
        underflows: lost,
        delay_changes: 0.0,
        recovery_s: (!family.events_s.is_empty()).then_some(f64::NAN),
        oracle_ratio: 1.0,
        piecewise_ratio: 1.0,
        hull_ratio: 1.0,
        split_ratio: (!family.events_s.is_empty()).then_some(1.0),
    }
}

/// The simulation of one regulation on one family and seed, dropping late
/// samples (the comparison's default).
#[must_use]
pub fn sim_config(
    family: &Family,
    regulation: Regulation,
    seed: u64,
    period: Duration,
) -> SimConfig {
    sim_config_under(family, regulation, seed, period, Underflow::DropLate)
}

/// [`sim_config`] under the given [`Underflow`] policy (`hold`: the paper's
/// FIFO keeps every sample and its delay grows at each underflow; a target
/// policy releases a late sample at the next release).
#[must_use]
pub fn sim_config_under(
    family: &Family,
    regulation: Regulation,
    seed: u64,
    period: Duration,
    underflow: Underflow,
) -> SimConfig {
    let mut cfg = SimConfig::paper(family.model.clone());
    cfg.loss = family.loss;
    cfg.transport = family.transport;
    cfg.mode = regulation.mode();
    cfg.playout = regulation.playout();
    cfg.underflow = underflow;
    cfg.period = period;
    cfg.duration = family.duration;
    cfg.seed = seed;
    cfg.remote_skew_ppm = family.skew_ppm;
    cfg.record_forward = true;
    cfg
}

/// Runs and measures one regulation on one family and seed.
///
/// # Errors
///
/// The simulator's error, as text.
pub fn run_one(
    family: &Family,
    regulation: Regulation,
    seed: u64,
    times: (Duration, Duration),
) -> Result<Measured, String> {
    run_one_under(family, regulation, seed, times, Underflow::DropLate)
}

/// [`run_one`] under the given [`Underflow`] policy.
///
/// # Errors
///
/// The simulator's error, as text.
pub fn run_one_under(
    family: &Family,
    regulation: Regulation,
    seed: u64,
    (period, window): (Duration, Duration),
    underflow: Underflow,
) -> Result<Measured, String> {
    let cfg = sim_config_under(family, regulation, seed, period, underflow);
    let out = run(&cfg).map_err(|e| e.to_string())?;
    Ok(measure_on(
        &out.forward,
        Instant::ZERO + family.duration,
        (period, window),
        family,
        oracle_grid(regulation, period),
    ))
}

/// A point for the delay / late-rate plot.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Point {
    /// Mean end-to-end delay over the seeds, s.
    pub mean_delay_s: f64,
    /// Late rate over the seeds.
    pub late_rate: f64,
}

/// A regulation's (or an oracle's) results on one family.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RegulationResult {
    /// Its name.
    pub regulation: String,
    /// Runs measured.
    pub runs: usize,
    /// Runs that failed (their errors in the report's notes).
    pub failed: usize,
    /// Mean end-to-end delay, s.
    pub mean_delay_s: Stat,
    /// Standard deviation of the end-to-end delay within a run, s.
    pub std_delay_s: Stat,
    /// 99th percentile of the end-to-end delay, s.
    pub p99_delay_s: Stat,
    /// Samples never released fresh / samples.
    pub late_rate: Stat,
    /// Repeat ticks per run.
    pub underflows: Stat,
    /// Changes of delay per run.
    pub delay_changes: Stat,
    /// Recovery after an event, s; `null` for families without events
    /// and for the oracles.
    pub recovery_s: Option<Stat>,
    /// Mean delay / the constant oracle's at the same late rate.
    pub oracle_ratio: Stat,
    /// Mean delay / the piecewise oracle's at the same late rate.
    pub piecewise_ratio: Stat,
    /// Mean delay / the constant oracle's convex envelope at the same late rate.
    pub hull_ratio: Stat,
    /// Mean delay / the split oracle's at the same late rate; `null` for
    /// families without events.
    pub split_ratio: Option<Stat>,
    /// The plot's point: (mean delay, late rate) averaged over seeds.
    pub point: Point,
}

impl RegulationResult {
    fn of(regulation: String, runs: &[RunMetrics], failed: usize) -> Self {
        let stat =
            |f: &dyn Fn(&RunMetrics) -> f64| Stat::of(&runs.iter().map(f).collect::<Vec<f64>>());
        let recovery: Vec<f64> = runs
            .iter()
            .filter_map(|r| r.recovery_s)
            .filter(|x| x.is_finite())
            .collect();
        let mean_delay_s = stat(&|r| r.mean_delay_s);
        let late_rate = stat(&|r| r.late_rate);
        RegulationResult {
            regulation,
            runs: runs.len(),
            failed,
            mean_delay_s,
            std_delay_s: stat(&|r| r.std_delay_s),
            p99_delay_s: stat(&|r| r.p99_delay_s),
            late_rate,
            underflows: stat(&|r| r.underflows),
            delay_changes: stat(&|r| r.delay_changes),
            recovery_s: (!recovery.is_empty()).then(|| Stat::of(&recovery)),
            oracle_ratio: stat(&|r| r.oracle_ratio),
            piecewise_ratio: stat(&|r| r.piecewise_ratio),
            hull_ratio: stat(&|r| r.hull_ratio),
            split_ratio: Stat::of_all(runs.iter().map(|r| r.split_ratio)),
            point: Point {
                mean_delay_s: mean_delay_s.mean,
                late_rate: late_rate.mean,
            },
        }
    }
}

/// Every regulation's results on one family.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FamilyResult {
    /// The family's name.
    pub name: String,
    /// What it is.
    pub description: String,
    /// Simulated time per run, s.
    pub duration_s: f64,
    /// Runs per regulation (seeds).
    pub seeds: u64,
    /// Onsets of the events whose recovery is measured, s.
    pub events_s: Vec<f64>,
    /// The regulations, in the order asked, then `oracle` and
    /// `oracle-piecewise` at the report's `epsilon`.
    pub regulations: Vec<RegulationResult>,
}

/// The whole comparison: what `ndr compare --json` prints.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[non_exhaustive]
pub struct CompareReport {
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// The period, s.
    pub period_s: f64,
    /// Seeds per seeded family.
    pub seeds: u64,
    /// The oracle rows' late rate.
    pub epsilon: f64,
    /// What the regulators did with a late sample: `drop-late` or `hold`.
    pub underflow: &'static str,
    /// The piecewise oracle's window, s.
    pub window_s: f64,
    /// Commands sent in the last `margin_s` of a run are not measured.
    pub margin_s: f64,
    /// The regulations' names, in order (the oracles excluded).
    pub regulations: Vec<String>,
    /// One entry per family.
    pub families: Vec<FamilyResult>,
    /// The late-rate-matched comparison ([`CompareConfig::matched`]): per
    /// family, the adaptive policy against each paper mode asked for.
    /// Absent from the JSON when not asked.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub matched: Vec<Matched>,
    /// Families skipped, runs failed.
    pub notes: Vec<String>,
}

type Job = (usize, Regulation, u64);
type Outcome = Result<(RunMetrics, Option<[RunMetrics; 2]>), String>;

fn job_outcome(
    cfg: &CompareConfig,
    (f, regulation, seed): Job,
    oracle_of: Option<Regulation>,
) -> Outcome {
    let family = cfg.families.get(f).ok_or("no such family")?;
    let m = run_one_under(
        family,
        regulation,
        seed,
        (cfg.period, cfg.window),
        cfg.underflow,
    )?;
    let oracles = (oracle_of == Some(regulation)).then(|| {
        let n = m.oracle.len();
        [
            oracle_metrics(&m.oracle.constant(cfg.epsilon), n, family),
            oracle_metrics(&m.oracle.piecewise(cfg.epsilon, cfg.window), n, family),
        ]
    });
    Ok((m.metrics, oracles))
}

/// `f(i)` for every `i` of `order` (taken in that order) on `threads`
/// workers; slot `i` of the result holds `f(i)` (`None` where `f` gave none
/// or `i` was not in `order`). The result does not depend on `threads`.
fn parallel<T: Send>(
    threads: usize,
    order: &[usize],
    f: impl Fn(usize) -> Option<T> + Sync,
) -> Vec<Option<T>> {
    use std::sync::atomic::{AtomicUsize, Ordering};
    let next = AtomicUsize::new(0);
    let len = order.iter().max().map_or(0, |&m| m + 1);
    let mut out: Vec<Option<T>> = (0..len).map(|_| None).collect();
    std::thread::scope(|scope| {
        let workers: Vec<_> = (0..threads.max(1))
            .map(|_| {
                scope.spawn(|| {
                    let mut done = Vec::new();
                    loop {
                        let k = next.fetch_add(1, Ordering::Relaxed);
                        let Some(&i) = order.get(k) else { break };
                        if let Some(o) = f(i) {
                            done.push((i, o));
                        }
                    }
                    done
                })
            })
            .collect();
        for w in workers {
            if let Ok(done) = w.join() {
                for (i, o) in done {
                    if let Some(slot) = out.get_mut(i) {
                        *slot = Some(o);
                    }
                }
            }
        }
    });
    out
}

/// Runs the comparison. Deterministic: the same configuration gives the
/// same report, whatever the number of threads.
#[must_use]
pub fn compare(cfg: &CompareConfig) -> CompareReport {
    // The oracle rows come from a static-mode run: its trace is the one
    // every target policy saw.
    let oracle_of = cfg
        .regulations
        .iter()
        .copied()
        .find(|r| r.mode() == Mode::PaperStatic)
        .or(cfg.regulations.first().copied());
    let mut jobs: Vec<Job> = Vec::new();
    for (f, family) in cfg.families.iter().enumerate() {
        let seeds = if family.seeded { cfg.seeds.max(1) } else { 1 };
        for seed in 1..=seeds {
            for &r in &cfg.regulations {
                jobs.push((f, r, seed));
            }
        }
    }
    // Longest first, so that two workers finish together.
    let mut order: Vec<usize> = (0..jobs.len()).collect();
    order.sort_by_key(|&i| {
        let f = jobs.get(i).map_or(0, |j| j.0);
        core::cmp::Reverse(cfg.families.get(f).map_or(0, |fam| fam.duration.as_nanos()))
    });
    let outcomes = parallel(cfg.threads, &order, |i| {
        jobs.get(i).map(|&job| job_outcome(cfg, job, oracle_of))
    });
    let matching = cfg.matched && cfg.underflow == Underflow::DropLate;
    let matched = if matching {
        matched::match_all(cfg, &jobs, &outcomes)
    } else {
        Vec::new()
    };
    let mut notes = Vec::new();
    if cfg.matched && !matching {
        notes.push(
            "--matched: not run under hold, where no sample is late (each stretches the delay \
             instead); run it under drop-late"
                .to_string(),
        );
    }
    if cfg.matched && !cfg.regulations.iter().any(|r| r.is_paper()) {
        notes.push("--matched: no paper mode among the regulations, nothing matched".to_string());
    }
    if let (true, Some(q)) = (matching, matched::matched_quantum(&cfg.regulations)) {
        notes.push(std::format!(
            "--matched: the adaptive policy searched is the first one asked for, its delay in \
             steps of {:.3} ms",
            delay_quantum(cfg.period, Some(q)).as_secs_f64() * 1e3
        ));
    }
    let families = cfg
        .families
        .iter()
        .enumerate()
        .map(|(f, family)| {
            let of_family = |p: Regulation| {
                jobs.iter()
                    .zip(&outcomes)
                    .filter(move |((jf, jp, _), _)| *jf == f && *jp == p)
            };
            let mut regulations = Vec::new();
            let mut oracle_rows: [Vec<RunMetrics>; 2] = [Vec::new(), Vec::new()];
            for &p in &cfg.regulations {
                let mut runs = Vec::new();
                let mut failed = 0;
                for ((_, _, seed), o) in of_family(p) {
                    match o {
                        Some(Ok((m, oracles))) => {
                            runs.push(*m);
                            if let Some([c, w]) = oracles {
                                oracle_rows[0].push(*c);
                                oracle_rows[1].push(*w);
                            }
                        }
                        Some(Err(e)) => {
                            failed += 1;
                            notes.push(std::format!("{} / {} / seed {seed}: {e}", family.name, p));
                        }
                        None => failed += 1,
                    }
                }
                regulations.push(RegulationResult::of(p.to_string(), &runs, failed));
            }
            for (name, runs) in ["oracle", "oracle-piecewise"].iter().zip(&oracle_rows) {
                regulations.push(RegulationResult::of(name.to_string(), runs, 0));
            }
            FamilyResult {
                name: family.name.clone(),
                description: family.description.clone(),
                duration_s: family.duration.as_secs_f64(),
                seeds: if family.seeded { cfg.seeds.max(1) } else { 1 },
                events_s: family.events_s.clone(),
                regulations,
            }
        })
        .collect();
    CompareReport {
        schema: SCHEMA,
        period_s: cfg.period.as_secs_f64(),
        seeds: cfg.seeds,
        epsilon: cfg.epsilon,
        underflow: cfg.underflow.name(),
        window_s: cfg.window.as_secs_f64(),
        margin_s: MARGIN.as_secs_f64(),
        regulations: cfg.regulations.iter().map(ToString::to_string).collect(),
        families,
        matched,
        notes,
    }
}
