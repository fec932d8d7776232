//! `ndr sim --paper`: the paper's scenarios, our numbers beside its numbers.

use ndr::core::endpoint::{Mode, Underflow};
use ndr::core::time::Duration;
use ndr::sim::delay::DelayModel;
use ndr::sim::{self, Report, SimConfig};
use serde::Serialize;

/// What the paper reports (or, for the dynamic rows, expects) for a scenario.
#[derive(Clone, Copy, Serialize)]
struct PaperRef {
    nrtt: &'static str,
    grtt: &'static str,
    ns: &'static str,
    queue: &'static str,
    period: &'static str,
    source: &'static str,
}

struct Scenario {
    name: &'static str,
    profile: &'static str,
    mode: Mode,
    duration_s: u64,
    paper: PaperRef,
}

const SCENARIOS: [Scenario; 5] = [
    Scenario {
        name: "paris-newyork static",
        profile: "paris-newyork",
        mode: Mode::PaperStatic,
        duration_s: 600,
        paper: PaperRef {
            nrtt: "610 ms / 500 ms",
            grtt: "7 s / 12 ms",
            ns: "13",
            queue: "4–16",
            period: "200 ms",
            source: "§4.2.3, measured",
        },
    },
    Scenario {
        name: "lan-75km static",
        profile: "lan-75km",
        mode: Mode::PaperStatic,
        duration_s: 600,
        paper: PaperRef {
            nrtt: "23 ms",
            grtt: "1.2 s",
            ns: "2",
            queue: "1–3",
            period: "200 ms",
            source: "§4.2.3, measured",
        },
    },
    Scenario {
        name: "lan-75km dynamic",
        profile: "lan-75km",
        mode: Mode::PaperDynamic,
        duration_s: 600,
        paper: PaperRef {
            nrtt: "23 ms",
            grtt: "0.3 s",
            ns: "2",
            queue: "",
            period: "50 ms",
            source: "§4.2.4.3, expected",
        },
    },
    Scenario {
        name: "paris-newyork dynamic",
        profile: "paris-newyork",
        mode: Mode::PaperDynamic,
        duration_s: 600,
        paper: PaperRef {
            nrtt: "610 ms",
            grtt: "≈ 3.9 s",
            ns: "",
            queue: "",
            period: "≈ 203 ms",
            source: "§4.2.4.3, expected",
        },
    },
    Scenario {
        name: "paper-fig6 static (predictor)",
        profile: "paper-fig6",
        mode: Mode::PaperStatic,
        duration_s: 1200,
        paper: PaperRef {
            nrtt: "varying",
            grtt: "",
            ns: "",
            queue: "",
            period: "200 ms",
            source: "§4.2.4.2, Figs. 6–9",
        },
    },
];

#[derive(Serialize)]
struct Row<'a> {
    scenario: &'a str,
    paper: PaperRef,
    ours: Report,
}

/// Runs the paper's scenarios at `seed`, each regulator under `underflow`;
/// JSON if `json`, else the tables.
pub fn run(seed: u64, underflow: Underflow, json: bool) -> Result<(), String> {
    let mut rows = Vec::new();
    for s in &SCENARIOS {
        let mut cfg = SimConfig::paper(DelayModel::profile(s.profile).map_err(|e| e.to_string())?);
        cfg.mode = s.mode;
        cfg.underflow = underflow;
        cfg.duration = Duration::from_secs(s.duration_s);
        cfg.seed = seed;
        let out = sim::run(&cfg).map_err(|e| format!("{}: {e}", s.name))?;
        rows.push(Row {
            scenario: s.name,
            paper: s.paper,
            ours: out.report,
        });
    }
    if json {
        let doc = serde_json::json!({ "seed": seed, "scenarios": rows });
        println!(
            "{}",
            serde_json::to_string(&doc).map_err(|e| e.to_string())?
        );
        return Ok(());
    }
    println!(
        "The paper's scenarios at T = 200 ms, seed {} (paper: Lelevé, Fraisse, Dauchez, IROS 2001)\n",
        seed
    );
    println!(
        "{:<32} {:<7} {:<17} {:<22} {:<6} {:<14} {:<9}",
        "scenario", "", "NRTT mean / std", "GRTT mean / std", "ns", "queue (s)", "T"
    );
    for r in &rows {
        let o = &r.ours;
        let p = &r.paper;
        println!(
            "{:<32} {:<7} {:<17} {:<22} {:<6} {:<14} {:<9}",
            r.scenario, "paper", p.nrtt, p.grtt, p.ns, p.queue, p.period
        );
        println!(
            "{:<32} {:<7} {:<17} {:<22} {:<6} {:<14} {:<9}",
            "",
            "ours",
            format!("{:.0} / {:.0} ms", o.nrtt_mean_s * 1e3, o.nrtt_std_s * 1e3),
            format!(
                "{:.2} s / {:.1} ms",
                o.settled_grtt_mean_s,
                o.settled_grtt_std_s * 1e3
            ),
            if o.initial_ns == o.ns {
                o.ns.to_string()
            } else {
                format!("{}→{}", o.initial_ns, o.ns)
            },
            format!(
                "{}–{} / {}–{}",
                o.queue_base_min, o.queue_base_max, o.queue_remote_min, o.queue_remote_max
            ),
            format!("{:.0} ms", o.period_s * 1e3)
        );
    }
    println!("\nGRTT is the settled value (since the last parameter change); queue is the");
    println!("occupancy just before each release, base / remote.");
    println!(
        "\nThe paper's relation GRTT = 2·s·T + NRTT, with s = max(s) as written, and with s = mean(s):"
    );
    for r in &rows {
        let o = &r.ours;
        println!(
            "  {:<32} GRTT {:.3} s · max(s): {:.3} s ({:+.0} ms) · mean(s): {:.3} s ({:+.0} ms) · T = {:.0} ms",
            r.scenario,
            o.settled_grtt_mean_s,
            o.relation_grtt_s,
            o.relation_error_s * 1e3,
            o.relation_mean_grtt_s,
            o.relation_mean_error_s * 1e3,
            o.period_s * 1e3
        );
    }
    let fig6 = &rows[4].ours;
    println!(
        "\nPredictor on paper-fig6, {:.0} s ahead: mean NRTT MAE {:.1} ms (RMSE {:.1}), mt MAE {:.1} ms (RMSE {:.1});",
        fig6.pred_horizon_s,
        fig6.pred_nrtt_mae_s * 1e3,
        fig6.pred_nrtt_rmse_s * 1e3,
        fig6.pred_mt_mae_s * 1e3,
        fig6.pred_mt_rmse_s * 1e3
    );
    println!(
        "the series for Figs. 8 and 9: ndr sim --profile paper-fig6 --duration-s 1200 --out fig6.csv"
    );
    Ok(())
}
