//! Times given on the command line.

use ndr::core::time::Duration;

/// `ms` milliseconds as a duration; the error names the flag, `name`.
pub fn millis(name: &str, ms: f64) -> Result<Duration, String> {
    if ms.is_finite() && ms >= 0.0 {
        Ok(Duration::from_secs_f64(ms / 1e3))
    } else {
        Err(format!(
            "{name} must be a finite, non-negative number of ms, got {ms}"
        ))
    }
}
