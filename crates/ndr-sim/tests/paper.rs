//! The paper's results, reproduced in the simulator, within bands.

use ndr_core::endpoint::Mode;
use ndr_core::time::Duration;
use ndr_sim::delay::DelayModel;
use ndr_sim::{Report, SimConfig, run};

fn sim(profile: &str, mode: Mode, seed: u64) -> Report {
    let mut cfg = SimConfig::paper(DelayModel::profile(profile).unwrap());
    cfg.mode = mode;
    cfg.seed = seed;
    run(&cfg).unwrap().report
}

fn within(x: f64, target: f64, rel: f64) -> bool {
    (x - target).abs() <= rel * target
}

#[test]
fn paris_new_york_static_matches_the_paper() {
    let r = sim("paris-newyork", Mode::PaperStatic, 1);
    assert!((11..=15).contains(&r.ns), "ns {}", r.ns);
    let max = r.queue_base_max.max(r.queue_remote_max);
    assert!((13..=19).contains(&max), "queue max {max}");
    assert!(within(r.grtt_mean_s, 7.0, 0.15), "GRTT {}", r.grtt_mean_s);
    assert!(
        within(r.nrtt_mean_s, 0.610, 0.10),
        "NRTT mean {}",
        r.nrtt_mean_s
    );
    assert!(
        within(r.nrtt_std_s, 0.500, 0.10),
        "NRTT std {}",
        r.nrtt_std_s
    );
    // GRTT = 2·s·T + NRTT holds within one period with the mean occupancy
    // (Little's law). With max(s) it is off by 1–1.6 s here: each queue's
    // maximum is set by the fastest path while the relation adds the mean
    // NRTT (docs/algorithms.md §7).
    assert!(
        r.relation_mean_error_s.abs() <= r.period_s,
        "relation off by {}",
        r.relation_mean_error_s
    );
    assert!(r.grtt_std_s < 1e-9, "the regulated delay is constant");
}

#[test]
fn paris_new_york_static_holds_across_seeds() {
    for seed in 2..=6 {
        let r = sim("paris-newyork", Mode::PaperStatic, seed);
        let max = r.queue_base_max.max(r.queue_remote_max);
        assert!((11..=15).contains(&r.ns), "seed {seed}: ns {}", r.ns);
        assert!((13..=19).contains(&max), "seed {seed}: queue max {max}");
        assert!(
            within(r.grtt_mean_s, 7.0, 0.15),
            "seed {seed}: GRTT {}",
            r.grtt_mean_s
        );
        assert!(r.relation_mean_error_s.abs() <= r.period_s, "seed {seed}");
    }
}

#[test]
fn lan_static_matches_the_paper() {
    let r = sim("lan-75km", Mode::PaperStatic, 1);
    assert_eq!(r.ns, 2);
    assert!(within(r.grtt_mean_s, 1.2, 0.15), "GRTT {}", r.grtt_mean_s);
    assert!(
        within(r.nrtt_mean_s, 0.023, 0.10),
        "NRTT mean {}",
        r.nrtt_mean_s
    );
    // Here the relation holds as the paper writes it, with max(s).
    assert!(
        r.relation_error_s.abs() <= r.period_s,
        "relation off by {}",
        r.relation_error_s
    );
    assert!(r.relation_mean_error_s.abs() <= r.period_s);
    assert!(r.grtt_std_s < 1e-9);
}

#[test]
fn lan_dynamic_settles_at_50_ms_and_0_3_s() {
    let r = sim("lan-75km", Mode::PaperDynamic, 1);
    assert_eq!(r.period_s, 0.05);
    assert_eq!(r.ns, 2);
    assert!(
        r.pauses >= 1 && r.resizes == r.pauses,
        "{} pauses, {} resizes",
        r.pauses,
        r.resizes
    );
    assert!(
        within(r.settled_grtt_mean_s, 0.3, 0.15),
        "GRTT {}",
        r.settled_grtt_mean_s
    );
    assert!(r.settled_grtt_std_s < 1e-9);
}

#[test]
fn paris_new_york_dynamic_is_near_the_papers_3_9_s() {
    for seed in 1..=4 {
        let r = sim("paris-newyork", Mode::PaperDynamic, seed);
        assert!(
            within(r.settled_grtt_mean_s, 3.9, 0.20),
            "seed {seed}: GRTT {} ({r:?})",
            r.settled_grtt_mean_s
        );
        assert!(
            within(r.period_s, 0.61 / 3.0, 0.25),
            "seed {seed}: period {}",
            r.period_s
        );
        assert!(r.pauses >= 1 && r.underflows == 0, "seed {seed}: {r:?}");
    }
}

#[test]
fn fig6_reports_prediction_errors() {
    let mut cfg = SimConfig::paper(DelayModel::PaperFig6);
    cfg.duration = Duration::from_secs(1200);
    cfg.record_series = true;
    let out = run(&cfg).unwrap();
    let r = out.report;
    assert!(r.pred_count > 5000, "{}", r.pred_count);
    assert!(r.pred_nrtt_mae_s.is_finite() && r.pred_mt_mae_s.is_finite());
    // The series covers the 20 minutes, one row per base tick, with the truth.
    assert!(out.series.len() >= 5990);
    assert!(out.series.iter().all(|row| row.truth_nrtt_s.is_finite()));
}

#[test]
fn the_same_seed_gives_the_same_report() {
    let a = sim("paris-newyork", Mode::PaperDynamic, 42);
    let b = sim("paris-newyork", Mode::PaperDynamic, 42);
    assert_eq!(a, b);
    let c = sim("paris-newyork", Mode::PaperDynamic, 43);
    assert_ne!(a, c);
}

/// The dynamic mode over a congested path at a short period: the period law
/// (`NRTT/3`) takes a pause to periods near a second, whose pattern of ten
/// probes outlasts a fixed 10 s limit. With that limit the link failed in
/// these runs (seeds 5, 7, 9, 10 at 74–106 s); the pause and its pattern
/// now get three times what they need.
#[test]
fn a_dynamic_pause_to_a_long_period_finishes_its_pattern() {
    for seed in [5, 7, 9, 10] {
        let mut cfg = SimConfig::paper(DelayModel::profile("paris-newyork").unwrap());
        cfg.mode = Mode::PaperDynamic;
        cfg.period = Duration::from_millis(20);
        cfg.duration = Duration::from_secs(120);
        cfg.underflow = ndr_core::endpoint::Underflow::DropLate;
        cfg.seed = seed;
        let r = match run(&cfg) {
            Ok(out) => out.report,
            Err(e) => panic!("seed {seed}: {e}"),
        };
        assert!(r.pauses >= 2, "seed {seed}: {} pauses", r.pauses);
        // The pattern after a pause ran at a period past half a second.
        assert!(r.period_s > 0.5, "seed {seed}: period {}", r.period_s);
    }
}
