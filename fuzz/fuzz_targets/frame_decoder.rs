//! Arbitrary bytes into the frame decoder and the stream deframer.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| ndr_fuzz::harness::decode(data));
