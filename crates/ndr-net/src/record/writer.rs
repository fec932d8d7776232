//! The recording's writer thread: MCAP through the `mcap` crate, a chunk
//! ended and written out at least every [`RecordConfig::chunk_every`].

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::sync::mpsc::Receiver;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use mcap::records::MessageHeader;
use ndr_core::endpoint::{Event, ProbeArrival, Status};
use ndr_core::time::Instant;
use ndr_core::wire::Role;
use serde::Serialize;
use serde_json::{Map, Value};

use super::message::{EventMsg, NetworkMsg, ProbeMsg, ReleaseMsg, StatsMsg};
use super::schema::{TOPICS, schemas};
use super::{Counters, Item, RecordConfig, RecordError};
use crate::delivery::{LinkEvent, Sample};
use crate::link::LinkSender;

/// How often the thread looks for new messages. It polls rather than
/// blocks so that a hub handing it a message never has to wake it.
const POLL: StdDuration = StdDuration::from_millis(10);
/// The most `late` messages one gap in the sequence numbers gives (the
/// rest are only counted by the link's stats).
const MAX_GAP_MESSAGES: u64 = 1000;

#[derive(Clone, Copy)]
enum Topic {
    Command = 0,
    State = 1,
    Event = 2,
    Stats = 3,
    Network = 4,
    Probe = 5,
}

struct LinkState {
    role: Role,
    sender: LinkSender,
    unix_origin_ns: i128,
    /// The newest fresh release: its seq and send time.
    last_fresh: Option<(u64, u64)>,
    period_ns: Option<u64>,
    /// Names of the released values, made at the first release.
    names: Vec<String>,
    closed: bool,
    /// The clock offset estimate and the last NRTT ([`Self::read_clock`]).
    clock: (f64, Option<f64>),
}

impl LinkState {
    fn side(&self) -> &'static str {
        match self.role {
            Role::Base => "base",
            _ => "remote",
        }
    }

    fn unix(&self, t: u64) -> u64 {
        let t = self.unix_origin_ns + i128::from(t);
        u64::try_from(t.max(0)).unwrap_or(u64::MAX)
    }

    /// Unix time of a send on the peer's clock, through the offset estimate.
    fn unix_of_peer(&self, sent: u64, offset_s: f64) -> u64 {
        let t = self.unix_origin_ns + i128::from(sent) + (offset_s * 1e9) as i128;
        u64::try_from(t.max(0)).unwrap_or(u64::MAX)
    }

    /// Reads the clock offset estimate (this side − peer) and the NRTT
    /// last measured from the link's latest stats: once a poll, not once
    /// a message, since the hub takes the same lock at every tick.
    fn read_clock(&mut self) {
        self.clock = self.sender.stats().map_or((0.0, None), |s| {
            (
                s.endpoint.clock_offset_s,
                s.last_nrtt.map(|d| d.as_secs_f64()),
            )
        });
    }
}

pub(super) struct Writer {
    /// `None` once finished.
    out: Option<mcap::Writer<BufWriter<File>>>,
    path: PathBuf,
    channels: [u16; 6],
    config: RecordConfig,
    counters: Arc<Counters>,
    links: HashMap<u32, LinkState>,
    sequence: u32,
    /// The values' names, one map reused for every release.
    values: Map<String, Value>,
}

impl Writer {
    pub(super) fn start(
        file: File,
        path: &Path,
        config: RecordConfig,
        counters: Arc<Counters>,
    ) -> Result<Writer, RecordError> {
        let error = |e: mcap::McapError| RecordError::Write {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        // Uncompressed: JSON at a link's rates is kilobytes a second, and
        // the recorder links no compression library.
        let options = mcap::WriteOptions::new()
            .compression(None)
            .profile("")
            .chunk_size(Some(mcap::WriteOptions::DEFAULT_CHUNK_SIZE));
        let mut out = options.create(BufWriter::new(file)).map_err(&error)?;
        let mut channels = [0; 6];
        for ((name, schema), (topic, id)) in schemas()
            .into_iter()
            .zip(TOPICS.iter().zip(channels.iter_mut()))
        {
            let schema_id = out
                .add_schema(name, "jsonschema", schema.as_bytes())
                .map_err(&error)?;
            *id = out
                .add_channel(schema_id, topic, "json", &BTreeMap::new())
                .map_err(&error)?;
        }
        out.flush().map_err(&error)?;
        Ok(Writer {
            out: Some(out),
            path: path.to_path_buf(),
            channels,
            config,
            counters,
            links: HashMap::new(),
            sequence: 0,
            values: Map::new(),
        })
    }

    fn error(&self, message: impl ToString) -> RecordError {
        RecordError::Write {
            path: self.path.clone(),
            message: message.to_string(),
        }
    }

    /// Writes what comes until the recorder finishes, a chunk at least
    /// every `chunk_every`; then the summary and the footer.
    pub(super) fn run(&mut self, rx: &Receiver<Item>) -> Result<(), RecordError> {
        let every = self.config.chunk_every.max(StdDuration::from_millis(1));
        let mut next_chunk = StdInstant::now() + every;
        loop {
            let stop = self.counters.stop.load(Ordering::Relaxed);
            for l in self.links.values_mut() {
                l.read_clock();
            }
            // Empty or disconnected: the stop flag ends the recording.
            while let Ok(item) = rx.try_recv() {
                self.item(item)?;
            }
            let now = StdInstant::now();
            if now >= next_chunk || stop {
                self.write_stats()?;
                let flushed = self.out()?.flush();
                flushed.map_err(|e| self.error(e))?;
                self.counters.chunks.fetch_add(1, Ordering::Relaxed);
                next_chunk = (next_chunk + every).max(now + every / 2);
            }
            if stop {
                break;
            }
            std::thread::sleep(POLL.min(next_chunk.saturating_duration_since(now)));
        }
        let Some(mut out) = self.out.take() else {
            return Ok(());
        };
        out.finish().map_err(|e| self.error(e))?;
        let mut file = out.into_inner();
        file.flush().map_err(|e| self.error(e))?;
        Ok(())
    }

    fn out(&mut self) -> Result<&mut mcap::Writer<BufWriter<File>>, RecordError> {
        let error = self.error("the file is already finished");
        self.out.as_mut().ok_or(error)
    }

    fn item(&mut self, item: Item) -> Result<(), RecordError> {
        match item {
            Item::Attach {
                link,
                role,
                sender,
                unix_origin_ns,
            } => {
                let state = LinkState {
                    role,
                    sender,
                    unix_origin_ns,
                    last_fresh: None,
                    period_ns: None,
                    names: Vec::new(),
                    closed: false,
                    clock: (0.0, None),
                };
                let at = state.sender.now().as_nanos();
                let stats = state.sender.stats();
                let msg = EventMsg {
                    link,
                    side: state.side(),
                    kind: "attached",
                    at_ns: at,
                    period_s: stats.map(|s| s.period.as_secs_f64()),
                    ns: stats.map(|s| s.ns),
                    ..EventMsg::default()
                };
                let t = state.unix(at);
                let mut state = state;
                state.period_ns = stats.map(|s| s.period.as_nanos());
                state.read_clock();
                self.links.insert(link, state);
                self.write(Topic::Event, t, t, &msg)
            }
            Item::Release { link, release } => self.release(link, &release),
            Item::Event { link, at, event } => self.event(link, at, &event),
            Item::Probe { link, probe } => self.probe(link, &probe),
        }
    }

    fn probe(&mut self, link: u32, p: &ProbeArrival) -> Result<(), RecordError> {
        let Some(l) = self.links.get(&link) else {
            return Ok(());
        };
        let direction = match l.role {
            Role::Base => "bwd",
            _ => "fwd",
        };
        let offset_s = l.clock.0;
        let (sent, arrived) = (p.sent_at.as_nanos(), p.arrived_at.as_nanos());
        let raw = secs_between(sent, arrived);
        let (log, publish) = (l.unix(arrived), l.unix_of_peer(sent, offset_s));
        let msg = ProbeMsg {
            link,
            direction,
            seq: p.seq,
            sent_ns: sent,
            arrived_ns: arrived,
            raw_s: raw,
            one_way_s: raw - offset_s,
            clock_offset_s: offset_s,
        };
        self.write(Topic::Probe, log, publish, &msg)
    }

    fn release(&mut self, link: u32, r: &Sample) -> Result<(), RecordError> {
        let Some(l) = self.links.get_mut(&link) else {
            return Ok(());
        };
        let (topic, direction) = match l.role {
            Role::Base => (Topic::State, "bwd"),
            _ => (Topic::Command, "fwd"),
        };
        if l.names.len() != r.values().len() {
            l.names = names(&self.config, l.role, r.values().len());
        }
        let (offset_s, nrtt_s) = l.clock;
        let (sent, arrived, released) = (
            r.sent_at.as_nanos(),
            r.arrived_at.as_nanos(),
            r.released_at.as_nanos(),
        );
        let log = l.unix(released);
        let publish = l.unix_of_peer(sent, offset_s);
        let fresh = r.status == Status::Fresh;
        // Samples passed over between two fresh releases: late (or lost).
        let gap = match (fresh, l.last_fresh) {
            (true, Some((seq, prev_sent))) if r.seq > seq + 1 => {
                let period = l
                    .period_ns
                    .unwrap_or(0)
                    .max(sent.saturating_sub(prev_sent) / (r.seq - seq).max(1));
                Some((seq + 1, period))
            }
            _ => None,
        };
        if fresh {
            l.last_fresh = Some((r.seq, sent));
        }
        let unix_of = |t: u64| l.unix_of_peer(t, offset_s);
        let mut missing = Vec::new();
        if let Some((first, period)) = gap {
            let last = r.seq.min(first + MAX_GAP_MESSAGES);
            for seq in first..last {
                let s = sent.saturating_sub((r.seq - seq) * period);
                missing.push((seq, s, unix_of(s)));
            }
        }
        let names = std::mem::take(&mut l.names);
        self.values.clear();
        for (name, v) in names.iter().zip(r.values()) {
            let v = serde_json::Number::from_f64(*v).map_or(Value::Null, Value::Number);
            self.values.insert(name.clone(), v);
        }
        if let Some(l) = self.links.get_mut(&link) {
            l.names = names;
        }
        let empty = Map::new();
        for &(seq, s, publish) in &missing {
            let msg = ReleaseMsg {
                link,
                seq,
                status: "late",
                sent_ns: s,
                arrived_ns: None,
                released_ns: released,
                end_to_end_s: secs_between(s, released),
                added_delay_s: None,
                grtt_s: None,
                answers_sent_ns: None,
                nrtt_s,
                values: &empty,
            };
            self.write(topic, log, publish, &msg)?;
            let net = NetworkMsg {
                link,
                direction,
                seq,
                sent_ns: s,
                arrived_ns: None,
                raw_s: None,
                one_way_s: None,
                clock_offset_s: offset_s,
                missing: true,
            };
            self.write(Topic::Network, log, publish, &net)?;
        }
        let grtt = r.grtt.map(|g| g.as_nanos());
        let values = std::mem::take(&mut self.values);
        let msg = ReleaseMsg {
            link,
            seq: r.seq,
            status: if fresh { "fresh" } else { "repeated" },
            sent_ns: sent,
            arrived_ns: Some(arrived),
            released_ns: released,
            end_to_end_s: secs_between(sent, released),
            added_delay_s: Some(r.added_delay().as_secs_f64()),
            grtt_s: r.grtt.map(|g| g.as_secs_f64()),
            answers_sent_ns: grtt.map(|g| released.saturating_sub(g)),
            nrtt_s,
            values: &values,
        };
        let written = self.write(topic, log, publish, &msg);
        self.values = values;
        written?;
        if fresh {
            let raw = secs_between(sent, arrived);
            let net = NetworkMsg {
                link,
                direction,
                seq: r.seq,
                sent_ns: sent,
                arrived_ns: Some(arrived),
                raw_s: Some(raw),
                one_way_s: Some(raw - offset_s),
                clock_offset_s: offset_s,
                missing: false,
            };
            let arrival = self.links.get(&link).map_or(log, |l| l.unix(arrived));
            self.write(Topic::Network, arrival, publish, &net)?;
        }
        Ok(())
    }

    fn event(&mut self, link: u32, at: Instant, e: &LinkEvent) -> Result<(), RecordError> {
        let Some(l) = self.links.get_mut(&link) else {
            return Ok(());
        };
        let mut msg = EventMsg {
            link,
            side: l.side(),
            kind: e.kind(),
            at_ns: at.as_nanos(),
            ..EventMsg::default()
        };
        match *e {
            Event::Started { period, ns } | Event::Paused { period, ns } => {
                msg.period_s = Some(period.as_secs_f64());
                msg.ns = Some(ns);
                l.period_ns = Some(period.as_nanos());
                // A new regime numbers on: no gap across it is a late sample.
                l.last_fresh = None;
            }
            Event::DelayChanged { delay, ticks } => {
                msg.delay_s = Some(delay.as_secs_f64());
                msg.ticks = Some(ticks);
            }
            Event::RoundTripChanged { grtt, ticks } => {
                msg.grtt_s = Some(grtt.as_secs_f64());
                msg.ticks = Some(ticks);
            }
            Event::LinkLost { silent_for } => msg.silent_for_s = Some(silent_for.as_secs_f64()),
            Event::LinkRestored { outage } => msg.outage_s = Some(outage.as_secs_f64()),
            Event::Closed { error } => {
                msg.error = error.map(|e| e.to_string());
                l.closed = true;
            }
            _ => {}
        }
        let t = l.unix(at.as_nanos());
        self.write(Topic::Event, t, t, &msg)
    }

    /// A `/ndr/stats` message per link; a closed link's last, then it is
    /// forgotten.
    fn write_stats(&mut self) -> Result<(), RecordError> {
        let mut ids: Vec<u32> = self.links.keys().copied().collect();
        ids.sort_unstable();
        for id in ids {
            let Some(l) = self.links.get(&id) else {
                continue;
            };
            let closed = l.closed;
            if let Some(s) = l.sender.stats() {
                let e = &s.endpoint;
                let at = l.sender.now().as_nanos();
                let msg = StatsMsg {
                    link: id,
                    side: l.side(),
                    phase: s.phase.name(),
                    period_s: s.period.as_secs_f64(),
                    ns: s.ns,
                    queue_len: s.queue_len,
                    samples_sent: e.samples_sent,
                    samples_received: e.samples_received,
                    released_fresh: e.released_fresh,
                    released_held: e.released_held,
                    underflows: e.underflows,
                    late: e.late,
                    samples_lost: e.samples_lost,
                    samples_recovered: e.samples_recovered + e.samples_from_repeats,
                    link_lost: e.link_lost,
                    nrtt_mean_s: e.nrtt.mean(),
                    nrtt_std_s: e.nrtt.std(),
                    nrtt_last_s: s.last_nrtt.map(|d| d.as_secs_f64()),
                    grtt_mean_s: e.grtt.mean(),
                    grtt_std_s: e.grtt.std(),
                    grtt_count: e.grtt.count(),
                    one_way_rx_mean_s: e.one_way_rx.mean(),
                    clock_offset_s: e.clock_offset_s,
                    clock_skew_ppm: e.clock_skew_ppm,
                    playout_delay_s: e.playout_delay_s,
                    delay_changes: e.delay_changes,
                    release_lateness_p50_s: s.release_lateness.p50.as_secs_f64(),
                    release_lateness_p99_s: s.release_lateness.p99.as_secs_f64(),
                    release_lateness_max_s: s.release_lateness.max.as_secs_f64(),
                    app_dropped: s.app_dropped,
                    record_queued: self.counters.queued.load(Ordering::Relaxed),
                    record_dropped: self.counters.dropped.load(Ordering::Relaxed),
                };
                let t = l.unix(at);
                self.write(Topic::Stats, t, t, &msg)?;
            }
            if closed {
                self.links.remove(&id);
            }
        }
        Ok(())
    }

    fn write(
        &mut self,
        topic: Topic,
        log_time: u64,
        publish_time: u64,
        msg: &impl Serialize,
    ) -> Result<(), RecordError> {
        let data = serde_json::to_vec(msg).map_err(|e| self.error(e))?;
        let header = MessageHeader {
            channel_id: self.channels[topic as usize],
            sequence: self.sequence,
            log_time,
            publish_time,
        };
        self.sequence = self.sequence.wrapping_add(1);
        let written = self.out()?.write_to_known_channel(&header, &data);
        written.map_err(|e| self.error(e))?;
        self.counters.written.fetch_add(1, Ordering::Relaxed);
        Ok(())
    }
}

/// `b − a` in seconds, either sign.
fn secs_between(a: u64, b: u64) -> f64 {
    (b as f64 - a as f64) * 1e-9
}

/// The names of `n` values released at a side in `role`: the configured
/// ones if they are `n`, else `command0…` or `state0…`.
fn names(config: &RecordConfig, role: Role, n: usize) -> Vec<String> {
    let (given, prefix) = match role {
        Role::Base => (config.state_names.as_ref(), "state"),
        _ => (config.command_names.as_ref(), "command"),
    };
    match given {
        Some(names) if names.len() == n => names.clone(),
        _ => (0..n).map(|i| format!("{prefix}{i}")).collect(),
    }
}
