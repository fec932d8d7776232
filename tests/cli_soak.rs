//! `ndr soak`, short: every kind of fault is injected, each connection's
//! samples come in order with none lost or repeated, nothing panics.

use std::process::Command;

#[test]
fn a_short_soak_under_faults_loses_nothing() {
    let out = Command::new(env!("CARGO_BIN_EXE_ndr"))
        .args([
            "soak",
            "--duration-s",
            "9",
            "--fault-every-s",
            "1.2",
            "--json",
        ])
        .output()
        .expect("ndr runs");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "ndr soak failed: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: serde_json::Value = serde_json::from_str(&stdout).expect("one JSON object");
    let n = |k: &str| r[k].as_u64().unwrap_or_else(|| panic!("{k} in {r}"));
    assert_eq!(r["ok"], true);
    for k in [
        "lost",
        "duplicated",
        "reordered",
        "corrupted",
        "remote_anomalies",
        "panics",
    ] {
        assert_eq!(n(k), 0, "{k}: {r}");
    }
    for k in [
        "faults_relay_restarts",
        "faults_garbage",
        "faults_remote_killed",
        "faults_spikes",
    ] {
        assert!(n(k) >= 1, "{k}: {r}");
    }
    assert_eq!(n("garbage_cut_off"), n("faults_garbage"), "{r}");
    assert!(n("reconnections") >= 3, "{r}");
    assert!(n("samples_released") > 3000, "{r}");
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
