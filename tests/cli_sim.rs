//! `ndr sim` as a user runs it: the binary, its JSON and its errors.

use std::path::PathBuf;
use std::process::{Command, Output};

fn ndr(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ndr"))
        .args(args)
        .output()
        .expect("the ndr binary runs")
}

fn temp_file(name: &str, contents: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ndr-cli-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(name);
    std::fs::write(&path, contents).unwrap();
    path
}

const REQUIRED: [&str; 25] = [
    "nrtt_mean_s",
    "nrtt_std_s",
    "grtt_mean_s",
    "grtt_std_s",
    "grtt_p99_s",
    "e2e_fwd_mean_s",
    "e2e_fwd_std_s",
    "e2e_bwd_mean_s",
    "e2e_bwd_std_s",
    "late_rate_fwd",
    "late_rate_bwd",
    "ns",
    "period_s",
    "queue_base_min",
    "queue_base_max",
    "queue_remote_min",
    "queue_remote_max",
    "samples_sent",
    "samples_released",
    "late_samples",
    "underflows",
    "resizes",
    "pauses",
    "pred_nrtt_mae_s",
    "pred_mt_mae_s",
];

#[test]
fn json_is_complete_and_byte_identical_for_a_seed() {
    let args = [
        "sim",
        "--profile",
        "paris-newyork",
        "--regulation",
        "paper-dynamic",
        "--duration-s",
        "120",
        "--seed",
        "9",
        "--json",
    ];
    let a = ndr(&args);
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));
    let b = ndr(&args);
    assert_eq!(a.stdout, b.stdout);
    let json: serde_json::Value = serde_json::from_slice(&a.stdout).unwrap();
    for key in REQUIRED {
        assert!(
            json.get(key).is_some_and(|v| v.is_number()),
            "missing {key}"
        );
    }
    let other = ndr(&[
        "sim",
        "--profile",
        "paris-newyork",
        "--regulation",
        "paper-dynamic",
        "--duration-s",
        "120",
        "--seed",
        "10",
        "--json",
    ]);
    assert_ne!(a.stdout, other.stdout);
}

#[test]
fn a_bad_trace_gets_an_error_naming_its_line() {
    let cases = [
        (
            "unsorted.csv",
            "t_s,fwd_ms,bwd_ms\n0,10,10\n5,10,10\n2,10,10\n",
            "line 4",
        ),
        ("negative.csv", "t_s,fwd_ms,bwd_ms\n0,10,-3\n", "line 2"),
        (
            "text.csv",
            "t_s,fwd_ms,bwd_ms\n0,10,10\n1,abc,10\n",
            "line 3",
        ),
        ("columns.csv", "t_s,fwd_ms\n0,10\n", "line 1"),
    ];
    for (name, contents, line) in cases {
        let path = temp_file(name, contents);
        let out = ndr(&[
            "sim",
            "--trace",
            path.to_str().unwrap(),
            "--duration-s",
            "10",
        ]);
        assert!(!out.status.success(), "{name} was accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(line), "{name}: {err}");
    }
}

#[test]
fn a_trace_replays_and_the_series_is_written() {
    let trace = temp_file("ok.csv", "t_s,fwd_ms,bwd_ms\n0,12,11\n30,40,35\n");
    let csv = std::env::temp_dir().join(format!("ndr-cli-test-{}/series.csv", std::process::id()));
    let out = ndr(&[
        "sim",
        "--trace",
        trace.to_str().unwrap(),
        "--duration-s",
        "60",
        "--period-ms",
        "100",
        "--out",
        csv.to_str().unwrap(),
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["profile"], "trace");
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert!(lines.next().unwrap().starts_with("t_s,period_s,ns,"));
    assert!(lines.count() > 500);
}

#[test]
fn unknown_profile_and_conflicting_sources_are_refused() {
    let out = ndr(&["sim", "--profile", "mars"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("paris-newyork"));
    let out = ndr(&["sim", "--profile", "lan-75km", "--trace", "x.csv"]);
    assert!(!out.status.success());
    let out = ndr(&["sim", "--dist", "x.dist"]);
    assert!(!out.status.success(), "--dist without --mean-ms/--std-ms");
}

#[test]
fn the_paper_table_runs() {
    let out = ndr(&["sim", "--paper", "--json"]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["scenarios"].as_array().unwrap().len(), 5);
}

#[test]
fn a_playout_policy_and_a_skewed_clock() {
    let args = [
        "sim",
        "--profile",
        "constant:30",
        "--period-ms",
        "20",
        "--underflow",
        "drop-late",
        "--regulation",
        "fixed:25",
        "--remote-skew-ppm",
        "-100",
        "--duration-s",
        "30",
        "--json",
    ];
    let out = ndr(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["regulation"], "fixed:25");
    assert_eq!(
        (&json["mode"], &json["playout"]),
        (&"paper-static".into(), &"fixed:25".into())
    );
    assert_eq!(json["late_samples"], 0);
    // 30 ms + 25 ms above the smallest delay, released on the 20 ms grid.
    let e2e = json["e2e_fwd_mean_s"].as_f64().unwrap();
    assert!((e2e - 0.060).abs() < 0.003, "{e2e}");
    let out = ndr(&["sim", "--regulation", "oracle"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown regulation"));
}

#[test]
fn the_regulation_is_the_only_flag_for_it() {
    // The old spellings are gone: refused before anything runs.
    for old in [["--mode", "paper-dynamic"], ["--playout", "neteq"]] {
        let o = ndr(&[&["sim", "--duration-s", "30"][..], &old[..]].concat());
        assert!(!o.status.success(), "{old:?}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            err.contains(&format!("unexpected argument '{}'", old[0])),
            "{err}"
        );
    }
}

#[test]
fn help_lists_the_names_each_option_takes() {
    for command in ["sim", "demo", "base", "remote"] {
        let out = ndr(&[command, "--help"]);
        assert!(out.status.success(), "{command}");
        let help = String::from_utf8_lossy(&out.stdout);
        for name in ["drop-late", "paper-dynamic", "adaptive[:PERCENT"] {
            assert!(help.contains(name), "{command} --help lacks {name}: {help}");
        }
    }
}

#[test]
fn quic_is_simulated_as_its_datagrams() {
    let run = |transport: &str| {
        ndr(&[
            "sim",
            "--profile",
            "lan-75km",
            "--loss",
            "2",
            "--transport",
            transport,
            "--period-ms",
            "20",
            "--duration-s",
            "30",
            "--json",
        ])
    };
    let quic = run("quic:2:1");
    assert!(
        quic.status.success(),
        "{}",
        String::from_utf8_lossy(&quic.stderr)
    );
    assert_eq!(quic.stdout, run("datagram:2:1").stdout);
    assert_ne!(quic.stdout, run("stream").stdout);
    let bad = run("quic:9");
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("quic:K"));
}
