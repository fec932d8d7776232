//! One connection's handshakes before it reaches the application: its
//! first message, TLS if the listener has it, then ndr's Hello, all within
//! the pre-authentication budget; then a seat and a place in the accept
//! queue, or a refusal as busy.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU8, AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr_core::endpoint::LinkError;
use ndr_core::time::Instant;
use ndr_core::wire::{self, Close, CloseReason, Header, Message, Role};
use tokio::net::TcpStream;
use tokio::runtime::Handle;
use tokio::sync::mpsc;
use tokio::time::Instant as TokioInstant;

use super::first::{self, Heard};
use super::quic_slots::Slot;
use super::{Common, Refusal};
use crate::link::Link;
use crate::tls::HandshakeError;

/// The stages of a handshake, in order.
pub(super) mod stage {
    use super::Heard;

    /// Accepted; the peer has sent nothing yet.
    pub(in crate::listener) const SILENT: u8 = 0;
    /// Part of its first message (TLS's ClientHello, or ndr's Hello).
    pub(in crate::listener) const SPEAKING: u8 = 1;
    /// All of its first message.
    pub(in crate::listener) const SPOKEN: u8 = 2;
    /// On the hub, past TLS if the listener has it: ndr's Hello exchange.
    pub(in crate::listener) const ON_HUB: u8 = 3;

    pub(in crate::listener) fn of(heard: Heard) -> u8 {
        match heard {
            Heard::Nothing => SILENT,
            Heard::Part(_) => SPEAKING,
            Heard::Whole => SPOKEN,
        }
    }
}

/// How far a handshake has got and when it last got further: told by its
/// task, read by the gate when it must evict.
pub(super) struct Progress {
    stage: AtomicU8,
    /// Bytes of the first message seen.
    bytes: AtomicUsize,
    /// When it last got further, in µs since `epoch`.
    moved: AtomicU64,
    epoch: StdInstant,
    /// Why the gate cut it short, if it did: set before its task is
    /// cancelled, so that the peer can be told.
    cut: Cut,
}

impl Progress {
    /// A handshake accepted at `now`, its peer having sent `heard`.
    pub(super) fn at(epoch: StdInstant, heard: Heard, now: StdInstant) -> Progress {
        let p = Progress {
            stage: AtomicU8::new(stage::of(heard)),
            bytes: AtomicUsize::new(0),
            moved: AtomicU64::new(0),
            epoch,
            cut: Cut::default(),
        };
        p.moved.store(p.micros(now), Ordering::Relaxed);
        p
    }

    fn micros(&self, at: StdInstant) -> u64 {
        u64::try_from(at.saturating_duration_since(self.epoch).as_micros()).unwrap_or(u64::MAX)
    }

    /// It reached `stage` with `bytes` of its first message seen.
    fn advance(&self, to: u8, bytes: usize) {
        self.advance_at(to, bytes, StdInstant::now());
    }

    /// [`advance`](Self::advance) at `now`.
    pub(super) fn advance_at(&self, to: u8, bytes: usize, now: StdInstant) {
        let (was, had) = (
            self.stage.fetch_max(to, Ordering::Relaxed),
            self.bytes.fetch_max(bytes, Ordering::Relaxed),
        );
        if to > was || bytes > had {
            self.moved.store(self.micros(now), Ordering::Relaxed);
        }
    }

    /// Its [`stage`].
    pub(super) fn stage(&self) -> u8 {
        self.stage.load(Ordering::Relaxed)
    }

    /// How long it has not got any further, at `now`.
    pub(super) fn stuck_for(&self, now: StdInstant) -> StdDuration {
        let moved = self.moved.load(Ordering::Relaxed);
        StdDuration::from_micros(self.micros(now).saturating_sub(moved))
    }

    /// Marks it cut short by the gate (`per_source`: for its source's cap).
    pub(super) fn cut(&self, per_source: bool) {
        self.cut.set(per_source);
    }
}

/// Why a handshake was cut short to make room, if it was: what its task
/// tells the peer as it ends.
#[derive(Default)]
pub(super) struct Cut(AtomicU8);

impl Cut {
    const NONE: u8 = 0;
    const SOURCE: u8 = 1;
    const FULL: u8 = 2;

    pub(super) fn set(&self, per_source: bool) {
        let why = if per_source { Cut::SOURCE } else { Cut::FULL };
        self.0.store(why, Ordering::Relaxed);
    }

    /// The error the link ends with (its Close reason the peer's).
    pub(super) fn error(&self) -> Option<LinkError> {
        match self.0.load(Ordering::Relaxed) {
            Cut::NONE => None,
            why => Some(LinkError::Evicted {
                per_source: why == Cut::SOURCE,
            }),
        }
    }
}

/// A plain connection before it reaches the hub: if its task is cancelled
/// because the gate cut it short, the peer gets a Close saying so rather
/// than a bare reset. (Under TLS nothing can be said before its handshake.)
struct Unheard<'a> {
    stream: Option<TcpStream>,
    cut: &'a Cut,
    tls: bool,
}

impl Drop for Unheard<'_> {
    fn drop(&mut self) {
        if let (Some(stream), Some(why), false) = (self.stream.take(), self.cut.error(), self.tls) {
            tell(stream, why.close_reason());
        }
    }
}

/// Writes a Close with `reason` on `stream` without waiting, having read
/// what the peer sent (closing with unread bytes would reset the
/// connection, and the peer could lose the Close with it).
pub(super) fn tell(stream: TcpStream, reason: CloseReason) {
    use std::io::{Read, Write};
    // Plain non-blocking calls: tokio's `try_` calls answer from readiness
    // it may not have seen yet.
    let Ok(mut stream) = stream.into_std() else {
        return;
    };
    let mut sink = [0u8; 512];
    // A few reads: a Hello is far shorter; a peer that sends more gets a
    // reset, as any.
    for _ in 0..4 {
        match stream.read(&mut sink) {
            Ok(n) if n > 0 => {}
            _ => break,
        }
    }
    let mut frame = [0u8; wire::MAX_FRAME_LEN];
    let header = Header::new(0, Instant::ZERO);
    if let Ok(n) = wire::encode(&header, &Message::Close(Close { reason }), &mut frame)
        && let Some(bytes) = frame.get(..n)
    {
        let _ = stream.write(bytes);
    }
}

/// A link whose handshake is under way: if its task is cancelled, the
/// link ends at once and its peer is told why: evicted if its slot went
/// to a newcomer (`cut` says so), else busy (the listener dropped).
struct Unfinished<'a> {
    link: Option<Link>,
    cut: &'a Cut,
}

impl Drop for Unfinished<'_> {
    fn drop(&mut self) {
        if let Some(link) = self.link.take() {
            link.dismiss(self.cut.error().unwrap_or(LinkError::Busy));
        }
    }
}

/// `future` within `deadline` (none: as long as it takes); `None` if the
/// deadline passed first.
async fn within<F: std::future::Future>(
    deadline: Option<TokioInstant>,
    future: F,
) -> Option<F::Output> {
    match deadline {
        Some(d) => tokio::time::timeout_at(d, future).await.ok(),
        None => Some(future.await),
    }
}

/// Why a handshake failed: the counter, and what the log says.
pub(super) type Failed = (Refusal, String);

/// One connection's handshakes, then its place in the accept queue.
pub(super) async fn handshake(
    common: Arc<Common>,
    stream: TcpStream,
    peer: SocketAddr,
    progress: Arc<Progress>,
    ready: mpsc::Sender<Link>,
) {
    match preauth(&common, stream, &progress).await {
        Ok(link) => enqueue(&common, link, peer, &ready),
        Err((why, what)) => common.refuse(why, peer, &what),
    }
}

/// TLS (if any) and ndr's Hello, within the pre-authentication budget,
/// telling `progress` how far it got.
async fn preauth(common: &Common, stream: TcpStream, progress: &Progress) -> Result<Link, Failed> {
    let tls = common.tls.is_some();
    let mut unheard = Unheard {
        stream: Some(stream),
        cut: &progress.cut,
        tls,
    };
    let budget: StdDuration = common.config.admission.preauth_timeout.into();
    let start = TokioInstant::now();
    let deadline = (!budget.is_zero()).then(|| start + budget);
    // TLS's own timeout bounds the wait for the ClientHello too.
    let tls_timeout = common.tls.as_ref().map(|t| t.handshake_timeout);
    let tls_first = tls_timeout.filter(|&t| deadline.is_none_or(|d| start + t < d));
    let speak_by = tls_first.map(|t| start + t).or(deadline);
    let late = || {
        (
            Refusal::Timeout,
            format!(
                "no handshake within {budget:?} (the pre-authentication budget, \
                 LinkConfig::admission.preauth_timeout)"
            ),
        )
    };
    let (role, hub) = common.setup();
    // The peer speaks first under TLS (its ClientHello) and on a plain link
    // to a remote (the base's Hello): until its first message is whole, its
    // connection stays off TLS and the hub (it costs a socket and a task).
    if (tls || role == Role::Remote)
        && let Some(stream) = unheard.stream.as_ref()
    {
        let told = |heard, bytes| progress.advance(stage::of(heard), bytes);
        match within(speak_by, first::wait_whole(stream, tls, told)).await {
            None => {
                return Err(match tls_first {
                    Some(t) => (Refusal::Timeout, HandshakeError::Timeout(t).to_string()),
                    None => late(),
                });
            }
            Some(Ok(false)) => {
                return Err((Refusal::Other, "it closed before its first message".into()));
            }
            Some(Ok(true)) => {}
            Some(Err(e)) => return Err((Refusal::Other, e.to_string())),
        }
    }
    let stream = unheard
        .stream
        .take()
        .ok_or_else(|| (Refusal::Other, "lost its connection".to_string()))?;
    let (stream, conn) = match &common.tls {
        None => (stream, None),
        Some(tls) => match within(deadline, tls.accept(stream)).await {
            None => return Err(late()),
            Some(Err(e)) => return Err((Refusal::of_tls(&e), e.to_string())),
            Some(Ok((stream, conn))) => (stream, Some(conn)),
        },
    };
    let chain: Option<Vec<_>> = conn
        .as_ref()
        .and_then(|c| c.peer_certificates())
        .map(|c| c.iter().map(|c| c.clone().into_owned()).collect());
    let link = Link::start(
        stream,
        role,
        common.config.clone(),
        Handle::current(),
        &hub,
        conn,
        crate::link::Listened {
            udp: common.udp.as_ref().map(|u| u.key),
            sharing: common.sharing_for(role),
        },
    )
    .map_err(|e| (Refusal::of_link(&e), e.to_string()))?;
    *link
        .shared()
        .peer_chain
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner) = chain;
    progress.advance(stage::ON_HUB, 0);
    hello(link, deadline, late, &progress.cut).await
}

/// A QUIC link its listener's hub accepted: its handshakes (QUIC's TLS,
/// then ndr's Hello, both on the hub) within the pre-authentication
/// budget, then its place in the accept queue; it holds `slot` until then,
/// unless a newcomer takes it first (the link then ends as busy).
pub(super) async fn quic(common: Arc<Common>, link: Link, slot: Slot, ready: mpsc::Sender<Link>) {
    let budget: StdDuration = common.config.admission.preauth_timeout.into();
    // QUIC's own handshake timeout is TLS's.
    let budget = match &common.tls {
        Some(tls) if budget.is_zero() || tls.handshake_timeout < budget => tls.handshake_timeout,
        _ => budget,
    };
    let deadline = (!budget.is_zero()).then(|| TokioInstant::now() + budget);
    let late = || {
        (
            Refusal::Timeout,
            format!(
                "no QUIC handshake within {budget:?} (the pre-authentication budget, \
                 LinkConfig::admission.preauth_timeout, or TlsConfig::handshake_timeout)"
            ),
        )
    };
    let peer = link.peer_addr();
    let cut = Cut::default();
    let outcome = tokio::select! {
        // The handshake first: once polled it owns the link, and dropping
        // it then ends the link as evicted instead of waiting on the hub.
        biased;
        outcome = hello(link, deadline, late, &cut) => Some(outcome),
        () = async {
            slot.cut().await;
            // Before the handshake is dropped: its link says why it ends.
            cut.set(false);
        } => None,
    };
    // Evicted (counted then): its link has been ended, or is now.
    let held = slot.release();
    match outcome {
        Some(Ok(mut link)) if held => {
            // Authenticated: to the hub that drives the listener's links,
            // away from strangers' handshakes.
            if !link.move_to(&common.live_hub()).await {
                tracing::debug!(%peer, "a QUIC link stays on its listener's hub");
            }
            enqueue(&common, link, peer, &ready);
        }
        Some(Ok(link)) => link.dismiss(LinkError::Evicted { per_source: false }),
        Some(Err((why, what))) if held => common.refuse(why, peer, &what),
        Some(Err(_)) | None => {}
    }
}

/// ndr's Hello on a link its hub drives, within `deadline`.
pub(super) async fn hello(
    link: Link,
    deadline: Option<TokioInstant>,
    late: impl Fn() -> Failed,
    cut: &Cut,
) -> Result<Link, Failed> {
    let mut unfinished = Unfinished {
        link: Some(link),
        cut,
    };
    let Some(link) = unfinished.link.as_mut() else {
        return Err((Refusal::Other, "lost its link".into()));
    };
    let outcome = within(deadline, link.handshake()).await;
    match outcome {
        None => {
            if let Some(link) = unfinished.link.take() {
                link.dismiss(LinkError::Timeout);
            }
            Err(late())
        }
        Some(Err(e)) => Err((Refusal::of_link(&e), e.to_string())),
        Some(Ok(())) => unfinished
            .link
            .take()
            .ok_or_else(|| (Refusal::Other, "lost its link".into())),
    }
}

/// A link whose handshake is done: to the accept queue if a seat is free
/// and the queue has room, else ended as busy.
pub(super) fn enqueue(
    common: &Common,
    mut link: Link,
    peer: SocketAddr,
    ready: &mpsc::Sender<Link>,
) {
    let asked = link.peer_seat();
    let may_control = match &common.tls {
        Some(tls) => {
            let chain = link
                .shared()
                .peer_chain
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
                .clone();
            chain.map_or(!tls.has_observers(), |c| tls.may_control(&c))
        }
        None => true,
    };
    if let (Some(s), Some(asked), Some(sharing)) = (link.sharing(), asked, &common.sharing) {
        match sharing.admit(
            s.key,
            Arc::clone(&s.address),
            (asked, s.offered),
            may_control,
        ) {
            Ok(observer) => s.observer = observer,
            Err(e) => {
                let why = Refusal::of_link(&crate::NetError::Link(e));
                link.dismiss(e);
                common.refuse(why, peer, &e);
                return;
            }
        }
    }
    // Observers take none of the links `with_max_links` counts.
    if link.is_observer() {
        queue(common, link, peer, ready);
        return;
    }
    let Some(seat) = common.seats.take(link.shared()) else {
        link.dismiss(LinkError::Busy);
        common.refuse(
            Refusal::Busy,
            peer,
            &"the listener serves as many links as it may (Listener::with_max_links): \
              the peer was told it is busy",
        );
        return;
    };
    link.hold(seat);
    queue(common, link, peer, ready);
}

/// To the accept queue if it has room, else ended as busy.
fn queue(common: &Common, link: Link, peer: SocketAddr, ready: &mpsc::Sender<Link>) {
    match ready.try_send(link) {
        Ok(()) => {}
        Err(mpsc::error::TrySendError::Full(link)) => {
            link.dismiss(LinkError::Busy);
            common.refuse(
                Refusal::Unclaimed,
                peer,
                &"the application did not take the links before it (the accept queue, \
                  LinkConfig::admission.accept_queue, is full): the peer was told it is busy",
            );
        }
        // The listener is gone.
        Err(mpsc::error::TrySendError::Closed(link)) => link.dismiss(LinkError::Closed),
    }
}
