//! An endpoint fed an arbitrary sequence of frames, ticks and calls.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| ndr_fuzz::harness::endpoint(data));
