//! `ndr demo --observers N`: bases that watch the robot beside the
//! operator, each on a link of its own through the relay, and what each
//! saw.

use std::fmt;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::endpoint::{Event, Status};
use ndr::net::{Link, NetError};
use serde::Serialize;

use crate::report::Seating;

/// What one observer saw, as the demo's report gives it.
#[derive(Clone, Debug, Serialize)]
pub struct Watched {
    /// Its number, from 1.
    pub observer: usize,
    /// States released to it fresh, and held (an empty queue's tick).
    pub states_fresh: u64,
    pub states_held: u64,
    /// The robot's control terms of those states, in order.
    pub terms_seen: Vec<u16>,
    /// Commands the robot applied that it was told of, and events its
    /// link dropped for want of reading (none while it reads each tick).
    pub applied_seen: u64,
    pub events_dropped: u64,
    /// Its own playout's constant delay, and the network's round trip.
    pub playout_delay_s: f64,
    pub nrtt_mean_s: f64,
    /// Its regulator's underflows and late samples.
    pub underflows: u64,
    pub late: u64,
    /// Whether it watched to the end, its link closed in order.
    pub ok: bool,
    pub end: String,
}

impl fmt::Display for Watched {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "observer {}: {} states ({} held), terms {:?}, {} applied commands seen, playout \
             {:.1} ms, {} underflows, {} late; {}",
            self.observer,
            self.states_fresh,
            self.states_held,
            self.terms_seen,
            self.applied_seen,
            self.playout_delay_s * 1e3,
            self.underflows,
            self.late,
            self.end
        )
    }
}

/// An observer watching on a thread of its own until `until` or `stop`.
pub struct Watcher(JoinHandle<Watched>);

impl Watcher {
    pub fn start(
        n: usize,
        link: Link,
        until: StdInstant,
        stop: Arc<AtomicBool>,
    ) -> Result<Watcher, String> {
        std::thread::Builder::new()
            .name(format!("ndr-demo-observer-{n}"))
            .spawn(move || watch(n, link, until, &stop))
            .map(Watcher)
            .map_err(|e| format!("cannot start observer {n}'s thread: {e}"))
    }

    /// What it saw, once it has stopped.
    pub fn join(self) -> Result<Watched, String> {
        self.0
            .join()
            .map_err(|_| "an observer's thread panicked".to_string())
    }
}

fn watch(n: usize, mut link: Link, until: StdInstant, stop: &AtomicBool) -> Watched {
    let mut seating = Seating {
        role: "observer",
        waited_for_control_s: None,
        terms_seen: Vec::new(),
    };
    let (mut fresh, mut held, mut applied) = (0_u64, 0_u64, 0_u64);
    let mut failed = None;
    while !stop.load(Ordering::Relaxed) {
        let left = until.saturating_duration_since(StdInstant::now());
        if left.is_zero() {
            break;
        }
        match link.recv_timeout(left.min(StdDuration::from_millis(100))) {
            Ok(s) => {
                seating.saw(s.term);
                if s.status == Status::Fresh {
                    fresh += 1;
                } else {
                    held += 1;
                }
            }
            Err(NetError::Timeout) => {}
            Err(e) => {
                failed = Some(format!("link failed: {e}"));
                break;
            }
        }
        // One applied command a tick: read as they come, none is dropped.
        applied += link
            .drain_events()
            .filter(|e| matches!(e, Event::Applied(_)))
            .count() as u64;
    }
    let stats = link.close();
    let events_dropped = stats.map_or(0, |s| s.events_dropped);
    let e = stats.map(|s| s.endpoint).unwrap_or_default();
    Watched {
        observer: n,
        states_fresh: fresh,
        states_held: held,
        terms_seen: seating.terms_seen,
        applied_seen: applied,
        events_dropped,
        playout_delay_s: e.playout_delay_s,
        nrtt_mean_s: e.nrtt.mean(),
        underflows: e.underflows,
        late: e.late,
        ok: failed.is_none() && fresh > 0,
        end: failed.unwrap_or_else(|| {
            if fresh > 0 {
                "watched to the end".into()
            } else {
                "no state came".into()
            }
        }),
    }
}
