//! The policies' own tests, driven by hand-made delays.

use super::adaptive::ADAPTIVE_BUCKETS;
use super::adaptive::{bucket_of, bucket_upper};
use super::classic::{DEFAULT_FIXED_LATENCY, FixedAboveMin, NetEq, RAMJEE_ALPHA, Ramjee1, Ramjee4};
use super::*;
use crate::time::{Duration, Instant};

fn ms(x: u64) -> Duration {
    Duration::from_millis(x)
}

fn feed(p: &mut impl TargetDelay, delays_ms: &[u64], period_ms: u64) {
    for (k, &d) in delays_ms.iter().enumerate() {
        p.observe(Instant::from_millis(k as u64 * period_ms), ms(d));
    }
}

fn close(a: Duration, b_s: f64) -> bool {
    (a.as_secs_f64() - b_s).abs() < 1e-9
}

#[test]
fn ramjee1_starts_as_running_mean() {
    let mut p = Ramjee1::new();
    assert_eq!(p.target(), None);
    feed(&mut p, &[100, 200], 20);
    // i=1: d=0.1, v=0; i=2 (weight 1/2): d=0.15, v=0.5·0 + 0.5·|0.15−0.2| = 0.025.
    let (d, v) = p.estimates();
    assert!((d - 0.15).abs() < 1e-12 && (v - 0.025).abs() < 1e-12);
    assert!(close(p.target().unwrap(), 0.25));
}

#[test]
fn ramjee1_uses_alpha_once_warm() {
    let mut p = Ramjee1::new();
    feed(&mut p, &[50; 600], 20);
    // Constant delays: d̂ = 50 ms, v̂ = 0 exactly.
    assert!(close(p.target().unwrap(), 0.05));
    p.observe(Instant::from_millis(100_000), ms(150));
    let a = RAMJEE_ALPHA;
    let d = a * 0.05 + (1.0 - a) * 0.15;
    let v = (1.0 - a) * (d - 0.15f64).abs();
    assert!(close(p.target().unwrap(), d + 4.0 * v));
}

#[test]
fn ramjee4_detects_a_spike_and_follows_it() {
    let mut p = Ramjee4::new();
    feed(&mut p, &[50, 50, 50], 20);
    assert!(close(p.target().unwrap(), 0.05));
    // A jump of 300 ms > 2·0 + 100 ms: spike mode, d̂ follows one for one.
    p.observe(Instant::from_millis(60), ms(350));
    assert!(p.in_spike());
    let (d, v) = p.estimates();
    assert!((d - 0.35).abs() < 1e-12);
    assert!(v.abs() < 1e-12);
    // Falling at 20 ms per sample: var = 0/2 + |2·330 − 350 − 50|/8 = 32.5 ms.
    p.observe(Instant::from_millis(80), ms(330));
    assert!(p.in_spike());
    let (d, _) = p.estimates();
    assert!((d - 0.33).abs() < 1e-12);
    // Flat again: var = 16.25 + |2·330 − 330 − 350|/8 = 18.75 ms; then
    // 9.375 + 0 = 9.375 ms; then 4.6875 ≤ 7.875 → normal, no update.
    p.observe(Instant::from_millis(100), ms(330));
    p.observe(Instant::from_millis(120), ms(330));
    assert!(p.in_spike());
    p.observe(Instant::from_millis(140), ms(330));
    assert!(!p.in_spike());
    let (d, _) = p.estimates();
    assert!((d - 0.33).abs() < 1e-12);
}

#[test]
fn ramjee4_small_changes_average_by_an_eighth() {
    let mut p = Ramjee4::new();
    feed(&mut p, &[80, 160], 20);
    // 80 ms jump < 100 ms: normal. d = 80 + 80/8 = 90, v = 70/8 = 8.75.
    assert!(!p.in_spike());
    assert!(close(p.target().unwrap(), 0.090 + 4.0 * 0.00875));
}

#[test]
fn neteq_quantile_of_relative_delays() {
    let mut p = NetEq::new(ms(20));
    // 29 samples at the minimum, one 45 ms above (bucket 2) at k = 5:
    // after 24 more it weighs 0.017·0.983^24 ≈ 0.0113 of a mass
    // 1 − 0.983^30 ≈ 0.402, 2.8 % < 5 %: the quantile is bucket 0.
    let mut delays = [100u64; 30];
    delays[5] = 145;
    feed(&mut p, &delays, 20);
    assert_eq!(p.base(), Some(ms(100)));
    assert_eq!(p.quantile_bucket(), 0);
    assert_eq!(p.target(), Some(ms(120)));
    // A second one: (0.017 + 0.0111) / 0.412 ≈ 6.8 % above bucket 0.
    p.observe(Instant::from_millis(600), ms(145));
    assert_eq!(p.quantile_bucket(), 2);
    assert_eq!(p.target(), Some(ms(160)));
}

#[test]
fn neteq_minimum_forgets_after_two_blocks() {
    let mut p = NetEq::new(ms(20));
    p.observe(Instant::from_millis(0_000), ms(50));
    p.observe(Instant::from_millis(1_000), ms(80));
    p.observe(Instant::from_millis(2_000), ms(80)); // new block, previous min 50
    assert_eq!(p.base(), Some(ms(50)));
    p.observe(Instant::from_millis(4_000), ms(80)); // the 50 ms block is gone
    assert_eq!(p.base(), Some(ms(80)));
}

#[test]
fn fixed_above_min_tracks_the_minimum() {
    let mut p = FixedAboveMin::new(ms(200));
    assert_eq!(p.target(), None);
    feed(&mut p, &[70, 40, 90], 20);
    assert_eq!(p.target(), Some(ms(240)));
}

#[test]
fn adaptive_buckets_cover_their_delays() {
    for us in [
        0u64, 49, 50, 6_399, 6_400, 6_450, 99_999, 1_234_567, 13_000_000,
    ] {
        let d = Duration::from_micros(us);
        let b = bucket_of(d);
        assert!(d < bucket_upper(b), "{us} µs in bucket {b}");
        if b > 0 {
            assert!(d >= bucket_upper(b - 1), "{us} µs above bucket {b}");
        }
    }
    // 64 buckets per octave: at most 1.6 % wide above 6.4 ms.
    let b = bucket_of(ms(500));
    let width = bucket_upper(b) - bucket_upper(b - 1);
    assert!(width.as_secs_f64() <= 0.016 * 0.5, "{width:?}");
    // The last bucket ends at 13.1 s and holds any longer delay.
    assert_eq!(
        bucket_upper(ADAPTIVE_BUCKETS - 1),
        Duration::from_micros(13_107_200)
    );
    assert_eq!(bucket_of(Duration::from_secs(14)), ADAPTIVE_BUCKETS - 1);
    assert_eq!(bucket_of(Duration::from_secs(1000)), ADAPTIVE_BUCKETS - 1);
}

#[test]
fn adaptive_quantile_window_and_slew() {
    let mut p = Adaptive::new(ms(20), 0.01);
    assert_eq!(p.target(), None);
    // 1000 delays: 989 at 10 ms, 11 at 90 ms; ε·n = 10 may be above:
    // the quantile is 90 ms's bucket.
    for k in 0..1000u64 {
        let d = if k % 90 == 5 { 90 } else { 10 };
        p.observe(Instant::from_millis(k * 20), ms(d));
    }
    let q = p.goal().unwrap();
    assert!(q > ms(90) && q < ms(92), "{q:?}");
    // Only small delays for the next 2 minutes: the window forgets the
    // large ones, and the target falls at most 2 ms (0.1·T) per sample.
    let before = p.target().unwrap();
    p.observe(Instant::from_millis(20_000), ms(10));
    let after = p.target().unwrap();
    assert!(before - after <= ms(2) + Duration::from_nanos(1));
    for k in 1..7000u64 {
        p.observe(Instant::from_millis(20_000 + k * 20), ms(10));
    }
    let q = p.goal().unwrap();
    assert!(q > ms(10) && q <= ms(11), "{q:?}");
    assert_eq!(p.target(), Some(q));
    // A rise is followed by up to one period per sample.
    p.observe(Instant::from_millis(200_000), ms(500));
    p.observe(Instant::from_millis(200_020), ms(500));
    assert!(p.target().unwrap() <= q + ms(40) + Duration::from_nanos(2));
}

#[test]
fn adaptive_quantile_scans_from_the_highest_delay_held() {
    // The scan starts at the highest bucket in the window: the same
    // quantile as a scan of the whole histogram, as blocks with the
    // largest delays leave the window and a level shift moves them.
    let full_scan = |a: &Adaptive| {
        let allowed = (a.epsilon * a.count as f64) as u64;
        let mut above = 0u64;
        for b in (0..ADAPTIVE_BUCKETS).rev() {
            above += u64::from(a.held(b));
            if above > allowed {
                return Some(bucket_upper(b));
            }
        }
        None
    };
    let mut a = Adaptive::new(ms(20), 1e-2);
    let mut state = 7u64;
    for k in 0..40_000u64 {
        state = state
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1);
        // Large delays only in the first 3 minutes, then small ones.
        let scale = if k < 9_000 { 2_000 } else { 50 };
        let d = ms((state >> 33) % scale);
        a.observe(Instant::from_millis(20 * k), d);
        if k % 97 == 0 {
            assert_eq!(a.quantile(), full_scan(&a), "sample {k}");
        }
        if k == 20_000 {
            a.rebase(ms(30), true);
            assert_eq!(a.quantile(), full_scan(&a));
            a.rebase(ms(500), false);
            assert_eq!(a.quantile(), full_scan(&a));
        }
    }
    // The large delays have left the window: the scan starts low.
    assert!(a.top < bucket_of(ms(1_000)), "{}", a.top);
}

#[test]
fn adaptive_late_budget_is_epsilon_of_the_window_and_leaves_with_it() {
    let mut a = Adaptive::new(ms(20), 1e-2);
    // 30 s blocks at 20 ms: 1 500 delays each.
    for k in 0..3_000u64 {
        a.observe(Instant::from_millis(20 * k), ms(5));
    }
    // ε·n = 30: 30 lost samples are within it, 31 are not.
    assert!(!a.over_budget(30) && a.over_budget(31));
    for _ in 0..25 {
        a.note_late();
    }
    assert!(!a.over_budget(5) && a.over_budget(6));
    // They were counted in the second block; when it is reused (4
    // blocks, three rotations on) they leave the window with its delays.
    for k in 3_000..6_000u64 {
        a.observe(Instant::from_millis(20 * k), ms(5));
    }
    assert!(!a.over_budget(35) && a.over_budget(36), "{}", a.late);
    for k in 6_000..7_501u64 {
        a.observe(Instant::from_millis(20 * k), ms(5));
    }
    assert_eq!(a.count(), 4_500 + 1);
    assert!(!a.over_budget(45) && a.over_budget(46), "{}", a.late);
}

#[test]
fn adaptive_late_budget_counts_a_block_while_the_window_is_younger() {
    let mut a = Adaptive::new(ms(20), 1e-2);
    // No delay yet: a 30 s block's 1 500 at 20 ms, ε·1 500 = 15.
    assert!(!a.over_budget(15) && a.over_budget(16));
    for k in 0..100u64 {
        a.observe(Instant::from_millis(20 * k), ms(5));
    }
    assert!(!a.over_budget(15) && a.over_budget(16));
    a.note_late();
    assert!((a.budget_used(0) - 1.0 / 15.0).abs() < 1e-12);
    assert!((a.budget_used(14) - 1.0).abs() < 1e-12);
    // Past a block's delays, the window's own count.
    for k in 100..2_000u64 {
        a.observe(Instant::from_millis(20 * k), ms(5));
    }
    assert!(!a.over_budget(19) && a.over_budget(20));
}

#[test]
fn adaptive_sample_cost_is_the_delay_the_quantile_adds_per_sample_kept() {
    let mut a = Adaptive::new(ms(20), 0.1);
    assert_eq!(a.sample_cost(), Duration::ZERO, "an empty window");
    // 2 000 delays spread evenly over 0–100 ms: a density of 10 per
    // second of delay. One sample fewer late takes the quantile up by
    // 1/(10·n) s, for the n·(1 − ε) released: 90 ms in all.
    for k in 0..2_000u64 {
        a.observe(Instant::from_millis(20 * k), Duration::from_micros(k * 50));
    }
    // Within the buckets' width (about 1 ms here) on the 5 ms between
    // the two quantiles.
    let c = a.sample_cost().as_secs_f64();
    assert!((c - 0.090).abs() < 0.009, "{c}");
    // Equal delays: the quantile saves no sample at any price short of
    // all of them (a zero difference), and a held silence is then worth
    // only what it costs nothing to hold.
    let mut b = Adaptive::new(ms(20), 0.1);
    for k in 0..2_000u64 {
        b.observe(Instant::from_millis(20 * k), ms(30));
    }
    assert_eq!(b.sample_cost(), Duration::ZERO);
}

#[test]
fn adaptive_rebase_moves_the_window_and_the_target() {
    // 1000 delays: 989 at 10 ms, 11 at 160 ms (measured above a floor
    // 150 ms too low). The floor rises by 150 ms: they are 10 ms above
    // it, and the others fall under it.
    let mut p = Adaptive::new(ms(20), 0.01);
    for k in 0..1000u64 {
        let d = if (500..511).contains(&k) { 160 } else { 10 };
        p.observe(Instant::from_millis(k * 20), ms(d));
    }
    let (goal, target, count) = (p.goal().unwrap(), p.target().unwrap(), p.count());
    assert!(goal > ms(160) && goal < ms(163), "{goal:?}");
    p.rebase(ms(150), true);
    assert_eq!(p.count(), count, "no delay lost");
    let q = p.goal().unwrap();
    assert!(q > ms(10) && q < ms(12), "{q:?}");
    assert!(
        (target.as_secs_f64() - 0.150 - p.target().unwrap().as_secs_f64()).abs() < 1e-9,
        "the target moves with the floor: {target:?} then {:?}",
        p.target()
    );
    // And back down: every delay 150 ms higher above the lower floor.
    p.rebase(ms(150), false);
    let q = p.goal().unwrap();
    assert!(q > ms(159) && q < ms(163), "{q:?}");
}

#[test]
fn adaptive_blocks_end_early_when_full() {
    // 200 000 delays in 20 s (a 100 µs period): more than a `u16` block
    // holds. Blocks end at 65 535 delays, the window keeps the last
    // three or four blocks, and the counts stay those of the window.
    let mut p = Adaptive::new(Duration::from_micros(100), 0.001);
    for k in 0..200_000u64 {
        let d = if k % 500 == 7 { ms(30) } else { ms(2) };
        p.observe(Instant::from_nanos(k * 100_000), d);
    }
    let total: u64 = (0..ADAPTIVE_BUCKETS).map(|b| u64::from(p.held(b))).sum();
    assert_eq!(total, p.count());
    assert!(p.count() > 3 * 65_535 - 1, "{}", p.count());
    // 0.2 % of the delays are 30 ms: the quantile is just above 30 ms.
    let q = p.goal().unwrap();
    assert!(q > ms(30) && q < ms(31), "{q:?}");
}

#[test]
fn names_round_trip() {
    for p in [
        Playout::Fifo,
        Playout::Ramjee1,
        Playout::Ramjee4,
        Playout::NetEq,
        Playout::FixedAboveMin { latency: ms(200) },
        Playout::Constant { delay: ms(120) },
        Playout::ADAPTIVE,
        adaptive(5000, None),
        adaptive(7000, None),
        adaptive(1, None),
        adaptive(123_456, None),
        adaptive(1000, Some(ms(10))),
        adaptive(5000, Some(Duration::from_micros(2500))),
    ] {
        let name = std::format!("{p}");
        assert_eq!(name.parse::<Playout>(), Ok(p), "{name}");
    }
    for (ppm, name) in [
        (7000, "adaptive:0.7"),
        (1, "adaptive:0.0001"),
        (120_500, "adaptive:12.05"),
    ] {
        assert_eq!(std::format!("{}", adaptive(ppm, None)), name);
    }
    assert_eq!(
        std::format!("{}", adaptive(1000, Some(ms(10)))),
        "adaptive:0.1:10"
    );
    for (given, name) in [
        ("constant:124", "constant:124"),
        ("constant:0.1", "constant:0.1"),
        ("fixed:12.5", "fixed:12.5"),
        ("constant:0.000001", "constant:0.000001"),
    ] {
        let p: Playout = given.parse().unwrap();
        assert_eq!(std::format!("{p}"), name);
    }
    assert_eq!(
        "fixed".parse::<Playout>(),
        Ok(Playout::FixedAboveMin {
            latency: DEFAULT_FIXED_LATENCY
        })
    );
    assert!("constant:-1".parse::<Playout>().is_err());
    assert!("oracle".parse::<Playout>().is_err());
    assert_eq!("adaptive:0.5".parse::<Playout>(), Ok(adaptive(5000, None)));
    assert!("adaptive:0".parse::<Playout>().is_err());
    assert!("adaptive:100".parse::<Playout>().is_err());
    assert_eq!(
        "adaptive:0.5:7.5".parse::<Playout>(),
        Ok(adaptive(5000, Some(Duration::from_micros(7500))))
    );
    // The quantum: milliseconds from 1 to 10 000, and a late rate too.
    for bad in [
        "adaptive:0.1:0.5",
        "adaptive:0.1:0",
        "adaptive:0.1:-10",
        "adaptive:0.1:10001",
        "adaptive:0.1:nan",
        "adaptive:0.1:",
        "adaptive::10",
        "adaptive:0.1:10:1",
    ] {
        assert!(bad.parse::<Playout>().is_err(), "{bad}");
    }
    // Each error says what was wrong, then what is valid.
    let says = |name: &str| std::format!("{}", name.parse::<Playout>().unwrap_err());
    assert!(says("lifo").starts_with("unknown playout policy; valid: fifo"));
    assert!("lifo".parse::<Playout>().unwrap_err().is_unknown_name());
    assert!(
        !"adaptive:0"
            .parse::<Playout>()
            .unwrap_err()
            .is_unknown_name()
    );
    assert!(says("constant:-1").starts_with("fixed:MS and constant:MS take milliseconds"));
    assert!(says("adaptive:100").starts_with("adaptive:PERCENT takes the target late rate"));
    for bad in ["adaptive:0.1:0.5", "adaptive:0.1:x", "adaptive:0.1:10:1"] {
        let m = says(bad);
        assert!(
            m.starts_with("adaptive:PERCENT:QUANTUM_MS takes the step"),
            "{m}"
        );
        assert!(m.contains("; valid: fifo"), "{m}");
    }
}

fn adaptive(epsilon_ppm: u32, quantum: Option<Duration>) -> Playout {
    Playout::Adaptive {
        epsilon_ppm,
        quantum,
    }
}

#[test]
fn the_quantum_asked_for_divides_the_period() {
    use super::schedule::delay_quantum;
    // Defaults: the period up to 20 ms, then T/⌈T/1 ms⌉, within a dead
    // band of T/⌈T/20 ms⌉.
    assert_eq!(Playout::ADAPTIVE.quantum(ms(20)), Some(ms(20)));
    assert_eq!(Playout::ADAPTIVE.quantum(ms(10)), Some(ms(10)));
    assert_eq!(Playout::ADAPTIVE.quantum(ms(200)), Some(ms(1)));
    assert_eq!(
        Playout::ADAPTIVE.quantum(ms(30)),
        Some(Duration::from_nanos(1_000_000))
    );
    assert_eq!(
        Playout::ADAPTIVE.quantum(Duration::from_micros(20_500)),
        Some(Duration::from_micros(976) + Duration::from_nanos(190))
    );
    assert_eq!(super::schedule::dead_band(ms(200), None), ms(20));
    assert_eq!(super::schedule::dead_band(ms(10), None), ms(10));
    assert_eq!(super::schedule::dead_band(ms(200), Some(ms(5))), ms(5));
    assert_eq!(Playout::Fifo.quantum(ms(20)), None);
    // Asked: the period cut in the fewest equal parts no longer than that.
    assert_eq!(adaptive(1000, Some(ms(10))).quantum(ms(20)), Some(ms(10)));
    assert_eq!(
        adaptive(1000, Some(ms(8))).quantum(ms(20)),
        Some(Duration::from_nanos(6_666_666))
    );
    assert_eq!(adaptive(1000, Some(ms(50))).quantum(ms(20)), Some(ms(20)));
    assert_eq!(delay_quantum(ms(50), Some(ms(10))), ms(10));
    assert_eq!(delay_quantum(ms(50), None), ms(1));
    assert_eq!(
        delay_quantum(ms(50), Some(ms(20))),
        Duration::from_nanos(16_666_666)
    );
    // The target's warm-up floor is a quantum, the one asked for.
    let setup = Setup::new(
        crate::wire::Role::Base,
        ms(20),
        crate::Underflow::Hold,
        None,
    );
    let Ok(Builtin(registry::Policies::Adaptive(p))) =
        Builtin::<Adaptive>::make(adaptive(1000, Some(ms(5))), &setup)
    else {
        panic!("not adaptive");
    };
    let a = p.quantile();
    assert_eq!(*a, Adaptive::with_quantum(ms(20), 1e-3, ms(5)));
    assert_ne!(*a, Adaptive::new(ms(20), 1e-3));
}
