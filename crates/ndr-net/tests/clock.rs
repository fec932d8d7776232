//! The lateness histogram the hub's release clock is measured with, on
//! hand-made data.

use ndr_core::time::Duration;
use ndr_net::clock::{LatenessHistogram, LatenessStats};

const MS: Duration = Duration::from_millis(1);
const US: Duration = Duration::from_micros(1);

#[test]
fn histogram_percentiles_on_hand_made_data() {
    let mut h = LatenessHistogram::new(MS);
    assert_eq!(h.percentile(50.0), None);
    assert_eq!(h.mean(), None);
    assert_eq!(h.stats(), LatenessStats::default());

    // 1.5 µs, 2.5 µs, …, 100.5 µs: one record in each bucket 1..=100.
    for i in 1..=100 {
        h.record(US * i + Duration::from_nanos(500));
    }
    assert_eq!(h.count(), 100);
    assert_eq!(h.min(), Some(Duration::from_nanos(1_500)));
    assert_eq!(h.max(), Some(Duration::from_nanos(100_500)));
    assert_eq!(h.mean(), Some(US * 51));
    // The upper edge of the bucket: at most 1 µs above the true value.
    assert_eq!(h.percentile(50.0), Some(US * 51));
    assert_eq!(h.percentile(99.0), Some(US * 100));
    assert_eq!(h.percentile(0.0), Some(US * 2));
    // Never above the maximum.
    assert_eq!(h.percentile(100.0), Some(Duration::from_nanos(100_500)));
    assert_eq!(h.percentile(250.0), h.percentile(100.0));
    assert_eq!(h.percentile(f64::NAN), None);
    assert_eq!(h.missed(), 0);
    assert_eq!(h.count_under_micros(0), 0);
    assert_eq!(h.count_under_micros(2), 1, "1.5 µs only");
    assert_eq!(h.count_under_micros(101), 100);

    // Past the linear range: counted in the overflow, reported by the max.
    h.record(MS * 20);
    h.record(MS);
    assert_eq!(h.overflow(), 1);
    assert_eq!(h.missed(), 2, "a tick a whole period late is missed");
    assert_eq!(h.percentile(100.0), Some(MS * 20));
    let stats = h.stats();
    assert_eq!(stats.count, 102);
    assert_eq!(stats.p999, MS * 20);
    assert_eq!(stats.max, MS * 20);
    assert_eq!(h.count_under_micros(10_001), 101, "not the overflow");
    assert_eq!(h.count_under_micros(20_001), 102, "all below the max");
    assert!(stats.to_string().starts_with("102 ticks, 2 missed: p50 "));

    h.clear();
    assert_eq!(h.count(), 0);
    assert_eq!(h.percentile(50.0), None);
    h.record(Duration::from_nanos(300));
    assert_eq!(h.percentile(50.0), Some(Duration::from_nanos(300)));
    assert_eq!(h.period(), MS);
}

#[test]
fn zero_lateness_reports_zero() {
    let mut h = LatenessHistogram::new(Duration::ZERO);
    for _ in 0..1000 {
        h.record(Duration::ZERO);
    }
    let stats = h.stats();
    assert_eq!(
        (stats.p50, stats.p999, stats.max),
        (Duration::ZERO, Duration::ZERO, Duration::ZERO)
    );
    assert_eq!(stats.missed, 0, "a zero period counts no miss");
}
