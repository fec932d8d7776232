//! netem distribution tables: parsing, the kernel's scaling, and sampling.

use std::path::PathBuf;
use std::sync::Arc;

use ndr_core::time::{Duration, Instant};
use ndr_netem::{DelayModel, Direction, DistError, DistTable, MAX_DIST_ENTRIES, NETEM_DIST_SCALE};

#[test]
fn parses_integers_and_comments_like_iproute2() {
    let t =
        DistTable::parse("# header\n -8192 0 +8192\n\n  # indented comment\n\t4096\r\n").unwrap();
    assert_eq!(t.entries(), &[-8192, 0, 8192, 4096]);
    assert_eq!(t.len(), 4);
    assert!(!t.is_empty());
    assert_eq!(
        DistTable::parse("-32768 32767").unwrap().entries(),
        &[i16::MIN, i16::MAX]
    );
}

#[test]
fn refuses_bad_tables_naming_the_line() {
    assert_eq!(DistTable::parse(""), Err(DistError::Empty));
    assert_eq!(DistTable::parse("# nothing\n\n"), Err(DistError::Empty));
    assert_eq!(
        DistTable::parse("1 2\n3 4.5\n"),
        Err(DistError::NotAnInteger {
            line: 2,
            token: "4.5".into()
        })
    );
    assert_eq!(
        DistTable::parse("1\n2\n0x10\n"),
        Err(DistError::NotAnInteger {
            line: 3,
            token: "0x10".into()
        })
    );
    assert_eq!(
        DistTable::parse("1 # trailing comments are not iproute2's format\n"),
        Err(DistError::NotAnInteger {
            line: 1,
            token: "#".into()
        })
    );
    assert_eq!(
        DistTable::parse("0\n32768\n"),
        Err(DistError::OutOfRange {
            line: 2,
            token: "32768".into()
        })
    );
    assert_eq!(
        DistTable::parse("-32769"),
        Err(DistError::OutOfRange {
            line: 1,
            token: "-32769".into()
        })
    );
    let huge = "9".repeat(5000);
    let e = DistTable::parse(&huge).unwrap_err();
    assert!(matches!(e, DistError::OutOfRange { line: 1, .. }));
    assert!(e.to_string().len() < 300, "{e}");
    let too_many = "1\n".repeat(MAX_DIST_ENTRIES + 1);
    assert_eq!(
        DistTable::parse(&too_many),
        Err(DistError::TooManyEntries {
            line: MAX_DIST_ENTRIES + 1
        })
    );
    let m = DistTable::parse("1\nabc\n").unwrap_err().to_string();
    assert!(m.contains("line 2") && m.contains("abc"), "{m}");
}

#[test]
fn scales_like_the_kernel_tabledist() {
    let d = |ns| Duration::from_nanos(ns);
    let mu = d(100_000_000);
    // One standard deviation up and down.
    assert_eq!(
        DistTable::scale_entry(8192, mu, d(20_000_000)),
        d(120_000_000)
    );
    assert_eq!(
        DistTable::scale_entry(-8192, mu, d(20_000_000)),
        d(80_000_000)
    );
    // Rounding of the remainder part, half away from zero: sigma = 8192 + 3,
    // t = 4096 → 3·4096/8192 = 1.5 → 2, plus 1·4096.
    assert_eq!(
        DistTable::scale_entry(4096, Duration::ZERO, d(8195)),
        d(4098)
    );
    assert_eq!(
        DistTable::scale_entry(-4096, d(10_000), d(8195)),
        d(10_000 - 4098)
    );
    // Negative results clamp to zero; huge ones do not overflow.
    assert_eq!(
        DistTable::scale_entry(-32768, d(1), d(1_000_000_000)),
        Duration::ZERO
    );
    assert_eq!(
        DistTable::scale_entry(32767, Duration::MAX, Duration::MAX),
        Duration::MAX
    );
    assert_eq!(NETEM_DIST_SCALE, 8192);
}

/// Mean and standard deviation (s) of `n` forward delays.
fn moments(model: &DelayModel, seed: u64, n: usize) -> (f64, f64) {
    let mut s = model.sampler(seed);
    let xs: Vec<f64> = (0..n)
        .map(|k| {
            s.delay(Direction::Forward, Instant::from_millis(k as u64))
                .as_secs_f64()
        })
        .collect();
    let mean = xs.iter().sum::<f64>() / n as f64;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
    (mean, var.sqrt())
}

/// A symmetric table of ±1 standard deviation: delays are mu ± sigma.
#[test]
fn samples_have_the_table_mean_and_std() {
    let table = Arc::new(DistTable::parse("-8192 8192 -8192 8192").unwrap());
    assert_eq!(table.moments(), (0.0, 1.0));
    let model = DelayModel::Dist {
        table,
        mean: Duration::from_millis(100),
        std: Duration::from_millis(20),
    };
    assert_eq!(model.name(), "dist");
    let (mean, std) = moments(&model, 3, 20_000);
    assert!((mean - 0.100).abs() < 0.001, "mean {mean}");
    assert!((std - 0.020).abs() < 0.0005, "std {std}");
}

/// A generated normal table of 4096 quantiles, like iproute2's `normal.dist`.
#[test]
fn generated_normal_table_gives_mu_and_sigma() {
    let n = 4096;
    let entries: Vec<i16> = (0..n)
        .map(|i| {
            let p = (i as f64 + 0.5) / n as f64;
            (inverse_normal(p) * 8192.0)
                .round()
                .clamp(-32768.0, 32767.0) as i16
        })
        .collect();
    let text: String = entries.iter().map(|e| format!("{e}\n")).collect();
    let table = DistTable::parse(&text).unwrap();
    let (m, s) = table.moments();
    assert!(m.abs() < 1e-3 && (s - 1.0).abs() < 0.01, "{m} {s}");
    let model = DelayModel::Dist {
        table: Arc::new(table),
        mean: Duration::from_millis(300),
        std: Duration::from_millis(50),
    };
    let (mean, std) = moments(&model, 11, 40_000);
    assert!((mean - 0.300).abs() < 0.0015, "mean {mean}");
    assert!((std - 0.050).abs() < 0.0015, "std {std}");
}

/// Acklam's rational approximation of the standard normal quantile
/// (relative error below 1.2e-9), enough to build a table.
fn inverse_normal(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.383_577_518_672_69e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

#[test]
fn directions_and_seeds_are_independent_streams() {
    let model = DelayModel::Dist {
        table: Arc::new(DistTable::parse("-8192 -4096 0 4096 8192").unwrap()),
        mean: Duration::from_millis(50),
        std: Duration::from_millis(10),
    };
    let fwd = |seed, interleave: bool| {
        let mut s = model.sampler(seed);
        (0..200u64)
            .map(|k| {
                if interleave {
                    let _ = s.delay(Direction::Backward, Instant::from_millis(k));
                }
                s.delay(Direction::Forward, Instant::from_millis(k))
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(fwd(5, false), fwd(5, true));
    assert_ne!(fwd(5, false), fwd(6, false));
}

#[test]
fn files_are_read_and_size_capped() {
    let dir = std::env::temp_dir().join(format!("ndr-dist-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let good = dir.join("t.dist");
    std::fs::write(&good, "# t\n-1 0 1\n").unwrap();
    assert_eq!(DistTable::from_path(&good).unwrap().entries(), &[-1, 0, 1]);
    let big = dir.join("big.dist");
    std::fs::write(&big, vec![b' '; 2 * 1024 * 1024]).unwrap();
    let e = DistTable::from_path(&big).unwrap_err();
    assert!(matches!(e, DistError::FileTooLarge { .. }), "{e:?}");
    let e = DistTable::from_path(dir.join("none.dist")).unwrap_err();
    assert!(
        matches!(e, DistError::Io { .. }) && e.to_string().contains("none.dist"),
        "{e}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// iproute2's own tables, when installed: each parses to 4096 entries; the
/// normal one has mean ≈ 0 and deviation ≈ 1 (in units of 8192), and for
/// every table `delay 100ms 20ms` gives `100 + 20·m` ms ± `20·s` ms, where
/// `(m, s)` are the table's own moments (pareto's are not exactly (0, 1):
/// its tail is cut at the 16-bit range).
#[test]
fn system_tables_when_present() {
    let mut dirs: Vec<PathBuf> = vec![PathBuf::from("/usr/lib/tc"), PathBuf::from("/usr/lib64/tc")];
    if let Ok(entries) = std::fs::read_dir("/usr/lib") {
        dirs.extend(entries.flatten().map(|e| e.path().join("tc")));
    }
    let Some(dir) = dirs.into_iter().find(|d| d.join("normal.dist").is_file()) else {
        println!("note: no iproute2 tables under /usr/lib/*/tc or /usr/lib/tc; skipped");
        return;
    };
    for name in ["normal", "pareto", "paretonormal", "experimental"] {
        let path = dir.join(format!("{name}.dist"));
        let Ok(table) = DistTable::from_path(&path) else {
            println!("note: {} missing or unreadable; skipped", path.display());
            continue;
        };
        assert_eq!(table.len(), 4096, "{name}");
        let (m, s) = table.moments();
        if name == "normal" {
            assert!(m.abs() < 0.01 && (s - 1.0).abs() < 0.02, "{name}: {m} {s}");
        }
        let model = DelayModel::Dist {
            table: Arc::new(table),
            mean: Duration::from_millis(100),
            std: Duration::from_millis(20),
        };
        let (mean, std) = moments(&model, 1, 40_000);
        println!(
            "{name}.dist: table mean {m:+.4} std {s:.4}; delay 100ms 20ms gives {:.2} ms, std {:.2} ms",
            mean * 1e3,
            std * 1e3
        );
        // Clamping at zero cannot bite: the tables reach -4 deviations at most.
        assert!(
            (mean - (0.100 + 0.020 * m)).abs() < 0.0015,
            "{name}: mean {mean}"
        );
        assert!((std - 0.020 * s).abs() < 0.002, "{name}: std {std}");
    }
}
