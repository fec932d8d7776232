//! `ndr soak`, short: every kind of fault is injected, each connection's
//! samples come in order with none lost or repeated without a counter
//! saying so, nothing panics. Over TCP, and over datagrams (plain UDP or
//! QUIC) that the relay loses.

use std::process::Command;
use std::sync::{Mutex, PoisonError};

/// One soak at a time: each runs a 1 kHz base and remote, and two at once
/// on a small machine would judge the machine more than the link.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// Runs `ndr soak --duration-s 9 --fault-every-s 1.2 --json` with `extra`;
/// its report, once it passed.
fn soak(extra: &[&str]) -> serde_json::Value {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(PoisonError::into_inner);
    let out = Command::new(env!("CARGO_BIN_EXE_ndr"))
        .args([
            "soak",
            "--duration-s",
            "9",
            "--fault-every-s",
            "1.2",
            "--json",
        ])
        .args(extra)
        .output()
        .expect("ndr runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "ndr soak {extra:?} failed: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value = serde_json::from_str(&stdout).expect("one JSON object");
    assert_eq!(r["ok"], true, "{r}");
    r
}

fn n(r: &serde_json::Value, k: &str) -> u64 {
    r[k].as_u64().unwrap_or_else(|| panic!("{k} in {r}"))
}

/// What every soak must show: no sample lost without a counter, repeated
/// or reordered, every fault injected, the faults that must be refused
/// refused.
fn assert_clean(r: &serde_json::Value) {
    for k in [
        "lost",
        "duplicated",
        "reordered",
        "corrupted",
        "remote_anomalies",
        "panics",
        "remote_crashes",
    ] {
        assert_eq!(n(r, k), 0, "{k}: {r}");
    }
    for k in [
        "faults_relay_restarts",
        "faults_garbage",
        "faults_remote_killed",
        "faults_spikes",
        "faults_hung_bases",
        "faults_stale_frames",
    ] {
        assert!(n(r, k) >= 1, "{k}: {r}");
    }
    assert_eq!(n(r, "garbage_cut_off"), n(r, "faults_garbage"), "{r}");
    assert_eq!(n(r, "hung_bases_dropped"), n(r, "faults_hung_bases"), "{r}");
    assert_eq!(
        n(r, "stale_frames_refused"),
        n(r, "faults_stale_frames"),
        "{r}"
    );
    // A relay restart does not end a QUIC link (it moves to the new
    // relay's address, as to a new network): only the remote's kill does.
    let quic = r["transport"]
        .as_str()
        .is_some_and(|t| t.starts_with("quic"));
    assert!(n(r, "reconnections") >= if quic { 1 } else { 3 }, "{r}");
    // It ran: at 1 kHz for 9 s, each sample released or, where a host
    // too busy for the rate held a hub past its queue, counted as dropped.
    let released = n(r, "samples_released");
    assert!(released > 1000, "{r}");
    assert!(released + n(r, "dropped_with_counter") > 3000, "{r}");
}

/// The garbage fault's datagrams: all counted as strays by the remote's
/// listener, no link harmed.
fn assert_garbage_datagrams_counted(r: &serde_json::Value) {
    assert!(n(r, "garbage_datagrams") >= 10, "{r}");
    assert_eq!(
        n(r, "garbage_datagrams_counted"),
        n(r, "garbage_datagrams"),
        "{r}"
    );
    assert_eq!(n(r, "garbage_datagrams_harmed"), 0, "{r}");
}

#[test]
fn a_short_soak_under_faults_loses_nothing() {
    let r = soak(&[]);
    assert_clean(&r);
    assert_eq!(r["transport"], "tcp", "{r}");
    assert_eq!(n(&r, "datagrams_received"), 0, "{r}");
}

/// A soak over `transport` (udp or quic) with 2 % of the datagrams lost
/// each way: nearly all made good from the next datagrams' copies, the
/// rest counted, the garbage datagrams counted as strays.
fn lossy_datagrams_recover_or_count(transport: &str) {
    let r = soak(&["--transport", transport, "--loss", "2"]);
    assert_clean(&r);
    assert_eq!(r["transport"], transport, "{r}");
    assert!(n(&r, "relay_datagrams_lost") > 100, "{r}");
    assert!(n(&r, "datagrams_received") > 3000, "{r}");
    // At 1 kHz each sample's datagram goes again half a period later while
    // the path loses datagrams: a loss is made good by its repeat, or by
    // the next datagrams' copies when both went (both ways: the base's
    // states and the remote's commands).
    assert!(n(&r, "datagrams_repeated") > 3000, "{r}");
    assert!(
        n(&r, "samples_recovered") + n(&r, "remote_samples_recovered") > 0,
        "{r}"
    );
    assert_garbage_datagrams_counted(&r);
}

/// The datagram transport as it ships (three samples per datagram): 2 %
/// of the datagrams lost each way, nearly all made good from the next
/// datagrams' copies, the rest counted.
#[test]
fn a_short_soak_over_lossy_datagrams_recovers_or_counts_every_sample() {
    lossy_datagrams_recover_or_count("udp");
}

/// QUIC: the same datagrams as QUIC DATAGRAM frames under mutual TLS 1.3
/// (the soak makes both sides' throwaway identities and pins them), 2 %
/// of them lost each way by the relay: QUIC resends none of them, so the
/// copies make good nearly every loss and the rest is counted, as over
/// plain UDP. The garbage datagrams go to the remote's QUIC port; the
/// garbage connection is a stranger's handshake, refused.
#[test]
fn a_short_soak_over_lossy_quic_recovers_or_counts_every_sample() {
    lossy_datagrams_recover_or_count("quic");
}

/// One sample per datagram, never repeated: each datagram the relay loses is a sample
/// lost for good (a few hundred), which the check must find counted
/// (`samples_lost`) on the side that missed it, or fail.
#[test]
fn a_short_soak_over_lossy_datagrams_without_copies_counts_every_loss() {
    let r = soak(&["--transport", "udp:1:0", "--loss", "2"]);
    assert_clean(&r);
    assert_eq!(r["transport"], "udp:1:0", "{r}");
    assert!(n(&r, "relay_datagrams_lost") > 100, "{r}");
    assert!(n(&r, "samples_lost") > 30, "{r}");
    assert!(n(&r, "remote_samples_lost") > 30, "{r}");
    assert_eq!(n(&r, "samples_recovered"), 0, "{r}");
    assert_garbage_datagrams_counted(&r);
}

/// Ctrl-C (SIGINT) stops a soak in order: it reports what it saw so far,
/// says it was cut short (a non-zero exit), stops its remote, and leaves
/// none of its throwaway identities behind.
#[test]
fn an_interrupted_quic_soak_reports_and_leaves_no_keys_behind() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(PoisonError::into_inner);
    let tmp = std::env::temp_dir().join(format!("ndr-soak-int-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let left = || {
        std::fs::read_dir(&tmp)
            .unwrap()
            .filter_map(Result::ok)
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|name| name.starts_with("ndr-soak-quic"))
            .collect::<Vec<_>>()
    };
    let mut soak = Command::new(env!("CARGO_BIN_EXE_ndr"));
    soak.args([
        "soak",
        "--transport",
        "quic",
        "--duration-s",
        "120",
        "--json",
    ])
    .env("TMPDIR", &tmp)
    .stdout(std::process::Stdio::piped())
    .stderr(std::process::Stdio::piped());
    // In a group of its own, which gets the signal, as the foreground
    // group at a terminal gets a Ctrl-C.
    std::os::unix::process::CommandExt::process_group(&mut soak, 0);
    let mut child = soak.spawn().expect("ndr runs");
    // Its identities made, then a second or two of soak.
    let made = std::time::Instant::now();
    while left().is_empty() {
        assert!(made.elapsed().as_secs() < 20, "no identities made");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    std::thread::sleep(std::time::Duration::from_secs(2));
    let sent = Command::new("kill")
        .args(["-INT", "--", &format!("-{}", child.id())])
        .status()
        .expect("kill runs");
    assert!(sent.success());
    let asked = std::time::Instant::now();
    let out = loop {
        if child.try_wait().unwrap().is_some() {
            break child.wait_with_output().unwrap();
        }
        assert!(
            asked.elapsed().as_secs() < 30,
            "still running 30 s after SIGINT"
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    };
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stdout}\n{stderr}");
    assert!(stderr.contains("interrupted after"), "{stderr}");
    let r: serde_json::Value = serde_json::from_str(&stdout).expect("one JSON object");
    assert_eq!(r["interrupted"], true, "{r}");
    assert_eq!(r["ok"], true, "{r}");
    assert!(r["ran_s"].as_f64().unwrap() < 60.0, "{r}");
    assert!(n(&r, "samples_released") > 0, "{r}");
    // Its remote was stopped, not lost: it is in a group of its own, and
    // the Ctrl-C was the soak's alone.
    assert_eq!(n(&r, "remote_crashes"), 0, "{r}");
    assert_eq!(left(), Vec::<String>::new());
    let _ = std::fs::remove_dir_all(&tmp);
}

#[test]
fn bad_options_are_refused() {
    let out = Command::new(env!("CARGO_BIN_EXE_ndr"))
        .args(["soak", "--duration-s=-3"])
        .output()
        .expect("ndr runs");
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--duration-s"));
}

#[test]
fn loss_without_datagrams_is_refused() {
    let out = Command::new(env!("CARGO_BIN_EXE_ndr"))
        .args(["soak", "--duration-s", "1", "--loss", "2"])
        .output()
        .expect("ndr runs");
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("--loss 2") && stderr.contains("--transport udp"),
        "{stderr}"
    );
}
