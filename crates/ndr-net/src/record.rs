//! Recordings of links in MCAP (feature `record`): what each side
//! released, when it was sent and released, the link's events, its
//! counters once a second and each arrival's one-way delay, in a file that
//! Foxglove, the `mcap` tools and `ndr sim --trace` open.
//!
//! A [`Recorder`] owns the file and a writer thread; [`Link::record`]
//! attaches a link to it. On the link's hub thread, each event and each
//! probe's arrival is copied into a bounded queue without waiting (a full
//! queue drops the copy and counts it in [`RecordStats::dropped`]), so a
//! recording never delays a release. The writer thread encodes the messages as JSON, ends an MCAP
//! chunk (indexed) at least once a second and writes it out, so that a
//! process killed without warning leaves a file readable up to its last
//! chunk; [`Recorder::finish`] writes the summary and the footer.
//!
//! The channels, each with a JSON schema (`jsonschema` encoding):
//!
//! | topic | one message per | log time | publish time |
//! |---|---|---|---|
//! | `/ndr/command` | command released by a remote (and command missed: `late`) | release | original send |
//! | `/ndr/state` | state released by a base (and state missed: `late`) | release | original send |
//! | `/ndr/event` | link event (delay and round trip changes, link lost and restored, …) | when the hub emitted it | the same |
//! | `/ndr/stats` | link, once a second | when read | the same |
//! | `/ndr/network` | fresh sample's arrival, and sample never released | arrival (release for a missing one) | original send |
//! | `/ndr/probe` | probe's arrival (the initialization pattern's frames, which size the queue) | arrival | original send |
//!
//! Times in messages are on the link's clock (`*_ns`, nanoseconds from its
//! hub's origin; a send time on the sender's); MCAP's log and publish
//! times are Unix nanoseconds, a peer's send time brought to this side's
//! clock by the link's clock offset estimate.

mod message;
mod replay;
mod schema;
mod writer;

use std::fmt;
use std::fs::File;
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};
use std::sync::mpsc::{self, SyncSender, TrySendError};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::{Duration as StdDuration, SystemTime, UNIX_EPOCH};

use ndr_core::endpoint::{Event, ProbeArrival};
use ndr_core::time::Instant;
use ndr_core::wire::Role;

use crate::delivery::{LinkEvent, Sample};
use crate::error::NetError;
use crate::hub::Tapped;
use crate::link::{Link, LinkSender};

pub use replay::{Crossing, MAX_RECORDING_BYTES, ProbeCrossing, RecordedNetwork, read_network};
pub use schema::TOPICS;

/// Messages the queue to the writer holds by default: seconds of a 1 kHz
/// link's releases, events and arrivals.
pub const RECORD_QUEUE: usize = 8192;

/// How a [`Recorder`] records.
#[derive(Clone, Debug)]
#[non_exhaustive]
pub struct RecordConfig {
    /// Messages waiting for the writer at most; past it they are dropped
    /// and counted ([`RecordStats::dropped`]). At least one.
    pub queue: usize,
    /// The longest time between two chunks written out: what a process
    /// killed without warning may lose at most. Also the period of the
    /// `/ndr/stats` messages.
    pub chunk_every: StdDuration,
    /// The names of a command's values (`command0`, `command1`, … when
    /// `None`, or when their number is not the link's).
    pub command_names: Option<Vec<String>>,
    /// The names of a state's values (`state0`, `state1`, … when `None`,
    /// or when their number is not the link's).
    pub state_names: Option<Vec<String>>,
}

impl Default for RecordConfig {
    fn default() -> Self {
        RecordConfig {
            queue: RECORD_QUEUE,
            chunk_every: StdDuration::from_secs(1),
            command_names: None,
            state_names: None,
        }
    }
}

impl RecordConfig {
    /// Names the values of commands and states (`/ndr/command` and
    /// `/ndr/state` carry them by name).
    #[must_use]
    pub fn with_names(mut self, commands: Vec<String>, states: Vec<String>) -> Self {
        self.command_names = Some(commands);
        self.state_names = Some(states);
        self
    }
}

/// What a [`Recorder`] counted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
#[non_exhaustive]
pub struct RecordStats {
    /// Links attached.
    pub links: u32,
    /// Events handed to the writer.
    pub queued: u64,
    /// Events dropped on the hub's thread: the writer's queue was full (the
    /// writer fell behind by [`RecordConfig::queue`] messages), or the
    /// writer had stopped.
    pub dropped: u64,
    /// MCAP messages written.
    pub written: u64,
    /// Chunks written out.
    pub chunks: u64,
}

/// Why a recording failed.
#[derive(Debug)]
#[non_exhaustive]
pub enum RecordError {
    /// The file could not be created.
    Create {
        /// The file.
        path: PathBuf,
        /// What the system said.
        error: io::Error,
    },
    /// Writing the file failed (disk full, removed, …): the recording
    /// stopped there; what was written before is readable.
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
    /// The writer thread could not start, or stopped abnormally.
    Writer(String),
    /// A recording could not be read back ([`read_network`]).
    Read {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
}

impl fmt::Display for RecordError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RecordError::Create { path, error } => write!(
                f,
                "cannot create the recording {}: {error}; give a writable path",
                path.display()
            ),
            RecordError::Write { path, message } => write!(
                f,
                "the recording {} stopped: {message}; what was written before is readable",
                path.display()
            ),
            RecordError::Writer(why) => write!(f, "the recording's writer failed: {why}"),
            RecordError::Read { path, message } => {
                write!(f, "cannot replay {}: {message}", path.display())
            }
        }
    }
}

impl std::error::Error for RecordError {}

/// What the tap hands the writer.
pub(crate) enum Item {
    /// A link attached: its number, role, handle for its stats, and its
    /// clock's origin in Unix nanoseconds.
    Attach {
        link: u32,
        role: Role,
        sender: LinkSender,
        unix_origin_ns: i128,
    },
    Release {
        link: u32,
        release: Sample,
    },
    Event {
        link: u32,
        at: Instant,
        event: LinkEvent,
    },
    Probe {
        link: u32,
        probe: ProbeArrival,
    },
}

/// Counters shared by the taps, the writer and the recorder.
#[derive(Default)]
pub(crate) struct Counters {
    pub(crate) queued: AtomicU64,
    pub(crate) dropped: AtomicU64,
    pub(crate) written: AtomicU64,
    pub(crate) chunks: AtomicU64,
    pub(crate) stop: AtomicBool,
}

impl Counters {
    fn offer(&self, tx: &SyncSender<Item>, item: Item) {
        match tx.try_send(item) {
            Ok(()) => self.queued.fetch_add(1, Ordering::Relaxed),
            Err(TrySendError::Full(_) | TrySendError::Disconnected(_)) => {
                self.dropped.fetch_add(1, Ordering::Relaxed)
            }
        };
    }
}

/// An MCAP recording of one or more links ([`Link::record`]): the file and
/// its writer thread. Dropping it finishes the file ([`finish`](Self::finish)
/// says how that went).
pub struct Recorder {
    path: PathBuf,
    tx: SyncSender<Item>,
    counters: Arc<Counters>,
    links: AtomicU32,
    writer: Mutex<Option<JoinHandle<Result<(), RecordError>>>>,
}

impl fmt::Debug for Recorder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Recorder")
            .field("path", &self.path)
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

impl Recorder {
    /// Creates the file (replacing one there) and starts its writer.
    ///
    /// # Errors
    ///
    /// [`RecordError::Create`] if the file cannot be created,
    /// [`RecordError::Writer`] if its thread cannot start.
    pub fn create(path: impl AsRef<Path>, config: RecordConfig) -> Result<Recorder, RecordError> {
        let path = path.as_ref().to_path_buf();
        let file = File::create(&path).map_err(|error| RecordError::Create {
            path: path.clone(),
            error,
        })?;
        let (tx, rx) = mpsc::sync_channel(config.queue.max(1));
        let counters = Arc::new(Counters::default());
        let mut out = writer::Writer::start(file, &path, config, Arc::clone(&counters))?;
        let writer = std::thread::Builder::new()
            .name("ndr-record".into())
            .spawn(move || out.run(&rx))
            .map_err(|e| RecordError::Writer(e.to_string()))?;
        Ok(Recorder {
            path,
            tx,
            counters,
            links: AtomicU32::new(0),
            writer: Mutex::new(Some(writer)),
        })
    }

    /// The file.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What was counted so far.
    #[must_use]
    pub fn stats(&self) -> RecordStats {
        RecordStats {
            links: self.links.load(Ordering::Relaxed),
            queued: self.counters.queued.load(Ordering::Relaxed),
            dropped: self.counters.dropped.load(Ordering::Relaxed),
            written: self.counters.written.load(Ordering::Relaxed),
            chunks: self.counters.chunks.load(Ordering::Relaxed),
        }
    }

    /// Writes what waits, the summary and the footer, and closes the file.
    /// Events of links still attached after this are dropped and counted.
    /// Calling it again returns the counts.
    ///
    /// # Errors
    ///
    /// [`RecordError::Write`] if the file could not be written to the end
    /// (what was written before stays readable).
    pub fn finish(&self) -> Result<RecordStats, RecordError> {
        self.counters.stop.store(true, Ordering::Relaxed);
        let writer = self
            .writer
            .lock()
            .unwrap_or_else(PoisonError::into_inner)
            .take();
        if let Some(writer) = writer {
            writer
                .join()
                .map_err(|_| RecordError::Writer("its thread panicked".into()))??;
        }
        Ok(self.stats())
    }

    fn attach(&self, link: &mut Link) -> Result<(), NetError> {
        let n = self.links.fetch_add(1, Ordering::Relaxed);
        let sender = link.sender();
        let unix_now = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as i128);
        let unix_origin_ns = unix_now - i128::from(sender.now().as_nanos());
        self.counters.offer(
            &self.tx,
            Item::Attach {
                link: n,
                role: link.role(),
                sender: sender.clone(),
                unix_origin_ns,
            },
        );
        let (tx, counters) = (self.tx.clone(), Arc::clone(&self.counters));
        link.tap(Box::new(move |tapped: Tapped<'_>| {
            let item = match tapped {
                Tapped::Event(Event::Released(release)) => Item::Release {
                    link: n,
                    release: release.clone(),
                },
                Tapped::Event(other) => Item::Event {
                    link: n,
                    at: sender.now(),
                    event: other.clone(),
                },
                Tapped::Probe(probe) => Item::Probe { link: n, probe },
            };
            counters.offer(&tx, item);
        }))
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        if let Err(e) = self.finish() {
            tracing::error!("{e}");
        }
    }
}

impl Link {
    /// Records this link into `recorder` from now on: its releases on
    /// `/ndr/command` (a remote's) or `/ndr/state` (a base's), its events,
    /// its counters once a second, its samples' arrivals and its probes'
    /// (see [`Recorder`]).
    /// Several links may share a recorder (a remote serving bases one
    /// after another, or both sides of a link in one process); each
    /// message names its link by number, in the order they were attached.
    ///
    /// # Errors
    ///
    /// The link's error if it has ended.
    pub fn record(&mut self, recorder: &Recorder) -> Result<(), NetError> {
        recorder.attach(self)
    }
}
