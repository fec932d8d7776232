//! Delay models: profile names, determinism, independence of the two
//! directions' streams, in-order delivery, the Fig. 6 generator.

use ndr_core::time::{Duration, Instant};
use ndr_netem::{
    DelayError, DelayModel, Direction, EpisodeParams, FIG6_DURATION, InOrderPath, PARIS_NEW_YORK,
    PROFILE_NAMES, fig6_truth,
};

const T_MS: u64 = 200;

/// `n` delays per direction at the paper's period, forward and backward
/// sampled alternately (as the simulator does) or forward alone.
fn delays(model: &DelayModel, seed: u64, n: u64, interleave: bool) -> Vec<Duration> {
    let mut s = model.sampler(seed);
    let mut out = Vec::new();
    for k in 0..n {
        let t = Instant::from_millis(k * T_MS);
        out.push(s.delay(Direction::Forward, t));
        if interleave {
            // Backward a little later, as the remote's frames would be.
            let _ = s.delay(Direction::Backward, t + Duration::from_millis(37));
        }
    }
    out
}

fn models() -> Vec<DelayModel> {
    PROFILE_NAMES
        .iter()
        .map(|n| DelayModel::profile(n).unwrap())
        .collect()
}

#[test]
fn profiles_parse_and_names_round_trip() {
    for name in PROFILE_NAMES {
        let m = DelayModel::profile(name).unwrap();
        assert_eq!(DelayModel::profile(&m.name()).unwrap(), m, "{name}");
    }
    assert_eq!(
        DelayModel::profile("constant").unwrap(),
        DelayModel::Constant {
            fwd: Duration::from_millis(50),
            bwd: Duration::from_millis(50)
        }
    );
    let c30 = DelayModel::profile("constant:30").unwrap();
    assert_eq!(
        c30,
        DelayModel::Constant {
            fwd: Duration::from_millis(30),
            bwd: Duration::from_millis(30)
        }
    );
    assert_eq!(c30.name(), "constant:30");
    let asym = DelayModel::profile("Constant:12.5, 40").unwrap();
    assert_eq!(
        asym,
        DelayModel::Constant {
            fwd: Duration::from_micros(12_500),
            bwd: Duration::from_millis(40)
        }
    );
    assert_eq!(DelayModel::profile(&asym.name()).unwrap(), asym);
    assert_eq!(
        DelayModel::profile(" PARIS-NEWYORK ").unwrap(),
        DelayModel::ParisNewYork
    );
    assert_eq!(DelayModel::ParisNewYork.to_string(), "paris-newyork");
}

#[test]
fn bad_profile_names_list_the_good_ones() {
    let e = DelayModel::profile("paris").unwrap_err();
    assert!(matches!(e, DelayError::UnknownProfile(_)));
    let m = e.to_string();
    for name in PROFILE_NAMES {
        assert!(m.contains(name), "{m}");
    }
    for bad in [
        "constant:",
        "constant:-1",
        "constant:nan",
        "constant:1e99",
        "constant:1,2,3",
        "constant:x",
    ] {
        assert!(
            matches!(DelayModel::profile(bad), Err(DelayError::BadConstant(_))),
            "{bad}"
        );
    }
    assert!(matches!(
        DelayModel::profile("lan-75km:3"),
        Err(DelayError::UnknownProfile(_))
    ));
}

#[test]
fn same_seed_same_delays_other_seed_other_delays() {
    for m in models() {
        let a = delays(&m, 42, 600, true);
        assert_eq!(a, delays(&m, 42, 600, true), "{m}");
        if !matches!(m, DelayModel::Constant { .. }) {
            assert_ne!(a, delays(&m, 43, 600, true), "{m}");
        }
    }
}

#[test]
fn forward_delays_ignore_backward_calls() {
    for m in models() {
        assert_eq!(delays(&m, 9, 1500, false), delays(&m, 9, 1500, true), "{m}");
    }
    // Even when one direction runs far ahead of the other.
    let m = DelayModel::ParisNewYork;
    let mut ahead = m.sampler(4);
    let fwd: Vec<_> = (0..500u64)
        .map(|k| ahead.delay(Direction::Forward, Instant::from_millis(k * T_MS)))
        .collect();
    let bwd: Vec<_> = (0..500u64)
        .map(|k| ahead.delay(Direction::Backward, Instant::from_millis(k * T_MS)))
        .collect();
    let mut lockstep = m.sampler(4);
    for k in 0..500u64 {
        let t = Instant::from_millis(k * T_MS);
        assert_eq!(lockstep.delay(Direction::Backward, t), bwd[k as usize]);
        assert_eq!(lockstep.delay(Direction::Forward, t), fwd[k as usize]);
    }
}

#[test]
fn in_order_path_holds_back_overtaking_frames() {
    let ms = Duration::from_millis;
    let t = Instant::from_millis;
    let mut p = InOrderPath::new();
    assert_eq!(p.last_arrival(), None);
    assert_eq!(p.deliver(t(0), ms(500)), t(500));
    // Would arrive at 300: waits for the previous frame.
    assert_eq!(p.deliver(t(200), ms(100)), t(500));
    assert_eq!(p.deliver(t(400), ms(50)), t(500));
    // Arriving exactly with the previous one is not being held back.
    assert_eq!(p.deliver(t(450), ms(50)), t(500));
    assert_eq!(p.deliver(t(600), ms(10)), t(610));
    assert_eq!(p.frames(), 5);
    assert_eq!(p.held_back(), 2);
    assert_eq!(p.last_arrival(), Some(t(610)));
    // Saturates instead of overflowing.
    assert_eq!(
        p.deliver(Instant::from_nanos(u64::MAX - 1), Duration::MAX),
        Instant::from_nanos(u64::MAX)
    );
}

#[test]
fn a_constant_model_delays_each_frame_by_its_own_directions_delay() {
    // What the relay computes for each frame it reads (its release time),
    // for frames 10 ms apart as the relay's real-time test sends them.
    let ms = Duration::from_millis;
    let m = DelayModel::Constant {
        fwd: ms(40),
        bwd: ms(60),
    };
    let mut s = m.sampler(7);
    let mut paths = [InOrderPath::new(), InOrderPath::new()];
    for k in 0..30u64 {
        let sent = Instant::from_millis(10 * k);
        for (path, dir, delay) in paths
            .iter_mut()
            .zip([(Direction::Forward, ms(40)), (Direction::Backward, ms(60))])
            .map(|(p, (dir, delay))| (p, dir, delay))
        {
            let d = s.delay(dir, sent);
            assert_eq!(d, delay, "frame {k} {dir:?}");
            assert_eq!(path.deliver(sent, d), sent + delay, "frame {k} {dir:?}");
        }
    }
    assert_eq!(paths.map(|p| p.held_back()), [0, 0]);
}

#[test]
fn every_profile_keeps_order_through_the_path() {
    for m in models() {
        let mut s = m.sampler(1);
        let mut path = InOrderPath::new();
        let mut last = Instant::ZERO;
        for k in 0..3000u64 {
            let sent = Instant::from_millis(k * T_MS);
            let d = s.delay(Direction::Backward, sent);
            let a = path.deliver(sent, d);
            assert!(a >= last && a >= sent + d, "{m}");
            last = a;
        }
    }
}

#[test]
fn delays_stay_in_a_sane_range() {
    for m in models() {
        let xs = delays(&m, 3, 6000, true);
        let max = xs.iter().max().unwrap().as_secs_f64();
        assert!(max < 3.0, "{m}: {max}");
    }
}

#[test]
fn absurd_episode_parameters_do_not_panic() {
    let mut p = PARIS_NEW_YORK;
    p.slot_s = f64::NAN;
    p.onset_spread_s = -1.0;
    p.occurrence = 7.0;
    p.height_s = (f64::INFINITY, -3.0);
    p.hold_s = (1e300, f64::NAN);
    p.fall_rate = -1.0;
    p.backward_lag_s = f64::NEG_INFINITY;
    p.jitter.mean_s = f64::NAN;
    p.jitter.shape = 0.0;
    let weird: [EpisodeParams; 2] = [
        p,
        EpisodeParams {
            slot_s: 1e-12,
            ..PARIS_NEW_YORK
        },
    ];
    for p in weird {
        let m = DelayModel::Episodes(p);
        let mut s = m.sampler(0);
        for t in [0, 1, 1_000_000_000, u64::MAX / 2, u64::MAX] {
            let _ = s.delay(Direction::Forward, Instant::from_nanos(t));
            let _ = s.delay(Direction::Backward, Instant::from_nanos(t));
        }
    }
}

#[test]
fn fig6_truth_has_sines_and_one_step() {
    assert_eq!(FIG6_DURATION, Duration::from_secs(1200));
    let mut means = Vec::new();
    let mut stds = Vec::new();
    for k in 0..=1200 {
        let (m, s) = fig6_truth(f64::from(k));
        assert!(
            (0.15..0.6).contains(&m) && (0.04..0.2).contains(&s),
            "{k}: {m} {s}"
        );
        means.push(m);
        stds.push(s);
    }
    // One jump larger than the sines could make in a second.
    let jumps: Vec<usize> = (1..means.len())
        .filter(|&i| (means[i] - means[i - 1]).abs() > 0.01)
        .collect();
    assert_eq!(jumps, vec![720]);
    assert!(stds.windows(2).all(|w| (w[1] - w[0]).abs() < 0.01));
    assert_eq!(fig6_truth(-5.0), fig6_truth(0.0));
    assert_eq!(fig6_truth(f64::NAN), fig6_truth(0.0));
}

/// Delays drawn over a window follow the generating mean and deviation.
#[test]
fn fig6_samples_follow_the_truth() {
    let m = DelayModel::PaperFig6;
    let mut s = m.sampler(8);
    for center in [100.0, 500.0, 900.0] {
        let (tm, ts) = fig6_truth(center);
        let xs: Vec<f64> = (0..4000)
            .map(|k| {
                // ±2 s around the centre: the truth barely moves.
                let t = center - 2.0 + f64::from(k) * 0.001;
                s.delay(Direction::Forward, Instant::from_secs_f64(t))
                    .as_secs_f64()
            })
            .collect();
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let std = (xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64).sqrt();
        assert!((mean - tm).abs() < 0.1 * ts, "{center}: {mean} vs {tm}");
        assert!((std - ts).abs() < 0.1 * ts, "{center}: {std} vs {ts}");
    }
}
