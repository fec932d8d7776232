//! Identification of the paper's second-order axis model by RLS (`Arx2`):
//! exact recovery from noise-free data, and tracking a plant that changes.

#[allow(unused_imports)]
use std::{borrow::ToOwned, boxed::Box, string::String, string::ToString, vec::Vec};
#[allow(unused_imports)]
use std::{eprintln, format, println, vec};

use std::f64::consts::PI;

use crate::Rls;
use crate::{Arx2, Tf2, Tf2State};

/// xorshift64: a seeded pseudo-random source, enough for a PRBS.
struct XorShift(u64);

impl XorShift {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// ±1 with equal probability: white, so persistently exciting of any order.
    fn prbs(&mut self) -> f64 {
        if self.next() >> 63 == 1 { 1.0 } else { -1.0 }
    }
}

/// Four incommensurate sines (rad/sample): persistently exciting of order 8,
/// more than the 5 parameters need.
fn sines(k: usize) -> f64 {
    let k = k as f64;
    (0.05 * k).sin()
        + 0.7 * (0.21 * k + 1.0).sin()
        + 0.5 * (0.63 * k + 2.0).sin()
        + 0.3 * (1.4 * k + 0.5).sin()
}

fn max_param_error(model: &Tf2, truth: &Tf2) -> f64 {
    model
        .params()
        .iter()
        .zip(truth.params())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max)
}

/// Drives `plant` with `input` for `steps` samples, identifying it with `arx`.
fn run(
    arx: &mut Arx2,
    plant: &mut Tf2State,
    input: &mut impl FnMut(usize) -> f64,
    range: std::ops::Range<usize>,
) {
    for k in range {
        let u = input(k);
        let y = plant.step(u);
        let _ = arx.update(u, y).unwrap();
    }
}

#[test]
fn recovers_low_pass_coefficients_noise_free() {
    let wn = 2.0 * PI; // 1 Hz
    for (period, steps) in [(0.01, 20_000), (0.2, 2_000)] {
        let truth = Tf2::low_pass(wn, 0.7, 1.0, period).unwrap();
        for input in ["prbs", "sines"] {
            let mut rng = XorShift(0x2545_f491_4f6c_dd1d);
            let mut u = |k: usize| {
                if input == "prbs" {
                    rng.prbs()
                } else {
                    sines(k)
                }
            };
            let mut plant = Tf2State::new(truth);
            let mut arx = Arx2::new(1.0, 1e8).unwrap();
            run(&mut arx, &mut plant, &mut u, 0..steps);
            let err = max_param_error(&arx.model(), &truth);
            assert!(
                err <= 1e-6,
                "T = {period}, {input}: max |θ̂ − θ| = {err:e}\n got {:?}\nwant {truth:?}",
                arx.model()
            );
            assert!(arx.model().is_stable());
            assert!((arx.model().dc_gain() - 1.0).abs() < 1e-4);
            assert_eq!(arx.updates(), steps as u64 - 2);
            assert_eq!(arx.rls().covariance_resets(), 0);
        }
    }
}

#[test]
fn recovers_a_generic_arx_model_with_plain_rls() {
    // The RLS alone on a hand-built regressor, a non-low-pass numerator.
    let truth = Tf2 {
        b: [0.4, -0.3, 0.15],
        a: [-1.2, 0.5],
    };
    assert!(truth.is_stable());
    let mut plant = Tf2State::new(truth);
    let mut rls = Rls::<5>::new(1.0, 1e8).unwrap();
    let mut rng = XorShift(7);
    let (mut u1, mut u2, mut y1, mut y2) = (0.0, 0.0, 0.0, 0.0);
    for _ in 0..1000 {
        let u = rng.prbs();
        let y = plant.step(u);
        let _ = rls.update(&[u, u1, u2, -y1, -y2], y).unwrap();
        (u2, u1, y2, y1) = (u1, u, y1, y);
    }
    let err = max_param_error(&Tf2::from_params(rls.weights()), &truth);
    assert!(err <= 1e-6, "{err:e}: {:?}", rls.weights());
}

/// The plant switches from `a` to `b` after `before` samples; returns the
/// parameter error against `b` after `after` more samples.
fn switch_run(lambda: f64, before: usize, after: usize) -> (f64, f64) {
    let a = Tf2::low_pass(2.0 * PI * 1.0, 0.7, 1.0, 0.2).unwrap();
    let b = Tf2::low_pass(2.0 * PI * 0.4, 0.3, 2.0, 0.2).unwrap();
    let mut rng = XorShift(0x9e37_79b9_7f4a_7c15);
    let mut u = |_| rng.prbs();
    let mut plant = Tf2State::new(a);
    let mut arx = Arx2::new(lambda, 1e8).unwrap();
    run(&mut arx, &mut plant, &mut u, 0..before);
    let err_a = max_param_error(&arx.model(), &a);
    plant.set_model(b);
    run(&mut arx, &mut plant, &mut u, before..before + after);
    (err_a, max_param_error(&arx.model(), &b))
}

#[test]
fn forgetting_tracks_a_plant_change() {
    // λ = 0.98: old data weighs 0.98ᴺ, 7e-14 after N = 1500 samples, so the
    // new plant is recovered essentially exactly.
    let (err_a, err_b) = switch_run(0.98, 1000, 1500);
    assert!(err_a <= 1e-6, "before the switch: {err_a:e}");
    assert!(
        err_b <= 1e-6,
        "λ = 0.98, 1500 samples after the switch: {err_b:e}"
    );
    // Already close after 300 samples (0.98³⁰⁰ ≈ 2e-3).
    let (_, err_b) = switch_run(0.98, 1000, 300);
    assert!(
        err_b <= 1e-2,
        "λ = 0.98, 300 samples after the switch: {err_b:e}"
    );

    // λ = 1: the estimate averages both plants over all data and stays wrong.
    let (err_a, err_b) = switch_run(1.0, 1000, 1500);
    assert!(err_a <= 1e-6, "before the switch: {err_a:e}");
    assert!(
        err_b >= 1e-2,
        "λ = 1 should not track, yet error is {err_b:e}"
    );
}

#[test]
fn covariance_reset_speeds_up_tracking_without_forgetting() {
    // Without forgetting, a manual covariance reset at the (known) change
    // lets the filter re-converge, starting from its current weights.
    let a = Tf2::low_pass(2.0 * PI * 1.0, 0.7, 1.0, 0.2).unwrap();
    let b = Tf2::low_pass(2.0 * PI * 0.4, 0.3, 2.0, 0.2).unwrap();
    let mut rng = XorShift(42);
    let mut u = |_| rng.prbs();
    let mut plant = Tf2State::new(a);
    let mut arx = Arx2::new(1.0, 1e8).unwrap();
    run(&mut arx, &mut plant, &mut u, 0..1000);
    plant.set_model(b);
    arx.rls_mut().reset_covariance();
    run(&mut arx, &mut plant, &mut u, 1000..2500);
    // The first samples after the reset still straddle the change, hence
    // the looser tolerance than the noise-free 1e-6.
    let err = max_param_error(&arx.model(), &b);
    assert!(err <= 1e-4, "{err:e}");
}
