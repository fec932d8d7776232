//! One relayed connection: one pump per direction, the upstream connected
//! when the client's first frame leaves.
//!
//! A path's connection setup takes its delay as its data does: the relay
//! connects to the upstream only when the client's first frame (or TLS
//! record) is due there, and writes it at once. So the upstream sees a new
//! connection with its first message, as it would across the network, and
//! a client that says nothing takes none of the upstream's handshake slots
//! (all the relay's clients share its one address there). A client that
//! has said nothing after [`SILENT_CLIENT_WAIT`] gets its upstream
//! connection anyway, for a protocol whose server speaks first.
//!
//! A pump is two halves joined in the connection's task: the reader cuts
//! the byte stream into frames by their length prefix, stamps each with its
//! release time and queues it; the writer sleeps until the head of the queue
//! is due and writes every frame due by then in one go. Release times never
//! decrease within a direction ([`InOrderPath`]), so a FIFO is enough. A
//! side that fails ends its own direction (after its frames in flight) and
//! the one towards it; a framing error or a full queue cuts both.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicUsize, Ordering};

use ndr_core::time::Instant;
use ndr_core::wire::{self, PREFIX_LEN, WireError};
use ndr_netem::{DelaySampler, Direction, InOrderPath};
use tokio::io::{AsyncBufReadExt, AsyncRead, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::sync::{mpsc, oneshot, watch};
use tokio::time::Instant as TokioInstant;

use super::stats::{DirCounters, Tally};
use super::{
    ConnectionEnd, ConnectionSummary, Ctx, RelayEvent, connection_seed, deadline, stopped,
};

/// Read buffer of each pump.
const READ_BUFFER: usize = 16 * 1024;
/// Most bytes gathered into one write when several frames are due at once.
const WRITE_BATCH: usize = 64 * 1024;
/// Time the rest of a connection has to finish once a side has failed:
/// bounds a drain towards a peer that stopped reading.
const DRAIN_AFTER_FAILURE: std::time::Duration = std::time::Duration::from_secs(30);
/// How long a client may say nothing before the relay connects to the
/// upstream for it all the same.
pub(super) const SILENT_CLIENT_WAIT: std::time::Duration = std::time::Duration::from_secs(1);

/// A frame waiting for its release time.
struct Held {
    at: TokioInstant,
    bytes: Vec<u8>,
}

/// Serves one accepted client until it ends, is cut, or the relay stops;
/// counts it and reports it.
pub(super) async fn connection(
    ctx: std::sync::Arc<Ctx>,
    index: u64,
    client: TcpStream,
    peer: SocketAddr,
    mut stop: watch::Receiver<bool>,
) {
    let started = std::time::Instant::now();
    tracing::info!(conn = index, %peer, "relay: connection opened");
    ctx.emit(&RelayEvent::Opened { conn: index, peer });
    let local = [DirCounters::default(), DirCounters::default()];
    let end = tokio::select! {
        end = serve(&ctx, index, client, &local) => end,
        () = stopped(&mut stop) => ConnectionEnd::Shutdown,
    };
    // Both sockets were owned by `serve`: they are closed by now.
    ctx.counters.ended(&end);
    let summary = ConnectionSummary {
        conn: index,
        peer,
        forward: local[0].snapshot(),
        backward: local[1].snapshot(),
        duration: started.elapsed(),
        end,
    };
    if summary.end.is_error() {
        tracing::warn!(conn = index, %peer, "relay: connection cut: {}", summary.end);
    } else {
        tracing::info!(conn = index, %peer, "relay: connection closed: {}", summary.end);
    }
    ctx.emit(&RelayEvent::Closed(summary));
}

async fn serve(
    ctx: &Ctx,
    index: u64,
    client: TcpStream,
    local: &[DirCounters; 2],
) -> ConnectionEnd {
    // Frames are small and timed: Nagle's algorithm would hold them back.
    if let Err(e) = client.set_nodelay(true) {
        tracing::debug!(conn = index, "relay: cannot set TCP_NODELAY: {e}");
    }
    // Each direction draws from its own stream of the sampler, and the
    // processes shared by both are functions of (seed, time): a clone per
    // direction gives the same delays as one shared sampler.
    let sampler = ctx.model.sampler(connection_seed(ctx.seed, index));
    let (client_rx, client_tx) = client.into_split();
    let tally = |dir: Direction| Tally {
        global: &ctx.counters.dirs[dir.index()],
        local: &local[dir.index()],
    };
    let (opened, upstream_rx) = oneshot::channel();
    let upstream = Upstream {
        ctx,
        index,
        opened,
        give_up: TokioInstant::now() + SILENT_CLIENT_WAIT,
    };
    let forward = pump(
        ctx,
        Direction::Forward,
        client_rx,
        Out::Connect(upstream),
        sampler.clone(),
        tally(Direction::Forward),
    );
    let backward = async {
        match upstream_rx.await {
            Ok(upstream_rx) => {
                pump(
                    ctx,
                    Direction::Backward,
                    upstream_rx,
                    Out::Open(client_tx),
                    sampler,
                    tally(Direction::Backward),
                )
                .await
            }
            // The client ended without a word: no upstream, nothing back.
            Err(_) => {
                let mut client_tx = client_tx;
                if let Err(e) = client_tx.shutdown().await {
                    tracing::debug!(conn = index, "relay: half-close failed: {e}");
                }
                Ok(())
            }
        }
    };
    ends(forward, backward).await
}

/// Where a direction writes: a side already open, or the upstream, to be
/// connected when the first frame is due.
enum Out<'a> {
    Open(OwnedWriteHalf),
    Connect(Upstream<'a>),
}

/// The upstream connection to open for a client.
struct Upstream<'a> {
    ctx: &'a Ctx,
    index: u64,
    /// Where its read half goes: the backward pump.
    opened: oneshot::Sender<OwnedReadHalf>,
    /// When to connect even though the client has said nothing.
    give_up: TokioInstant,
}

impl Upstream<'_> {
    /// Connects; the write half for the forward pump.
    async fn open(self) -> Result<OwnedWriteHalf, ConnectionEnd> {
        let ctx = self.ctx;
        let timeout = ctx.config.connect_timeout;
        let stream = match tokio::time::timeout(timeout, TcpStream::connect(ctx.upstream)).await {
            Ok(Ok(stream)) => stream,
            Ok(Err(e)) => {
                return Err(ConnectionEnd::UpstreamFailed {
                    error: format!("cannot connect to {}: {e}", ctx.upstream),
                });
            }
            Err(_) => {
                return Err(ConnectionEnd::UpstreamFailed {
                    error: format!("{} did not answer within {timeout:?}", ctx.upstream),
                });
            }
        };
        if let Err(e) = stream.set_nodelay(true) {
            tracing::debug!(conn = self.index, "relay: cannot set TCP_NODELAY: {e}");
        }
        let (rx, tx) = stream.into_split();
        // The backward pump is gone only once the connection is ending.
        let _ = self.opened.send(rx);
        Ok(tx)
    }
}

/// How the connection ends, given its two directions: when both have
/// ended, or at once when one is cut; after a side has failed, what is left
/// has [`DRAIN_AFTER_FAILURE`] to finish.
async fn ends(
    forward: impl Future<Output = Result<(), ConnectionEnd>>,
    backward: impl Future<Output = Result<(), ConnectionEnd>>,
) -> ConnectionEnd {
    tokio::pin!(forward, backward);
    let (first, forward_first) = tokio::select! {
        end = &mut forward => (end, true),
        end = &mut backward => (end, false),
    };
    let other = async {
        if forward_first {
            backward.await
        } else {
            forward.await
        }
    };
    match first {
        Ok(()) => other.await.err().unwrap_or(ConnectionEnd::Finished),
        Err(end) if is_failed_side(&end) => {
            let _ = tokio::time::timeout(DRAIN_AFTER_FAILURE, other).await;
            end
        }
        // Cut: the other direction's frames in flight are dropped with it.
        Err(end) => end,
    }
}

/// Carries one direction until its source's end of stream has been passed
/// on, or fails.
///
/// A failed read (the source reset) is the source's end: the frames it sent
/// before still arrive, then the end of stream is passed on, and the failure
/// is returned. A failed write (the destination gone) drops the frames in
/// flight and stops reading. Any other error (framing, a queue over its
/// bound) is returned at once: the connection is cut.
async fn pump<R>(
    ctx: &Ctx,
    dir: Direction,
    from: R,
    to: Out<'_>,
    sampler: DelaySampler,
    tally: Tally<'_>,
) -> Result<(), ConnectionEnd>
where
    R: AsyncRead + Unpin,
{
    let (tx, rx) = mpsc::channel(ctx.config.max_queue_frames.max(1));
    let queued_bytes = AtomicUsize::new(0);
    // The reader owns the sender: once it returns, the writer sees the end
    // of the queue after its last frame.
    let reader = read_side(ctx, dir, from, sampler, tx, &queued_bytes, tally);
    let writer = write_side(dir, to, rx, &queued_bytes, tally);
    tokio::pin!(reader, writer);
    tokio::select! {
        read = &mut reader => match read {
            Ok(()) => writer.await,
            Err(end) if is_failed_side(&end) => {
                // Already failed: a failed write changes nothing to report.
                let _ = writer.await;
                Err(end)
            }
            Err(end) => Err(end),
        },
        // The writer returns before the reader only when a write (or the
        // upstream's connection) failed.
        written = &mut writer => written,
    }
}

/// `true` for the end of a side that failed (a reset, a peer gone), which
/// leaves the rest of the connection to finish; any other error cuts it.
const fn is_failed_side(end: &ConnectionEnd) -> bool {
    matches!(end, ConnectionEnd::Io { .. })
}

async fn read_side<R: AsyncRead + Unpin>(
    ctx: &Ctx,
    dir: Direction,
    from: R,
    mut sampler: DelaySampler,
    tx: mpsc::Sender<Held>,
    queued_bytes: &AtomicUsize,
    tally: Tally<'_>,
) -> Result<(), ConnectionEnd> {
    let mut from = BufReader::with_capacity(READ_BUFFER, from);
    let mut path = InOrderPath::new();
    // Decided by the direction's first bytes.
    let mut format = None;
    loop {
        let bytes = match read_unit(&mut from, &mut format).await {
            Ok(Some(bytes)) => bytes,
            Ok(None) => return Ok(()),
            Err(ReadError::Wire(error)) => return Err(ConnectionEnd::Framing { dir, error }),
            Err(ReadError::Record(header)) => return Err(ConnectionEnd::BadRecord { dir, header }),
            Err(ReadError::Truncated(got)) => {
                tracing::warn!(
                    ?dir,
                    "relay: stream ended inside a frame ({got} bytes of it dropped)"
                );
                return Ok(());
            }
            Err(ReadError::Io(e)) => {
                return Err(ConnectionEnd::Io {
                    dir,
                    error: format!("read: {e}"),
                });
            }
        };
        let now = std::time::Instant::now();
        let sent = Instant::from_std(ctx.origin, now);
        let held_before = path.held_back();
        let release = path.deliver(sent, sampler.delay(dir, sent));
        tally.received(path.held_back() > held_before);
        let at = deadline(ctx.origin, release);

        let len = bytes.len();
        let queued = queued_bytes.fetch_add(len, Ordering::Relaxed) + len;
        let limit = &ctx.config;
        if queued > limit.max_queue_bytes {
            return Err(ConnectionEnd::QueueFull {
                dir,
                frames: limit.max_queue_frames.max(1) - tx.capacity(),
                bytes: queued,
            });
        }
        match tx.try_send(Held { at, bytes }) {
            Ok(()) => {}
            Err(mpsc::error::TrySendError::Full(_)) => {
                return Err(ConnectionEnd::QueueFull {
                    dir,
                    frames: limit.max_queue_frames.max(1),
                    bytes: queued,
                });
            }
            // The writer has stopped, with an error that ends the connection.
            Err(mpsc::error::TrySendError::Closed(_)) => return Ok(()),
        }
    }
}

async fn write_side(
    dir: Direction,
    to: Out<'_>,
    mut rx: mpsc::Receiver<Held>,
    queued_bytes: &AtomicUsize,
    tally: Tally<'_>,
) -> Result<(), ConnectionEnd> {
    let (mut to, mut connect) = match to {
        Out::Open(to) => (Some(to), None),
        Out::Connect(upstream) => (None, Some(upstream)),
    };
    let mut batch = Vec::with_capacity(WRITE_BATCH);
    let mut next: Option<Held> = None;
    loop {
        let head = match next.take() {
            Some(held) => held,
            None => {
                let give_up = connect.as_ref().map(|c| c.give_up);
                let got = match give_up {
                    Some(at) => tokio::select! {
                        got = rx.recv() => Some(got),
                        () = tokio::time::sleep_until(at) => None,
                    },
                    None => Some(rx.recv().await),
                };
                match got {
                    Some(Some(held)) => held,
                    Some(None) => break,
                    // Nothing from the client yet: connect all the same.
                    None => {
                        if let Some(upstream) = connect.take() {
                            to = Some(upstream.open().await?);
                        }
                        continue;
                    }
                }
            }
        };
        tokio::time::sleep_until(head.at).await;
        if let Some(upstream) = connect.take() {
            to = Some(upstream.open().await?);
        }
        let Some(out) = to.as_mut() else {
            break;
        };
        batch.clear();
        batch.extend_from_slice(&head.bytes);
        let mut frames = 1;
        // Everything else already due goes in the same write.
        while let Ok(held) = rx.try_recv() {
            if held.at > TokioInstant::now() || batch.len() + held.bytes.len() > WRITE_BATCH {
                next = Some(held);
                break;
            }
            batch.extend_from_slice(&held.bytes);
            frames += 1;
        }
        out.write_all(&batch).await.map_err(|e| ConnectionEnd::Io {
            dir,
            error: format!("write: {e}"),
        })?;
        queued_bytes.fetch_sub(batch.len(), Ordering::Relaxed);
        tally.delivered(frames, batch.len() as u64);
    }
    // The source has closed and everything in flight is delivered: pass the
    // end of stream on (a half-close; the other direction carries on). A
    // client that never said a word has no upstream to tell.
    if let Some(mut out) = to
        && let Err(e) = out.shutdown().await
    {
        tracing::debug!(?dir, "relay: half-close failed: {e}");
    }
    Ok(())
}

enum ReadError {
    Wire(WireError),
    /// Not a TLS record header, in a TLS stream.
    Record([u8; TLS_HEADER]),
    /// End of stream after this many bytes of a frame.
    Truncated(usize),
    Io(std::io::Error),
}

/// What a direction carries.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Format {
    /// ndr frames, by their length prefix.
    Frames,
    /// TLS records, by their 5-byte header.
    Tls,
}

/// A TLS record header: type, version (2), length (2, big-endian).
const TLS_HEADER: usize = 5;
/// Largest TLS record body (2^14 plus the most expansion TLS allows).
const TLS_MAX_BODY: usize = (1 << 14) + 2048;

/// `true` for the start of a TLS record: a handshake record of TLS 1.0 to
/// 1.3. A frame prefix starting so would claim over 64 KiB.
fn is_tls(prefix: &[u8; PREFIX_LEN]) -> bool {
    prefix[0] == 0x16 && prefix[1] == 0x03 && (1..=4).contains(&prefix[2])
}

/// The next whole frame (prefix included) or TLS record (header included);
/// `None` at a clean end of stream. Only the prefix or header is checked:
/// the rest is passed on as it is.
async fn read_unit<R: AsyncRead + Unpin>(
    from: &mut BufReader<R>,
    format: &mut Option<Format>,
) -> Result<Option<Vec<u8>>, ReadError> {
    if from.fill_buf().await.map_err(ReadError::Io)?.is_empty() {
        return Ok(None);
    }
    let mut prefix = [0u8; PREFIX_LEN];
    read_exact(from, &mut prefix, 0).await?;
    let format = *format.get_or_insert(if is_tls(&prefix) {
        Format::Tls
    } else {
        Format::Frames
    });
    if format == Format::Tls {
        return read_record(from, prefix).await.map(Some);
    }
    let len = match wire::frame_len(&prefix) {
        Ok(Some(len)) => len,
        Ok(None) => return Err(ReadError::Truncated(PREFIX_LEN)),
        Err(e) => return Err(ReadError::Wire(e)),
    };
    let mut bytes = vec![0u8; len];
    let (head, rest) = bytes.split_at_mut(PREFIX_LEN.min(len));
    head.copy_from_slice(&prefix[..head.len()]);
    read_exact(from, rest, PREFIX_LEN).await?;
    Ok(Some(bytes))
}

/// The rest of a TLS record whose first header bytes are `prefix`.
async fn read_record<R: AsyncRead + Unpin>(
    from: &mut BufReader<R>,
    prefix: [u8; PREFIX_LEN],
) -> Result<Vec<u8>, ReadError> {
    let mut header = [0u8; TLS_HEADER];
    header[..PREFIX_LEN].copy_from_slice(&prefix);
    read_exact(from, &mut header[PREFIX_LEN..], PREFIX_LEN).await?;
    let len = usize::from(u16::from_be_bytes([header[3], header[4]]));
    // Change cipher spec, alert, handshake, application data, heartbeat.
    if !(0x14..=0x18).contains(&header[0]) || header[1] != 0x03 || len > TLS_MAX_BODY {
        return Err(ReadError::Record(header));
    }
    let mut bytes = vec![0u8; TLS_HEADER + len];
    bytes[..TLS_HEADER].copy_from_slice(&header);
    read_exact(from, &mut bytes[TLS_HEADER..], TLS_HEADER).await?;
    Ok(bytes)
}

async fn read_exact<R: AsyncRead + Unpin>(
    from: &mut BufReader<R>,
    buf: &mut [u8],
    already: usize,
) -> Result<(), ReadError> {
    let mut got = 0;
    while got < buf.len() {
        match from.read(&mut buf[got..]).await {
            Ok(0) => return Err(ReadError::Truncated(already + got)),
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(ReadError::Io(e)),
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndr_core::wire::MAX_FRAME_LEN;

    #[test]
    fn a_tls_record_is_never_taken_for_a_frame_nor_a_frame_for_one() {
        for minor in 1..=4 {
            let head = [0x16, 0x03, minor, 0x00];
            assert!(is_tls(&head));
            assert!(wire::frame_len(&head).is_err());
        }
        for len in PREFIX_LEN..=MAX_FRAME_LEN {
            let prefix = u32::try_from(len).unwrap().to_le_bytes();
            assert!(!is_tls(&prefix), "{len}");
        }
    }

    fn reset(dir: Direction) -> ConnectionEnd {
        ConnectionEnd::Io {
            dir,
            error: "read: connection reset".into(),
        }
    }

    #[tokio::test(start_paused = true)]
    async fn once_a_side_has_failed_the_rest_has_a_bounded_time_to_finish() {
        let started = TokioInstant::now();
        let failed = async { Err(reset(Direction::Backward)) };
        let end = ends(std::future::pending(), failed).await;
        assert_eq!(end, reset(Direction::Backward));
        assert_eq!(started.elapsed(), DRAIN_AFTER_FAILURE);

        // A cut does not wait at all.
        let started = TokioInstant::now();
        let cut = async {
            Err(ConnectionEnd::Framing {
                dir: Direction::Forward,
                error: WireError::LengthOutOfRange(u32::MAX),
            })
        };
        let end = ends(cut, std::future::pending()).await;
        assert!(matches!(end, ConnectionEnd::Framing { .. }), "{end:?}");
        assert_eq!(started.elapsed(), std::time::Duration::ZERO);

        // A side that finished cleanly leaves the other all the time it
        // needs, and the other's failure is the end.
        let started = TokioInstant::now();
        let slow = async {
            tokio::time::sleep(2 * DRAIN_AFTER_FAILURE).await;
            Err(reset(Direction::Forward))
        };
        let end = ends(slow, async { Ok(()) }).await;
        assert_eq!(end, reset(Direction::Forward));
        assert_eq!(started.elapsed(), 2 * DRAIN_AFTER_FAILURE);
    }

    #[tokio::test]
    async fn records_are_read_whole_and_a_bad_header_is_refused() {
        let mut stream = vec![0x16, 0x03, 0x01, 0x00, 0x02, 0xaa, 0xbb];
        stream.extend([0x17, 0x03, 0x03, 0x00, 0x01, 0xcc]);
        stream.extend([0x42, 0x03, 0x03, 0x00, 0x01, 0xdd]);
        let mut from = BufReader::new(&stream[..]);
        let mut format = None;
        let first = read_unit(&mut from, &mut format).await.ok().flatten();
        assert_eq!(first.as_deref(), Some(&stream[..7]));
        let second = read_unit(&mut from, &mut format).await.ok().flatten();
        assert_eq!(second.as_deref(), Some(&stream[7..13]));
        assert!(matches!(
            read_unit(&mut from, &mut format).await,
            Err(ReadError::Record([0x42, ..]))
        ));
    }
}
