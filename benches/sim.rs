//! How fast the simulator runs the paper's 20-minute `paper-fig6` scenario:
//! at T = 200 ms (6 000 ticks a side; target < 50 ms) and at T = 1 ms
//! (1.2 million ticks a side; target < 5 s); and the same 20 minutes at
//! T = 200 ms with a loop closed across the link (`ndr control`: the
//! Smith-predicted tracking loop over the static FIFO, and the delay-free
//! design it is measured against).

use std::hint::black_box;
use std::time::Duration as StdDuration;

use criterion::{Criterion, criterion_group, criterion_main};
use ndr::core::time::Duration;
use ndr::sim::control::{LinkKind, LoopConfig, Scenario, run_loop};
use ndr::sim::delay::DelayModel;
use ndr::sim::{SimConfig, run};

fn fig6(period: Duration) -> SimConfig {
    let mut cfg = SimConfig::paper(DelayModel::PaperFig6);
    cfg.duration = Duration::from_secs(1200);
    cfg.period = period;
    cfg
}

fn sim(c: &mut Criterion) {
    let slow = fig6(Duration::from_millis(200));
    c.bench_function("sim paper-fig6 20 min, T = 200 ms", |b| {
        b.iter(|| black_box(run(black_box(&slow)).unwrap().report.grtt_count))
    });
    let tracking = LoopConfig::new(slow.clone(), Scenario::Tracking, LinkKind::PaperStatic);
    c.bench_function(
        "closed loop paper-fig6 20 min, T = 200 ms (Smith over paper-static, and the design)",
        |b| b.iter(|| black_box(run_loop(black_box(&tracking)).unwrap().rms_vs_reference)),
    );
    let mut group = c.benchmark_group("sim slow");
    group
        .sample_size(10)
        .measurement_time(StdDuration::from_secs(30));
    let fast = fig6(Duration::from_millis(1));
    group.bench_function("sim paper-fig6 20 min, T = 1 ms", |b| {
        b.iter(|| black_box(run(black_box(&fast)).unwrap().report.grtt_count))
    });
    group.finish();
}

criterion_group!(benches, sim);
criterion_main!(benches);
