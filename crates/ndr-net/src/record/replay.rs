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
    /// The file ended inside a record (its writer was killed): what came
    /// before is here.
    pub truncated: bool,
}

#[derive(Deserialize)]
struct Kind {
    kind: String,
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
    for m in stream {
        let m = match m {
            Ok(m) => m,
            Err(_) => {
                net.truncated = true;
                break;
            }
        };
        if m.channel.topic == "/ndr/event" {
            let attached =
                serde_json::from_slice::<Kind>(&m.data).is_ok_and(|e| e.kind == "attached");
            if attached {
                let first = net.attached_unix_ns.get_or_insert(m.log_time);
                *first = (*first).min(m.log_time);
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
