//! The adaptive playout in simulated time: the clock estimate
//! against the simulator's true skew and offset, the delay against the
//! oracle, the late rate near its target, no pause, an event per change.

use ndr_core::Regulation;
use ndr_core::playout::Playout;
use ndr_core::time::Duration;
use ndr_sim::compare::{Family, builtin, run_one, sim_config};
use ndr_sim::run;

const T: Duration = Duration::from_millis(20);
const WINDOW: Duration = Duration::from_secs(10);
const ADAPTIVE: Regulation = Regulation::Target(Playout::ADAPTIVE);

fn named(name: &str, secs: u64) -> Family {
    let mut f = builtin()
        .into_iter()
        .find(|f| f.name == name)
        .expect("a built-in family");
    f.duration = Duration::from_secs(secs);
    f.events_s.retain(|&t| t < secs as f64);
    f
}

/// The end-to-end delay (release − send) of each command sent within `sent`
/// (seconds); every one must have been released.
fn command_delays(out: &ndr_sim::SimOutput, sent: std::ops::Range<f64>) -> Vec<f64> {
    out.forward
        .samples
        .iter()
        .filter(|c| sent.contains(&c.sent_at.as_secs_f64()))
        .map(|c| (c.released_at.expect("released") - c.sent_at).as_secs_f64())
        .collect()
}

/// The end-to-end delay of each command sent within `sent` (seconds) that
/// was released fresh.
fn fresh_delays(out: &ndr_sim::SimOutput, sent: std::ops::Range<f64>) -> Vec<f64> {
    out.forward
        .samples
        .iter()
        .filter(|c| sent.contains(&c.sent_at.as_secs_f64()))
        .filter_map(|c| Some((c.released_at? - c.sent_at).as_secs_f64()))
        .collect()
}

/// The smallest and the largest of `xs`.
fn span(xs: &[f64]) -> (f64, f64) {
    let lo = xs.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = xs.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (lo, hi)
}

#[test]
fn skew_and_offset_estimates_match_the_simulator_after_10_minutes() {
    for (name, ppm) in [("skew+100ppm", 100.0), ("skew-100ppm", -100.0)] {
        let cfg = sim_config(&named(name, 600), ADAPTIVE, 1, T);
        let r = run(&cfg).expect("the run").report;
        assert!(
            (r.remote_clock_skew_ppm - ppm).abs() < 5.0,
            "{name}: remote {}",
            r.remote_clock_skew_ppm
        );
        assert!(
            (r.base_clock_skew_ppm + ppm).abs() < 5.0,
            "{name}: base {}",
            r.base_clock_skew_ppm
        );
        // remote − base after 600 s; symmetric paths whose fastest frames
        // are within a millisecond of the 40 ms floor.
        let truth = ppm * 1e-6 * 600.0;
        assert!(
            (r.remote_clock_offset_s - truth).abs() < 1e-3,
            "{name}: offset {} vs {truth}",
            r.remote_clock_offset_s
        );
        // The one-way delays, offset removed: about 40 ms + 10 ms of jitter.
        for d in [r.one_way_fwd_mean_s, r.one_way_bwd_mean_s] {
            assert!((d - 0.050).abs() < 0.005, "{name}: one-way {d}");
        }
        assert_eq!(r.pauses, 0);
    }
}

#[test]
fn the_delay_is_near_the_oracle_and_the_late_rate_near_epsilon() {
    // (family, largest late rate): ε = 0.1 %, plus the start (the first
    // quantiles come from few samples). paris-newyork's episodes are held
    // once the late rate is spent (0.79 % late before, letting every
    // episode the window did not cover go).
    for (name, secs, late) in [
        ("lan-75km", 120, 0.002),
        ("skew+100ppm", 120, 0.002),
        ("skew-100ppm", 120, 0.002),
        ("paris-newyork", 120, 0.002),
    ] {
        let m = run_one(&named(name, secs), ADAPTIVE, 1, (T, WINDOW))
            .expect("the run")
            .metrics;
        assert!(m.oracle_ratio <= 1.15, "{name}: ratio {}", m.oracle_ratio);
        assert!(m.late_rate <= late, "{name}: late rate {}", m.late_rate);
    }
    // After a step the adaptive target beats any constant one.
    let m = run_one(&named("step", 120), ADAPTIVE, 1, (T, WINDOW))
        .expect("the run")
        .metrics;
    assert!(m.oracle_ratio < 1.0, "step: ratio {}", m.oracle_ratio);
}

#[test]
fn an_hour_at_100_ppm_keeps_the_delay_and_the_late_rate() {
    // The remote's ticks follow the base's grid through the clock estimate
    // and the delay is held in whole ticks: from the first minute on, the
    // true end-to-end delay (release on the simulation's clock − send) stays
    // put. Without the skew correction it would drift by 360 ms.
    // The two runs side by side: the debug build takes a while.
    let runs: Vec<_> = std::thread::scope(|s| {
        let handles: Vec<_> = [("skew+100ppm", 100.0), ("skew-100ppm", -100.0)]
            .into_iter()
            .map(|(name, ppm)| {
                s.spawn(move || {
                    let mut cfg = sim_config(&named(name, 3600), ADAPTIVE, 2, T);
                    cfg.duration = Duration::from_secs(3600);
                    (name, ppm, run(&cfg).expect("the run"))
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("a run"))
            .collect()
    });
    for (name, ppm, out) in runs {
        assert_eq!(out.report.pauses, 0);
        let rate = 1.0 + ppm * 1e-6;
        let (mut delays, mut late) = (Vec::new(), 0u32);
        for c in &out.forward.samples {
            let sent = c.sent_at.as_secs_f64();
            if !(60.0..3590.0).contains(&sent) {
                continue;
            }
            match c.released_at {
                Some(r) => delays.push(r.as_secs_f64() / rate - sent),
                None => late += 1,
            }
        }
        let n = delays.len() as f64;
        let mean = delays.iter().sum::<f64>() / n;
        let std = (delays.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / n).sqrt();
        assert!(std <= 1e-3, "{name}: std {std} around {mean}");
        // Measured 0.12 ms. Holding every cheap silence with the late
        // budget nearly unspent made it 0.90 ms: each one a quantum's rise
        // falling back over ten releases.
        assert!(std <= 0.3e-3, "{name}: std {std} around {mean}");
        let late_rate = f64::from(late) / (n + f64::from(late));
        eprintln!("{name}: true delay {mean:.6} s, std {std:.6} s, late rate {late_rate:.6}");
        assert!(late_rate < 0.002, "{name}: late rate {late_rate}");
    }
}

#[test]
fn every_change_of_delay_is_an_event() {
    let cfg = sim_config(&named("step", 90), ADAPTIVE, 3, T);
    let r = run(&cfg).expect("the run").report;
    assert_eq!(r.pauses, 0);
    // The step moves the delay: at least one change after the start.
    assert!(r.delay_changes_fwd >= 2, "{}", r.delay_changes_fwd);

    // Each change reached the application as an event (none dropped).
    assert_eq!(r.delay_events_fwd, r.delay_changes_fwd);
}

#[test]
fn the_delay_falls_by_sliding_the_releases_without_skipping_a_sample() {
    // The paper's Fig. 6: slow sines in the delay, so that the target rises
    // and falls for ten minutes. A fall brings the releases forward by a
    // tenth of a period each (one every 0.9·T) instead of skipping samples;
    // the grid the remote follows moves by a twentieth of a period at most.
    let cfg = sim_config(&named("paper-fig6", 600), ADAPTIVE, 1, T);
    let out = run(&cfg).expect("the run");
    assert_eq!(out.report.skipped, 0);
    assert_eq!(out.report.pauses, 0);
    let fresh: Vec<(f64, f64)> = out
        .forward
        .samples
        .iter()
        .filter_map(|c| {
            let r = c.released_at?.as_secs_f64();
            Some((r, r - c.sent_at.as_secs_f64()))
        })
        .collect();
    let per = T.as_secs_f64();
    let gaps: Vec<f64> = fresh.windows(2).map(|w| w[1].0 - w[0].0).collect();
    let shortest = gaps.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(
        shortest >= 0.85 * per - 1e-6,
        "a release {shortest} s after the last"
    );
    let sliding = gaps.iter().filter(|&&g| g < 0.95 * per).count();
    let (mut highest, mut fall) = (0.0f64, 0.0f64);
    for &(_, d) in &fresh {
        highest = highest.max(d);
        fall = fall.max(highest - d);
    }
    assert!(fall > 0.2, "the delay fell by {fall} s at most");
    assert!(sliding >= 100, "{sliding} releases sliding forward");
}

/// At the paper's 200 ms period the window's 30 s blocks held 600 delays,
/// fewer than the 1/ε = 1000 that end the warm-up margin, so the margin (up
/// to a period) stayed and the delay never came down from its start at two
/// ticks (400 ms each way for a 12 ms network); the blocks now grow with
/// the period. Held in whole ticks it then settled at one tick, 200 ms each
/// way (the paper's dynamic mode got 300 ms of round trip by moving to
/// `T = 50 ms`). In quanta of 20 ms it settled at 40 ms, released between
/// the ticks; in quanta of 1 ms, at the millisecond over the network's
/// 22 ms at most.
#[test]
fn at_a_long_period_the_delay_settles_between_the_ticks() {
    let t = Duration::from_millis(200);
    let cfg = sim_config(&named("lan-75km", 600), ADAPTIVE, 1, t);
    let out = run(&cfg).expect("the run");
    let r = &out.report;
    let delay = r.playout_delay_fwd_s;
    assert!((0.022..=0.025).contains(&delay), "delay {delay} s");
    assert!(
        (delay * 1e3 - (delay * 1e3).round()).abs() < 1e-6,
        "delay {delay} s"
    );
    // Once the window holds 1/ε delays (200 s at 5 Hz), every command takes
    // exactly that delay: its release is 23 ms or so after its send, well
    // before the next tick.
    let settled = command_delays(&out, 300.0..590.0);
    // Exactly, but for the offset estimate's error (a fraction of a
    // millisecond: half the asymmetry of the two paths' fastest frames).
    assert!(settled.len() > 1400, "{} commands", settled.len());
    let (lo, hi) = span(&settled);
    assert!(
        lo > delay - 1e-3 && hi < delay + 1e-3,
        "commands {lo} to {hi} s late"
    );
    assert!(hi - lo < 5e-4, "commands {lo} to {hi} s late");
    // Both ways (the base's cutoff once ran half a period ahead of the
    // states' arrivals and dropped nearly all of them as late), and its
    // rises of a quantum move the releases later without repeating one.
    // Without a 20 ms step of margin the warm-up's guess of the tail lets
    // one sample go, under ε (one in 3 000), and its silence is held.
    assert!(r.late_samples <= 1, "{} late", r.late_samples);
    assert!(r.underflows <= 2, "{} underflows", r.underflows);
    assert!(
        r.e2e_bwd_mean_s < 0.03,
        "states {} s late",
        r.e2e_bwd_mean_s
    );
    assert_eq!(r.skipped, 0);
    assert_eq!(r.pauses, 0);
}

/// A quantum asked for (`adaptive:0.1:10`) holds the delay in its own
/// steps: on the paper's LAN at `T = 20 ms` the need (about 25 ms) rounds
/// up to 30 ms each way instead of the default's 40, released half-way
/// between the ticks, with no more late samples.
#[test]
fn a_finer_quantum_holds_a_lower_delay_in_its_steps() {
    let family = named("lan-75km", 300);
    let delay_with = |playout: &str| {
        let p: Playout = playout.parse().expect("a playout");
        let out = run(&sim_config(&family, Regulation::Target(p), 1, T)).expect("the run");
        let settled = command_delays(&out, 120.0..290.0);
        (out.report, settled)
    };
    let (default, _) = delay_with("adaptive");
    let (fine, settled) = delay_with("adaptive:0.1:10");
    assert!(
        (default.playout_delay_fwd_s - 0.04).abs() < 1e-9,
        "default: {} s",
        default.playout_delay_fwd_s
    );
    assert!(
        (fine.playout_delay_fwd_s - 0.03).abs() < 1e-9,
        "10 ms quanta: {} s",
        fine.playout_delay_fwd_s
    );
    // Every command settled takes that delay, to the offset estimate's error.
    assert!(settled.len() > 8000, "{} commands", settled.len());
    let (lo, hi) = span(&settled);
    assert!(lo > 0.029 && hi < 0.031, "commands {lo} to {hi} s late");
    assert_eq!(fine.late_samples, 0);
    assert_eq!(fine.skipped, 0);
    assert_eq!(fine.pauses, 0);
    assert!(
        fine.delay_changes_fwd <= 4,
        "{} changes",
        fine.delay_changes_fwd
    );
}

/// The two hubs of a real link start their grids anywhere within a period
/// of each other. A remote that kept its own grid made each direction's
/// true delay its announced one plus or minus that phase (on `step`: 238 to
/// 251 ms, 0.17 to 0.30 % late); following the base's grid, the phase
/// changes nothing.
#[test]
fn each_direction_keeps_its_announced_delay_whatever_the_remote_grids_phase() {
    let family = named("step", 120);
    let run_at = |phase_ms: u64| {
        let mut cfg = sim_config(&family, ADAPTIVE, 1, T);
        cfg.remote_phase = Duration::from_millis(phase_ms);
        run(&cfg).expect("the run").report
    };
    let aligned = run_at(0);
    for phase_ms in [5, 10, 15] {
        let r = run_at(phase_ms);
        for (what, got, want) in [
            ("commands' delay", r.e2e_fwd_mean_s, aligned.e2e_fwd_mean_s),
            ("states' delay", r.e2e_bwd_mean_s, aligned.e2e_bwd_mean_s),
        ] {
            // The fault this guards put each direction ±φ off its delay for
            // the whole run (5 to 15 ms here). Where the first estimates
            // fall against a quantum boundary may hold the warm-up's delay
            // a quantum lower for some seconds in one phase and not in
            // another: up to 1.7 ms on the run's mean.
            assert!(
                (got - want).abs() < 2.5e-3,
                "phase {phase_ms} ms: {what} {got} s, aligned {want} s"
            );
        }
        // Within 3 of the ~6 000 samples: a held silence may keep one the
        // other run lets go (the fault above was 0.13 %, 8 samples).
        assert!(
            (r.late_rate_fwd - aligned.late_rate_fwd).abs() < 5e-4,
            "phase {phase_ms} ms: late {} against {}",
            r.late_rate_fwd,
            aligned.late_rate_fwd
        );
    }
}

/// `ndr compare` measures the commands only; the states go through the
/// base's playout, which at a sub-tick delay once dropped 99.97 % of them
/// as late (its cutoff ran half a period ahead of their arrivals). Every
/// family, at two long periods: the two directions' late rates are alike.
#[test]
fn at_long_periods_the_states_fare_as_the_commands() {
    for period_ms in [50, 200] {
        let t = Duration::from_millis(period_ms);
        for family in builtin() {
            let name = family.name.clone();
            let r = run(&sim_config(&family, ADAPTIVE, 1, t))
                .expect("the run")
                .report;
            let (fwd, bwd) = (r.late_rate_fwd, r.late_rate_bwd);
            // Measured: at most 0.76 % either way, the two within 0.06 %.
            assert!(
                fwd < 0.01 && bwd < 0.01,
                "{name} at {period_ms} ms: {fwd} {bwd}"
            );
            assert!(
                bwd <= 2.0 * fwd + 0.002 && fwd <= 2.0 * bwd + 0.002,
                "{name} at {period_ms} ms: {fwd} {bwd}"
            );
        }
    }
}

#[test]
fn an_outage_is_not_a_delay_to_cover_for_minutes() {
    use ndr_core::endpoint::Underflow;
    use ndr_core::time::Instant;
    use ndr_sim::compare::WAN;
    use ndr_sim::compare::trace;
    use ndr_sim::delay::{DelayModel, EventKind, EventParams, Trace, TraceRow};
    // One 5 s outage of the forward path at 30 s. The watchdog (1 s) calls
    // the link lost; the delay then goes back to what the jitter needs,
    // instead of covering 5 s for the window's two minutes. Two shapes:
    // one frame held 5 s and every frame behind it in its burst; and the
    // frames of 100 ms each held 5 s (they come a period apart, then the
    // burst of those held behind them). The predictor's forecast from the
    // outage's round trips may move the delay by a quantum at most (from
    // 36 s on: unbounded, it held the delay 0.56 s high for 5 s).
    let mut stall = named("tcp-stall", 120);
    stall.model = DelayModel::Events(EventParams {
        jitter: WAN,
        kind: EventKind::Stalls {
            first_s: 30.0,
            every_s: 1000.0,
            stall_s: 5.0,
        },
    });
    let mut jitter = 12345u64;
    let rows = (0..12_000u64)
        .map(|k| {
            // 40–60 ms, from a small LCG: the same rows at every run.
            jitter = jitter
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            let d = Duration::from_micros(40_000 + (jitter >> 33) % 20_000);
            let held = (3000..3010).contains(&k);
            TraceRow {
                at: Instant::from_millis(k * 10),
                fwd: if held { d + Duration::from_secs(5) } else { d },
                bwd: d,
            }
        })
        .collect();
    let held = trace("held", Trace::from_rows(rows).expect("a valid trace"));
    for (family, underflow) in [
        (&stall, Underflow::DropLate),
        (&stall, Underflow::Hold),
        (&held, Underflow::DropLate),
        (&held, Underflow::Hold),
    ] {
        let mut cfg = sim_config(family, ADAPTIVE, 2, T);
        cfg.underflow = underflow;
        let out = run(&cfg).expect("the run");
        let (_, before_max) = span(&fresh_delays(&out, 20.0..29.0));
        let (_, after_max) = span(&fresh_delays(&out, 36.0..110.0));
        assert!(
            after_max <= before_max + 0.021,
            "{} {underflow:?}: {before_max} s before the outage, up to {after_max} s after",
            family.name
        );
        assert!(
            out.report.link_lost >= 1 && out.report.outage_delays > 0,
            "{} {underflow:?}: the watchdog said nothing, or no outage was seen",
            family.name
        );
        // Nothing is replayed from the outage under hold: its stale samples
        // are discarded (counted), none is released seconds late.
        let released_late = out
            .forward
            .samples
            .iter()
            .filter_map(|c| Some((c.released_at? - c.sent_at).as_secs_f64()))
            .filter(|&d| d > 1.5)
            .count();
        assert_eq!(released_late, 0, "{} {underflow:?}", family.name);
    }
}

#[test]
fn a_level_shift_is_counted_once() {
    // A +150 ms step of the forward path at 60 s. The clock estimate takes
    // it for a level shift a block or two later; until then the delays
    // were measured above the old floor. Rebased, the window does not
    // count the step again on top of the new floor: the delay settles at
    // what it held before plus the step (it had stayed 150 ms higher, at
    // 390 ms, to the end of the run).
    for seed in 1..=3 {
        let cfg = sim_config(&named("step", 120), ADAPTIVE, seed, T);
        let out = run(&cfg).expect("the run");
        let (_, before) = span(&fresh_delays(&out, 40.0..59.0));
        let (_, after) = span(&fresh_delays(&out, 80.0..110.0));
        assert!(
            after <= before + 0.150 + 0.041,
            "seed {seed}: {before} s before the step, up to {after} s after"
        );
    }
}

#[test]
fn the_late_rate_stays_within_epsilon_through_stalls_and_episodes() {
    // Stalls, spikes, congestion episodes and a step: events the window's
    // quantile covers only after it has seen them. Once the window's lost
    // samples reach ε of its delays, a silence past a slot holds the delay
    // ahead of it (the stalled frames are released in order, later) instead
    // of losing more. Without it, at ε = 0.1 % on seed 1: tcp-stall 0.31 %,
    // spikes 0.34 %, paris-newyork 0.79 %, step 0.21 % late; at 1 %, 1.0–
    // 1.2 % on all but step.
    for name in ["tcp-stall", "spikes", "paris-newyork", "step"] {
        for epsilon_ppm in [1_000, 10_000] {
            let policy = Regulation::Target(Playout::Adaptive {
                epsilon_ppm,
                quantum: None,
            });
            let cfg = sim_config(&named(name, 120), policy, 1, T);
            let out = run(&cfg).expect("the run");
            let epsilon = f64::from(epsilon_ppm) * 1e-6;
            let m = run_one(&named(name, 120), policy, 1, (T, WINDOW))
                .expect("the run")
                .metrics;
            assert!(
                m.late_rate <= epsilon,
                "{name} at ε = {epsilon}: late rate {}",
                m.late_rate
            );
            // Held, not reordered: the commands are released in the order
            // they were sent.
            let released: Vec<f64> = out
                .forward
                .samples
                .iter()
                .filter_map(|c| Some(c.released_at?.as_secs_f64()))
                .collect();
            assert!(
                released.windows(2).all(|w| w[0] < w[1]),
                "{name} at ε = {epsilon}: a release out of order"
            );
            assert_eq!(out.report.pauses, 0);
        }
    }
}

#[test]
fn a_drifting_level_is_followed() {
    // The paper's Fig. 6: one-way delays from a gamma whose mean and
    // deviation follow slow sines (7 and 5 minutes). The window of two
    // minutes lags a rising sine; moved by the drift of its mean, the
    // target follows it, and fewer samples are late at no more delay.
    let family = named("paper-fig6", 1200);
    for seed in 1..=3 {
        // Seeds 1–3: 0.17–0.27 % late at 0.93–0.94 of the oracle's delay
        // (0.36–0.49 % at 0.99–1.01 with the window alone).
        let m = run_one(&family, ADAPTIVE, seed, (T, WINDOW))
            .expect("the run")
            .metrics;
        assert!(m.late_rate <= 0.003, "seed {seed}: {m:?}");
        assert!(m.oracle_ratio <= 0.96, "seed {seed}: {m:?}");
    }
}

#[test]
fn over_a_route_flap_at_coarse_periods_the_delay_sits_on_the_longer_route() {
    // route-flap: 21 ms one-way (at most 25), 50 ms more on the other route,
    // flipping every 4 s. At T = 50 and 200 ms the delay moved in steps of
    // 16.7 and 20 ms, and sat a step over the longer route (1.19 of the
    // oracle's delay at 200 ms over 10 seeds). In steps of 1 ms within a
    // dead band of 20 ms it sits on the longer route, no step above it, and
    // loses no more samples. Means over seeds, as `ndr compare` reports.
    const SEEDS: u64 = 5;
    for period in [50, 200] {
        let (mut ratio, mut late) = (0.0, 0.0);
        for seed in 1..=SEEDS {
            let m = run_one(
                &named("route-flap", 120),
                ADAPTIVE,
                seed,
                (Duration::from_millis(period), WINDOW),
            )
            .expect("the run")
            .metrics;
            assert!(
                m.mean_delay_s <= 0.075 * 1.1,
                "T = {period} ms, seed {seed}: {m:?}"
            );
            ratio += m.oracle_ratio / SEEDS as f64;
            late += m.late_rate / SEEDS as f64;
        }
        assert!(ratio <= 1.10, "T = {period} ms: ratio {ratio}");
        assert!(late <= 1e-3, "T = {period} ms: late rate {late}");
    }
}
