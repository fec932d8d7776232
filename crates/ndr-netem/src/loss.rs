//! Packet loss: which packets a path drops, and what a drop costs a TCP
//! stream.
//!
//! A [`LossModel`] says how packets are lost (none, independently, or in
//! Gilbert–Elliott bursts); [`LossModel::sampler`] draws, for one seed, a
//! [`LossSampler`] that answers "is this packet lost?" per direction, from
//! ChaCha streams of its own (so that adding loss to a run does not change
//! its delays). [`TcpPath`] turns the losses of a TCP stream into what the
//! receiver sees: nothing is missing, but a lost segment stalls the stream
//! until it is sent again: once the next segment's acknowledgement shows
//! the gap, or after a retransmission timeout, doubled at each repeat.
//!
//! ```
//! use ndr_core::time::{Duration, Instant};
//! use ndr_netem::{Direction, LossModel};
//!
//! let model: LossModel = "ge:2:4".parse().unwrap(); // 2 % in bursts of 4
//! let mut loss = model.sampler(7);
//! let lost = (0..100_000).filter(|_| loss.lost(Direction::Forward)).count();
//! assert!((1_600..2_400).contains(&lost), "{lost}");
//! ```

use core::fmt;
use core::str::FromStr;
use std::string::{String, ToString};

use ndr_core::time::{Duration, Instant};
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

use crate::Direction;

/// How a path loses packets, the same each way.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[non_exhaustive]
pub enum LossModel {
    /// Nothing is lost.
    #[default]
    None,
    /// Each packet is lost with probability `rate`, independently.
    Bernoulli {
        /// The loss probability, `0 ≤ rate < 1`.
        rate: f64,
    },
    /// Gilbert–Elliott: a good state that loses nothing and a bad state
    /// that loses every packet, entered with probability `p` after a good
    /// packet and left with probability `r` after a bad one. The mean loss
    /// is `p / (p + r)`, in bursts of mean length `1 / r`.
    GilbertElliott {
        /// Good → bad, per packet.
        p: f64,
        /// Bad → good, per packet.
        r: f64,
    },
}

impl LossModel {
    /// Gilbert–Elliott losses of mean `rate` in bursts of mean `burst`
    /// packets.
    pub fn bursts(rate: f64, burst: f64) -> Result<LossModel, LossError> {
        if !(rate.is_finite() && (0.0..1.0).contains(&rate)) {
            return Err(LossError::Rate(rate));
        }
        if !(burst.is_finite() && burst >= 1.0) {
            return Err(LossError::Burst(burst));
        }
        let r = 1.0 / burst;
        Ok(LossModel::GilbertElliott {
            p: rate * r / (1.0 - rate),
            r,
        })
    }

    /// The mean share of packets lost.
    #[must_use]
    pub fn rate(&self) -> f64 {
        match *self {
            LossModel::None => 0.0,
            LossModel::Bernoulli { rate } => rate,
            LossModel::GilbertElliott { p, r } => p / (p + r),
        }
    }

    /// Whether it loses anything.
    #[must_use]
    pub fn is_none(&self) -> bool {
        self.rate() == 0.0
    }

    /// Its draws for `seed`.
    #[must_use]
    pub fn sampler(&self, seed: u64) -> LossSampler {
        LossSampler {
            model: *self,
            rng: [
                crate::seeded_stream(seed, crate::STREAM_LOSS_FORWARD),
                crate::seeded_stream(seed, crate::STREAM_LOSS_BACKWARD),
            ],
            bad: [false; 2],
        }
    }
}

impl fmt::Display for LossModel {
    /// The name [`LossModel::from_str`] reads back.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            LossModel::None => f.write_str("none"),
            LossModel::Bernoulli { rate } => write!(f, "{}", Percent(rate)),
            LossModel::GilbertElliott { r, .. } => {
                write!(f, "ge:{}:{}", Percent(self.rate()), Number(1.0 / r))
            }
        }
    }
}

/// A share as a percentage without the sign, shortest form.
struct Percent(f64);

impl fmt::Display for Percent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        Number(self.0 * 100.0).fmt(f)
    }
}

/// A number rounded to 1e-9, shortest form.
struct Number(f64);

impl fmt::Display for Number {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let x = (self.0 * 1e9).round() / 1e9;
        write!(f, "{x}")
    }
}

/// Why a loss model's name or numbers were refused.
#[derive(Clone, Debug, PartialEq)]
#[non_exhaustive]
pub enum LossError {
    /// The name is none of the forms.
    Name(String),
    /// A loss rate outside `0 ≤ rate < 100 %`.
    Rate(f64),
    /// A mean burst shorter than one packet.
    Burst(f64),
}

impl fmt::Display for LossError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LossError::Name(name) => write!(
                f,
                "unknown loss model {name:?}; give none, PERCENT (each packet lost \
                 independently, e.g. 2 or 0.5) or ge:PERCENT:BURST (Gilbert–Elliott: \
                 PERCENT lost in bursts of BURST packets on average, e.g. ge:2:4)"
            ),
            LossError::Rate(rate) => write!(
                f,
                "a loss rate of {} % is out of range: give 0 to less than 100",
                rate * 100.0
            ),
            LossError::Burst(b) => write!(
                f,
                "a mean burst of {b} packets is out of range: give 1 or more"
            ),
        }
    }
}

impl std::error::Error for LossError {}

impl FromStr for LossModel {
    type Err = LossError;

    /// `none`, `PERCENT` (Bernoulli) or `ge:PERCENT:BURST`.
    fn from_str(s: &str) -> Result<Self, LossError> {
        let name = || LossError::Name(s.to_string());
        let number = |t: &str| {
            t.trim()
                .trim_end_matches('%')
                .parse::<f64>()
                .map_err(|_| name())
        };
        let s = s.trim();
        if s == "none" {
            return Ok(LossModel::None);
        }
        if let Some(rest) = s.strip_prefix("ge:") {
            let (rate, burst) = rest.split_once(':').ok_or_else(name)?;
            return LossModel::bursts(number(rate)? / 100.0, number(burst)?);
        }
        let rate = number(s)? / 100.0;
        if !(rate.is_finite() && (0.0..1.0).contains(&rate)) {
            return Err(LossError::Rate(rate));
        }
        Ok(if rate == 0.0 {
            LossModel::None
        } else {
            LossModel::Bernoulli { rate }
        })
    }
}

/// The losses of a [`LossModel`] for one seed: one stream per direction.
#[derive(Clone, Debug)]
pub struct LossSampler {
    model: LossModel,
    rng: [ChaCha8Rng; 2],
    bad: [bool; 2],
}

impl LossSampler {
    /// Whether a packet sent again a timeout after it was lost is lost
    /// again: at the model's mean rate, as the burst that took it is
    /// most likely over a timeout later (it does not move the bursts'
    /// state).
    pub fn lost_again(&mut self, direction: Direction) -> bool {
        let rate = self.model.rate();
        rate > 0.0 && self.rng[direction.index()].random::<f64>() < rate
    }

    /// Whether the next packet `direction` carries is lost.
    pub fn lost(&mut self, direction: Direction) -> bool {
        let i = direction.index();
        match self.model {
            LossModel::None => false,
            LossModel::Bernoulli { rate } => self.rng[i].random::<f64>() < rate,
            LossModel::GilbertElliott { p, r } => {
                let bad = self.bad[i];
                let u: f64 = self.rng[i].random();
                self.bad[i] = if bad { u >= r } else { u < p };
                bad
            }
        }
    }
}

/// Linux's smallest retransmission timeout, which a path of a few
/// milliseconds' round trip is held to.
pub const MIN_RTO: Duration = Duration::from_millis(200);

/// A TCP stream over a lossy path, as its receiver sees it: every segment
/// arrives, in order, but a lost one holds back every segment behind it
/// until it is sent again. The first time, Linux's RACK sends it again once
/// a later segment's acknowledgement shows the gap and a quarter of a round
/// trip more has passed (with one segment per period: a period and 1.25
/// round trips after it was sent), or at the retransmission timeout if that
/// comes first; a segment lost again waits the timeout (at least
/// [`MIN_RTO`]), doubled at each repeat.
#[derive(Clone, Debug, Default)]
pub struct TcpPath {
    path: crate::InOrderPath,
    retransmits: u64,
}

impl TcpPath {
    /// A stream that has carried nothing.
    #[must_use]
    pub fn new() -> Self {
        TcpPath::default()
    }

    /// The arrival of a segment sent at `sent` whose one-way delay is
    /// `delay`, sent again while `lost(attempt)` says the path drops it
    /// (attempt 0 is the first sending); `recovery` says when a loss is
    /// repaired.
    pub fn deliver(
        &mut self,
        sent: Instant,
        delay: Duration,
        recovery: Recovery,
        mut lost: impl FnMut(u32) -> bool,
    ) -> Instant {
        let mut wait = Duration::ZERO;
        let mut timeout = recovery.rto.max(MIN_RTO);
        // A segment lost 30 times in a row is past any link's liveness.
        for attempt in 0..30 {
            if !lost(attempt) {
                break;
            }
            self.retransmits += 1;
            if attempt == 0 {
                wait += recovery.fast.min(timeout);
            } else {
                wait += timeout;
                timeout = timeout * 2;
            }
        }
        self.path.deliver(sent + wait, delay)
    }

    /// Segments sent again so far.
    #[must_use]
    pub fn retransmits(&self) -> u64 {
        self.retransmits
    }

    /// Segments that arrived later than their own delay said, held back
    /// behind an earlier one.
    #[must_use]
    pub fn held_back(&self) -> u64 {
        self.path.held_back()
    }
}

/// When a [`TcpPath`] repairs a loss.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Recovery {
    /// After the first loss of a segment: when the acknowledgements show
    /// it (RACK), if before the timeout.
    pub fast: Duration,
    /// The retransmission timeout (at least [`MIN_RTO`] is used).
    pub rto: Duration,
}

impl Recovery {
    /// A stream that sends a segment every `period` over a path whose
    /// round trip is `rtt`: RACK's repair a period and 1.25 round trips
    /// after the send, and Linux's timeout, the round trip plus four of
    /// its deviations, taken here as `2·rtt`.
    #[must_use]
    pub fn linux(period: Duration, rtt: Duration) -> Recovery {
        Recovery {
            fast: period + rtt + rtt / 4,
            rto: (rtt * 2).max(MIN_RTO),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_read_back() {
        for name in ["none", "2", "0.5", "ge:2:4", "ge:5:1.5"] {
            let m: LossModel = name.parse().unwrap();
            assert_eq!(m.to_string(), name);
        }
        assert_eq!("0".parse::<LossModel>(), Ok(LossModel::None));
        assert!(matches!(
            "100".parse::<LossModel>(),
            Err(LossError::Rate(_))
        ));
        assert!(matches!(
            "ge:2:0.5".parse::<LossModel>(),
            Err(LossError::Burst(_))
        ));
        let err = "lots".parse::<LossModel>().unwrap_err();
        assert!(err.to_string().contains("ge:PERCENT:BURST"), "{err}");
    }

    #[test]
    fn bernoulli_and_bursts_lose_their_rate_and_bursts_come_in_runs() {
        let runs = |model: LossModel| {
            let mut s = model.sampler(3);
            let draws: std::vec::Vec<bool> =
                (0..200_000).map(|_| s.lost(Direction::Backward)).collect();
            let lost = draws.iter().filter(|&&l| l).count() as f64 / draws.len() as f64;
            let starts = draws.windows(2).filter(|w| !w[0] && w[1]).count().max(1);
            let burst = draws.iter().filter(|&&l| l).count() as f64 / starts as f64;
            (lost, burst)
        };
        let (lost, burst) = runs(LossModel::Bernoulli { rate: 0.05 });
        assert!((lost - 0.05).abs() < 0.003 && burst < 1.1, "{lost} {burst}");
        let (lost, burst) = runs(LossModel::bursts(0.05, 4.0).unwrap());
        assert!(
            (lost - 0.05).abs() < 0.005 && (burst - 4.0).abs() < 0.4,
            "{lost} {burst}"
        );
    }

    #[test]
    fn a_lost_segment_waits_a_timeout_doubled_at_each_repeat_and_holds_the_rest() {
        let mut tcp = TcpPath::new();
        let d = Duration::from_millis(5);
        let ms = Duration::from_millis;
        // T = 20 ms, a 10 ms round trip: repaired 32.5 ms after the send.
        let r = Recovery::linux(ms(20), ms(10));
        assert_eq!(
            r,
            Recovery {
                fast: Duration::from_micros(32_500),
                rto: ms(200)
            }
        );
        let t = |ms| Instant::from_millis(ms);
        assert_eq!(tcp.deliver(t(0), d, r, |_| false), t(5));
        // Lost once: the next segment's acknowledgement shows it.
        assert_eq!(
            tcp.deliver(t(20), d, r, |a| a < 1),
            t(20) + ms(5) + Duration::from_micros(32_500)
        );
        // Lost three times: then 200 ms, then 400 ms more.
        assert_eq!(
            tcp.deliver(t(100), d, r, |a| a < 3),
            t(100) + ms(5) + Duration::from_micros(632_500)
        );
        // The next one, on time for itself, waits behind it.
        assert_eq!(
            tcp.deliver(t(120), d, r, |_| false),
            t(100) + ms(5) + Duration::from_micros(632_500)
        );
        assert_eq!((tcp.retransmits(), tcp.held_back()), (4, 1));
        // A timeout shorter than the repair: the timeout.
        let slow = Recovery::linux(ms(500), ms(10));
        assert_eq!(tcp.deliver(t(2000), d, slow, |a| a < 1), t(2205));
    }
}
