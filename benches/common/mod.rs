//! What the link benches share.

use ndr::core::time::Instant;
use ndr::core::wire::{self, Header, MAX_FRAME_LEN, Message};

/// One 1-axis Data frame, the bytes a link sends at each tick: the raw
/// baselines carry the same.
pub fn frame() -> Vec<u8> {
    let header = Header {
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
