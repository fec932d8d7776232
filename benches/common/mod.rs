//! What the link benches share.

use ndr::core::time::Instant;
use ndr::core::wire::{self, Header, MAX_FRAME_LEN, Message};
use ndr::net::TlsConfig;

/// One 1-axis Data frame, the bytes a link sends at each tick: the raw
/// baselines carry the same.
pub fn frame() -> Vec<u8> {
    let header = Header {
        term: 0,
        seq: 1,
        sent_at: Instant::from_millis(1),
        echo: None,
        released: None,
    };
    let mut buf = vec![0; MAX_FRAME_LEN];
    let n = wire::encode(&header, &Message::Data(&[0.5]), &mut buf).unwrap();
    buf.truncate(n);
    buf
}

/// One 1-axis Bundle with the copies of the two samples before it: the
/// bytes a datagram link sends at each tick (and again at each repeat).
#[allow(dead_code)]
pub fn bundle() -> Vec<u8> {
    let header = Header {
        term: 0,
        seq: 3,
        sent_at: Instant::from_millis(3),
        echo: None,
        released: None,
    };
    let older = [2_u64, 1].map(|seq| wire::OlderSample {
        seq,
        sent_at: Instant::from_millis(seq),
        released: None,
        values: &[0.5],
    });
    let msg = Message::Bundle {
        session: 0x5eed,
        repeat: 0,
        missed: 0,
        newest: &[0.5],
        older: &older,
    };
    let mut buf = vec![0; wire::MAX_DATAGRAM_LEN];
    let n = wire::encode(&header, &msg, &mut buf).unwrap();
    buf.truncate(n);
    buf
}

/// The remote's and the base's TLS configurations, each pinning the other,
/// from throwaway certificates (a QUIC link needs them).
#[allow(dead_code)]
pub fn tls_pair() -> (TlsConfig, TlsConfig) {
    let dir = std::env::temp_dir().join(format!("ndr-bench-tls-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let b = ndr::keygen::write(&dir, "base").unwrap();
    let r = ndr::keygen::write(&dir, "remote").unwrap();
    let remote = TlsConfig::from_files(&r.cert, &r.key, &b.cert).unwrap();
    let base = TlsConfig::from_files(&b.cert, &b.key, &r.cert).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    (remote, base)
}
