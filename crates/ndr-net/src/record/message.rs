//! The messages of a recording, as their JSON encodes them (the schemas in
//! `schema.rs` describe the same fields).

use serde::Serialize;
use serde_json::{Map, Value};

/// A release on `/ndr/command` or `/ndr/state` (or a sample missed: `late`).
#[derive(Serialize)]
pub(super) struct ReleaseMsg<'a> {
    pub link: u32,
    pub seq: u64,
    /// `fresh`, `repeated` (the last sample again, the due one missing) or
    /// `late` (never released: lost, or came after its release time).
    pub status: &'static str,
    /// On the sender's clock.
    pub sent_ns: u64,
    /// On this side's clock; `None` for a `late` sample.
    pub arrived_ns: Option<u64>,
    pub released_ns: u64,
    /// Release − send, on the two clocks as they are.
    pub end_to_end_s: f64,
    /// Release − arrival.
    pub added_delay_s: Option<f64>,
    /// The round trip this release closed, if any.
    pub grtt_s: Option<f64>,
    /// The send time, on this side's clock, of this side's sample the
    /// round trip started from: `released_ns` − `grtt_s`.
    pub answers_sent_ns: Option<u64>,
    /// The network round trip this side measured last.
    pub nrtt_s: Option<f64>,
    pub values: &'a Map<String, Value>,
}

/// An arrival on `/ndr/network`, or a sample that never came in time.
#[derive(Serialize)]
pub(super) struct NetworkMsg {
    pub link: u32,
    /// `fwd` (base → remote, seen by a remote) or `bwd` (remote → base,
    /// seen by a base).
    pub direction: &'static str,
    pub seq: u64,
    /// On the sender's clock.
    pub sent_ns: u64,
    /// On this side's clock; `None` when missing.
    pub arrived_ns: Option<u64>,
    /// Arrival − send, on the two clocks as they are.
    pub raw_s: Option<f64>,
    /// `raw_s` − the clock offset estimate: the one-way delay.
    pub one_way_s: Option<f64>,
    /// The clock offset estimate (this side − sender) used.
    pub clock_offset_s: f64,
    /// Never released: lost, or came after its release time.
    pub missing: bool,
}

/// A probe's arrival on `/ndr/probe`: the initialization pattern's
/// frames, whose round trips size the queue.
#[derive(Serialize)]
pub(super) struct ProbeMsg {
    pub link: u32,
    /// `fwd` (base → remote, seen by a remote) or `bwd` (remote → base,
    /// seen by a base).
    pub direction: &'static str,
    pub seq: u64,
    /// On the sender's clock.
    pub sent_ns: u64,
    /// On this side's clock.
    pub arrived_ns: u64,
    /// Arrival − send, on the two clocks as they are.
    pub raw_s: f64,
    /// `raw_s` − the clock offset estimate: the one-way delay.
    pub one_way_s: f64,
    /// The clock offset estimate (this side − sender) used.
    pub clock_offset_s: f64,
}

/// A link event on `/ndr/event`.
#[derive(Serialize, Default)]
pub(super) struct EventMsg {
    pub link: u32,
    pub side: &'static str,
    /// `connected`, `started`, `paused`, `link_lost`, `delay_changed`,
    /// `round_trip_changed`, `link_restored`, `closed`, and `attached` when
    /// the recording of the link starts.
    pub kind: &'static str,
    pub at_ns: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub period_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ns: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub delay_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub grtt_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ticks: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub silent_for_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub outage_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

/// A link's counters on `/ndr/stats`.
#[derive(Serialize)]
pub(super) struct StatsMsg {
    pub link: u32,
    pub side: &'static str,
    pub phase: &'static str,
    pub period_s: f64,
    pub ns: usize,
    pub queue_len: usize,
    pub samples_sent: u64,
    pub samples_received: u64,
    pub released_fresh: u64,
    pub released_held: u64,
    pub underflows: u64,
    pub late: u64,
    pub samples_lost: u64,
    pub samples_recovered: u64,
    pub link_lost: u64,
    pub nrtt_mean_s: f64,
    pub nrtt_std_s: f64,
    pub nrtt_last_s: Option<f64>,
    pub grtt_mean_s: f64,
    pub grtt_std_s: f64,
    pub grtt_count: u64,
    pub one_way_rx_mean_s: f64,
    pub clock_offset_s: f64,
    pub clock_skew_ppm: f64,
    pub playout_delay_s: f64,
    pub delay_changes: u64,
    pub release_lateness_p50_s: f64,
    pub release_lateness_p99_s: f64,
    pub release_lateness_max_s: f64,
    pub app_dropped: u64,
    pub record_queued: u64,
    pub record_dropped: u64,
}
