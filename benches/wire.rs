//! Frame codec: one Data frame of 8 channels through encode, check and copy-out,
//! the per-sample cost on each side of the link.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use ndr::core::time::{Duration, Instant};
use ndr::core::wire::{self, Echo, Frame, Header, MAX_FRAME_LEN, Message, Payload};

fn encode_decode(c: &mut Criterion) {
    let header = Header {
        seq: 1_000,
        sent_at: Instant::from_millis(200_000),
        echo: Some(Echo {
            sent_at: Instant::from_millis(199_950),
            hold: Duration::from_micros(120),
        }),
        released: Some(996),
    };
    let values = [0.1, -0.2, 0.3, -0.4, 0.5, -0.6, 0.7, -0.8];

    // The stack buffer a driver reuses for every frame: zeroing 2 KiB per frame
    // would cost more than the codec itself.
    let mut buf = [0u8; MAX_FRAME_LEN];
    c.bench_function("frame encode+decode, 8 channels", |b| {
        b.iter(|| {
            let n = wire::encode(
                black_box(&header),
                &Message::Data(black_box(&values)),
                &mut buf,
            )
            .expect("valid frame");
            let frame = Frame::new_checked(black_box(&buf[..n])).expect("valid frame");
            let mut out = [0.0f64; 8];
            if let Payload::Data(channels) = frame.payload() {
                channels.copy_to(&mut out).expect("8 channels");
            }
            black_box(out)
        });
    });
}

criterion_group!(benches, encode_decode);
criterion_main!(benches);
