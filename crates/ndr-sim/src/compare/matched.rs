//! The late-rate-matched comparison (`ndr compare --matched`): the adaptive
//! policy against each paper mode at an equal or lower late rate.
//!
//! The adaptive policy's late rate is not its ε (far below it at a small ε,
//! with a floor where an event comes before its window has seen one, as
//! paris-newyork's first congestion episode), and a paper mode's late
//! rate varies per seed, so rows at fixed ε do not answer "lower delay at an
//! equal or lower late rate". Here, per family, seed and paper mode, the
//! paper run's late rate `L` is the limit, and ε is searched on the same
//! seed (the same delays): a bisection in log space over ε's parts per
//! million (the policy's range, 1..=500 000), starting at `L`, widening by
//! [`STRIDE`] until the limit is bracketed, then halving the bracket (in log)
//! until it is narrower than [`BRACKET`], in at most [`MATCH_PROBES`] runs.
//! The match is the run of lowest mean delay among those with a late rate
//! `≤ L`; none when no ε reaches `L`. The adaptive policy wins a seed when
//! its match's delay is below the paper run's; it wins the family when it
//! has a match on every seed where the paper mode ran and its mean delay
//! over those is below the paper mode's.
//!
//! Choosing ε per seed uses each seed's `L`, which a user does not know in
//! advance. [`OneEpsilon`] takes one ε for all the seeds instead, searched
//! the same way against the paper mode's mean late rate: the match is the
//! lowest mean delay whose mean late rate is at most the paper mode's (a
//! seed may then be above its own `L`).

use std::collections::BTreeMap;
use std::string::String;
use std::vec::Vec;

use ndr_core::Regulation;
use ndr_core::playout::Playout;
use ndr_core::time::Duration;
use serde::Serialize;

use super::{Family, RunMetrics, Stat, run_one};

/// Adaptive runs per search, at most.
pub const MATCH_PROBES: usize = 16;
/// The search widens its bracket by this factor of ε per run.
pub const STRIDE: u32 = 8;
/// The search stops when its bracket's ends are within this ratio.
pub const BRACKET: f64 = 1.02;
/// ε's range in parts per million (the policy clamps to 10⁻⁶..0.5).
const PPM: (u32, u32) = (1, 500_000);

/// One adaptive run of a search.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Probe {
    /// Its ε.
    pub epsilon: f64,
    /// Its mean end-to-end delay, s.
    pub mean_delay_s: f64,
    /// Its late rate.
    pub late_rate: f64,
}

/// The lowest-delay probe with a late rate `≤ limit`, searched as the module
/// docs say; `eval(ppm)` runs the policy at ε = `ppm`·10⁻⁶ and gives its
/// `(mean delay, late rate)` (`None`: the run failed, counted as above the
/// limit). Deterministic: the probes depend only on `limit` and `eval`.
pub fn search(limit: f64, mut eval: impl FnMut(u32) -> Option<(f64, f64)>) -> Option<Probe> {
    let (lo, hi) = PPM;
    let mut below: Option<u32> = None; // the largest ε whose run is ≤ limit
    let mut above: Option<u32> = None; // the smallest ε whose run is > limit
    let mut best: Option<Probe> = None;
    let mut ppm = ((limit * 1e6).round().max(0.0) as u32).clamp(lo, hi);
    for _ in 0..MATCH_PROBES {
        match eval(ppm) {
            Some((delay, late)) if late <= limit => {
                below = below.max(Some(ppm));
                if best.is_none_or(|b| delay < b.mean_delay_s) {
                    best = Some(Probe {
                        epsilon: f64::from(ppm) * 1e-6,
                        mean_delay_s: delay,
                        late_rate: late,
                    });
                }
            }
            _ => above = Some(above.map_or(ppm, |a| a.min(ppm))),
        }
        ppm = match (below, above) {
            (Some(b), None) if b < hi => b.saturating_mul(STRIDE).min(hi),
            (None, Some(a)) if a > lo => (a / STRIDE).max(lo),
            (Some(b), Some(a)) if f64::from(a) > f64::from(b) * BRACKET => {
                let mid = libm::sqrt(f64::from(a) * f64::from(b)).round() as u32;
                if mid <= b || mid >= a {
                    break;
                }
                mid
            }
            _ => break,
        };
    }
    best
}

/// One seed of a match.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MatchedSeed {
    /// The seed.
    pub seed: u64,
    /// The paper run's mean delay, s.
    pub paper_delay_s: f64,
    /// The paper run's late rate: the limit.
    pub paper_late_rate: f64,
    /// The paper run's delay ÷ the split oracle's at its late rate
    /// ([`RunMetrics::split_ratio`]): how much lower a delay that learns of
    /// the events at the first one could go, in hindsight; `null` for a
    /// family without events.
    pub paper_split_ratio: Option<f64>,
    /// The adaptive match; `null` when no ε reached the limit.
    pub adaptive: Option<Probe>,
    /// A match with a lower delay than the paper run's.
    pub win: bool,
}

/// The adaptive policy at one ε on every seed, against a paper mode's mean.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct OneEpsilon {
    /// The ε.
    pub epsilon: f64,
    /// Its mean delay over the seeds, s.
    pub adaptive_delay_s: Stat,
    /// Its late rate over the seeds.
    pub adaptive_late_rate: Stat,
    /// A lower mean delay than the paper mode's.
    pub win: bool,
}

/// The adaptive policy against one paper mode on one family.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Matched {
    /// The family.
    pub family: String,
    /// The paper mode.
    pub against: String,
    /// Seeds where the paper mode ran.
    pub seeds: usize,
    /// Seeds where it failed (not compared).
    pub paper_failed: usize,
    /// Seeds with an adaptive match.
    pub matched: usize,
    /// Seeds the adaptive policy wins.
    pub wins: usize,
    /// A match on every seed and a lower mean delay.
    pub win: bool,
    /// The paper mode's mean delay over its seeds, s.
    pub paper_delay_s: Stat,
    /// The paper mode's late rate.
    pub paper_late_rate: Stat,
    /// The paper runs' [`MatchedSeed::paper_split_ratio`]; `null` for a
    /// family without events.
    pub paper_split_ratio: Option<Stat>,
    /// The matches' mean delay, s (matched seeds only).
    pub adaptive_delay_s: Stat,
    /// The matches' late rate.
    pub adaptive_late_rate: Stat,
    /// The matches' ε.
    pub epsilon: Stat,
    /// The paper run's delay less the match's, per matched seed (paired:
    /// a confidence interval that excludes 0 is a significant difference), s.
    pub delay_gain_s: Stat,
    /// One ε for every seed: the lowest mean delay over the compared seeds
    /// whose mean late rate is at most the paper mode's; `null` when no ε
    /// meets it.
    pub one_epsilon: Option<OneEpsilon>,
    /// Adaptive runs made for this family (shared by its paper modes).
    pub adaptive_runs: usize,
    /// Per seed.
    pub runs: Vec<MatchedSeed>,
}

/// Adaptive runs by ε (ppm): `(mean delay, late rate)`, `None` if failed.
pub type Runs = BTreeMap<u32, Option<(f64, f64)>>;

/// What [`match_seed`] gives: the matches and the runs made.
pub type SeedMatches = (Vec<Option<MatchedSeed>>, Runs);

/// The quantum of the adaptive policy the matched comparison searches: that
/// of the first `adaptive` among `regulations` (`None`, the default, if it
/// asks for none or there is none), so that `--regulation adaptive:0.1:10
/// --matched` matches the regulation asked for.
#[must_use]
pub fn matched_quantum(regulations: &[Regulation]) -> Option<Duration> {
    regulations.iter().find_map(|p| match *p {
        Regulation::Target(Playout::Adaptive { quantum, .. }) => Some(quantum),
        _ => None,
    })?
}

/// One adaptive run of `family` at ε = `epsilon_ppm`·10⁻⁶, its delay held
/// in steps of `quantum` (`None`: the default).
fn adaptive_run(
    family: &Family,
    epsilon_ppm: u32,
    seed: u64,
    times: (Duration, Duration),
    quantum: Option<Duration>,
) -> Option<(f64, f64)> {
    let p = Regulation::Target(Playout::Adaptive {
        epsilon_ppm,
        quantum,
    });
    let r = run_one(family, p, seed, times).ok()?.metrics;
    Some((r.mean_delay_s, r.late_rate))
}

/// The searches of one family and seed against each paper run's late rate,
/// sharing their adaptive runs (the delay in steps of `quantum`, `None` for
/// the default): the matches, in the order of `paper`, and the adaptive runs
/// made.
pub fn match_seed(
    family: &Family,
    seed: u64,
    paper: &[Option<RunMetrics>],
    times: (Duration, Duration),
    quantum: Option<Duration>,
) -> SeedMatches {
    let mut runs = Runs::new();
    let matches = paper
        .iter()
        .map(|m| {
            let m = (*m)?;
            let adaptive = search(m.late_rate, |ppm| {
                *runs
                    .entry(ppm)
                    .or_insert_with(|| adaptive_run(family, ppm, seed, times, quantum))
            });
            Some(MatchedSeed {
                seed,
                paper_delay_s: m.mean_delay_s,
                paper_late_rate: m.late_rate,
                paper_split_ratio: m.split_ratio,
                adaptive,
                win: adaptive.is_some_and(|a| a.mean_delay_s < m.mean_delay_s),
            })
        })
        .collect();
    (matches, runs)
}

impl Matched {
    /// The summary of `runs` (one per seed where the paper mode ran).
    #[must_use]
    pub fn of(
        family: String,
        against: String,
        runs: Vec<MatchedSeed>,
        paper_failed: usize,
        one_epsilon: Option<OneEpsilon>,
        adaptive_runs: usize,
    ) -> Self {
        let stat = |xs: Vec<f64>| Stat::of(&xs);
        let found: Vec<Probe> = runs.iter().filter_map(|r| r.adaptive).collect();
        let paper_delay_s = stat(runs.iter().map(|r| r.paper_delay_s).collect());
        let adaptive_delay_s = stat(found.iter().map(|a| a.mean_delay_s).collect());
        Matched {
            family,
            against,
            seeds: runs.len(),
            paper_failed,
            matched: found.len(),
            wins: runs.iter().filter(|r| r.win).count(),
            win: !runs.is_empty()
                && found.len() == runs.len()
                && adaptive_delay_s.mean < paper_delay_s.mean,
            paper_delay_s,
            paper_late_rate: stat(runs.iter().map(|r| r.paper_late_rate).collect()),
            paper_split_ratio: Stat::of_all(runs.iter().map(|r| r.paper_split_ratio)),
            adaptive_delay_s,
            adaptive_late_rate: stat(found.iter().map(|a| a.late_rate).collect()),
            epsilon: stat(found.iter().map(|a| a.epsilon).collect()),
            delay_gain_s: stat(
                runs.iter()
                    .filter_map(|r| Some(r.paper_delay_s - r.adaptive?.mean_delay_s))
                    .collect(),
            ),
            one_epsilon,
            adaptive_runs,
            runs,
        }
    }
}

/// The matched comparison against every paper mode of `cfg.regulations`, from
/// the paper runs among `outcomes` (`jobs`' outcomes); families in order,
/// then paper modes in the order asked.
pub(super) fn match_all(
    cfg: &super::CompareConfig,
    jobs: &[super::Job],
    outcomes: &[Option<super::Outcome>],
) -> Vec<Matched> {
    let quantum = matched_quantum(&cfg.regulations);
    let mut papers: Vec<Regulation> = Vec::new();
    for &p in &cfg.regulations {
        if p.is_paper() && !papers.contains(&p) {
            papers.push(p);
        }
    }
    let paper_run = |f: usize, seed: u64, p: Regulation| {
        jobs.iter()
            .zip(outcomes)
            .find(|((jf, jp, js), _)| *jf == f && *jp == p && *js == seed)
            .and_then(|(_, o)| o.as_ref()?.as_ref().ok().map(|(m, _)| *m))
    };
    let mut tasks: Vec<(usize, u64)> = Vec::new();
    for (f, family) in cfg.families.iter().enumerate() {
        let seeds = if family.seeded { cfg.seeds.max(1) } else { 1 };
        tasks.extend((1..=seeds).map(|seed| (f, seed)));
    }
    let duration = |f: usize| cfg.families.get(f).map_or(0, |x| x.duration.as_nanos());
    let mut order: Vec<usize> = (0..tasks.len()).collect();
    order.sort_by_key(|&i| core::cmp::Reverse(tasks.get(i).map_or(0, |t| duration(t.0))));
    let done = super::parallel(cfg.threads, &order, |i| {
        let &(f, seed) = tasks.get(i)?;
        let family = cfg.families.get(f)?;
        let paper: Vec<Option<RunMetrics>> =
            papers.iter().map(|&p| paper_run(f, seed, p)).collect();
        Some(match_seed(
            family,
            seed,
            &paper,
            (cfg.period, cfg.window),
            quantum,
        ))
    });
    let mut out = Vec::new();
    for (f, family) in cfg.families.iter().enumerate() {
        let of_family: Vec<(u64, &SeedMatches)> = tasks
            .iter()
            .zip(&done)
            .filter(|((tf, _), _)| *tf == f)
            .filter_map(|((_, seed), d)| Some((*seed, d.as_ref()?)))
            .collect();
        let mut runs: BTreeMap<(u32, u64), Option<(f64, f64)>> = BTreeMap::new();
        for (seed, (_, r)) in &of_family {
            runs.extend(r.iter().map(|(&ppm, &x)| ((ppm, *seed), x)));
        }
        let seeds = if family.seeded { cfg.seeds.max(1) } else { 1 };
        for (k, p) in papers.iter().enumerate() {
            let matched: Vec<MatchedSeed> = of_family
                .iter()
                .filter_map(|(_, d)| d.0.get(k).copied().flatten())
                .collect();
            let failed = usize::try_from(seeds)
                .unwrap_or(usize::MAX)
                .saturating_sub(matched.len());
            let one = one_epsilon(cfg, family, &matched, &mut runs);
            out.push(Matched::of(
                family.name.clone(),
                p.to_string(),
                matched,
                failed,
                one,
                0,
            ));
        }
        // Known once every mode's one-ε search has run.
        let total = runs.len();
        for m in out.iter_mut().rev().take(papers.len()) {
            m.adaptive_runs = total;
        }
    }
    out
}

/// The one-ε match of a family against a paper mode's seeds `matched`
/// (searched as [`search`] does, on the mean late rate), with the runs
/// already made by `(ppm, seed)`; new ones on the seeds in parallel.
fn one_epsilon(
    cfg: &super::CompareConfig,
    family: &Family,
    matched: &[MatchedSeed],
    runs: &mut BTreeMap<(u32, u64), Option<(f64, f64)>>,
) -> Option<OneEpsilon> {
    if matched.is_empty() {
        return None;
    }
    let n = matched.len() as f64;
    let limit = matched.iter().map(|m| m.paper_late_rate).sum::<f64>() / n;
    let paper_delay = matched.iter().map(|m| m.paper_delay_s).sum::<f64>() / n;
    let times = (cfg.period, cfg.window);
    let quantum = matched_quantum(&cfg.regulations);
    let mut at = |ppm: u32| -> Option<Vec<(f64, f64)>> {
        let missing: Vec<u64> = matched
            .iter()
            .map(|m| m.seed)
            .filter(|&s| !runs.contains_key(&(ppm, s)))
            .collect();
        let order: Vec<usize> = (0..missing.len()).collect();
        let new = super::parallel(cfg.threads, &order, |i| {
            let seed = *missing.get(i)?;
            Some(adaptive_run(family, ppm, seed, times, quantum))
        });
        for (seed, r) in missing.iter().zip(new) {
            runs.insert((ppm, *seed), r.flatten());
        }
        matched
            .iter()
            .map(|m| runs.get(&(ppm, m.seed)).copied().flatten())
            .collect()
    };
    let mut per_seed: BTreeMap<u32, Vec<(f64, f64)>> = BTreeMap::new();
    let best = search(limit, |ppm| {
        let xs = at(ppm)?;
        let mean = |f: fn(&(f64, f64)) -> f64| xs.iter().map(f).sum::<f64>() / n;
        let point = (mean(|x| x.0), mean(|x| x.1));
        per_seed.insert(ppm, xs);
        Some(point)
    })?;
    let ppm = (best.epsilon * 1e6).round() as u32;
    let xs = per_seed.get(&ppm)?;
    let stat = |f: fn(&(f64, f64)) -> f64| Stat::of(&xs.iter().map(f).collect::<Vec<f64>>());
    Some(OneEpsilon {
        epsilon: best.epsilon,
        adaptive_delay_s: stat(|x| x.0),
        adaptive_late_rate: stat(|x| x.1),
        win: best.mean_delay_s < paper_delay,
    })
}
