//! The relay's delay trace: a steady delay with spikes.

use std::time::Duration as StdDuration;

use ndr::core::time::{Duration, Instant};
use ndr::sim::delay::{Trace, TraceRow};

/// A delay spike in the relay's trace, `SPIKE_LEN_S` long, every 0.7 fault
/// periods (so each relay, restarted every third fault, sees a few).
pub(super) const SPIKE_EVERY_FAULTS: f64 = 0.7;
const SPIKE_LEN_S: f64 = 0.2;
const SPIKE_DELAY_MS: u64 = 150;
const BASE_DELAY_US: u64 = 500;

/// 0.5 ms each way, with a 150 ms spike for 200 ms every `every` seconds.
pub(super) fn spike_trace(duration_s: f64, every: f64) -> Result<Trace, String> {
    let base = Duration::from_micros(BASE_DELAY_US);
    let spike = Duration::from_millis(SPIKE_DELAY_MS);
    let mut rows = vec![TraceRow {
        at: Instant::ZERO,
        fwd: base,
        bwd: base,
    }];
    let mut t = every;
    while t < duration_s + every {
        let at = Instant::ZERO + Duration::from_secs_f64(t);
        rows.push(TraceRow {
            at,
            fwd: spike,
            bwd: spike,
        });
        rows.push(TraceRow {
            at: at + Duration::from_secs_f64(SPIKE_LEN_S),
            fwd: base,
            bwd: base,
        });
        t += every;
    }
    Trace::from_rows(rows).map_err(|e| e.to_string())
}

pub(super) fn spikes_within(lifetime: StdDuration, every: f64) -> u64 {
    (lifetime.as_secs_f64() / every) as u64
}
