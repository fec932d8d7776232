//! `ndr compare` as a user runs it: every regulation and family in its JSON,
//! the same output for the same seeds, trace files, missing netem tables.

use std::path::PathBuf;

use serde_json::Value;

mod cli_common;
use cli_common::{json, ndr};

const REGULATIONS: [&str; 9] = [
    "paper-static",
    "paper-dynamic",
    "ramjee-1",
    "ramjee-4",
    "neteq",
    "fixed:200",
    "adaptive",
    "oracle",
    "oracle-piecewise",
];

const BUILTIN: [&str; 8] = [
    "paris-newyork",
    "lan-75km",
    "paper-fig6",
    "step",
    "spikes",
    "tcp-stall",
    "skew+100ppm",
    "skew-100ppm",
];

const STATS: [&str; 9] = [
    "mean_delay_s",
    "std_delay_s",
    "p99_delay_s",
    "late_rate",
    "underflows",
    "delay_changes",
    "oracle_ratio",
    "piecewise_ratio",
    "hull_ratio",
];

fn names(v: &Value) -> Vec<&str> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|x| x["name"].as_str().or(x["regulation"].as_str()).unwrap())
        .collect()
}

#[test]
fn every_regulation_on_every_family() {
    // A 100 ms period: the same families and policies, 5× fewer ticks.
    let report = json(&["compare", "--json", "--seeds", "1", "--period-ms", "100"]);
    assert_eq!(report["period_s"], 0.1);
    assert_eq!(report["schema"], "ndr-compare/2");
    assert_eq!(report["underflow"], "drop-late");
    let families = names(&report["families"]);
    for f in BUILTIN {
        assert!(families.contains(&f), "{f} missing from {families:?}");
    }
    // netem families: present, or named in a note when this machine has no table.
    for table in ["normal", "pareto", "paretonormal", "experimental"] {
        let name = format!("netem-{table}");
        let noted = report["notes"]
            .as_array()
            .unwrap()
            .iter()
            .any(|n| n.as_str().unwrap().starts_with(&format!("{name} skipped")));
        assert!(families.contains(&name.as_str()) || noted, "{name}");
    }
    for f in report["families"].as_array().unwrap() {
        assert_eq!(names(&f["regulations"]), REGULATIONS, "{}", f["name"]);
        for p in f["regulations"].as_array().unwrap() {
            for s in STATS {
                assert!(
                    p[s]["mean"].is_number(),
                    "{} {} {s}",
                    f["name"],
                    p["regulation"]
                );
                assert!(p[s]["ci95"].is_number());
            }
            assert!(p["point"]["mean_delay_s"].is_number());
            assert!(p["point"]["late_rate"].is_number());
            let events = !f["events_s"].as_array().unwrap().is_empty();
            let measured = p["runs"].as_u64().unwrap() > 0;
            let oracle = p["regulation"].as_str().unwrap().starts_with("oracle");
            assert_eq!(
                p["recovery_s"].is_object(),
                events && measured && !oracle,
                "{} {}",
                f["name"],
                p["regulation"]
            );
            // The split oracle cuts at the first event: only with events.
            assert_eq!(
                p["split_ratio"].is_object(),
                events && measured,
                "{} {}",
                f["name"],
                p["regulation"]
            );
            if p["split_ratio"].is_object() {
                assert!(p["split_ratio"]["mean"].as_f64().unwrap() > 0.0);
            }
        }
    }
}

/// Two seeds at T = 50 ms, in JSON: a short comparison.
const SHORT: [&str; 6] = ["compare", "--json", "--seeds", "2", "--period-ms", "50"];

#[test]
fn the_same_seeds_give_the_same_bytes() {
    let mut args = SHORT.to_vec();
    args.extend(["--family", "spikes", "--family", "skew-100ppm"]);
    let (a, b) = (ndr(&args), ndr(&args));
    assert!(a.status.success());
    assert_eq!(a.stdout, b.stdout);
}

#[test]
fn seeds_give_confidence_intervals() {
    let report = json(&[
        "compare",
        "--json",
        "--seeds",
        "3",
        "--family",
        "lan-75km",
        "--regulation",
        "ramjee-1",
    ]);
    assert_eq!(report["seeds"], 3);
    let f = &report["families"][0];
    assert_eq!(
        names(&f["regulations"]),
        ["ramjee-1", "oracle", "oracle-piecewise"]
    );
    let p = &f["regulations"][0];
    assert_eq!(p["runs"], 3);
    assert!(p["mean_delay_s"]["ci95"].as_f64().unwrap() > 0.0);
}

#[test]
fn a_trace_file_is_a_family() {
    let dir = std::env::temp_dir().join(format!("ndr-cli-compare-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path: PathBuf = dir.join("mylink.csv");
    std::fs::write(&path, "t_s,fwd_ms,bwd_ms\n0,30,30\n20,90,30\n40,30,30\n").unwrap();
    let report = json(&["compare", "--json", "--traces", path.to_str().unwrap()]);
    assert_eq!(names(&report["families"]), ["mylink"]);
    assert_eq!(report["families"][0]["seeds"], 1);
    let duration = report["families"][0]["duration_s"].as_f64().unwrap();
    assert!((duration - 60.0).abs() < 1e-9, "{duration}");
}

#[test]
fn missing_netem_tables_are_a_note_and_bad_names_an_error() {
    let report = json(&[
        "compare",
        "--json",
        "--seeds",
        "1",
        "--tc-dir",
        "/nonexistent-tc",
        "--family",
        "netem-pareto",
        "--family",
        "lan-75km",
        "--regulation",
        "neteq",
    ]);
    assert_eq!(names(&report["families"]), ["lan-75km"]);
    let notes = report["notes"].as_array().unwrap();
    assert_eq!(notes.len(), 1);
    assert!(
        notes[0]
            .as_str()
            .unwrap()
            .starts_with("netem-pareto skipped")
    );

    let out = ndr(&["compare", "--family", "mars"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("unknown family `mars`") && err.contains("lan-75km"),
        "{err}"
    );
    // Late rates do not compare under hold: said before anything runs.
    let out = ndr(&["compare", "--matched", "--underflow", "hold"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--matched compares late rates") && err.contains("--underflow hold"),
        "{err}"
    );
    let out = ndr(&["compare", "--regulation", "lifo"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("regulation `lifo`: unknown regulation; valid: adaptive"),
        "{err}"
    );
    // `fifo` names the queue, not its sizing: the message says both ways.
    let out = ndr(&["compare", "--regulation", "fifo"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("paper-static") && err.contains("paper-dynamic"),
        "{err}"
    );
    // A known regulation with a value out of range says which value.
    let out = ndr(&["compare", "--regulation", "adaptive:0.1:0.5"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("regulation `adaptive:0.1:0.5`: adaptive:PERCENT:QUANTUM_MS takes the step"),
        "{err}"
    );
}

#[test]
fn the_families_run_as_long_as_asked() {
    // 70 s of tcp-stall: its stalls at 30 and 50 s, the run measured.
    let report = json(&[
        "compare",
        "--json",
        "--seeds",
        "1",
        "--family",
        "tcp-stall",
        "--regulation",
        "paper-static",
        "--duration-s",
        "70",
    ]);
    let f = &report["families"][0];
    assert_eq!(f["duration_s"], 70.0);
    assert_eq!(f["events_s"], serde_json::json!([30.0, 50.0]));
    assert!(
        f["regulations"][0]["mean_delay_s"]["mean"]
            .as_f64()
            .unwrap()
            > 0.0
    );
    // Too short to measure, or too long to hold in memory: said, not run.
    for bad in ["5", "7200", "nan"] {
        let out = ndr(&["compare", "--duration-s", bad]);
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("--duration-s must be 20 to 3600 seconds"),
            "{err}"
        );
    }
}

#[test]
fn matched_is_deterministic_and_only_when_asked() {
    let mut args = SHORT.to_vec();
    args.extend([
        "--family",
        "lan-75km",
        "--regulation",
        "paper-static",
        "--regulation",
        "paper-dynamic",
    ]);
    let plain: Value = serde_json::from_slice(&ndr(&args).stdout).unwrap();
    assert!(
        plain.get("matched").is_none(),
        "no `matched` key unless asked"
    );
    args.push("--matched");
    let (a, b) = (ndr(&args), ndr(&args));
    assert!(a.status.success());
    assert_eq!(a.stdout, b.stdout);
    let report: Value = serde_json::from_slice(&a.stdout).unwrap();
    // The families' rows are those of the run without --matched.
    assert_eq!(report["families"], plain["families"]);
    let matched = report["matched"].as_array().unwrap();
    let against: Vec<&str> = matched
        .iter()
        .map(|m| m["against"].as_str().unwrap())
        .collect();
    assert_eq!(against, ["paper-static", "paper-dynamic"]);
    for m in matched {
        assert_eq!(m["family"], "lan-75km");
        let one = &m["one_epsilon"];
        let paper = m["paper_late_rate"]["mean"].as_f64().unwrap();
        assert!(one["adaptive_late_rate"]["mean"].as_f64().unwrap() <= paper + 1e-12);
        let runs = m["runs"].as_array().unwrap();
        assert_eq!(runs.len() as u64 + m["paper_failed"].as_u64().unwrap(), 2);
        // lan-75km has no event to cut the split oracle at.
        assert!(m["paper_split_ratio"].is_null());
        for r in runs {
            assert!(r["paper_split_ratio"].is_null());
            let limit = r["paper_late_rate"].as_f64().unwrap();
            if let Some(a) = r["adaptive"].as_object() {
                assert!(a["late_rate"].as_f64().unwrap() <= limit);
                let win =
                    a["mean_delay_s"].as_f64().unwrap() < r["paper_delay_s"].as_f64().unwrap();
                assert_eq!(r["win"], win);
            }
        }
    }
    // The tables print a matched section too (one seed: quicker).
    args.retain(|a| *a != "--json");
    if let Some(seeds) = args.iter().position(|a| *a == "--seeds") {
        args[seeds + 1] = "1";
    }
    let out = ndr(&args);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains("adaptive at an equal or lower late rate")
            && text.contains("adaptive at one ε for all seeds"),
        "{text}"
    );
}

#[test]
fn the_old_policy_flag_is_refused() {
    let o = ndr(&["compare", "--json", "--seeds", "1", "--policy", "ramjee-1"]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("unexpected argument '--policy'"), "{err}");
}
