//! Running the `ndr` binary as a user does, for the CLI tests.

use std::process::{Command, Output};

use serde_json::Value;

/// `ndr ARGS…`, its status and output.
pub fn ndr(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ndr"))
        .args(args)
        .output()
        .expect("the ndr binary runs")
}

/// `ndr ARGS…`, which must succeed and print one JSON object.
pub fn json(args: &[&str]) -> Value {
    let out = ndr(args);
    assert!(
        out.status.success(),
        "ndr {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("one JSON object on stdout")
}
