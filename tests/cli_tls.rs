//! `ndr keygen`, and `ndr base` / `ndr remote` refusing a plain link off
//! loopback unless `--insecure`.

use std::process::Command;
use std::time::{Duration, Instant};

fn ndr(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_ndr"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn keygen_writes_a_pair_and_prints_its_fingerprint() {
    let dir = std::env::temp_dir().join(format!("ndr-cli-keygen-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = ndr(&["keygen", "--out", dir.to_str().unwrap(), "--name", "robot"]);
    assert!(out.status.success(), "{out:?}");
    let stdout = String::from_utf8(out.stdout).unwrap();
    let line = stdout.lines().find(|l| l.starts_with("sha256:")).unwrap();
    let printed: ndr::net::Fingerprint = line["sha256:".len()..].parse().unwrap();
    let pins = ndr::net::tls::read_fingerprints(dir.join("robot.crt")).unwrap();
    assert_eq!(pins, [printed]);
    assert!(dir.join("robot.key").exists());
    // A second run must not overwrite the key.
    let again = ndr(&["keygen", "--out", dir.to_str().unwrap(), "--name", "robot"]);
    assert!(!again.status.success());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn plain_links_off_loopback_need_insecure() {
    let start = Instant::now();
    let out = ndr(&["base", "--connect", "192.0.2.1:9", "--duration-s", "1"]);
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("--insecure") && err.contains("TLS"), "{err}");
    // Refused before connecting (TEST-NET-1 would hang the connect).
    assert!(start.elapsed() < Duration::from_secs(5));
    let out = ndr(&["remote", "--listen", "0.0.0.0:0", "--once"]);
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("--insecure"), "{err}");
}
