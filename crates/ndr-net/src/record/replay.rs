//! Reading back what a recording measured of the network (`/ndr/network`,
//! `/ndr/probe`), for the simulator to replay it.

use std::path::Path;

use mcap::read::{MessageStream, Options};
use serde::Deserialize;

use super::RecordError;

/// The largest recording read back, in bytes.
pub const MAX_RECORDING_BYTES: u64 = 1 << 30;

/// One sample's crossing of the network, as a recording measured it.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Crossing {
    /// When it was sent, Unix nanoseconds (the sender's clock brought to
    /// the recording side's by the clock offset estimate).
    pub sent_unix_ns: u64,
    /// Its one-way delay, seconds; `None` if it was never released (lost,
    /// or came after its release time).
    pub one_way_s: Option<f64>,
}

/// One probe's crossing of the network (`/ndr/probe`): the frames of the
/// initialization pattern, whose round trips sized the queue.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct ProbeCrossing {
    /// Its sequence number, in its sender's count of Data frames.
    pub seq: u64,
    /// When it was sent, Unix nanoseconds (as [`Crossing::sent_unix_ns`]).
    pub sent_unix_ns: u64,
    /// Its one-way delay, seconds.
    pub one_way_s: f64,
}

/// What a recording measured of the network, each way, in send order.
#[derive(Clone, Debug, Default, PartialEq)]
#[non_exhaustive]
pub struct RecordedNetwork {
    /// Base → remote: the commands' arrivals at the remote.
    pub forward: Vec<Crossing>,
    /// Remote → base: the states' arrivals at the base.
    pub backward: Vec<Crossing>,
    /// Base → remote: the probes that arrived at the remote before its
    /// first command (a link's set-up), by sequence number. Empty for a
    /// recording without `/ndr/probe`.
    pub forward_probes: Vec<ProbeCrossing>,
    /// Remote → base: the probes that arrived at the base before its
    /// first state, likewise.
    pub backward_probes: Vec<ProbeCrossing>,
    /// When the recording of the link began (its first `attached`
    /// event), Unix nanoseconds: just after the handshake, before the
    /// initialization pattern and the first sample.
    pub attached_unix_ns: Option<u64>,
    /// The period the link started at (its first `started` event), seconds.
    pub period_s: Option<f64>,
    /// For each state the base released that closed a round trip, when the
    /// command it answers is in the recording too (a recording of both
    /// sides): how long after that command's release the remote sent the
    /// state, seconds, on the remote's clock. A period for an application
    /// that answers at the next tick, nothing for one that answers in the
    /// tick of the release.
    pub answer_lags_s: Vec<f64>,
    /// The file ended inside a record (its writer was killed): what came
    /// before is here.
    pub truncated: bool,
}

#[derive(Deserialize)]
struct Kind {
    kind: String,
    period_s: Option<f64>,
}

/// A release on `/ndr/command` or `/ndr/state`, the fields a replay reads.
#[derive(Deserialize)]
struct Release {
    status: String,
    sent_ns: u64,
    released_ns: u64,
    answers_sent_ns: Option<u64>,
}

#[derive(Deserialize)]
struct Probe {
    direction: String,
    seq: u64,
    one_way_s: f64,
    raw_s: Option<f64>,
}

#[derive(Deserialize)]
struct Arrival {
    direction: String,
    one_way_s: Option<f64>,
    clock_offset_s: Option<f64>,
    missing: bool,
}

/// The network's crossings recorded on `/ndr/network` in the MCAP file at
/// `path` (up to its last whole record, if its writer was killed).
///
/// # Errors
///
/// [`RecordError::Read`] if the file cannot be read, is larger than
/// [`MAX_RECORDING_BYTES`], is not an MCAP file, or holds a `/ndr/network`
/// message that is not an arrival.
pub fn read_network(path: impl AsRef<Path>) -> Result<RecordedNetwork, RecordError> {
    let path = path.as_ref();
    let error = |message: String| RecordError::Read {
        path: path.to_path_buf(),
        message,
    };
    let size = std::fs::metadata(path)
        .map_err(|e| error(e.to_string()))?
        .len();
    if size > MAX_RECORDING_BYTES {
        return Err(error(format!(
            "{size} bytes, more than the {MAX_RECORDING_BYTES} a replay reads"
        )));
    }
    let bytes = std::fs::read(path).map_err(|e| error(e.to_string()))?;
    let stream = MessageStream::new_with_options(&bytes, Options::IgnoreEndMagic.into())
        .map_err(|e| error(format!("not an MCAP recording: {e}")))?;
    let mut net = RecordedNetwork::default();
    // The probes each way with their raw delays (arrival − send, on the
    // two clocks as they are); each way's first sample's send time and
    // clock offset estimate.
    let mut probes: [Vec<(ProbeCrossing, Option<f64>)>; 2] = [Vec::new(), Vec::new()];
    let mut offsets: [Option<(u64, f64)>; 2] = [None, None];
    // Fresh commands' releases by their send time; states' (send, answered
    // command's send time).
    let mut commands = std::collections::HashMap::new();
    let mut states = Vec::new();
    for m in stream {
        let m = match m {
            Ok(m) => m,
            Err(_) => {
                net.truncated = true;
                break;
            }
        };
        if m.channel.topic == "/ndr/event" {
            let event = serde_json::from_slice::<Kind>(&m.data).ok();
            if event.as_ref().is_some_and(|e| e.kind == "attached") {
                let first = net.attached_unix_ns.get_or_insert(m.log_time);
                *first = (*first).min(m.log_time);
            }
            if let Some(Kind { kind, period_s }) = event
                && kind == "started"
                && net.period_s.is_none()
            {
                net.period_s = period_s;
            }
        }
        if let topic @ ("/ndr/command" | "/ndr/state") = m.channel.topic.as_str()
            && let Ok(r) = serde_json::from_slice::<Release>(&m.data)
            && r.status == "fresh"
        {
            if topic == "/ndr/command" {
                commands.insert(r.sent_ns, r.released_ns);
            } else if let Some(answers) = r.answers_sent_ns {
                states.push((r.sent_ns, answers));
            }
        }
        if m.channel.topic == "/ndr/probe" {
            let p: Probe = serde_json::from_slice(&m.data)
                .map_err(|e| error(format!("a /ndr/probe message is not a probe: {e}")))?;
            let probe = ProbeCrossing {
                seq: p.seq,
                sent_unix_ns: m.publish_time,
                one_way_s: p.one_way_s,
            };
            match p.direction.as_str() {
                "fwd" => probes[0].push((probe, p.raw_s)),
                "bwd" => probes[1].push((probe, p.raw_s)),
                other => return Err(error(format!("a probe's direction is {other:?}"))),
            }
            continue;
        }
        if m.channel.topic != "/ndr/network" {
            continue;
        }
        let a: Arrival = serde_json::from_slice(&m.data)
            .map_err(|e| error(format!("a /ndr/network message is not an arrival: {e}")))?;
        let crossing = Crossing {
            sent_unix_ns: m.publish_time,
            one_way_s: if a.missing { None } else { a.one_way_s },
        };
        if !a.missing
            && let Some(offset) = a.clock_offset_s
        {
            let first = match a.direction.as_str() {
                "fwd" => &mut offsets[0],
                _ => &mut offsets[1],
            };
            if first.is_none_or(|(sent, _)| m.publish_time < sent) {
                *first = Some((m.publish_time, offset));
            }
        }
        match a.direction.as_str() {
            "fwd" => net.forward.push(crossing),
            "bwd" => net.backward.push(crossing),
            other => return Err(error(format!("an arrival's direction is {other:?}"))),
        }
    }
    net.answer_lags_s = states
        .iter()
        .filter_map(|(sent, answers)| {
            let released = commands.get(answers)?;
            Some((*sent as f64 - *released as f64) * 1e-9)
        })
        .collect();
    for way in [&mut net.forward, &mut net.backward] {
        way.sort_by_key(|c| c.sent_unix_ns);
    }
    // The clock offset estimate is young during the set-up (its first
    // stamps can be a stalled handshake's): each probe's delay is its raw
    // one less the estimate its way's first sample was given, so that
    // the set-up's round trips are what the link measured.
    let [fwd, bwd] = probes;
    net.forward_probes = rebased(fwd, offsets[0]);
    net.backward_probes = rebased(bwd, offsets[1]);
    // A link's set-up: the probes before its first sample that way (a
    // later session's, or a dynamic pause's, come after it).
    for (probes, way) in [
        (&mut net.forward_probes, &net.forward),
        (&mut net.backward_probes, &net.backward),
    ] {
        if let Some(first) = way.first() {
            probes.retain(|p| p.sent_unix_ns < first.sent_unix_ns);
        }
    }
    if net.forward.is_empty() && net.backward.is_empty() {
        return Err(error(
            "no arrival on /ndr/network: record a link that released samples".into(),
        ));
    }
    Ok(net)
}

/// The probes, each one's delay its raw one less `offset` (the estimate
/// its way's first sample was given) when both are known.
fn rebased(
    probes: Vec<(ProbeCrossing, Option<f64>)>,
    offset: Option<(u64, f64)>,
) -> Vec<ProbeCrossing> {
    probes
        .into_iter()
        .map(|(mut p, raw)| {
            if let (Some(raw), Some((_, offset))) = (raw, offset) {
                p.one_way_s = raw - offset;
            }
            p
        })
        .collect()
}
