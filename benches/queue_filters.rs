//! Costs of the paper's building blocks: the NDR queue, the Kalman filter and
//! the whole network predictor. Targets (issue 2): ≤ 10 ns, ≤ 50 ns, ≤ 300 ns.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use ndr::core::kalman::Kalman3;
use ndr::core::predictor::{NetworkPredictor, PredictorConfig};
use ndr::core::regulator::{Regulator, Tick};
use ndr::core::time::Duration;

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
            black_box(p.update(black_box(Some(nrtt)), black_box(Some(gap))))
        })
    });
}

criterion_group!(benches, queue, kalman, predictor);
criterion_main!(benches);
