//! The fuzz harnesses (see `harness.rs`), as a library for the targets.
#![forbid(unsafe_code)]

#[path = "../harness.rs"]
pub mod harness;
