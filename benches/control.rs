//! The control building blocks' hot paths, one tick per iteration: a Smith
//! predictor step (feedback and command) with a given model, and a wave
//! transform step (master and slave sides with the channel's energy
//! account).
//!
//! Inputs cycle through a precomputed table so that nothing is
//! constant-folded.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use ndr_core::Tf2;
use ndr_core::control::{SmithPredictor, WaveEnergy, WaveTransform};

const TABLE: usize = 1024;

/// xorshift64 mapped to [−1, 1).
fn noise(state: &mut u64) -> f64 {
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    (*state >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

fn table(seed: u64) -> Vec<f64> {
    let mut s = seed;
    (0..TABLE).map(|_| noise(&mut s)).collect()
}

fn smith_step(c: &mut Criterion) {
    let plant = Tf2::low_pass(std::f64::consts::TAU * 0.5, 0.7, 1.0, 0.02).unwrap();
    let mut smith = SmithPredictor::<256>::with_model(plant, 40).unwrap();
    let (ys, us) = (table(0x9e37_79b9_7f4a_7c15), table(0x2545_f491_4f6c_dd1d));
    let mut i = 0;
    c.bench_function("smith predictor step (H=256, D=40)", |b| {
        b.iter(|| {
            let k = i % TABLE;
            i += 1;
            let seen = smith.feedback(Some(black_box(ys[k]))).unwrap();
            smith.command(black_box(us[k]) - 0.1 * seen).unwrap();
            black_box(seen)
        })
    });
}

fn wave_step(c: &mut Criterion) {
    let w = WaveTransform::new(2.0).unwrap();
    let mut energy = WaveEnergy::default();
    let (xs, fs) = (table(0x1234_5678_9abc_def1), table(0x0fed_cba9_8765_4321));
    let mut i = 0;
    c.bench_function("wave transform step (master + slave + energy)", |b| {
        b.iter(|| {
            let k = i % TABLE;
            i += 1;
            let m = w.master(black_box(xs[k]), black_box(fs[k])).unwrap();
            let s = w.slave(black_box(m.wave), black_box(xs[k])).unwrap();
            energy.sent(m.wave, 0.02);
            energy.delivered(s.wave, 0.02);
            black_box((m.force, s.velocity))
        })
    });
    black_box(energy.generated());
}

criterion_group!(benches, smith_step, wave_step);
criterion_main!(benches);
