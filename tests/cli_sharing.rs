//! A robot shared by several `ndr base` processes at once, as a user runs
//! them: a controller, an observer, a base waiting for control that is
//! handed it when the controller leaves or hangs. Margins are wide: what
//! is checked is who held control, in which order, and that no command of
//! an ended term was applied, not timing accuracy. The two tests run at
//! once: each is mostly waiting (a liveness time, a hand-over), and their
//! processes at 50 Hz are a light load beside a build's.

use std::path::{Path, PathBuf};
use std::process::ExitStatus;
use std::time::{Duration, Instant};

mod cli_proc;

use cli_proc::Proc;

type Value = serde_json::Value;

/// `ndr remote --observers 2 --once --json` on a free loopback port; its
/// address.
fn remote() -> (Proc, String) {
    let args = [
        "remote",
        "--listen",
        "127.0.0.1:0",
        "--period-ms",
        "20",
        "--observers",
        "2",
        "--once",
        "--json",
    ];
    let mut remote = Proc::spawn(&args);
    let prefix = "waiting for bases on ";
    let line = remote.line_with(prefix, Duration::from_secs(20));
    let at = line.find(prefix).unwrap() + prefix.len();
    (
        remote,
        line[at..].split_whitespace().next().unwrap().to_string(),
    )
}

fn csv_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("ndr-cli-sharing-{name}-{}.csv", std::process::id()))
}

/// `ndr base --json` to `addr` for `seconds`, with `extra` arguments.
fn base(addr: &str, seconds: &str, csv: &Path, extra: &[&str]) -> Proc {
    let mut args = vec![
        "base",
        "--connect",
        addr,
        "--duration-s",
        seconds,
        "--period-ms",
        "20",
        "--json",
        "--out",
    ];
    args.push(csv.to_str().unwrap());
    args.extend_from_slice(extra);
    Proc::spawn(&args)
}

/// Waits for `p` until `limit`: its exit status, its JSON report, and when
/// it was seen to exit.
fn report(p: Proc, limit: Duration) -> (ExitStatus, Value, Instant) {
    let (status, stdout, stderr) = p.wait(limit);
    let ended = Instant::now();
    let json = serde_json::from_str(&stdout)
        .unwrap_or_else(|e| panic!("no JSON report ({e}): {stdout:?}; stderr:\n{stderr}"));
    (status, json, ended)
}

/// The CSV's fresh states: (time, seq).
fn fresh_states(csv: &Path) -> Vec<(f64, u64)> {
    let text = std::fs::read_to_string(csv).expect("the CSV is written");
    text.lines()
        .skip(1)
        .filter_map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[2] == "fresh").then(|| (f[0].parse().unwrap(), f[1].parse().unwrap()))
        })
        .collect()
}

fn session<'a>(remote: &'a Value, terms: &Value) -> &'a Value {
    remote["sessions"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| &s["terms"] == terms)
        .unwrap_or_else(|| panic!("no session with terms {terms}: {remote}"))
}

#[test]
fn a_waiting_base_is_handed_control_when_the_controller_leaves() {
    let (mut remote, addr) = remote();
    let (csv_a, csv_o, csv_b) = (csv_path("a"), csv_path("o"), csv_path("b"));
    let a = base(&addr, "6", &csv_a, &[]);
    let o = base(&addr, "14", &csv_o, &["--observe"]);
    // B comes once A holds control (a loaded host may start A late).
    remote.line_with("holds control (term 1)", Duration::from_secs(20));
    std::thread::sleep(Duration::from_secs(1));
    let b_started = Instant::now();
    let b = base(&addr, "4", &csv_b, &["--wait-for-control", "20"]);

    let (status_a, report_a, a_ended) = report(a, Duration::from_secs(60));
    let (status_b, report_b, _) = report(b, Duration::from_secs(60));
    let (status_o, report_o, _) = report(o, Duration::from_secs(60));
    let (status_r, stdout_r, stderr_r) = remote.wait(Duration::from_secs(60));
    assert!(status_a.success(), "{report_a}");
    assert!(status_b.success(), "{report_b}");
    assert!(status_o.success(), "{report_o}");
    assert!(status_r.success(), "{stderr_r}");

    assert_eq!(report_a["role"], "controller", "{report_a}");
    assert_eq!(report_b["role"], "controller", "{report_b}");
    // (States of term 1 still on their way at the grant come first.)
    let terms_b = report_b["terms_seen"].as_array().unwrap();
    assert_eq!(terms_b.last(), Some(&serde_json::json!(2)), "{report_b}");
    // B was granted control when A left: its wait, from its start, ends
    // within 1.5 s of A's end.
    let waited = report_b["waited_for_control_s"].as_f64().expect("B waited");
    let granted = b_started + Duration::from_secs_f64(waited);
    let apart = if granted > a_ended {
        granted - a_ended
    } else {
        a_ended - granted
    };
    assert!(
        apart < Duration::from_millis(1500),
        "granted {apart:?} from A's end; {report_b}"
    );

    // The observer: its states in order, none missing for longer than the
    // hand-over holds the robot, both terms seen.
    assert_eq!(report_o["role"], "observer", "{report_o}");
    // (Term 0: it may have joined before A's grant.)
    let terms: Vec<u64> = report_o["terms_seen"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(Value::as_u64)
        .filter(|&t| t != 0)
        .collect();
    assert_eq!(terms, [1, 2], "{report_o}");
    let states = fresh_states(&csv_o);
    assert!(states.len() > 300, "{} states", states.len());
    assert!(
        states.windows(2).all(|w| w[1].1 > w[0].1),
        "states out of order"
    );
    let gap = states
        .windows(2)
        .map(|w| w[1].0 - w[0].0)
        .fold(0.0, f64::max);
    assert!(gap < 1.5, "the observer went {gap} s without a state");

    // The robot: one hand-over; A's commands in term 1, B's in term 2;
    // none of an ended term applied.
    let r: Value = serde_json::from_str(&stdout_r)
        .unwrap_or_else(|e| panic!("no JSON report ({e}): {stdout_r:?}; stderr:\n{stderr_r}"));
    assert_eq!(r["handovers"], 1, "{r}");
    assert!(r["observers_max"].as_u64() >= Some(2), "{r}");
    assert_eq!(r["commands_after_term"], 0, "{r}");
    let sa = session(&r, &serde_json::json!([1]));
    let sb = session(&r, &serde_json::json!([2]));
    assert!(sa["commands_applied"].as_u64() > Some(100), "{r}");
    assert!(sb["commands_applied"].as_u64() > Some(50), "{r}");
    assert_eq!(sa["commands_after_term"], 0, "{r}");
    let by_term = &r["commands_applied_by_term"];
    assert_eq!(by_term[0][1], sa["commands_applied"], "{r}");
    assert_eq!(by_term[1][1], sb["commands_applied"], "{r}");
    let so = session(&r, &serde_json::json!([]));
    assert_eq!(so["role"], "observer", "{r}");
    assert_eq!(so["commands_applied"], 0, "{r}");
    for csv in [csv_a, csv_o, csv_b] {
        let _ = std::fs::remove_file(csv);
    }
}

/// The remote drops a base silent for the liveness time (10 s).
const LIVENESS_S: f64 = 10.0;

#[cfg(unix)]
#[test]
fn a_hung_controller_is_replaced_by_the_waiting_base_within_the_liveness_time() {
    let (mut remote, addr) = remote();
    let (csv_a, csv_b) = (csv_path("hung-a"), csv_path("hung-b"));
    let a = base(&addr, "60", &csv_a, &[]);
    remote.line_with("holds control (term 1)", Duration::from_secs(20));
    let b_started = Instant::now();
    let b = base(&addr, "2", &csv_b, &["--wait-for-control", "30"]);
    std::thread::sleep(Duration::from_secs(2));
    a.signal("STOP");
    let stopped = Instant::now();

    let (status_b, report_b, _) = report(b, Duration::from_secs(60));
    a.signal("CONT");
    // A finds its link gone, and says so.
    let (status_a, _, _) = a.wait(Duration::from_secs(60));
    let (_, stdout_r, stderr_r) = remote.wait(Duration::from_secs(60));
    assert!(status_b.success(), "{report_b}");
    assert!(!status_a.success());
    assert_eq!(report_b["role"], "controller", "{report_b}");
    let waited = report_b["waited_for_control_s"].as_f64().expect("B waited");
    let granted = b_started + Duration::from_secs_f64(waited);
    // Not before A went silent for most of the liveness time, and not
    // much after it.
    let after = granted.saturating_duration_since(stopped).as_secs_f64();
    assert!(
        after > LIVENESS_S - 3.0 && after < LIVENESS_S + 3.0,
        "granted {after} s after A stopped; {report_b}"
    );
    let r: Value = serde_json::from_str(&stdout_r)
        .unwrap_or_else(|e| panic!("no JSON report ({e}): {stdout_r:?}; stderr:\n{stderr_r}"));
    assert_eq!(r["handovers"], 1, "{r}");
    assert_eq!(r["commands_after_term"], 0, "{r}");
    let sa = session(&r, &serde_json::json!([1]));
    assert!(sa["end"].as_str().unwrap().contains("silent"), "{r}");
    for csv in [csv_a, csv_b] {
        let _ = std::fs::remove_file(csv);
    }
}
