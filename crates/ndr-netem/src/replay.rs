//! A [`Trace`] from one-way delays measured sample by sample (a link's
//! recording, `/ndr/network`): the network of a session from the field,
//! for the simulator to replay.

use std::vec::Vec;

use ndr_core::time::{Duration, Instant};

use super::{Direction, Trace, TraceError, TraceRow};

/// One sample's crossing: when it was sent (from the replay's origin) and
/// its one-way delay, `None` if it never came in time (lost, or released
/// late).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OneWay {
    /// The send time, from the origin the two directions share.
    pub sent: Instant,
    /// The delay; `None` for a sample that never came in time.
    pub delay: Option<Duration>,
}

/// The delays of `way` (in send order) with each missing one filled: the
/// sample came no earlier than the next one that arrived, as in-order
/// delivery has it (the last ones missing take the last delay known).
fn filled(way: &[OneWay]) -> Vec<(Instant, Duration)> {
    let mut out = Vec::with_capacity(way.len());
    let mut next_arrival: Option<Instant> = None;
    for w in way.iter().rev() {
        let delay = match w.delay {
            Some(d) => {
                next_arrival = w.sent.checked_add(d);
                d
            }
            None => match next_arrival {
                Some(a) => a.checked_duration_since(w.sent).unwrap_or(Duration::ZERO),
                // Filled from the last delay known, below.
                None => Duration::MAX,
            },
        };
        out.push((w.sent, delay));
    }
    out.reverse();
    let last_known = way.iter().rev().find_map(|w| w.delay);
    for (_, d) in &mut out {
        if *d == Duration::MAX {
            *d = last_known.unwrap_or(Duration::ZERO);
        }
    }
    out
}

/// Each sample's row of `way` (in send order): from halfway between the
/// send before it and its own on, so that a frame takes the delay of the
/// sample sent nearest to it. A replay's sends fall near the recorded
/// ones, a little before or after (clock estimates, a playout's choices):
/// each still meets its own sample's delay, not its neighbour's.
fn nearest(way: Vec<(Instant, Duration)>) -> Vec<(Instant, Duration)> {
    let mut before: Option<Instant> = None;
    way.into_iter()
        .map(|(sent, d)| {
            let from = before.map_or(sent, |b| b + (sent - b) / 2);
            before = Some(sent);
            (from, d)
        })
        .collect()
}

/// The spans of `way` (in send order) in which a frame takes the delay of
/// a sample that never came in time (`starts`: each sample's row start).
fn losses(way: &[OneWay], starts: &[(Instant, Duration)]) -> Vec<(Instant, Instant)> {
    let end = Instant::from_nanos(u64::MAX);
    way.iter()
        .zip(starts)
        .enumerate()
        .filter(|(_, (w, _))| w.delay.is_none())
        .map(|(i, (_, &(from, _)))| (from, starts.get(i + 1).map_or(end, |s| s.0)))
        .collect()
}

/// The trace that gives a frame sent at `t` the delay of the sample sent
/// nearest to `t` in its direction: one row per sample, both directions
/// on one time line. A direction with no sample takes the other's delays
/// (a recording made on one side only measured its own). A frame nearest
/// to a sample that never came in time takes, as a stream's frame, the
/// delay in-order delivery gave it (no earlier than the next one); as a
/// datagram, it is lost ([`Trace::lost`]).
///
/// # Errors
///
/// [`TraceError::NoRows`] when neither direction has a sample;
/// [`TraceError::TooManyRows`] past [`MAX_TRACE_ROWS`](super::MAX_TRACE_ROWS).
pub fn one_way_trace(forward: &[OneWay], backward: &[OneWay]) -> Result<Trace, TraceError> {
    let mut forward = forward.to_vec();
    let mut backward = backward.to_vec();
    forward.sort_by_key(|w| w.sent);
    backward.sort_by_key(|w| w.sent);
    let (mut fwd, mut bwd) = (nearest(filled(&forward)), nearest(filled(&backward)));
    let (mut fwd_lost, mut bwd_lost) = (losses(&forward, &fwd), losses(&backward, &bwd));
    if fwd.is_empty() {
        fwd.clone_from(&bwd);
        fwd_lost.clone_from(&bwd_lost);
    }
    if bwd.is_empty() {
        bwd.clone_from(&fwd);
        bwd_lost.clone_from(&fwd_lost);
    }
    let (Some(&(_, mut f)), Some(&(_, mut b))) = (fwd.first(), bwd.first()) else {
        return Err(TraceError::NoRows);
    };
    let mut rows = Vec::with_capacity(fwd.len() + bwd.len());
    let (mut i, mut j) = (0, 0);
    while i < fwd.len() || j < bwd.len() {
        let take_fwd = match (fwd.get(i), bwd.get(j)) {
            (Some(x), Some(y)) => x.0 <= y.0,
            (Some(_), None) => true,
            _ => false,
        };
        let at = if take_fwd {
            let (at, d) = fwd[i];
            f = d;
            i += 1;
            at
        } else {
            let (at, d) = bwd[j];
            b = d;
            j += 1;
            at
        };
        rows.push(TraceRow { at, fwd: f, bwd: b });
    }
    Ok(Trace::from_rows(rows)?
        .with_losses(Direction::Forward, fwd_lost)
        .with_losses(Direction::Backward, bwd_lost))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    fn at(v: u64) -> Instant {
        Instant::from_millis(v)
    }

    #[test]
    fn each_frame_takes_the_delay_of_the_sample_sent_nearest_to_it() {
        let fwd = [
            OneWay {
                sent: at(0),
                delay: Some(ms(10)),
            },
            OneWay {
                sent: at(100),
                delay: Some(ms(30)),
            },
        ];
        let bwd = [OneWay {
            sent: at(50),
            delay: Some(ms(20)),
        }];
        let t = one_way_trace(&fwd, &bwd).unwrap();
        use crate::Direction::{Backward, Forward};
        assert_eq!(t.delay(Forward, at(0)), ms(10));
        assert_eq!(t.delay(Forward, at(49)), ms(10));
        // A frame sent a little before the second sample is that sample.
        assert_eq!(t.delay(Forward, at(50)), ms(30));
        assert_eq!(t.delay(Forward, at(99)), ms(30));
        assert_eq!(t.delay(Forward, at(100)), ms(30));
        // Before the first backward sample, its first delay.
        assert_eq!(t.delay(Backward, at(0)), ms(20));
        assert_eq!(t.delay(Backward, at(120)), ms(20));
    }

    #[test]
    fn a_missing_sample_came_no_earlier_than_the_next_and_one_side_mirrors() {
        let fwd = [
            OneWay {
                sent: at(0),
                delay: Some(ms(10)),
            },
            OneWay {
                sent: at(10),
                delay: None,
            },
            OneWay {
                sent: at(20),
                delay: Some(ms(50)),
            },
            OneWay {
                sent: at(30),
                delay: None,
            },
        ];
        let t = one_way_trace(&fwd, &[]).unwrap();
        use crate::Direction::{Backward, Forward};
        // Arrived with the next, at 70 ms: 60 ms after its send.
        assert_eq!(t.delay(Forward, at(10)), ms(60));
        assert_eq!(t.delay(Forward, at(6)), ms(60));
        // The last, with nothing after it: the last delay known.
        assert_eq!(t.delay(Forward, at(30)), ms(50));
        assert_eq!(t.delay(Backward, at(20)), ms(50));
        assert_eq!(one_way_trace(&[], &[]), Err(TraceError::NoRows));
    }

    #[test]
    fn a_sample_never_released_is_a_loss_for_the_frames_nearest_it() {
        let at_ms = |v: u64, d: Option<u64>| OneWay {
            sent: at(v),
            delay: d.map(ms),
        };
        let fwd = [at_ms(0, Some(10)), at_ms(100, None), at_ms(200, Some(10))];
        let t = one_way_trace(&fwd, &[]).unwrap();
        use crate::Direction::{Backward, Forward};
        // The frames nearest the missing sample: from halfway before it to
        // halfway after it.
        for (sent, lost) in [
            (0, false),
            (49, false),
            (50, true),
            (149, true),
            (150, false),
        ] {
            assert_eq!(t.lost(Forward, at(sent)), lost, "{sent} ms");
            assert_eq!(t.lost(Backward, at(sent)), lost, "{sent} ms, mirrored");
        }
    }

    #[test]
    fn a_probe_is_found_by_its_number_and_one_below_the_last_recorded_was_lost() {
        use crate::Direction::{Backward, Forward};
        use crate::RecordedProbe::{Delayed, Lost, Unrecorded};
        let t = one_way_trace(
            &[OneWay {
                sent: at(0),
                delay: Some(ms(10)),
            }],
            &[],
        )
        .unwrap()
        .with_probes(Forward, vec![(7, ms(40)), (5, ms(30)), (5, ms(99))]);
        assert_eq!(t.probe(Forward, 5), Delayed(ms(30)));
        assert_eq!(t.probe(Forward, 7), Delayed(ms(40)));
        assert_eq!(t.probe(Forward, 6), Lost);
        assert_eq!(t.probe(Forward, 0), Lost);
        assert_eq!(t.probe(Forward, 8), Unrecorded);
        assert_eq!(t.probe(Backward, 5), Unrecorded);
    }
}
