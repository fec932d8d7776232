//! The host's own pauses during a demo, and the late samples they explain.
//!
//! A virtual machine whose host holds it for tens of milliseconds holds
//! every thread at once: base, relay and remote. Samples due in that time
//! are late however the link is built, and at 1 kHz a few such pauses a
//! minute are more late samples than the playout's target allows. A
//! watcher thread that sleeps a millisecond at a time sees the pause as an
//! oversleep; each side notes when it released a tick without its sample;
//! at the end, the late ticks within a pause or shortly after it (while
//! the samples it held back are still on their way) are told apart from
//! the rest, so that a report can show what the link did outside them.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::endpoint::Status;
use ndr::core::time::Instant;
use ndr::net::{Link, Sample};

/// How long the watcher sleeps at a time.
const NAP: StdDuration = StdDuration::from_millis(1);
/// An oversleep past this is a pause: an idle host wakes a sleeper within
/// a fraction of a millisecond.
const PAUSE: StdDuration = StdDuration::from_millis(2);
/// Pauses, and late ticks on each side, kept at most: late ticks past that
/// count against the link (a run with that many is broken anyway).
const MAX_KEPT: usize = 1 << 16;

/// A pause of the host: from when the watcher should have woken to when
/// it did.
#[derive(Clone, Copy, Debug)]
struct Pause {
    from: StdInstant,
    to: StdInstant,
}

/// Watches for pauses until stopped.
pub struct Watch {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Vec<Pause>>>,
}

impl Watch {
    /// Starts the watcher thread; `None` (and a warning) if it cannot run.
    pub fn start() -> Option<Watch> {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let thread = std::thread::Builder::new()
            .name("ndr-demo-watch".into())
            .spawn(move || watch(&flag));
        match thread {
            Ok(t) => Some(Watch {
                stop,
                thread: Some(t),
            }),
            Err(e) => {
                tracing::warn!("no watch for host pauses: {e}");
                None
            }
        }
    }

    /// Stops the watcher: the pauses it saw.
    fn finish(mut self) -> Vec<Pause> {
        self.stop.store(true, Ordering::Relaxed);
        self.thread
            .take()
            .and_then(|t| t.join().ok())
            .unwrap_or_default()
    }
}

impl Drop for Watch {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

fn watch(stop: &AtomicBool) -> Vec<Pause> {
    let mut pauses = Vec::new();
    while !stop.load(Ordering::Relaxed) {
        let due = StdInstant::now() + NAP;
        std::thread::sleep(NAP);
        let woke = StdInstant::now();
        if woke.saturating_duration_since(due) > PAUSE && pauses.len() < MAX_KEPT {
            pauses.push(Pause {
                from: due,
                to: woke,
            });
        }
    }
    pauses
}

/// When one side released ticks without their sample.
#[derive(Debug, Default)]
pub struct LateTicks {
    at: Vec<StdInstant>,
}

/// Notes `sample` in `late` if its tick went without it (held).
pub fn note(late: Option<&Mutex<LateTicks>>, link: &Link, sample: &Sample) {
    if let Some(late) = late
        && sample.status == Status::Held
    {
        late.lock()
            .unwrap_or_else(PoisonError::into_inner)
            .push(link, sample.released_at);
    }
}

impl LateTicks {
    /// A tick `link` released at `released_at` (its clock) went without
    /// its sample.
    fn push(&mut self, link: &Link, released_at: Instant) {
        if self.at.len() >= MAX_KEPT {
            return;
        }
        let ago: StdDuration = (link.now() - released_at).into();
        let now = StdInstant::now();
        self.at.push(now.checked_sub(ago).unwrap_or(now));
    }
}

/// What the pauses explain of the late ticks.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct PauseSummary {
    /// Pauses the watcher saw (oversleeps past 2 ms).
    pub host_pauses: u64,
    /// Their length in all, and the longest, in seconds.
    pub host_paused_s: f64,
    pub host_pause_max_s: f64,
    /// The time within a pause or in the `after` that follows one, in
    /// seconds (overlaps counted once).
    pub host_pause_windows_s: f64,
    /// Late samples (both sides) released within those windows, and the
    /// others: all the late samples the link counted but those, so that
    /// one the application never saw (a delivery its full queue dropped)
    /// counts against the link.
    pub late_in_host_pauses: u64,
    pub late_outside_host_pauses: u64,
}

/// Stops `watch` and tells the late ticks of `sides` within a pause, or
/// within `after` of its end, from the rest of the `late` the links
/// counted.
pub fn summarize(
    watch: Option<Watch>,
    sides: &[&Mutex<LateTicks>],
    after: StdDuration,
    late: u64,
) -> Option<PauseSummary> {
    let pauses = watch?.finish();
    let windows = merged(&pauses, after);
    let mut s = PauseSummary {
        host_pauses: pauses.len() as u64,
        host_paused_s: pauses.iter().map(|p| secs(p.from, p.to)).sum(),
        host_pause_max_s: pauses
            .iter()
            .map(|p| secs(p.from, p.to))
            .fold(0.0, f64::max),
        host_pause_windows_s: windows.iter().map(|w| secs(w.from, w.to)).sum(),
        ..PauseSummary::default()
    };
    for side in sides {
        let ticks = side.lock().unwrap_or_else(PoisonError::into_inner);
        for &t in &ticks.at {
            // `windows` is sorted and disjoint.
            let i = windows.partition_point(|w| w.to < t);
            if windows.get(i).is_some_and(|w| w.from <= t) {
                s.late_in_host_pauses += 1;
            }
        }
    }
    s.late_in_host_pauses = s.late_in_host_pauses.min(late);
    s.late_outside_host_pauses = late - s.late_in_host_pauses;
    Some(s)
}

/// The pauses, each stretched by `after`, merged where they overlap.
fn merged(pauses: &[Pause], after: StdDuration) -> Vec<Pause> {
    let mut windows: Vec<Pause> = Vec::with_capacity(pauses.len());
    for p in pauses {
        let to = p.to + after;
        match windows.last_mut() {
            Some(last) if p.from <= last.to => last.to = last.to.max(to),
            _ => windows.push(Pause { from: p.from, to }),
        }
    }
    windows
}

fn secs(from: StdInstant, to: StdInstant) -> f64 {
    to.saturating_duration_since(from).as_secs_f64()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(origin: StdInstant, ms: u64) -> StdInstant {
        origin + StdDuration::from_millis(ms)
    }

    #[test]
    fn a_late_tick_counts_as_the_hosts_only_within_a_pause_or_just_after() {
        let o = StdInstant::now();
        let pauses = vec![
            Pause {
                from: at(o, 100),
                to: at(o, 120),
            },
            // Overlaps the first's window: one window, 100 to 170 ms.
            Pause {
                from: at(o, 140),
                to: at(o, 145),
            },
            Pause {
                from: at(o, 500),
                to: at(o, 503),
            },
        ];
        let windows = merged(&pauses, StdDuration::from_millis(25));
        let spans: Vec<(u128, u128)> = windows
            .iter()
            .map(|w| {
                (
                    w.from.duration_since(o).as_millis(),
                    w.to.duration_since(o).as_millis(),
                )
            })
            .collect();
        assert_eq!(spans, [(100, 170), (500, 528)]);

        let late = Mutex::new(LateTicks {
            at: [50, 100, 169, 171, 510, 600]
                .iter()
                .map(|&ms| at(o, ms))
                .collect(),
        });
        let watch = Watch {
            stop: Arc::new(AtomicBool::new(false)),
            thread: Some(std::thread::spawn(move || pauses)),
        };
        // The link counted two more than the application saw.
        let s = summarize(Some(watch), &[&late], StdDuration::from_millis(25), 8)
            .expect("a watch gives a summary");
        assert_eq!(s.host_pauses, 3);
        assert_eq!(s.late_in_host_pauses, 3);
        // 50, 171 and 600 ms, and the two it never saw.
        assert_eq!(s.late_outside_host_pauses, 5);
        assert!((s.host_paused_s - 0.028).abs() < 1e-9);
        assert!((s.host_pause_max_s - 0.020).abs() < 1e-9);
        assert!((s.host_pause_windows_s - 0.098).abs() < 1e-9);
    }
}
