//! Costs of the paper's building blocks: the NDR queue, the Kalman filter and
//! the whole network predictor. Targets: ≤ 10 ns, ≤ 50 ns, ≤ 300 ns.
//! And of the adaptive playout's target: one delay observed, per
//! received sample.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use ndr::core::Kalman3;
use ndr::core::playout::{Adaptive, TargetDelay};
use ndr::core::regulator::{Regulator, Tick};
use ndr::core::time::{Duration, Instant};
use ndr::core::{NetworkPredictor, PredictorConfig};

const T: Duration = Duration::from_millis(200);

fn queue(c: &mut Criterion) {
    // A steady-state queue holding a few samples of 8 axes, as a link would.
    let mut r: Regulator<[f64; 8], 32> = Regulator::new(4).unwrap();
    for k in 0..4 {
        r.push([k as f64; 8]).unwrap();
    }
    let _ = r.tick();
    let mut x = 0.0;
    c.bench_function("queue push+pop ([f64; 8], N = 32)", |b| {
        b.iter(|| {
            x += 1.0;
            let _ = r.push(black_box([x; 8]));
            match r.tick() {
                Tick::Released(s) => black_box(s),
                _ => unreachable!("the queue holds its stock"),
            }
        })
    });
}

fn queue_64(c: &mut Criterion) {
    // The same with samples of 64 channels.
    let mut r: Regulator<[f64; 64], 32> = Regulator::new(4).unwrap();
    for k in 0..4 {
        r.push([k as f64; 64]).unwrap();
    }
    let _ = r.tick();
    let mut x = 0.0;
    c.bench_function("queue push+pop ([f64; 64], N = 32)", |b| {
        b.iter(|| {
            x += 1.0;
            let _ = r.push(black_box([x; 64]));
            match r.tick() {
                Tick::Released(s) => black_box(s),
                _ => unreachable!("the queue holds its stock"),
            }
        })
    });
}

fn kalman(c: &mut Criterion) {
    let mut k = Kalman3::new(1.0, T, 50).unwrap();
    let mut z = 0.6;
    c.bench_function("kalman3 predict+update", |b| {
        b.iter(|| {
            z += 1e-4;
            k.predict();
            black_box(k.update(black_box(z)).unwrap())
        })
    });
}

fn predictor(c: &mut Criterion) {
    let mut p = NetworkPredictor::new(PredictorConfig::paper(T)).unwrap();
    let mut i = 0u64;
    c.bench_function("network predictor step (observe nrtt + gap, step)", |b| {
        b.iter(|| {
            i += 1;
            let nrtt = Duration::from_micros(600_000 + (i * 7919) % 50_000);
            let gap = Duration::from_micros((i * 104_729) % 30_000);
            p.observe_nrtt(black_box(nrtt));
            p.observe_gap(black_box(gap));
            black_box(p.step())
        })
    });
}

fn adaptive(c: &mut Criterion) {
    // At T = 20 ms and ε = 0.1 %: exponential jitter (10 ms mean) above the
    // floor and a 300 ms stall every 1 000 samples, the window filled first
    // (4 blocks of 30 s).
    let period = Duration::from_millis(20);
    let mut a = Adaptive::new(period, 1e-3);
    let mut state = 0x2545_f491_4f6c_dd1du64;
    let mut k = 0u64;
    let mut next = || {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        k += 1;
        let u = (state >> 11) as f64 / (1u64 << 53) as f64;
        let jitter = -(1.0 - u).ln() * 0.010;
        let delay = if k % 1000 < 15 {
            0.300 - (k % 1000) as f64 * 0.020
        } else {
            jitter
        };
        let at = Instant::from_nanos(period.as_nanos().saturating_mul(k));
        (at, Duration::from_secs_f64(delay))
    };
    for _ in 0..6000 {
        let (at, d) = next();
        a.observe(at, d);
    }
    c.bench_function("adaptive target observe (T = 20 ms, ε = 0.1 %)", |b| {
        b.iter(|| {
            let (at, d) = next();
            a.observe(black_box(at), black_box(d));
            black_box(a.target())
        })
    });
}

criterion_group!(benches, queue, queue_64, kalman, predictor, adaptive);
criterion_main!(benches);
