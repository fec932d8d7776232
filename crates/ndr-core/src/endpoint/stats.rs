//! Counters and running statistics of a link endpoint.

use crate::time::Duration;

/// Mean, standard deviation and range of a series, in O(1) memory (Welford).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Running {
    count: u64,
    mean: f64,
    m2: f64,
    min: f64,
    max: f64,
}

impl Running {
    /// Adds one value.
    pub(crate) fn push(&mut self, x: f64) {
        self.count += 1;
        if self.count == 1 {
            self.min = x;
            self.max = x;
        } else {
            self.min = self.min.min(x);
            self.max = self.max.max(x);
        }
        let d = x - self.mean;
        self.mean += d / self.count as f64;
        self.m2 += d * (x - self.mean);
    }

    /// Adds a duration, in seconds.
    pub fn push_duration(&mut self, d: Duration) {
        self.push(d.as_secs_f64());
    }

    /// Values seen.
    #[must_use]
    pub fn count(&self) -> u64 {
        self.count
    }

    /// Their mean (0 when empty).
    #[must_use]
    pub fn mean(&self) -> f64 {
        self.mean
    }

    /// Their population standard deviation (0 when fewer than two).
    #[must_use]
    pub fn std(&self) -> f64 {
        if self.count < 2 {
            0.0
        } else {
            libm::sqrt(self.m2 / self.count as f64)
        }
    }

    /// The smallest (0 when empty).
    #[must_use]
    pub fn min(&self) -> f64 {
        self.min
    }

    /// The largest (0 when empty).
    #[must_use]
    pub fn max(&self) -> f64 {
        self.max
    }
}

/// What a reader wants of the series: `count`, `mean`, `std`, `min`, `max`
/// (not the running sum of squares behind `std`).
#[cfg(feature = "serde")]
impl serde::Serialize for Running {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut m = s.serialize_struct("Running", 5)?;
        m.serialize_field("count", &self.count)?;
        m.serialize_field("mean", &self.mean)?;
        m.serialize_field("std", &self.std())?;
        m.serialize_field("min", &self.min)?;
        m.serialize_field("max", &self.max)?;
        m.end()
    }
}

/// Everything an endpoint counted. Invariant of the receive side, under
/// `drop-late`: `samples_received = released_fresh + queued + late + rejected
/// + discarded + skipped`; under `hold` the same without `late` (a late
/// sample is still released, one tick later; `late` counts the underflows it
/// caused). The fuzz harness (`fuzz/harness.rs`) checks it after every step.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct Stats {
    /// Frames sent, of any kind.
    pub frames_sent: u64,
    /// Frames received, of any kind.
    pub frames_received: u64,
    /// Samples (Data frames with channels) sent.
    pub samples_sent: u64,
    /// Samples sent that repeated the previous one because the application
    /// gave none since the last tick.
    pub samples_repeated: u64,
    /// Samples received from the peer.
    pub samples_received: u64,
    /// Samples released fresh to the application.
    pub released_fresh: u64,
    /// Ticks that repeated the last sample (underflows with a sample to repeat).
    pub released_held: u64,
    /// Running ticks whose due sample was missing.
    pub underflows: u64,
    /// Samples that arrived after their release slot. Under `drop-late` they
    /// are discarded; under `hold` each underflow is one (the due sample came
    /// late and was released at a later tick).
    pub late: u64,
    /// Samples refused because the regulator was full.
    pub rejected: u64,
    /// Samples discarded because they belonged to a stream that a pause
    /// ended, or (adaptive playout under `hold`) came after an outage past
    /// their slot: stale, and kept they would stretch the delay to the
    /// outage's length.
    pub discarded: u64,
    /// Target-delay playout: samples passed over because the target fell and
    /// a newer sample was due at the same tick.
    pub skipped: u64,
    /// Probe frames (Data without channels) of the initialization pattern received.
    pub probes_received: u64,
    /// Probe arrivals kept for the driver
    /// ([`Endpoint::keep_probe_arrivals`](super::Endpoint::keep_probe_arrivals))
    /// that it did not take in time.
    pub probe_arrivals_dropped: u64,
    /// Pauses of the dynamic mode.
    pub pauses: u64,
    /// Parameter changes (starts after a pause).
    pub resizes: u64,
    /// Watchdog alarms: times no fresh sample came for the watchdog time.
    pub link_lost: u64,
    /// Parameter changes clamped to what the regulator can hold.
    pub(crate) clamped: u64,
    /// Frames given up because the driver did not drain `poll_transmit`.
    pub tx_dropped: u64,
    /// Data frames the peer numbered but never sent: its `tx_dropped`, seen
    /// from here as a gap in `seq` (its driver stalled).
    pub frames_missing: u64,
    /// Round trips whose start had left the send-time history.
    pub(crate) grtt_unmeasured: u64,
    /// Datagram transport: datagrams of this session taken (each a Bundle
    /// of samples).
    pub datagrams_received: u64,
    /// Datagram transport: repeats sent (a sample's datagram sent again,
    /// 1 ms apart); the peer drops
    /// those that find the sample taken, as stale.
    pub datagrams_repeated: u64,
    /// Datagram transport: samples taken from a later datagram's copy
    /// (their own datagram was lost or came late).
    pub samples_recovered: u64,
    /// Datagram transport: samples taken from a repeat of their datagram
    /// (the first send was lost or came late).
    pub samples_from_repeats: u64,
    /// Datagram transport: times the peer's count of this side's samples
    /// it missed grew, each keeping this side's repeats going for
    /// [`REPEAT_HOLD`](super::REPEAT_HOLD).
    pub(crate) loss_reports: u64,
    /// Datagram transport: samples never received, neither in their own
    /// datagram nor in a later one's copies, before a newer one came.
    pub samples_lost: u64,
    /// Datagram transport: datagrams that came after a newer one (repeated
    /// by the network, reordered, or replayed), dropped whole.
    pub datagrams_stale: u64,
    /// Datagram transport: datagrams with another session's token (a stray
    /// or a spoof), dropped.
    pub datagrams_foreign: u64,
    /// Datagram transport: datagrams refused for anything else (not a
    /// valid Bundle, another width, before the handshake, a `seq` of
    /// 2⁶⁴ − 1, a stamp from the future), dropped; the link carries on.
    pub datagrams_refused: u64,
    /// Datagram transport: valid datagrams from an address not validated
    /// as the peer's (a peer that moved, before it is validated, or a
    /// stranger who saw a token), dropped.
    pub datagrams_off_path: u64,
    /// Datagram transport: new tokens given to the peer to validate the
    /// address of a datagram from elsewhere.
    pub tokens_renewed: u64,
    /// Datagram transport: tokens given that came back in a datagram,
    /// validating the address it came from as the peer's.
    pub paths_validated: u64,
    /// Network round-trip times, in seconds.
    pub nrtt: Running,
    /// Round trips as the application sees them, in seconds.
    pub grtt: Running,
    /// One-way delays of the frames received, in seconds (raw delay minus
    /// the clock offset estimate; from the first echo on).
    pub one_way_rx: Running,
    /// One-way delays of our frames, from the peer's echoes, in seconds.
    pub(crate) one_way_tx: Running,
    /// The clock offset estimate `local − peer` at the latest frame, in
    /// seconds (0 until both directions have a floor). Serialized as
    /// `clock_offset`, the name the bindings show.
    #[cfg_attr(feature = "serde", serde(rename = "clock_offset"))]
    pub clock_offset_s: f64,
    /// The clock skew estimate `d(local − peer)/dt`, in ppm.
    pub clock_skew_ppm: f64,
    /// Target-delay playout: the end-to-end delay of the samples released
    /// now, in seconds (offset-corrected for the adaptive policy).
    /// Serialized as `playout_delay`, the name the bindings show.
    #[cfg_attr(feature = "serde", serde(rename = "playout_delay"))]
    pub playout_delay_s: f64,
    /// The same in ticks (periods, rounded up).
    pub(crate) playout_delay_ticks: u64,
    /// Changes of the playout delay (each one an [`Event::DelayChanged`]):
    /// of `playout_delay_ticks` for the fixed policies, of
    /// `playout_delay_s` at rest for the adaptive one.
    ///
    /// [`Event::DelayChanged`]: super::Event::DelayChanged
    pub delay_changes: u64,
    /// The round trip of this side's samples in ticks (`⌈GRTT / T⌉`), the
    /// last measured; 0 before the first.
    pub(crate) round_trip_ticks: u64,
    /// Changes of `round_trip_ticks`, the first measured one included
    /// (each one an [`Event::RoundTripChanged`]).
    ///
    /// [`Event::RoundTripChanged`]: super::Event::RoundTripChanged
    pub(crate) round_trip_changes: u64,
    /// Adaptive playout: frames left out of the target's delay window
    /// because they ended a silence longer than the watchdog time, or came
    /// after such a frame still held longer than that, or in the burst held
    /// behind them (an outage, which the watchdog reports as
    /// [`Event::LinkLost`], not a delay to cover for minutes).
    ///
    /// [`Event::LinkLost`]: super::Event::LinkLost
    pub outage_delays: u64,
    /// Remote: commands released from a frame of a control term this link
    /// no longer holds (a controller's queue after a hand-over, or a base
    /// that sends on after losing control), never handed to the application.
    pub commands_refused_stale_term: u64,
    /// Remote: commands from a base that holds no control (an observer, or
    /// a base still waiting for its grant), refused on arrival.
    pub commands_refused_observer: u64,
    /// Remote: commands of a base given control in its Hello that came
    /// before the driver granted it ([`Endpoint::offer`](super::Endpoint::offer)),
    /// refused.
    pub commands_before_grant: u64,
    /// Terms of control granted on this link.
    pub grants: u64,
    /// Remote: applied commands sent to this link's observer.
    pub applied_sent: u64,
    /// Remote: applied commands this link's observer was too slow for,
    /// dropped (the oldest first).
    pub applied_dropped: u64,
    /// Base (an observer): applied commands received.
    pub applied_received: u64,
}
