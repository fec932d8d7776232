//! The operator's command signals: values, axes, parsing and printing.

use ndr_sim::signal::{Signal, SignalError};

#[test]
fn default_is_a_slow_unit_sine() {
    let s = Signal::default();
    assert_eq!(
        s,
        Signal::Sine {
            amplitude: 1.0,
            freq_hz: 0.2,
            offset: 0.0
        }
    );
    assert!(s.value(0.0, 0).abs() < 1e-12);
    assert!((s.value(1.25, 0) - 1.0).abs() < 1e-12); // a quarter period
    assert!((s.value(3.75, 0) + 1.0).abs() < 1e-12);
    assert!((s.value(5.0, 0) - s.value(0.0, 0)).abs() < 1e-12);
}

#[test]
fn axes_get_distinct_phases() {
    for s in [
        Signal::default(),
        "steps:low=0,high=1,period=4".parse().unwrap(),
    ] {
        for a in 0..8 {
            for b in a + 1..8 {
                let differ = (0..200).any(|k| {
                    let t = f64::from(k) * 0.05;
                    (s.value(t, a) - s.value(t, b)).abs() > 1e-9
                });
                assert!(differ, "{s}: axes {a} and {b} are identical");
            }
        }
    }
    // A constant is the same everywhere.
    let c = Signal::Constant(0.5);
    assert_eq!(c.value(3.0, 0), 0.5);
    assert_eq!(c.value(1e9, 7), 0.5);
}

#[test]
fn steps_is_a_square_wave() {
    let s: Signal = "steps:low=-1,high=2,period=4".parse().unwrap();
    assert_eq!(s.value(0.0, 0), 2.0);
    assert_eq!(s.value(1.999, 0), 2.0);
    assert_eq!(s.value(2.0, 0), -1.0);
    assert_eq!(s.value(3.999, 0), -1.0);
    assert_eq!(s.value(4.0, 0), 2.0);
    let high = (0..4000)
        .filter(|&k| s.value(f64::from(k) * 0.001, 3) == 2.0)
        .count();
    assert_eq!(high, 2000);
}

#[test]
fn parses_the_cli_forms() {
    let p = |s: &str| s.parse::<Signal>().unwrap();
    assert_eq!(p("sine"), Signal::default());
    assert_eq!(
        p("sine:amp=2,freq=0.5"),
        Signal::Sine {
            amplitude: 2.0,
            freq_hz: 0.5,
            offset: 0.0
        }
    );
    assert_eq!(
        p(" SINE: offset = 1 , amplitude=3 "),
        Signal::Sine {
            amplitude: 3.0,
            freq_hz: 0.2,
            offset: 1.0
        }
    );
    assert_eq!(
        p("steps"),
        Signal::Steps {
            low: 0.0,
            high: 1.0,
            period_s: 4.0
        }
    );
    assert_eq!(
        p("steps:low=0,high=1,period=4"),
        Signal::Steps {
            low: 0.0,
            high: 1.0,
            period_s: 4.0
        }
    );
    assert_eq!(p("constant:0.5"), Signal::Constant(0.5));
    assert_eq!(p("constant:value=-2"), Signal::Constant(-2.0));
    assert_eq!(p("constant"), Signal::Constant(0.0));
}

#[test]
fn display_round_trips() {
    for s in [
        Signal::default(),
        Signal::Sine {
            amplitude: 0.1,
            freq_hz: 1.0 / 3.0,
            offset: -1e-7,
        },
        Signal::Steps {
            low: -1.5,
            high: 2.25,
            period_s: 0.2,
        },
        Signal::Constant(0.5),
    ] {
        let text = s.to_string();
        assert_eq!(text.parse::<Signal>().unwrap(), s, "{text}");
    }
    assert_eq!(
        Signal::default().to_string(),
        "sine:amp=1,freq=0.2,offset=0"
    );
}

#[test]
fn errors_are_clear() {
    let e = |s: &str| s.parse::<Signal>().unwrap_err();
    assert!(matches!(e("triangle"), SignalError::UnknownKind(_)));
    assert!(e("triangle").to_string().contains("sine"));
    assert!(matches!(e("sine:phase=1"), SignalError::UnknownKey { .. }));
    assert!(e("sine:phase=1").to_string().contains("amp, freq, offset"));
    assert!(matches!(e("sine:amp"), SignalError::MissingValue { .. }));
    assert_eq!(e("sine:amp=1,amp=2"), SignalError::Duplicate { key: "amp" });
    assert!(matches!(
        e("sine:amp=x"),
        SignalError::BadNumber { key: "amp", .. }
    ));
    assert!(matches!(e("sine:freq=nan"), SignalError::BadNumber { .. }));
    assert!(matches!(
        e("sine:freq=-1"),
        SignalError::OutOfRange { key: "freq", .. }
    ));
    assert!(matches!(
        e("steps:period=0"),
        SignalError::OutOfRange { key: "period", .. }
    ));
    assert!(matches!(e("constant:inf"), SignalError::BadNumber { .. }));
}

#[test]
fn absurd_inputs_stay_finite() {
    let bad = Signal::Steps {
        low: 1.0,
        high: 2.0,
        period_s: 0.0,
    };
    assert_eq!(bad.value(1.0, 0), 1.0);
    let s = Signal::default();
    assert!(s.value(f64::NAN, 0).is_finite());
    assert!(s.value(1e300, usize::MAX).is_finite());
    assert!(s.value(-5.0, 1).is_finite());
}
