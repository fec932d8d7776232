//! `ndr base --wait-for-remote` and `--reconnect` with real processes: a
//! base started before its remote is served once the remote comes; a
//! remote killed (SIGKILL) and started again two seconds later under a
//! base that reconnects, over tcp, udp and quic: the base runs to its
//! duration, counts one reconnect and the outage, and releases no state
//! twice or out of order. Margins are seconds wide: a loaded host delays
//! the processes' starts, not what is checked.

mod cli_proc;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use cli_proc::{Proc, free_port, serial};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ndr-reconnect-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A certificate pair for a QUIC link, made by `ndr keygen`.
fn keys(dir: &Path) {
    for name in ["base", "remote"] {
        let (status, _, err) =
            Proc::spawn(&["keygen", "--out", dir.to_str().unwrap(), "--name", name])
                .wait(Duration::from_secs(30));
        assert!(status.success(), "{err}");
    }
}

/// `--transport` and the certificate options of each side.
fn transport_args(transport: &str, dir: &Path) -> (Vec<String>, Vec<String>) {
    let mut base = vec!["--transport".to_string(), transport.to_string()];
    let mut remote = base.clone();
    if transport == "quic" {
        let f = |n: &str| dir.join(n).to_str().unwrap().to_string();
        base.extend([
            "--cert".into(),
            f("base.crt"),
            "--key".into(),
            f("base.key"),
            "--peer-cert".into(),
            f("remote.crt"),
        ]);
        remote.extend([
            "--cert".into(),
            f("remote.crt"),
            "--key".into(),
            f("remote.key"),
            "--peer-cert".into(),
            f("base.crt"),
        ]);
    }
    (base, remote)
}

fn spawn(args: &[String]) -> Proc {
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    Proc::spawn(&args)
}

/// The JSON report on the base's stdout.
fn report(stdout: &str) -> serde_json::Value {
    serde_json::from_str(stdout.lines().next().unwrap_or_default())
        .unwrap_or_else(|e| panic!("not a JSON report ({e}): {stdout}"))
}

/// The series' (sequence, held) rows.
fn series(csv: &Path) -> Vec<(u64, bool)> {
    let text = std::fs::read_to_string(csv).unwrap();
    text.lines()
        .skip(1)
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            (f[1].parse().unwrap(), f[2] == "held")
        })
        .collect()
}

fn waits_for_a_remote_started_two_seconds_later(transport: &str, json: bool) {
    let _one = serial();
    let dir = scratch(&format!("wait-{transport}"));
    let addr = format!("127.0.0.1:{}", free_port());
    let csv = dir.join("base.csv");
    let mut args: Vec<String> = [
        "base",
        "--connect",
        &addr,
        "--wait-for-remote",
        "10",
        "--duration-s",
        "2",
        "--out",
        csv.to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec();
    args.extend(["--transport".into(), transport.into()]);
    if json {
        args.push("--json".into());
    }
    let base = spawn(&args);
    std::thread::sleep(Duration::from_secs(2));
    let remote = spawn(
        &[
            "remote",
            "--listen",
            &addr,
            "--once",
            "--transport",
            transport,
        ]
        .map(String::from),
    );
    let (status, out, err) = base.wait(Duration::from_secs(40));
    assert!(status.success(), "{out}\n{err}");
    let waited = if json {
        let r = report(&out);
        assert_eq!(r["ok"], true, "{r}");
        assert!(r["samples_released"].as_u64().unwrap() > 0, "{r}");
        r["waited_for_remote_s"].as_f64().unwrap()
    } else {
        // "  waited     2.31 s for the remote"
        let line = out
            .lines()
            .find(|l| l.trim_start().starts_with("waited"))
            .unwrap_or_else(|| panic!("no wait in the report:\n{out}"));
        line.split_whitespace().nth(1).unwrap().parse().unwrap()
    };
    // Started two seconds after the base: it waited about that long (its
    // own start, and the remote's, under load move it by a fraction).
    assert!((1.0..10.0).contains(&waited), "waited {waited} s\n{out}");
    drop(remote);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn a_base_waits_for_its_remote_over_tcp() {
    waits_for_a_remote_started_two_seconds_later("tcp", true);
}

#[test]
fn a_base_waits_for_its_remote_over_udp_and_says_so() {
    waits_for_a_remote_started_two_seconds_later("udp", false);
}

const LOST: &str = "was lost";

fn comes_back_after_a_remote_restart(transport: &str) {
    let _one = serial();
    let dir = scratch(transport);
    if transport == "quic" {
        keys(&dir);
    }
    let (base_tr, remote_tr) = transport_args(transport, &dir);
    let addr = format!("127.0.0.1:{}", free_port());
    let csv = dir.join("base.csv");
    let mut remote_args: Vec<String> = ["remote", "-v", "--listen", &addr]
        .map(String::from)
        .to_vec();
    remote_args.extend(remote_tr);
    let mut base_args: Vec<String> = [
        "base",
        "--connect",
        &addr,
        "--reconnect",
        "--wait-for-remote",
        "10",
        "--duration-s",
        "10",
        "--json",
        "--out",
        csv.to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec();
    base_args.extend(base_tr);

    let mut first = spawn(&remote_args);
    let mut base = spawn(&base_args);
    first.line_with("samples flow", Duration::from_secs(20));
    std::thread::sleep(Duration::from_millis(1500));
    first.signal("KILL");
    let (_, _, _) = first.wait(Duration::from_secs(10));
    std::thread::sleep(Duration::from_secs(2));
    // Over QUIC nothing tells the base its remote died until it hears
    // from the new one: not before.
    if transport == "quic" {
        assert_eq!(base.count(LOST), 0, "{}", base.stderr());
    }
    let restarted = Instant::now();
    let second = spawn(&remote_args);
    base.line_with(LOST, Duration::from_secs(15));
    let noticed = restarted.elapsed();
    let (status, out, err) = base.wait(Duration::from_secs(40));
    assert!(status.success(), "{out}\n{err}");
    let r = report(&out);
    assert_eq!(r["ok"], true, "{r}");
    assert_eq!(r["reconnects"], 1, "{r}");
    // Two seconds away, then the new link's start.
    let outage = r["outage_total_s"].as_f64().unwrap();
    assert!((1.9..8.0).contains(&outage), "outage {outage} s: {r}");
    assert_eq!(r["seq_out_of_order"], 0, "{r}");
    // The series: each fresh state after the last, each held one a repeat
    // of it, states on both sides of the outage.
    let rows = series(&csv);
    let mut last = None;
    for &(seq, held) in &rows {
        match last {
            Some(l) if held => assert_eq!(seq, l, "a held row not repeating {l}"),
            Some(l) => assert!(seq > l, "{seq} after {l}"),
            None => assert!(!held),
        }
        if !held {
            last = Some(seq);
        }
    }
    assert!(rows.len() > 60, "{} rows", rows.len());
    assert!(err.contains("is back after"), "{err}");
    if transport == "quic" {
        // The restarted remote's stateless reset, not the liveness time.
        assert!(
            noticed < Duration::from_secs(1),
            "noticed after {noticed:?}"
        );
    }
    eprintln!("{transport}: outage {outage:.3} s, loss seen {noticed:?} after the restart");
    drop(second);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn a_base_comes_back_after_its_remote_restarts_over_tcp() {
    comes_back_after_a_remote_restart("tcp");
}

#[test]
fn a_base_comes_back_after_its_remote_restarts_over_udp() {
    comes_back_after_a_remote_restart("udp");
}

#[test]
fn a_base_comes_back_after_its_remote_restarts_over_quic_at_once() {
    comes_back_after_a_remote_restart("quic");
}
