//! Zenoh links in a hub ([`Transport::Zenoh`](crate::Transport::Zenoh)).
//!
//! A link's frames are zenoh publications on keys of its own
//! ([`crate::zenoh_link`]): the samples' datagrams on one key (best
//! effort, express, dropped rather than queued under congestion: the
//! playout decides what is late, not zenoh's queues), every other frame on
//! another (reliable). zenoh hands what its subscribers get to callbacks
//! on its own threads: each copies the frame, with its arrival time, into
//! the link's bounded inbox and, if the hub is not already told, writes a
//! byte to a socket pair whose other end the hub polls under the link's
//! token. The hub then hands the inbox to the endpoint as it would a
//! socket's frames. A full inbox drops the newest frame and counts it.

use std::io::{self, Read as _, Write as _};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, TrySendError, sync_channel};
use std::time::Instant as StdInstant;

use mio::net::UnixStream;
use ndr_core::endpoint::Origin;
use ndr_core::time::Instant;
use ndr_core::wire::{MAX_DATAGRAM_LEN, MAX_FRAME_LEN};
use zenoh::Wait as _;
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};

use super::{Entry, Path};

/// Frames a link's inbox holds for its hub: at 1 kHz, a quarter second's
/// worth of both keys; the hub empties it at each wake-up.
const INBOX: usize = 512;
/// The longest payload taken: a Bundle, or any frame of a stream.
const MAX_PAYLOAD: usize = if MAX_FRAME_LEN > MAX_DATAGRAM_LEN {
    MAX_FRAME_LEN
} else {
    MAX_DATAGRAM_LEN
};

/// The keys a link publishes on and subscribes to.
pub(crate) struct Keys {
    /// Its frames other than the samples (handshake, Control, Close…).
    pub frames_out: String,
    /// Its samples' datagrams.
    pub samples_out: String,
    /// The peer's frames.
    pub frames_in: String,
    /// The peer's samples.
    pub samples_in: String,
}

/// What a zenoh link's hub counted of its frames.
#[derive(Default)]
pub(crate) struct Counters {
    /// Frames that arrived to a full inbox, or longer than any frame.
    pub dropped: AtomicU64,
    /// Frames zenoh refused to publish.
    pub unsent: AtomicU64,
}

/// A frame as a subscriber got it.
struct Arrived {
    at: StdInstant,
    sample: bool,
    bytes: Vec<u8>,
}

/// A link's publishers, subscribers and inbox.
pub(crate) struct ZenohPath {
    frames: Publisher<'static>,
    samples: Publisher<'static>,
    _subscribers: [Subscriber<()>; 2],
    inbox: Receiver<Arrived>,
    /// The hub's end of the wake-up pair, polled under the link's token.
    pub(super) wake: UnixStream,
    /// Whether a byte is in the pair that the hub has not read yet.
    armed: Arc<AtomicBool>,
    pub(crate) counters: Arc<Counters>,
    /// Keeps the session open while the link lives (a base's own).
    _session: zenoh::Session,
}

impl ZenohPath {
    /// Declares the link's publishers and subscribers on `session`;
    /// `first`, a frame already heard (the base's Hello, on a listener's
    /// side), waits in the inbox.
    pub(crate) fn open(
        session: &zenoh::Session,
        keys: &Keys,
        first: Option<(StdInstant, Vec<u8>)>,
    ) -> Result<ZenohPath, zenoh::Error> {
        let (tx, inbox) = sync_channel(INBOX);
        let (wake, wake_writer) = UnixStream::pair()?;
        let wake_writer = Arc::new(wake_writer);
        let armed = Arc::new(AtomicBool::new(false));
        let counters = Arc::new(Counters::default());
        if let Some((at, bytes)) = first {
            let _ = tx.try_send(Arrived {
                at,
                sample: false,
                bytes,
            });
            armed.store(true, Ordering::Release);
            let _ = (&*wake_writer).write(&[1]);
        }
        let subscriber = |key: &str, sample: bool| {
            let (tx, writer, armed, counters) = (
                tx.clone(),
                Arc::clone(&wake_writer),
                Arc::clone(&armed),
                Arc::clone(&counters),
            );
            session
                .declare_subscriber(key.to_owned())
                .callback(move |s: zenoh::sample::Sample| {
                    let at = StdInstant::now();
                    let payload = s.payload();
                    if payload.len() > MAX_PAYLOAD {
                        counters.dropped.fetch_add(1, Ordering::Relaxed);
                        return;
                    }
                    let bytes = payload.to_bytes().into_owned();
                    match tx.try_send(Arrived { at, sample, bytes }) {
                        Ok(()) => {}
                        Err(TrySendError::Full(_)) => {
                            counters.dropped.fetch_add(1, Ordering::Relaxed);
                            return;
                        }
                        Err(TrySendError::Disconnected(_)) => return,
                    }
                    if !armed.swap(true, Ordering::AcqRel) {
                        // A full pair already wakes the hub.
                        let _ = (&*writer).write(&[1]);
                    }
                })
                .wait()
        };
        let subscribers = [
            subscriber(&keys.frames_in, false)?,
            subscriber(&keys.samples_in, true)?,
        ];
        let frames = session
            .declare_publisher(keys.frames_out.clone())
            .congestion_control(CongestionControl::Drop)
            .priority(Priority::InteractiveHigh)
            .wait()?;
        let samples = session
            .declare_publisher(keys.samples_out.clone())
            .congestion_control(CongestionControl::Drop)
            .priority(Priority::RealTime)
            .express(true)
            .wait()?;
        Ok(ZenohPath {
            frames,
            samples,
            _subscribers: subscribers,
            inbox,
            wake,
            armed,
            counters,
            _session: session.clone(),
        })
    }

    /// Whether a subscriber of the peer's side listens to its frames.
    pub(crate) async fn peer_listens(&self) -> bool {
        self.frames
            .matching_status()
            .await
            .is_ok_and(|m| m.matching())
    }
}

/// Hands the endpoint every frame in the link's inbox.
pub(super) fn receive(e: &mut Entry, origin: StdInstant) {
    let Path::Zenoh(z) = &mut e.path else {
        return;
    };
    let mut sink = [0u8; 64];
    loop {
        match (&z.wake).read(&mut sink) {
            Ok(0) => break,
            Ok(_) => {}
            Err(err) if err.kind() == io::ErrorKind::Interrupted => {}
            Err(_) => break,
        }
    }
    // Before the inbox is emptied: a frame that comes after this is
    // announced anew.
    z.armed.store(false, Ordering::Release);
    let handled = StdInstant::now();
    while let Ok(a) = z.inbox.try_recv() {
        e.rx_lag
            .push_duration(handled.saturating_duration_since(a.at).into());
        let at = Instant::from_std(origin, a.at);
        if a.sample {
            // Refused datagrams are counted by the endpoint; the key
            // routes them, as QUIC's connection does.
            let _ = e.endpoint.handle_datagram(at, &a.bytes, Origin::Path);
        } else {
            // A fatal error closes the endpoint, which reports it.
            let _ = e.endpoint.handle_frame(at, &a.bytes);
        }
        if e.endpoint.is_closed() {
            return;
        }
    }
}

/// Publishes one of the endpoint's frames: a Bundle on the samples' key,
/// anything else on the frames' key.
pub(super) fn send(z: &ZenohPath, frame: &[u8]) {
    let publisher = if ndr_core::wire::is_bundle(frame) {
        &z.samples
    } else {
        &z.frames
    };
    if publisher.put(frame.to_vec()).wait().is_err() {
        z.counters.unsent.fetch_add(1, Ordering::Relaxed);
    }
}
