//! What `ndr demo` and `ndr base` report: how the run ended, the per-tick
//! series (streamed to CSV as it comes) and the table or JSON at the end.

use std::fmt;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use ndr::core::endpoint::LinkError;
use ndr::core::time::Duration;
use ndr::net::clock::LatenessStats;
use ndr::net::{LinkStats, NetError, RelayStats};
use serde::Serialize;

use crate::args::record::RecordingSummary;
use crate::args::{LinkArgs, RunArgs};
use crate::pauses::PauseSummary;
use crate::tracking::TrackingSummary;

/// How a run of the operator ended.
#[derive(Clone, Debug, PartialEq)]
pub enum End {
    /// It ran its duration over a link that released samples; closed in order.
    Completed,
    /// No link came up: no connection, or no sample was ever released.
    NeverConnected(String),
    /// No link came up: the peer refused it, for `reason` (a [`refusal`]).
    Refused { reason: &'static str, why: String },
    /// The link came up, then ended before the run did.
    LinkFailed(String),
    /// The peer ended the link in order (Close code 0: it was stopped, or
    /// its run ended) before this side's run was over.
    PeerEnded(String),
    /// This side failed (its command refused, its series unwritable): the
    /// link was ended as an application failure.
    AppFailure(String),
    /// It waited for control (`--wait-for-control`) and was not granted it
    /// in time; the link was closed in order.
    NotGranted(String),
}

impl End {
    /// Whether the run is a success (the exit status says so).
    pub fn ok(&self) -> bool {
        *self == End::Completed
    }
}

/// Why the peer refused a link that never came up, as the report's
/// `refused` names it: `busy` (it serves another base), `per_source` (too
/// many handshakes pending from this side's address), `evicted` (every
/// handshake slot taken), `version`, `role`, `width`, `layout`, `period`,
/// `mode`, `transport` (the peers' settings differ), `observer_only` (this
/// side's identity may only observe a shared robot), `observers_full`
/// (every observer's seat taken); `None` for any other
/// end.
pub fn refusal(e: &NetError) -> Option<&'static str> {
    use ndr::core::wire::CloseReason;
    let NetError::Link(e) = e else {
        return None;
    };
    let reason = match *e {
        LinkError::PeerClosed { reason } => reason,
        LinkError::VersionMismatch { .. }
        | LinkError::RoleMismatch { .. }
        | LinkError::WidthMismatch { .. }
        | LinkError::LayoutMismatch { .. }
        | LinkError::PeriodMismatch { .. }
        | LinkError::ModeMismatch { .. }
        | LinkError::TransportMismatch { .. } => e.close_reason(),
        _ => return None,
    };
    Some(match reason {
        CloseReason::Busy => "busy",
        CloseReason::EvictedSource => "per_source",
        CloseReason::Evicted => "evicted",
        CloseReason::VersionMismatch => "version",
        CloseReason::RoleMismatch => "role",
        CloseReason::WidthMismatch => "width",
        CloseReason::LayoutMismatch => "layout",
        CloseReason::PeriodMismatch => "period",
        CloseReason::ModeMismatch => "mode",
        CloseReason::TransportMismatch => "transport",
        CloseReason::ObserverOnly => "observer_only",
        CloseReason::ObserversFull => "observers_full",
        _ => return None,
    })
}

/// How a link that failed after `released` samples ended the run: refused,
/// never connected, or failed.
pub fn link_ended(e: &NetError, released: u64) -> End {
    use ndr::core::wire::CloseReason;
    if let NetError::Link(LinkError::PeerClosed {
        reason: CloseReason::Normal,
    }) = e
    {
        return End::PeerEnded(e.to_string());
    }
    if released > 0 {
        return End::LinkFailed(e.to_string());
    }
    match refusal(e) {
        Some(reason) => End::Refused {
            reason,
            why: e.to_string(),
        },
        None => End::NeverConnected(e.to_string()),
    }
}

impl fmt::Display for End {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            End::Completed => f.write_str("completed"),
            End::NeverConnected(why) | End::Refused { why, .. } => {
                write!(f, "never connected: {why}")
            }
            End::LinkFailed(why) => write!(f, "link failed: {why}"),
            End::PeerEnded(why) => write!(f, "ended early: {why}"),
            End::AppFailure(why) => write!(f, "application failure: {why}"),
            End::NotGranted(why) => write!(f, "not granted control: {why}"),
        }
    }
}

/// One released state, as a row of the series.
pub struct Row {
    pub t_s: f64,
    pub seq: u64,
    pub held: bool,
    pub grtt_s: Option<f64>,
    /// The network's round trip last measured by the base, seconds.
    pub nrtt_s: Option<f64>,
    pub command: f64,
    pub state: f64,
}

/// The base's per-tick series: each row goes to the CSV as it comes, and
/// only bounded summaries stay in memory, so a run of hours stays flat.
pub struct Series {
    path: PathBuf,
    out: BufWriter<File>,
    rows: u64,
    grtt: LogHistogram,
    /// The last fresh state's sequence number.
    last_fresh: Option<u64>,
    out_of_order: u64,
}

/// What the series kept of its rows.
pub struct SeriesSummary {
    /// Rows written.
    pub rows: u64,
    /// The 99th percentile of the rows' GRTTs, seconds (0 for none).
    pub grtt_p99_s: f64,
    /// Rows whose sequence number does not follow the last fresh one: a
    /// fresh state not after it, a held one not repeating it.
    pub out_of_order: u64,
}

impl Series {
    /// Creates the CSV (before any link, so a bad path fails at once) and
    /// writes its header.
    pub fn create(path: &Path) -> Result<Series, String> {
        let file = File::create(path).map_err(|e| write_error(path, &e))?;
        let mut series = Series {
            path: path.to_path_buf(),
            out: BufWriter::new(file),
            rows: 0,
            grtt: LogHistogram::new(),
            last_fresh: None,
            out_of_order: 0,
        };
        writeln!(series.out, "t_s,seq,status,grtt_s,nrtt_s,command,state")
            .map_err(|e| write_error(path, &e))?;
        Ok(series)
    }

    /// Appends a row.
    pub fn push(&mut self, r: &Row) -> Result<(), String> {
        let status = if r.held { "held" } else { "fresh" };
        // An unmeasured round trip is an empty field.
        let secs = |s: Option<f64>| s.map(|s| format!("{s:.6}")).unwrap_or_default();
        let written = writeln!(
            self.out,
            "{:.6},{},{status},{},{},{:.6},{:.6}",
            r.t_s,
            r.seq,
            secs(r.grtt_s),
            secs(r.nrtt_s),
            r.command,
            r.state
        );
        written.map_err(|e| write_error(&self.path, &e))?;
        if let Some(g) = r.grtt_s {
            self.grtt.record(g);
        }
        let follows = match self.last_fresh {
            Some(last) if r.held => r.seq == last,
            Some(last) => r.seq > last,
            None => !r.held,
        };
        if !follows {
            self.out_of_order += 1;
        }
        if !r.held {
            self.last_fresh = Some(r.seq);
        }
        self.rows += 1;
        Ok(())
    }

    /// Flushes the CSV; the summary, and the error if the flush failed.
    pub fn close(mut self) -> (SeriesSummary, Option<String>) {
        let error = self.out.flush().err().map(|e| write_error(&self.path, &e));
        let summary = SeriesSummary {
            rows: self.rows,
            grtt_p99_s: self.grtt.quantile(0.99),
            out_of_order: self.out_of_order,
        };
        (summary, error)
    }
}

fn write_error(path: &Path, e: &std::io::Error) -> String {
    format!(
        "cannot write {}: {e}; give a writable file with --out",
        path.display()
    )
}

/// A histogram of positive values in logarithmic buckets of fixed number:
/// quantiles within half a bucket (0.5 %) in constant memory, however many
/// values it saw.
struct LogHistogram {
    counts: Vec<u64>,
    n: u64,
    min: f64,
    max: f64,
}

impl LogHistogram {
    /// The smallest and largest values told apart, seconds.
    const LOW: f64 = 1e-6;
    const HIGH: f64 = 1e3;
    /// Each bucket's upper bound over its lower one.
    const RATIO: f64 = 1.01;

    fn new() -> LogHistogram {
        let buckets = ((Self::HIGH / Self::LOW).ln() / Self::RATIO.ln()).ceil() as usize + 1;
        LogHistogram {
            counts: vec![0; buckets],
            n: 0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
        }
    }

    fn record(&mut self, x: f64) {
        if !x.is_finite() {
            return;
        }
        let last = self.counts.len() - 1;
        let i = if x <= Self::LOW {
            0
        } else {
            (((x / Self::LOW).ln() / Self::RATIO.ln()) as usize).min(last)
        };
        self.counts[i] += 1;
        self.n += 1;
        self.min = self.min.min(x);
        self.max = self.max.max(x);
    }

    /// The `q` quantile by nearest rank (as `ndr::sim::percentile`),
    /// as its bucket's geometric middle within the values seen; 0 for none.
    fn quantile(&self, q: f64) -> f64 {
        if self.n == 0 {
            return 0.0;
        }
        let rank = ((q * self.n as f64).ceil() as u64).clamp(1, self.n);
        let mut seen = 0;
        for (i, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                let middle = Self::LOW * Self::RATIO.powf(i as f64 + 0.5);
                return middle.clamp(self.min, self.max);
            }
        }
        self.max
    }
}

/// A base's seat at the remote's robot, for its report.
pub struct Seating {
    /// `controller` or `observer`: what the base was when its run began.
    pub role: &'static str,
    /// With `--wait-for-control`: from the start until control was granted.
    pub waited_for_control_s: Option<f64>,
    /// The control terms of the states released to it, each once, in the
    /// order first seen.
    pub terms_seen: Vec<u16>,
}

impl Seating {
    /// Notes the term of a state released.
    pub fn saw(&mut self, term: u16) {
        if self.terms_seen.last() != Some(&term) && !self.terms_seen.contains(&term) {
            self.terms_seen.push(term);
        }
    }
}

/// What a run of the operator ended with.
pub struct Outcome<'a> {
    /// Where the delays came from (a profile) or whom the base talked to.
    pub profile: String,
    /// The base's final counters (none if no link was made).
    pub base: Option<LinkStats>,
    /// The remote's, when it ran in this process.
    pub remote: Option<LinkStats>,
    /// The relay's, when it ran in this process.
    pub relay: Option<&'a RelayStats>,
    /// What the series kept.
    pub series: SeriesSummary,
    /// How the run ended.
    pub end: End,
    /// What the base's tracking loop measured (`--controller`).
    pub tracking: Option<TrackingSummary>,
    /// The host's pauses and the late ticks they explain (`ndr demo`).
    pub host: Option<PauseSummary>,
    /// The recording (`--record`).
    pub recording: Option<RecordingSummary>,
    /// `ndr base`: its seat at the robot.
    pub seating: Option<Seating>,
    /// `ndr demo --observers`: what each observer saw.
    pub observers: Vec<crate::watchers::Watched>,
}

/// What `ndr demo --json` and `ndr base --json` print. Times in seconds.
#[derive(Serialize)]
struct DemoReport {
    command: &'static str,
    /// Whether the run completed over a link (the exit status is 0 then).
    ok: bool,
    /// How it ended: `completed`, `never connected: …`, `link failed: …`,
    /// `ended early: …` (the peer ended the link in order) or
    /// `application failure: …`.
    end: String,
    /// Why the peer refused the link, if it did (see [`refusal`]): `busy`,
    /// `per_source`, `evicted`, `version`, …; null otherwise.
    refused: Option<&'static str>,
    /// `ndr base`: `controller` or `observer` (a base that waited for
    /// control and got it is a controller); null for the demo.
    role: Option<&'static str>,
    /// `ndr base --wait-for-control`: seconds from its start until control
    /// was granted; null otherwise, or when it was not granted.
    waited_for_control_s: Option<f64>,
    /// `ndr base`: the control terms of the states released to it, in the
    /// order first seen (an observer across a hand-over sees two; 0 is
    /// before any base held control).
    terms_seen: Option<Vec<u16>>,
    /// `ndr base`: seconds its connection waited for the remote
    /// (`--wait-for-remote`); 0 when it was there at once.
    waited_for_remote_s: f64,
    /// Times the link lost its peer and came back (`--reconnect`), the
    /// time it was down in all (from each loss to the new link's start),
    /// the longest outage, and states of a link that was over refused
    /// (never released to the operator).
    reconnects: u64,
    outage_total_s: f64,
    outage_longest_s: f64,
    stale_releases: u64,
    /// Rows of the series whose sequence number does not follow the last
    /// fresh one (a state released twice or out of order): 0.
    seq_out_of_order: u64,
    profile: String,
    /// How the delay was regulated (`--regulation`'s name).
    regulation: String,
    /// This side's playout, a part of `regulation` (`fifo` for the paper's).
    playout: String,
    underflow: &'static str,
    period_s: f64,
    duration_s: f64,
    axes: u16,
    /// How samples crossed: `tcp`, or `udp:K:R` (datagrams of K samples,
    /// each sent R more times).
    transport: String,
    /// Values in each command and in each state sample.
    command_width: u16,
    state_width: u16,
    ns: usize,
    nrtt_mean_s: f64,
    nrtt_std_s: f64,
    grtt_mean_s: f64,
    grtt_std_s: f64,
    grtt_p99_s: f64,
    grtt_count: u64,
    queue_base_min: usize,
    queue_base_max: usize,
    queue_remote_min: Option<usize>,
    queue_remote_max: Option<usize>,
    samples_sent: u64,
    samples_released: u64,
    late_samples: u64,
    underflows: u64,
    link_lost: u64,
    pauses: u64,
    /// Datagram transport, both sides: samples lost for good (neither their
    /// datagram nor a later one's copies came), samples recovered from a
    /// later datagram's copies or from a repeat of their own, repeats sent,
    /// datagrams dropped as repeated or reordered, and datagrams not sent.
    samples_lost: u64,
    samples_recovered: u64,
    samples_from_repeats: u64,
    datagrams_repeated: u64,
    datagrams_stale: u64,
    datagrams_unsent: u64,
    /// Datagram transport, both sides: datagrams dropped as another
    /// session's (a token their link no longer uses), refused (invalid,
    /// too far ahead, stamped in the future), from an address not
    /// validated, or with no link's token at all (strays, counted on the
    /// hubs' sockets).
    datagrams_foreign: u64,
    datagrams_refused: u64,
    datagrams_off_path: u64,
    datagrams_stray: u64,
    /// Both sides: samples never sent because a hub was held past its
    /// endpoint's transmit queue (the host's doing, not the network's; the
    /// peer counts them as lost), and samples sent again because the
    /// application gave none in time.
    tx_dropped: u64,
    samples_repeated: u64,
    /// The remote's estimates: one-way delay base → remote, clock offset
    /// (remote − base), skew (ppm); the base's: one-way delay back.
    one_way_fwd_mean_s: f64,
    one_way_bwd_mean_s: f64,
    remote_clock_offset_s: f64,
    remote_clock_skew_ppm: f64,
    /// Target-delay playouts: each side's delay at the end (0 for the FIFO).
    playout_delay_fwd_s: f64,
    playout_delay_bwd_s: f64,
    /// Target-delay playouts: how many delays each side announced (its
    /// first, then each change, made without a pause).
    delay_changes_fwd: u64,
    delay_changes_bwd: u64,
    clock_base_p50_s: f64,
    clock_base_p99_s: f64,
    clock_remote_p50_s: f64,
    clock_remote_p99_s: f64,
    /// The latest each hub served a deadline: a host that held the process
    /// shows here first.
    clock_base_max_s: f64,
    clock_remote_max_s: f64,
    /// Wakes of the hubs for a deadline (a tick, a repeat, a timer) 1 ms
    /// late or more, both sides (their `lateness.missed`): the host's
    /// doing, a hub held. Not ticks: one wake may serve several ticks of
    /// several links. One held past a period may make a sample late or move
    /// the FIFO's delay a period.
    wakes_late: u64,
    /// How long before a deadline each side's hub spins, as learned from
    /// its timer at the end.
    spin_margin_base_s: f64,
    spin_margin_remote_s: f64,
    relay_frames_fwd: Option<u64>,
    relay_frames_bwd: Option<u64>,
    /// Datagrams the relay delivered each way, and lost by its loss model
    /// (both ways).
    relay_datagrams_fwd: Option<u64>,
    relay_datagrams_bwd: Option<u64>,
    relay_datagrams_lost: Option<u64>,
    csv: String,
    /// Rows in the CSV (one per state released to the base).
    csv_rows: u64,
    /// The base's controller (`--controller`): `none`, `smith` or `pid`.
    controller: &'static str,
    /// With a controller: the tracking loop's RMS errors (positions over
    /// the reference's amplitude, as `ndr control`) against the reference
    /// and against the delay-free design delayed by the round trip, the
    /// mean round trip it was given (ticks) and its changes.
    tracking: Option<TrackingSummary>,
    /// `ndr demo`: the host's own pauses (a thread's oversleeps past 2 ms:
    /// the whole process held), and the late ticks within a pause or just
    /// after it, against the others: the late rate the link is answerable
    /// for is the latter's.
    #[serde(flatten)]
    host: Option<PauseSummary>,
    /// `--record`: the file, the messages and chunks written, the events
    /// dropped (the writer fell behind) and the error that stopped it.
    recording: Option<RecordingSummary>,
    /// `ndr demo --observers`: what each observer saw.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    observers: Vec<crate::watchers::Watched>,
}

/// A run that completed but whose series could not be written failed.
pub fn with_series_error(mut outcome: Outcome<'_>, error: Option<String>) -> Outcome<'_> {
    if let Some(e) = error {
        if outcome.end.ok() {
            outcome.end = End::AppFailure(e);
        } else {
            tracing::error!("{e}");
        }
    }
    outcome
}

/// Prints the report (table or JSON), whatever the end; then the end as
/// the error when the run failed, for a non-zero exit status.
pub fn finish(link: &LinkArgs, run: &RunArgs, outcome: &Outcome<'_>) -> Result<(), String> {
    let report = report(link, run, outcome);
    if run.json {
        println!(
            "{}",
            serde_json::to_string(&report).map_err(|e| e.to_string())?
        );
    } else {
        print_table(&report);
    }
    if outcome.end.ok() {
        Ok(())
    } else {
        Err(outcome.end.to_string())
    }
}

fn report(link: &LinkArgs, run: &RunArgs, o: &Outcome<'_>) -> DemoReport {
    let (b, remote, relay) = (o.base.as_ref(), o.remote.as_ref(), o.relay);
    let eb = b.map(|s| s.endpoint).unwrap_or_default();
    let er = remote.map(|s| s.endpoint).unwrap_or_default();
    let range = |s: Option<&LinkStats>| s.and_then(|s| s.queue_range).unwrap_or((0, 0));
    let clock = |s: Option<&LinkStats>, p: fn(&LatenessStats) -> Duration| {
        s.map_or(0.0, |s| p(&s.lateness).as_secs_f64())
    };
    DemoReport {
        command: if relay.is_some() { "demo" } else { "base" },
        ok: o.end.ok(),
        end: o.end.to_string(),
        refused: match o.end {
            End::Refused { reason, .. } => Some(reason),
            _ => None,
        },
        role: o.seating.as_ref().map(|s| s.role),
        waited_for_control_s: o.seating.as_ref().and_then(|s| s.waited_for_control_s),
        terms_seen: o.seating.as_ref().map(|s| s.terms_seen.clone()),
        waited_for_remote_s: b.map_or(0.0, |s| s.waited.as_secs_f64()),
        reconnects: b.map_or(0, |s| s.reconnect.reconnects),
        outage_total_s: b.map_or(0.0, |s| s.reconnect.outage_total.as_secs_f64()),
        outage_longest_s: b.map_or(0.0, |s| s.reconnect.longest_outage.as_secs_f64()),
        stale_releases: b.map_or(0, |s| s.reconnect.stale),
        seq_out_of_order: o.series.out_of_order,
        profile: o.profile.clone(),
        regulation: link.regulation_name(),
        playout: link.playout_name(),
        underflow: link.underflow.name(),
        // The link's (a dynamic mode may change it), else the one asked for.
        period_s: b.map_or(link.period_ms / 1e3, |s| s.period.as_secs_f64()),
        duration_s: run.duration_s,
        axes: link.axes,
        transport: link.transport().to_string(),
        command_width: link.axes,
        state_width: link.state.width(link.axes).unwrap_or(0),
        ns: b.map_or(0, |s| s.ns),
        nrtt_mean_s: eb.nrtt.mean(),
        nrtt_std_s: eb.nrtt.std(),
        grtt_mean_s: eb.grtt.mean(),
        grtt_std_s: eb.grtt.std(),
        grtt_p99_s: o.series.grtt_p99_s,
        grtt_count: eb.grtt.count(),
        queue_base_min: range(b).0,
        queue_base_max: range(b).1,
        queue_remote_min: remote.map(|_| range(remote).0),
        queue_remote_max: remote.map(|_| range(remote).1),
        samples_sent: eb.samples_sent + er.samples_sent,
        samples_released: eb.released_fresh + er.released_fresh,
        late_samples: eb.late + er.late,
        underflows: eb.underflows + er.underflows,
        link_lost: eb.link_lost + er.link_lost,
        pauses: eb.pauses,
        samples_lost: eb.samples_lost + er.samples_lost,
        samples_recovered: eb.samples_recovered + er.samples_recovered,
        samples_from_repeats: eb.samples_from_repeats + er.samples_from_repeats,
        datagrams_repeated: eb.datagrams_repeated + er.datagrams_repeated,
        datagrams_stale: eb.datagrams_stale + er.datagrams_stale,
        datagrams_unsent: b.map_or(0, |s| s.datagrams_unsent)
            + remote.map_or(0, |s| s.datagrams_unsent),
        datagrams_foreign: eb.datagrams_foreign + er.datagrams_foreign,
        datagrams_refused: eb.datagrams_refused + er.datagrams_refused,
        datagrams_off_path: eb.datagrams_off_path + er.datagrams_off_path,
        datagrams_stray: b.map_or(0, |s| s.datagrams_stray)
            + remote.map_or(0, |s| s.datagrams_stray),
        tx_dropped: eb.tx_dropped + er.tx_dropped,
        samples_repeated: eb.samples_repeated + er.samples_repeated,
        one_way_fwd_mean_s: er.one_way_rx.mean(),
        one_way_bwd_mean_s: eb.one_way_rx.mean(),
        remote_clock_offset_s: er.clock_offset_s,
        remote_clock_skew_ppm: er.clock_skew_ppm,
        playout_delay_fwd_s: er.playout_delay_s,
        playout_delay_bwd_s: eb.playout_delay_s,
        delay_changes_fwd: er.delay_changes,
        delay_changes_bwd: eb.delay_changes,
        clock_base_p50_s: clock(b, |l| l.p50),
        clock_base_p99_s: clock(b, |l| l.p99),
        clock_remote_p50_s: clock(remote, |l| l.p50),
        clock_remote_p99_s: clock(remote, |l| l.p99),
        clock_base_max_s: clock(b, |l| l.max),
        clock_remote_max_s: clock(remote, |l| l.max),
        wakes_late: b.map_or(0, |s| s.lateness.missed) + remote.map_or(0, |s| s.lateness.missed),
        spin_margin_base_s: b.map_or(0.0, |s| s.spin_margin.as_secs_f64()),
        spin_margin_remote_s: remote.map_or(0.0, |s| s.spin_margin.as_secs_f64()),
        relay_frames_fwd: relay.map(|r| r.forward.frames_delivered),
        relay_frames_bwd: relay.map(|r| r.backward.frames_delivered),
        relay_datagrams_fwd: relay.map(|r| r.datagrams.forward.delivered),
        relay_datagrams_bwd: relay.map(|r| r.datagrams.backward.delivered),
        relay_datagrams_lost: relay.map(|r| r.datagrams.forward.lost + r.datagrams.backward.lost),
        csv: run.out.display().to_string(),
        csv_rows: o.series.rows,
        controller: run.controller.name(),
        tracking: o.tracking,
        host: o.host,
        recording: o.recording.clone(),
        observers: o.observers.clone(),
    }
}

fn print_table(r: &DemoReport) {
    let ms = |s: f64| format!("{:.2} ms", s * 1e3);
    println!(
        "ndr {} · {} · {} · {} · {} · T = {} · {:.0} s · {} axis(es), {} command / {} state values",
        r.command,
        r.profile,
        r.regulation,
        r.underflow,
        r.transport,
        ms(r.period_s),
        r.duration_s,
        r.axes,
        r.command_width,
        r.state_width
    );
    println!("  end        {}", r.end);
    if let (Some(role), Some(terms)) = (r.role, &r.terms_seen) {
        let waited = r
            .waited_for_control_s
            .map_or_else(String::new, |w| format!(" · waited {w:.2} s for control"));
        println!("  seat       {role}{waited} · terms seen {terms:?}");
    }
    if r.waited_for_remote_s > 0.0 {
        println!("  waited     {:.2} s for the remote", r.waited_for_remote_s);
    }
    if r.reconnects > 0 {
        println!(
            "  reconnect  {} time(s) · down {:.2} s in all, longest {:.2} s · {} stale state(s) refused",
            r.reconnects, r.outage_total_s, r.outage_longest_s, r.stale_releases
        );
    }
    println!("                     mean          std");
    println!(
        "  NRTT       {:>12} {:>12}   (the network, both ways)",
        ms(r.nrtt_mean_s),
        ms(r.nrtt_std_s)
    );
    println!(
        "  GRTT       {:>12} {:>12}   (as the controller sees it; p99 {}, {} round trips)",
        ms(r.grtt_mean_s),
        ms(r.grtt_std_s),
        ms(r.grtt_p99_s),
        r.grtt_count
    );
    let remote_queue = match (r.queue_remote_min, r.queue_remote_max) {
        (Some(lo), Some(hi)) => format!(" · remote {lo}–{hi}"),
        _ => String::new(),
    };
    println!(
        "  queues     ns {} · base {}–{}{remote_queue} (occupancy before a release)",
        r.ns, r.queue_base_min, r.queue_base_max
    );
    println!(
        "  samples    {} sent · {} released · {} late · {} underflows · {} link-lost alarms",
        r.samples_sent, r.samples_released, r.late_samples, r.underflows, r.link_lost
    );
    if r.transport != "tcp" {
        println!(
            "  datagrams  {} samples recovered from copies · {} from repeats · {} lost · {} repeats sent · {} stale datagrams · {} not sent",
            r.samples_recovered,
            r.samples_from_repeats,
            r.samples_lost,
            r.datagrams_repeated,
            r.datagrams_stale,
            r.datagrams_unsent
        );
        println!(
            "  dropped    {} foreign · {} refused · {} from an address not validated · {} strays (datagrams)",
            r.datagrams_foreign, r.datagrams_refused, r.datagrams_off_path, r.datagrams_stray
        );
    }
    if r.playout != "fifo" {
        // A target-delay playout: the constant delay each side holds now,
        // beside the one-way network delays its clock estimate measures.
        println!(
            "  playout    delay {} forward · {} back · delays announced {} / {} (network one-way {} / {}; remote clock {:+.3} ms, {:+.1} ppm)",
            ms(r.playout_delay_fwd_s),
            ms(r.playout_delay_bwd_s),
            r.delay_changes_fwd,
            r.delay_changes_bwd,
            ms(r.one_way_fwd_mean_s),
            ms(r.one_way_bwd_mean_s),
            r.remote_clock_offset_s * 1e3,
            r.remote_clock_skew_ppm
        );
    }
    let us = |s: f64| format!("{:.0} µs", s * 1e6);
    let (remote_clock, remote_spin) = if r.queue_remote_max.is_some() {
        (
            format!(
                " · remote {} / {}",
                us(r.clock_remote_p50_s),
                us(r.clock_remote_p99_s)
            ),
            format!(" / {}", us(r.spin_margin_remote_s)),
        )
    } else {
        (String::new(), String::new())
    };
    println!(
        "  clock      release lateness p50 / p99: base {} / {}{remote_clock} (spin margin learned {}{remote_spin})",
        us(r.clock_base_p50_s),
        us(r.clock_base_p99_s),
        us(r.spin_margin_base_s),
    );
    if let (Some(f), Some(b)) = (r.relay_frames_fwd, r.relay_frames_bwd) {
        println!("  relay      {f} frames forward, {b} back");
    }
    if let (Some(f), Some(b), Some(lost)) = (
        r.relay_datagrams_fwd,
        r.relay_datagrams_bwd,
        r.relay_datagrams_lost,
    ) && f + b + lost > 0
    {
        println!("             {f} datagrams forward, {b} back, {lost} lost by its loss model");
    }
    if let Some(h) = &r.host {
        println!(
            "  host       {} pauses of this process (longest {}, {} in all) · {} late within them or just after · {} late outside",
            h.host_pauses,
            ms(h.host_pause_max_s),
            ms(h.host_paused_s),
            h.late_in_host_pauses,
            h.late_outside_host_pauses
        );
    }
    if let Some(t) = &r.tracking {
        println!(
            "  tracking   {} · RMS error {:.4} against the reference · {:.2e} against the delayed design · round trip {:.1} ticks ({} changes, {} ticks)",
            r.controller,
            t.rms_vs_reference,
            t.rms_vs_delayed_design,
            t.round_trip_mean_ticks,
            t.round_trip_changes,
            t.ticks
        );
    }
    println!("  series     {} ({} rows)", r.csv, r.csv_rows);
    if let Some(rec) = &r.recording {
        println!(
            "  recording  {} ({} messages, {} chunks, {} dropped){}",
            rec.path,
            rec.messages,
            rec.chunks,
            rec.dropped,
            rec.error
                .as_ref()
                .map_or_else(String::new, |e| format!(": {e}"))
        );
    }
    for o in &r.observers {
        println!("  watching   {o}");
    }
}

/// How `ndr base` names the link in its report's header and `profile`:
/// the transport's kind, the address, and whether TLS is on (QUIC always
/// runs it), e.g. `quic 192.0.2.7:7300 · TLS`.
pub fn base_profile(
    transport: crate::transport::LinkTransport,
    to: SocketAddr,
    tls: bool,
) -> String {
    let security = if tls { "TLS" } else { "plain" };
    if transport.is_zenoh() {
        // A zenoh link has no address: the robot is found by name.
        return format!("zenoh · {security}");
    }
    let kind = if transport.is_quic() {
        "quic"
    } else if transport.datagrams() {
        "udp"
    } else {
        "tcp"
    };
    format!("{kind} {to} · {security}")
}

/// A datagram link's counts, for the remote's line on each base: `None` on
/// a stream.
pub fn datagram_counts(s: &LinkStats) -> Option<String> {
    let e = &s.endpoint;
    let handed = e.datagrams_received
        + e.datagrams_stale
        + e.datagrams_foreign
        + e.datagrams_refused
        + e.datagrams_off_path;
    (handed > 0).then(|| {
        format!(
            "datagrams {} taken, {} stale, {} foreign, {} refused, {} from an address not \
             validated, {} strays; samples {} recovered, {} lost; {} path changes",
            e.datagrams_received,
            e.datagrams_stale,
            e.datagrams_foreign,
            e.datagrams_refused,
            e.datagrams_off_path,
            s.datagrams_stray,
            e.samples_recovered + e.samples_from_repeats,
            e.samples_lost,
            s.datagram_path_changes
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_profile_names_the_transport_and_tls() {
        let to: SocketAddr = "192.0.2.7:7300".parse().unwrap();
        let quic = "quic".parse().unwrap();
        assert_eq!(base_profile(quic, to, true), "quic 192.0.2.7:7300 · TLS");
        let tcp = "tcp".parse().unwrap();
        assert_eq!(base_profile(tcp, to, true), "tcp 192.0.2.7:7300 · TLS");
        let udp = "udp:2:1".parse().unwrap();
        assert_eq!(base_profile(udp, to, false), "udp 192.0.2.7:7300 · plain");
    }

    #[test]
    fn a_peer_that_ended_the_link_in_order_is_not_a_failure() {
        use ndr::core::wire::CloseReason;
        let e = NetError::Link(LinkError::PeerClosed {
            reason: CloseReason::Normal,
        });
        for released in [0, 30] {
            let end = link_ended(&e, released);
            assert!(matches!(end, End::PeerEnded(_)), "{end:?}");
            let msg = end.to_string();
            assert!(
                msg.starts_with("ended early: the peer ended the link in order"),
                "{msg}"
            );
            assert!(!msg.contains("failed"), "{msg}");
        }
    }

    #[test]
    fn the_histogram_quantile_is_within_half_a_bucket_of_the_exact_one() {
        let xs: Vec<f64> = (1..=10_000).map(|i| 1e-3 * f64::from(i).sqrt()).collect();
        let mut h = LogHistogram::new();
        xs.iter().for_each(|&x| h.record(x));
        for q in [0.5, 0.9, 0.99, 1.0] {
            let exact = ndr::sim::percentile(&xs, q);
            let got = h.quantile(q);
            assert!((got / exact - 1.0).abs() < 0.006, "q {q}: {got} vs {exact}");
        }
        // A constant series reports its value exactly.
        let mut h = LogHistogram::new();
        (0..100).for_each(|_| h.record(0.0423));
        assert_eq!(h.quantile(0.99), 0.0423);
        assert_eq!(LogHistogram::new().quantile(0.99), 0.0);
    }
}
