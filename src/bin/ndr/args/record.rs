//! `--record`: an MCAP recording of the link, on the commands that run one.

use std::path::PathBuf;

use ndr::net::{Link, RecordConfig, RecordStats, Recorder};
use serde::Serialize;

use crate::robot::StateLayout;

/// Where to record the link, shared by `demo`, `base` and `remote`.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct RecordArgs {
    /// Record the link to this MCAP file (Foxglove, the `mcap` tools,
    /// `ndr.read_recording`, `python -m ndr plot` and `ndr sim --trace`
    /// open it): every release with its send and release times, the link's
    /// events, its counters once a second and each arrival's one-way delay.
    /// Written by a thread of its own, a chunk at least every second.
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
}

impl RecordArgs {
    /// The recorder, if one was asked for, its values named after the
    /// link's layout (`command0…`, `positions0…`).
    pub fn start(&self, axes: u16, layout: &StateLayout) -> Result<Option<Recorder>, String> {
        let Some(path) = &self.record else {
            return Ok(None);
        };
        let (commands, states) = layout.channel_names(axes);
        let config = RecordConfig::default().with_names(commands, states);
        Recorder::create(path, config)
            .map(Some)
            .map_err(|e| e.to_string())
    }
}

/// Attaches `link` to `recorder`, if there is one; a link that ended
/// already is recorded no further (its end is reported elsewhere).
pub fn attach(recorder: Option<&Recorder>, link: &mut Link) {
    if let Some(r) = recorder
        && let Err(e) = link.record(r)
    {
        tracing::warn!("the recording does not take the link: {e}");
    }
}

/// What the report says of a recording.
#[derive(Clone, Debug, Serialize)]
pub struct RecordingSummary {
    /// The file.
    pub path: String,
    /// MCAP messages written, chunks written out, and events the link's
    /// hub could not hand to the writer (its queue full): dropped, counted.
    pub messages: u64,
    pub chunks: u64,
    pub dropped: u64,
    /// Why the file could not be written to its end, if it could not.
    pub error: Option<String>,
}

/// Finishes the recording (summary and footer) and says how it went.
pub fn finish(recorder: Option<Recorder>) -> Option<RecordingSummary> {
    let r = recorder?;
    let path = r.path().display().to_string();
    let (stats, error) = match r.finish() {
        Ok(s) => (s, None),
        Err(e) => (r.stats(), Some(e.to_string())),
    };
    Some(summary(path, stats, error))
}

fn summary(path: String, s: RecordStats, error: Option<String>) -> RecordingSummary {
    RecordingSummary {
        path,
        messages: s.written,
        chunks: s.chunks,
        dropped: s.dropped,
        error,
    }
}
