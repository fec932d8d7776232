//! A link on the datagram transport whose datagrams the script carries:
//! the peer's bundles late, twice, reordered, lost, replayed or forged,
//! and raw bytes, into `handle_datagram`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| ndr_fuzz::harness::datagram(data));
