//! The base-side estimator on a noise-free link with regulated delays:
//! once the remote is identified, `x3e[n]` equals the remote's state `y[n]`
//! and `x3p[n]` equals `y[n + Df]`.

#[allow(unused_imports)]
use std::{borrow::ToOwned, boxed::Box, string::String, string::ToString, vec::Vec};
#[allow(unused_imports)]
use std::{eprintln, format, println, vec};

use std::f64::consts::PI;

use crate::{Arx2, Tf2, Tf2State};
use crate::{Estimate, Estimator};

/// The operator's command: four incommensurate sines (rad/tick).
fn command(n: usize) -> f64 {
    let n = n as f64;
    (0.05 * n).sin()
        + 0.7 * (0.21 * n + 1.0).sin()
        + 0.5 * (0.63 * n + 2.0).sin()
        + 0.3 * (1.4 * n + 0.5).sin()
}

/// The remote's true outputs `y[0..len]`: the plant, at rest before the first
/// command arrives, fed `p[m] = u[m − df(m)]`.
fn remote(plant: Tf2, len: usize, df: impl Fn(usize) -> usize) -> Vec<f64> {
    let mut s = Tf2State::new(plant);
    (0..len)
        .map(|m| s.step(m.checked_sub(df(m)).map_or(0.0, command)))
        .collect()
}

fn plant(period: f64) -> Tf2 {
    Tf2::low_pass(2.0 * PI * 1.0, 0.7, 1.0, period).unwrap()
}

const TOL: f64 = 1e-6;

fn assert_exact(e: &Estimate, y: &[f64], n: usize, df: usize) {
    assert!(e.from_model, "n = {n}: still warming up");
    assert!(
        (e.x3e - y[n]).abs() <= TOL,
        "n = {n}: x3e = {} but y[n] = {}",
        e.x3e,
        y[n]
    );
    assert!(
        (e.x3p - y[n + df]).abs() <= TOL,
        "n = {n}: x3p = {} but y[n + Df] = {}",
        e.x3p,
        y[n + df]
    );
}

/// Runs the link for `ticks` ticks; `lost(n)` drops the sample due at `n`.
/// Checks exactness from `settled` on and returns the estimator.
fn run_link(
    period: f64,
    df: usize,
    db: usize,
    ticks: usize,
    settled: usize,
    lost: impl Fn(usize) -> bool,
) -> Estimator<16> {
    let y = remote(plant(period), ticks + df + 1, |_| df);
    let mut est = Estimator::<16>::new(df, db, Arx2::new(1.0, 1e8).unwrap()).unwrap();
    for n in 0..ticks {
        let sample = n.checked_sub(db).filter(|_| !lost(n)).map(|m| y[m]);
        let e = est.step(command(n), sample).unwrap();
        if n >= settled {
            assert_exact(&e, &y, n, df);
        }
        assert!(e.x3e.is_finite() && e.x3p.is_finite());
    }
    est
}

#[test]
fn estimates_match_the_remote_once_identified() {
    for (period, df, db) in [
        (0.2, 3, 4),
        (0.2, 0, 1),
        (0.01, 3, 4),
        (0.05, 6, 2),
        (0.2, 0, 0),
    ] {
        let est = run_link(period, df, db, 3000, 1000, |_| false);
        let err = est
            .model()
            .params()
            .iter()
            .zip(plant(period).params())
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(
            err <= 1e-6,
            "T = {period}, Df = {df}, Db = {db}: |θ̂ − θ| = {err:e}"
        );
    }
}

#[test]
fn estimates_are_held_until_the_model_is_usable() {
    let (df, db) = (3, 4);
    let y = remote(plant(0.2), 100, |_| df);
    let mut est = Estimator::<16>::new(df, db, Arx2::new(1.0, 1e8).unwrap()).unwrap();
    for n in 0..100_usize {
        let sample = n.checked_sub(db).map(|m| y[m]);
        let e = est.step(command(n), sample).unwrap();
        // Identification starts at n = Db + Df = 7 (p[m] = u[0]), records two
        // samples, then adapts from n = 9; the fifth adaptation is at n = 13.
        let expected_updates = n.saturating_sub(8) as u64;
        assert_eq!(est.arx().unwrap().updates(), expected_updates, "n = {n}");
        if n < 13 {
            assert!(!e.from_model, "n = {n}");
            let held = n.checked_sub(db).map_or(0.0, |m| y[m]);
            assert_eq!((e.x3e, e.x3p), (held, held), "n = {n}");
        } else {
            assert!(e.from_model, "n = {n}");
        }
    }
}

#[test]
fn missing_samples_in_steady_state() {
    let (df, db) = (3, 4);
    // A burst of six underflows, then one in 37 ticks.
    let lost = |n: usize| (1500..1506).contains(&n) || (n > 1200 && n.is_multiple_of(37));
    let est = run_link(0.2, df, db, 3000, 1000, lost);
    assert_eq!(
        est.arx().unwrap().updates(),
        adaptations(df, db, 3000, lost)
    );
}

/// Adaptations expected when no regressor may hold a substituted output:
/// tick n adapts only if the samples due at n, n − 1 and n − 2 all arrived.
/// Identification starts at n = Db + Df (p[m] = u[0]) and first adapts two
/// ticks later.
fn adaptations(df: usize, db: usize, ticks: usize, lost: impl Fn(usize) -> bool) -> u64 {
    (db + df + 2..ticks)
        .filter(|&n| !lost(n) && !lost(n - 1) && !lost(n - 2))
        .count() as u64
}

#[test]
fn missing_samples_during_identification_do_not_bias_it() {
    // Frequent losses from the start, while the model is still poor: the
    // substitutes are wrong then, but never adapted on.
    let lost = |n: usize| n.is_multiple_of(5) || n.is_multiple_of(7);
    let est = run_link(0.2, 2, 3, 4000, 2500, lost);
    let expected = adaptations(2, 3, 4000, lost);
    assert_eq!(est.arx().unwrap().updates(), expected);
    assert!(expected > 500, "{expected}");
}

/// At tick `c` the link's delays change from `from` to `to`; the remote
/// switches its input mapping at output index `s`. Checks exactness before
/// the switch is visible and again one tick after the change.
fn delay_change(mut est: Estimator<16>, to: (usize, usize), c: usize, s: usize) {
    let from = est.delays();
    let df_at = |m: usize| if m < s { from.0 } else { to.0 };
    let y = remote(plant(0.2), 3100, df_at);
    for n in 0..3000 {
        if n == c {
            est.set_delays(to.0, to.1).unwrap();
            assert_eq!(est.delays(), to);
        }
        let (df, db) = est.delays();
        let e = est
            .step(command(n), n.checked_sub(db).map(|m| y[m]))
            .unwrap();
        if n == c {
            // One sample after the change cannot anchor the simulation.
            assert!(!e.from_model);
            assert_eq!((e.x3e, e.x3p), (y[n - db], y[n - db]));
        } else if (1000..s - from.0).contains(&n) || n > c {
            // From n = s − Df on, the remote's switch is not yet visible to
            // the base, whose predictions still follow the old delays.
            assert_exact(&e, &y, n, df);
        }
    }
}

#[test]
fn delays_can_change_mid_run() {
    // (3, 4) → (1, 2) at c = 1500. Before the change the base adapts on
    // outputs up to m = c − 1 − 4 = 1495, whose regressors reach p[1495];
    // after it, it anchors and adapts from m = c − 2 = 1498 with regressors
    // from p[1497]. A remote switch at s = 1497 is consistent with both.
    let est = Estimator::<16>::new(3, 4, Arx2::new(1.0, 1e8).unwrap()).unwrap();
    delay_change(est, (1, 2), 1500, 1497);
}

#[test]
fn delays_can_grow_mid_run_with_a_fixed_model() {
    // (3, 4) → (2, 6): outputs 1494 and 1495 are released twice, once under
    // each assumption, so no switch point is consistent with identification;
    // a fixed model only needs the new mapping from the first anchor's
    // predecessor m = c − 6 − 1 on.
    let est = Estimator::<16>::with_model(3, 4, plant(0.2)).unwrap();
    delay_change(est, (2, 6), 1500, 1493);
}

#[test]
fn a_fixed_model_needs_no_identification() {
    let (df, db) = (3, 4);
    let y = remote(plant(0.2), 200, |_| df);
    let mut est = Estimator::<16>::with_model(df, db, plant(0.2)).unwrap();
    for n in 0..190 {
        let e = est
            .step(command(n), n.checked_sub(db).map(|m| y[m]))
            .unwrap();
        if n > df + db {
            assert_exact(&e, &y, n, df);
        }
    }
}
