//! Trace replay (DESIGN §6): lookup semantics, and every error with its line.

use std::sync::Arc;

use ndr_core::time::{Duration, Instant};
use ndr_netem::{Column, DelayModel, Direction, MAX_TRACE_ROWS, Trace, TraceError, TraceRow};

fn ms(x: u64) -> Duration {
    Duration::from_millis(x)
}

fn at(s: f64) -> Instant {
    Instant::from_secs_f64(s)
}

#[test]
fn last_row_at_or_before_the_send_time_applies() {
    let trace =
        Trace::parse("t_s,fwd_ms,bwd_ms\n1,10,20\n2.5,30,40\n2.5,35,45\n4,50,60\n").unwrap();
    assert_eq!(trace.rows().len(), 4);
    let fwd = |s| trace.delay(Direction::Forward, at(s));
    let bwd = |s| trace.delay(Direction::Backward, at(s));
    // Before the first row: the first row's.
    assert_eq!(fwd(0.0), ms(10));
    assert_eq!(bwd(0.5), ms(20));
    assert_eq!(fwd(1.0), ms(10));
    assert_eq!(fwd(2.4999), ms(10));
    // Equal times: the later row wins.
    assert_eq!(fwd(2.5), ms(35));
    assert_eq!(bwd(3.9), ms(45));
    assert_eq!(fwd(4.0), ms(50));
    // Past the end: the last row's, for ever.
    assert_eq!(bwd(1e6), ms(60));
    assert_eq!(trace.duration(), Duration::from_secs(4));
}

#[test]
fn tolerates_whitespace_crlf_comments_and_blank_lines() {
    let text = "# recorded on a relay\r\n  t_s , fwd_ms ,bwd_ms  \r\n\r\n 0 , 30.5 , 31 \r\n# a comment\r\n1e1,1.25,0\r\n\n";
    let trace = Trace::parse(text).unwrap();
    assert_eq!(
        trace.rows(),
        &[
            TraceRow {
                at: Instant::ZERO,
                fwd: Duration::from_micros(30_500),
                bwd: ms(31)
            },
            TraceRow {
                at: at(10.0),
                fwd: Duration::from_micros(1250),
                bwd: Duration::ZERO
            },
        ]
    );
}

#[test]
fn csv_round_trips_to_the_nanosecond() {
    let rows = vec![
        TraceRow {
            at: Instant::from_nanos(1),
            fwd: Duration::from_nanos(1_234_567),
            bwd: ms(7),
        },
        TraceRow {
            at: Instant::from_nanos(2_000_000_123),
            fwd: Duration::ZERO,
            bwd: Duration::from_nanos(999_999_999),
        },
    ];
    let trace = Trace::from_rows(rows).unwrap();
    let text = trace.to_csv();
    assert!(text.starts_with("t_s,fwd_ms,bwd_ms\n"));
    assert_eq!(Trace::parse(&text).unwrap(), trace);
}

#[test]
fn replays_through_the_model_and_sampler() {
    let trace = Arc::new(Trace::parse("t_s,fwd_ms,bwd_ms\n0,100,200\n1,300,400\n").unwrap());
    let model = DelayModel::Trace(Arc::clone(&trace));
    assert_eq!(model.name(), "trace");
    let mut s = model.sampler(1);
    assert_eq!(s.delay(Direction::Forward, at(0.5)), ms(100));
    assert_eq!(s.delay(Direction::Backward, at(0.5)), ms(200));
    assert_eq!(s.delay(Direction::Forward, at(1.0)), ms(300));
    assert_eq!(s.delay(Direction::Backward, at(7.0)), ms(400));
}

fn err(text: &str) -> TraceError {
    Trace::parse(text).unwrap_err()
}

#[test]
fn every_error_names_its_line() {
    assert_eq!(err(""), TraceError::Empty);
    assert_eq!(err("# only a comment\n\n"), TraceError::Empty);
    assert_eq!(err("t_s,fwd_ms,bwd_ms\n"), TraceError::NoRows);
    assert_eq!(
        err("time,fwd,bwd\n0,1,2\n"),
        TraceError::BadHeader {
            line: 1,
            found: "time,fwd,bwd".into()
        }
    );
    // A data row where the header should be.
    assert!(matches!(
        err("# c\n0,1,2\n"),
        TraceError::BadHeader { line: 2, .. }
    ));
    assert_eq!(
        err("t_s,fwd_ms,bwd_ms\n0,1,2\n1,2\n"),
        TraceError::ColumnCount { line: 3, found: 2 }
    );
    assert_eq!(
        err("t_s,fwd_ms,bwd_ms\n0,1,2,3\n"),
        TraceError::ColumnCount { line: 2, found: 4 }
    );
    assert_eq!(
        err("t_s,fwd_ms,bwd_ms\n0,1,2\n1,x,2\n"),
        TraceError::NotANumber {
            line: 3,
            column: Column::Forward,
            text: "x".into()
        }
    );
    assert_eq!(
        err("t_s,fwd_ms,bwd_ms\n0,1,\n"),
        TraceError::NotANumber {
            line: 2,
            column: Column::Backward,
            text: String::new()
        }
    );
    assert_eq!(
        err("t_s,fwd_ms,bwd_ms\nnan,1,2\n"),
        TraceError::NotFinite {
            line: 2,
            column: Column::Time
        }
    );
    assert_eq!(
        err("t_s,fwd_ms,bwd_ms\n0,inf,2\n"),
        TraceError::NotFinite {
            line: 2,
            column: Column::Forward
        }
    );
    assert_eq!(
        err("t_s,fwd_ms,bwd_ms\n0,1,2\n1,1,-2\n"),
        TraceError::Negative {
            line: 3,
            column: Column::Backward,
            value: -2.0
        }
    );
    assert_eq!(
        err("t_s,fwd_ms,bwd_ms\n-1,1,2\n"),
        TraceError::Negative {
            line: 2,
            column: Column::Time,
            value: -1.0
        }
    );
    assert!(matches!(
        err("t_s,fwd_ms,bwd_ms\n0,1e300,2\n"),
        TraceError::TooLarge {
            line: 2,
            column: Column::Forward,
            ..
        }
    ));
    assert!(matches!(
        err("t_s,fwd_ms,bwd_ms\n1e20,1,2\n"),
        TraceError::TooLarge {
            line: 2,
            column: Column::Time,
            ..
        }
    ));
    assert_eq!(
        err("t_s,fwd_ms,bwd_ms\n0,1,2\n# comment\n5,1,2\n4,1,2\n"),
        TraceError::Unsorted {
            line: 5,
            t_s: 4.0,
            previous_s: 5.0
        }
    );
}

#[test]
fn messages_say_what_is_wrong_and_where() {
    let m = err("t_s,fwd_ms,bwd_ms\n0,1,2\n1,oops,2\n").to_string();
    assert!(
        m.contains("line 3") && m.contains("fwd_ms") && m.contains("oops"),
        "{m}"
    );
    let m = err("t,f,b\n").to_string();
    assert!(
        m.contains("line 1") && m.contains("t_s,fwd_ms,bwd_ms"),
        "{m}"
    );
    let m = err("t_s,fwd_ms,bwd_ms\n3,1,2\n2,1,2\n").to_string();
    assert!(m.contains("line 3") && m.contains("sort"), "{m}");
    // Long garbage is quoted short.
    let long = "x".repeat(10_000);
    let m = err(&format!("t_s,fwd_ms,bwd_ms\n0,{long},2\n")).to_string();
    assert!(m.len() < 200, "{m}");
}

#[test]
fn row_count_is_capped() {
    let rows = vec![
        TraceRow {
            at: Instant::ZERO,
            fwd: Duration::ZERO,
            bwd: Duration::ZERO,
        };
        MAX_TRACE_ROWS + 1
    ];
    assert!(matches!(
        Trace::from_rows(rows),
        Err(TraceError::TooManyRows { .. })
    ));
    assert_eq!(Trace::from_rows(Vec::new()), Err(TraceError::NoRows));
}

#[test]
fn files_are_read_and_their_errors_reported() {
    let dir = std::env::temp_dir().join(format!("ndr-trace-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let good = dir.join("good.csv");
    std::fs::write(&good, "t_s,fwd_ms,bwd_ms\n0,12,13\n").unwrap();
    let trace = Trace::from_path(&good).unwrap();
    assert_eq!(trace.delay(Direction::Backward, Instant::ZERO), ms(13));

    let missing = dir.join("missing.csv");
    let e = Trace::from_path(&missing).unwrap_err();
    assert!(matches!(e, TraceError::Io { .. }), "{e:?}");
    assert!(e.to_string().contains("missing.csv"), "{e}");

    let binary = dir.join("binary.csv");
    std::fs::write(&binary, [0xff, 0xfe, 0x00]).unwrap();
    let e = Trace::from_path(&binary).unwrap_err();
    assert!(e.to_string().contains("UTF-8"), "{e}");
    std::fs::remove_dir_all(&dir).unwrap();
}
