//! A whole link (two endpoints on the shared `Pair`) run by an arbitrary
//! script of wire delays, losses, stops, garbage, time and calls.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| ndr_fuzz::harness::pair(data));
