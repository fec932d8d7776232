//! What an honest peer's frames can be, checked before any of them is used.
//!
//! Over a stream (TCP, TLS) every Data frame is the one after the previous:
//! its `seq` is one more, and its send stamp — its tick's scheduled time on
//! the peer's clock — at least half a period later (a remote's ticks move
//! with its releases by up to half a period; see `Endpoint::following_tick`).
//! `seq` numbers the sender's ticks: one whose driver stalled for more ticks
//! than its transmit queue holds gave up the oldest frames (and counted
//! them), so a later `seq` passes when its stamp leaves room for the ticks
//! it skipped; a repeat, a step back or an unexplained jump does not.
//! And no frame can arrive before it was sent: once an echo has bounded the
//! offset between the clocks, a stamp later than its arrival by more than
//! the skew allows is from the future. A frame that breaks one of these is
//! a protocol error that ends the link; nothing of it is released, and it
//! never reaches the clock estimate (a stamp of 2⁶³ ns froze the releases
//! for the rest of the session).

use crate::time::{Duration, Instant};

use super::LinkError;

/// The most the peers' clocks may drift apart, relative: 1 000 ppm, ten
/// times a crystal's tolerance.
const SKEW_ALLOWED: f64 = 1e-3;

/// What the timestamps of two hosts may disagree by besides the skew: a
/// kernel receive stamp turned into a monotonic instant.
const STAMP_SLACK: Duration = Duration::from_millis(1);

/// The latest stamp a clock may read: 2⁶³ − 1 ns, 292 years from its
/// origin. The clocks' offset, the delays and the release slots are signed
/// nanoseconds, exact for any two stamps up to this one.
pub(super) const LAST_STAMP: Instant = Instant::from_nanos(i64::MAX as u64);

/// The checks on received frames, and what they remember.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct RxCheck {
    /// The `seq` the next Data frame must carry (`None` before the first).
    next_seq: Option<u64>,
    /// The previous Data frame's send stamp.
    last_stamp: Option<Instant>,
    /// The smallest period the link has run at: stamps advance by at least
    /// half of it, across a change of period too.
    smallest_period: Duration,
    /// A lower bound of `local − peer` (ns), from an echo, and when it was
    /// found: our frame sent at `s` reached the peer at its `p − h`, so
    /// `θ ≥ s − (p − h)`.
    offset_floor: Option<(i128, Instant)>,
}

fn ns(t: Instant) -> i128 {
    i128::from(t.as_nanos())
}

impl RxCheck {
    pub(super) fn new(period: Duration) -> Self {
        RxCheck {
            next_seq: None,
            last_stamp: None,
            smallest_period: period,
            offset_floor: None,
        }
    }

    /// Whether an echo has bounded the offset between the clocks, so that
    /// [`check_stamp`](Self::check_stamp) can tell a stamp from the future.
    pub(super) fn bounded(&self) -> bool {
        self.offset_floor.is_some()
    }

    /// The link now runs at `period`.
    pub(super) fn period_changed(&mut self, period: Duration) {
        self.smallest_period = self.smallest_period.min(period);
    }

    /// A frame stamped `sent_at` (peer clock) arrived at `now`: an error if
    /// it cannot have been sent yet, or no clock reads it.
    pub(super) fn check_stamp(&self, sent_at: Instant, now: Instant) -> Result<(), LinkError> {
        let Some((floor, found)) = self.offset_floor else {
            return Self::in_range(sent_at);
        };
        let drift = now.saturating_duration_since(found).as_secs_f64() * SKEW_ALLOWED;
        let allowed = i128::from(STAMP_SLACK.as_nanos()) + (drift * 1e9) as i128;
        let ahead = ns(sent_at) + floor - ns(now);
        if ahead > allowed {
            let ahead = u64::try_from(ahead).unwrap_or(u64::MAX);
            return Err(LinkError::StampAhead {
                ahead: Duration::from_nanos(ahead),
            });
        }
        Self::in_range(sent_at)
    }

    fn in_range(sent_at: Instant) -> Result<(), LinkError> {
        if sent_at > LAST_STAMP {
            return Err(LinkError::StampOutOfRange { got: sent_at });
        }
        Ok(())
    }

    /// A Data frame `seq` stamped `sent_at`: an error unless it is the next
    /// one, or a later one whose stamp leaves room for the ticks between
    /// (a sender whose driver stalled past its transmit queue gave up the
    /// oldest frames: `seq` numbers its ticks). Remembered when it passes;
    /// returns how many frames were missing before it.
    pub(super) fn accept_data(&mut self, seq: u64, sent_at: Instant) -> Result<u64, LinkError> {
        // No sender counts that far, and `released` could not name it
        // (2⁶⁴ − 1 is the wire's "none").
        if seq == u64::MAX {
            return Err(LinkError::OutOfSequence {
                expected: self.next_seq.unwrap_or(0),
                got: seq,
            });
        }
        let mut missing = 0;
        if let (Some(expected), Some(last)) = (self.next_seq, self.last_stamp) {
            // Ticks are half the shortest period apart at least.
            let step = (self.smallest_period / 2).max(Duration::from_nanos(1));
            let earliest = |ticks: u64| {
                step.as_nanos()
                    .checked_mul(ticks)
                    .and_then(|n| last.checked_add(Duration::from_nanos(n)))
            };
            if seq < expected {
                return Err(LinkError::OutOfSequence { expected, got: seq });
            }
            missing = seq - expected;
            match earliest(missing + 1) {
                Some(e) if sent_at >= e => {}
                // A gap its stamp does not explain: not a stall.
                _ if missing > 0 => {
                    return Err(LinkError::OutOfSequence { expected, got: seq });
                }
                e => {
                    return Err(LinkError::StampBehind {
                        earliest: e.unwrap_or(Instant::from_nanos(u64::MAX)),
                        got: sent_at,
                    });
                }
            }
        }
        self.next_seq = Some(seq + 1);
        self.last_stamp = Some(sent_at);
        Ok(missing)
    }

    /// How many ticks fit between the stamps `from` and `to`: ticks are
    /// half the shortest period apart at least.
    pub(super) fn tick_room(&self, from: Instant, to: Instant) -> u64 {
        let step = (self.smallest_period / 2).as_nanos().max(1);
        to.saturating_duration_since(from).as_nanos() / step
    }

    /// The peer echoed our frame sent at `ours` (our clock), holding it for
    /// `hold`, in its frame stamped `theirs`, which arrived at `now`.
    pub(super) fn observe_echo(
        &mut self,
        ours: Instant,
        hold: Duration,
        theirs: Instant,
        now: Instant,
    ) {
        let floor = ns(ours) - (ns(theirs) - i128::from(hold.as_nanos()));
        let better = match self.offset_floor {
            None => true,
            Some((old, found)) => {
                let drift = now.saturating_duration_since(found).as_secs_f64() * SKEW_ALLOWED;
                floor >= old - (drift * 1e9) as i128
            }
        };
        if better {
            self.offset_floor = Some((floor, now));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: Duration = Duration::from_millis(10);

    fn at_ms(ms: u64) -> Instant {
        Instant::from_millis(ms)
    }

    #[test]
    fn the_next_frame_passes_and_a_repeat_a_gap_or_a_step_back_do_not() {
        let mut c = RxCheck::new(T);
        assert_eq!(c.accept_data(7, at_ms(100)), Ok(0));
        assert_eq!(c.accept_data(8, at_ms(110)), Ok(0));
        assert_eq!(
            c.accept_data(8, at_ms(120)),
            Err(LinkError::OutOfSequence {
                expected: 9,
                got: 8
            })
        );
        assert_eq!(
            c.accept_data(4, at_ms(120)),
            Err(LinkError::OutOfSequence {
                expected: 9,
                got: 4
            })
        );
        assert_eq!(
            c.accept_data(9 + (1 << 63), at_ms(120)),
            Err(LinkError::OutOfSequence {
                expected: 9,
                got: 9 + (1 << 63)
            })
        );
        // Half a period later at least: a remote's grid moving to its releases.
        assert_eq!(
            c.accept_data(9, at_ms(114)),
            Err(LinkError::StampBehind {
                earliest: at_ms(115),
                got: at_ms(114)
            })
        );
        assert_eq!(c.accept_data(9, at_ms(115)), Ok(0));
        // A failed check remembers nothing.
        assert_eq!(c.accept_data(10, at_ms(125)), Ok(0));
        // A sender that stalled and gave up frames 11 to 13: its stamp is
        // four ticks on at least.
        assert_eq!(
            c.accept_data(14, at_ms(144)),
            Err(LinkError::OutOfSequence {
                expected: 11,
                got: 14
            })
        );
        assert_eq!(c.accept_data(14, at_ms(145)), Ok(3));
    }

    #[test]
    fn no_frame_is_numbered_the_wires_none() {
        let max = u64::MAX;
        let mut c = RxCheck::new(T);
        let out = |expected| Err(LinkError::OutOfSequence { expected, got: max });
        // Not even the first, which sets the sequence.
        assert_eq!(c.accept_data(max, at_ms(100)), out(0));
        assert_eq!(c.accept_data(max - 1, at_ms(100)), Ok(0));
        // Nor the next after 2⁶⁴ − 2.
        assert_eq!(c.accept_data(max, at_ms(110)), out(max));
    }

    #[test]
    fn a_shorter_period_lowers_the_gap_for_good() {
        let mut c = RxCheck::new(T);
        c.period_changed(Duration::from_millis(4));
        c.period_changed(Duration::from_millis(50));
        assert_eq!(c.accept_data(0, at_ms(100)), Ok(0));
        assert_eq!(c.accept_data(1, at_ms(102)), Ok(0));
    }

    #[test]
    fn a_stamp_from_the_future_is_refused_once_an_echo_bounds_the_clocks() {
        let mut c = RxCheck::new(T);
        // Before any echo, nothing bounds the offset.
        assert_eq!(c.check_stamp(LAST_STAMP, at_ms(0)), Ok(()));
        // The peer's clock is 1 000 ms behind ours, 5 ms each way: our frame
        // sent at 2 000 reached it at its 1 005, answered at its 1 008.
        c.observe_echo(
            at_ms(2000),
            Duration::from_millis(3),
            at_ms(1008),
            at_ms(2013),
        );
        // An honest frame: sent at its 1 018, here at 2 023.
        assert_eq!(c.check_stamp(at_ms(1018), at_ms(2023)), Ok(()));
        // Sent "at its 1 030", here at 2 023: 2 ms after it arrived (the
        // bound is 5 ms under the true offset), beyond the 1 ms allowed.
        assert_eq!(
            c.check_stamp(at_ms(1030), at_ms(2023)),
            Err(LinkError::StampAhead {
                ahead: Duration::from_millis(2)
            })
        );
        assert!(matches!(
            c.check_stamp(Instant::from_nanos(1 << 63), at_ms(2023)),
            Err(LinkError::StampAhead { .. })
        ));
        // Our frame sent at 0 reached a peer whose clock is near its end at
        // its 2⁶³ − 2 s: a stamp no clock reads is never ahead of that
        // bound, and refused before it as after.
        let mut fresh = RxCheck::new(T);
        let past = Instant::from_nanos(1 << 63);
        let out = Err(LinkError::StampOutOfRange { got: past });
        assert_eq!(fresh.check_stamp(past, at_ms(0)), out);
        fresh.observe_echo(
            at_ms(0),
            Duration::ZERO,
            Instant::from_nanos((1 << 63) - 2_000_000_000),
            at_ms(10),
        );
        assert_eq!(fresh.check_stamp(LAST_STAMP, at_ms(2010)), Ok(()));
        assert_eq!(fresh.check_stamp(past, at_ms(2010)), out);
        // An hour later, the skew allowed (3.6 s) covers a drifting clock.
        let hour = 3_600_000;
        assert_eq!(
            c.check_stamp(at_ms(1018 + hour + 3000), at_ms(2023 + hour)),
            Ok(())
        );
    }
}
