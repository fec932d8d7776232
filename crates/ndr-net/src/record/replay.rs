//! Reading back what a recording measured of the network (`/ndr/network`),
//! for the simulator to replay it.

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

/// What a recording measured of the network, each way, in send order.
#[derive(Clone, Debug, Default, PartialEq)]
#[non_exhaustive]
pub struct RecordedNetwork {
    /// Base → remote: the commands' arrivals at the remote.
    pub forward: Vec<Crossing>,
    /// Remote → base: the states' arrivals at the base.
    pub backward: Vec<Crossing>,
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
struct Arrival {
    direction: String,
    one_way_s: Option<f64>,
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
        if m.channel.topic != "/ndr/network" {
            continue;
        }
        let a: Arrival = serde_json::from_slice(&m.data)
            .map_err(|e| error(format!("a /ndr/network message is not an arrival: {e}")))?;
        let crossing = Crossing {
            sent_unix_ns: m.publish_time,
            one_way_s: if a.missing { None } else { a.one_way_s },
        };
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
    if net.forward.is_empty() && net.backward.is_empty() {
        return Err(error(
            "no arrival on /ndr/network: record a link that released samples".into(),
        ));
    }
    Ok(net)
}
