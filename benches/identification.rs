//! System identification and state estimation hot paths, one call per
//! iteration: RLS update (P = 4), ARX(2) update (RLS with P = 5) and one
//! estimator tick with online identification.
//!
//! Inputs cycle through a precomputed table of pseudo-random samples so that
//! nothing is constant-folded and no `sin` call is timed with the update.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use ndr_core::Estimator;
use ndr_core::Rls;
use ndr_core::{Arx2, Tf2, Tf2State};

const TABLE: usize = 1024;

/// xorshift64 mapped to [−1, 1).
fn noise(state: &mut u64) -> f64 {
    *state ^= *state << 13;
    *state ^= *state >> 7;
    *state ^= *state << 17;
    (*state >> 11) as f64 / (1u64 << 52) as f64 - 1.0
}

/// Input/output pairs of the paper's axis model (1 Hz, ζ = 0.7, T = 0.2 s)
/// driven by white noise.
fn plant_table() -> Vec<(f64, f64)> {
    let tf = Tf2::low_pass(2.0 * std::f64::consts::PI, 0.7, 1.0, 0.2).unwrap();
    let mut plant = Tf2State::new(tf);
    let mut s = 0x2545_f491_4f6c_dd1d;
    (0..TABLE)
        .map(|_| {
            let u = noise(&mut s);
            (u, plant.step(u))
        })
        .collect()
}

fn rls_update(c: &mut Criterion) {
    let mut s = 0x9e37_79b9_7f4a_7c15;
    let table: Vec<([f64; 4], f64)> = (0..TABLE)
        .map(|_| {
            let x = [noise(&mut s), noise(&mut s), noise(&mut s), noise(&mut s)];
            let d = 0.5 * x[0] - x[1] + 0.25 * x[2] + 2.0 * x[3] + 1e-3 * noise(&mut s);
            (x, d)
        })
        .collect();
    let mut rls = Rls::<4>::new(0.99, 1e3).unwrap();
    let mut i = 0;
    c.bench_function("rls update P=4", |b| {
        b.iter(|| {
            let (x, d) = &table[i % TABLE];
            i += 1;
            black_box(rls.update(black_box(x), black_box(*d)))
        })
    });
    assert_eq!(rls.covariance_resets(), 0);
}

fn arx2_update(c: &mut Criterion) {
    let table = plant_table();
    let mut arx = Arx2::new(0.99, 1e3).unwrap();
    let mut i = 0;
    c.bench_function("arx2 update", |b| {
        b.iter(|| {
            let (u, y) = table[i % TABLE];
            i += 1;
            black_box(arx.update(black_box(u), black_box(y)))
        })
    });
}

fn estimator_step(c: &mut Criterion) {
    let table = plant_table();
    let arx = Arx2::new(0.99, 1e3).unwrap();
    let mut est = Estimator::<16>::new(3, 4, arx).unwrap();
    // Warm up past the fallback so the timed path simulates the model.
    for &(u, y) in &table {
        let _ = est.step(u, Some(y)).unwrap();
    }
    assert!(est.step(0.0, Some(0.0)).unwrap().from_model);
    let mut i = 0;
    c.bench_function("estimator step (Df=3, Db=4)", |b| {
        b.iter(|| {
            let (u, y) = table[i % TABLE];
            i += 1;
            black_box(est.step(black_box(u), black_box(Some(y))))
        })
    });
}

criterion_group!(benches, rls_update, arx2_update, estimator_step);
criterion_main!(benches);
