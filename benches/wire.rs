//! Frame codec: one Data frame of 8 and of 64 channels through encode,
//! check and copy-out, the per-sample cost on each side of the link; and a
//! datagram's Bundle of 64 channels (the newest sample and the copies that
//! fit the datagram budget) the same way.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use ndr::core::time::{Duration, Instant};
use ndr::core::wire::{
    self, Echo, Frame, Header, MAX_DATAGRAM_LEN, MAX_FRAME_LEN, Message, OlderSample, Payload,
};

fn encode_decode(c: &mut Criterion) {
    let header = Header {
        term: 0,
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

fn wide(c: &mut Criterion) {
    let header = Header {
        term: 0,
        seq: 1_000,
        sent_at: Instant::from_millis(200_000),
        echo: Some(Echo {
            sent_at: Instant::from_millis(199_950),
            hold: Duration::from_micros(120),
        }),
        released: Some(996),
    };
    let values: [f64; 64] = std::array::from_fn(|i| i as f64 * 0.01 - 0.3);
    let mut buf = vec![0u8; MAX_DATAGRAM_LEN];
    c.bench_function("frame encode+decode, 64 channels", |b| {
        b.iter(|| {
            let n = wire::encode(
                black_box(&header),
                &Message::Data(black_box(&values)),
                &mut buf,
            )
            .expect("valid frame");
            let frame = Frame::new_checked(black_box(&buf[..n])).expect("valid frame");
            let mut out = [0.0f64; 64];
            if let Payload::Data(channels) = frame.payload() {
                channels.copy_to(&mut out).expect("64 channels");
            }
            black_box(out)
        });
    });
    // One older copy fits the 1 200-byte budget beside 64 values.
    let older = [OlderSample {
        seq: 999,
        sent_at: Instant::from_millis(199_980),
        released: Some(995),
        values: &values,
    }];
    c.bench_function("bundle encode+decode, 64 channels, one copy", |b| {
        b.iter(|| {
            let msg = Message::Bundle {
                session: 0x5eed,
                repeat: 0,
                missed: 0,
                newest: black_box(&values),
                older: black_box(&older),
            };
            let n = wire::encode(black_box(&header), &msg, &mut buf).expect("valid bundle");
            let frame = Frame::new_checked(black_box(&buf[..n])).expect("valid bundle");
            let mut out = [0.0f64; 64];
            let mut copy = [0.0f64; 64];
            if let Payload::Bundle(bundle) = frame.payload() {
                bundle.newest().copy_to(&mut out).expect("64 channels");
                for o in bundle.older() {
                    o.values.copy_to(&mut copy).expect("64 channels");
                }
            }
            black_box((out, copy))
        });
    });
}

criterion_group!(benches, encode_decode, wide);
criterion_main!(benches);
