//! A base that waits for its remote and reconnects after losing it
//! ([`LinkConfig::wait_for_remote`], [`LinkConfig::reconnect`]): which
//! failures are worth another attempt, the attempts themselves, and the
//! thread that makes them while a link is down. What the application sees
//! across sessions is the core's ([`Sessions`]).

use std::io;
use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, TryRecvError};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr_core::endpoint::LinkError;
use ndr_core::reconnect::Sessions;
use ndr_core::time::{Duration, Instant};
use ndr_core::wire::CloseReason;
use tokio::sync::Notify;

use crate::config::{LinkConfig, Rejoin};
use crate::error::NetError;
use crate::hub::{Hub, Shared};
use crate::link::Link;
use crate::pool::HubChoice;
use crate::tls::HandshakeError;
use crate::transport::Transport;

/// Whether a failed attempt to reach the remote may succeed later: nothing
/// listens yet, the host or the network cannot be reached yet, no answer
/// came, or the remote still serves the base's previous session.
pub(crate) fn waitable(e: &NetError) -> bool {
    match e {
        NetError::Io(e) => matches!(
            e.kind(),
            io::ErrorKind::ConnectionRefused
                | io::ErrorKind::ConnectionReset
                | io::ErrorKind::ConnectionAborted
                | io::ErrorKind::HostUnreachable
                | io::ErrorKind::NetworkUnreachable
                | io::ErrorKind::TimedOut
                | io::ErrorKind::NotConnected
                | io::ErrorKind::UnexpectedEof
        ),
        NetError::Handshake(HandshakeError::Timeout(_)) | NetError::Timeout => true,
        NetError::Link(e) => recoverable(e),
        _ => false,
    }
}

/// Whether a link that ended with `e` lost its peer (and may find it
/// again), rather than being refused or closed by this side.
pub(crate) fn recoverable(e: &LinkError) -> bool {
    match e {
        LinkError::Disconnected
        | LinkError::PeerSilent { .. }
        | LinkError::Timeout
        | LinkError::Wire(_) => true,
        LinkError::PeerClosed { reason } => matches!(
            *reason,
            CloseReason::Normal
                | CloseReason::Timeout
                | CloseReason::Application
                | CloseReason::Busy
                | CloseReason::Evicted
                | CloseReason::EvictedSource
        ),
        _ => false,
    }
}

/// The least time worth another attempt.
const MIN_ATTEMPT: StdDuration = StdDuration::from_millis(50);

/// The longest one attempt waits for an answer that does not come (a QUIC
/// handshake to a port nobody listens on gets none): 1 s, doubling with
/// the attempts to 8 s, at most the time left.
fn attempt_limit(attempt: u32, left: Option<StdDuration>) -> StdDuration {
    let grown = StdDuration::from_secs(1 << attempt.min(3));
    left.map_or(grown, |l| l.min(grown))
}

/// Connects as [`Link::connect`] does, trying again while the failure is
/// [`waitable`] and `wait` is not over (`None`: until `stop`). Returns the
/// link and how long it waited for the remote.
pub(crate) async fn dial_waiting(
    hub: &Hub,
    addr: SocketAddr,
    config: &LinkConfig,
    wait: Option<StdDuration>,
    stop: Option<&AtomicBool>,
) -> Result<(Link, StdDuration), NetError> {
    let start = StdInstant::now();
    let end = wait.map(|w| start + w);
    let quic = matches!(config.transport, Transport::Quic { .. });
    let mut attempt = 0_u32;
    loop {
        let began = StdInstant::now();
        let left = end.map(|e| e.saturating_duration_since(began));
        // A QUIC attempt to a port nobody listens on gets no answer at all:
        // it is cut short to try afresh once the remote is there. Any other
        // waits no longer than the handshake may take.
        let limit = if quic {
            attempt_limit(attempt, left)
        } else {
            let handshake: StdDuration = config.endpoint.handshake_timeout.into();
            left.map_or(handshake, |l| l.min(handshake))
        };
        let dialled = crate::connect::dial(hub, addr, config.clone());
        // One attempt, not waiting: the steps' own limits hold.
        let result = if wait == Some(StdDuration::ZERO) {
            dialled.await
        } else {
            match tokio::time::timeout(limit, dialled).await {
                Ok(r) => r,
                Err(_) => Err(NetError::Timeout),
            }
        };
        let e = match result {
            // The first attempt's own time is no wait.
            Ok(link) if attempt == 0 => return Ok((link, StdDuration::ZERO)),
            Ok(link) => return Ok((link, began - start)),
            Err(e) => e,
        };
        let left = end.map(|e| e.saturating_duration_since(StdInstant::now()));
        // Too little time left for another attempt: give up with this one's error.
        let spent = left.is_some_and(|l| l < MIN_ATTEMPT * 2);
        if !waitable(&e) || spent {
            return Err(e);
        }
        let pause: StdDuration = config.backoff.delay(attempt).into();
        let pause = left.map_or(pause, |l| pause.min(l - MIN_ATTEMPT));
        tracing::debug!("the remote at {addr} is not reached yet ({e}); trying again");
        attempt = attempt.saturating_add(1);
        let until = StdInstant::now() + pause;
        // In short steps, so that a link closed meanwhile stops trying.
        while StdInstant::now() < until {
            if stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
                return Err(NetError::Link(LinkError::Closed));
            }
            let step = until
                .saturating_duration_since(StdInstant::now())
                .min(StdDuration::from_millis(50));
            tokio::time::sleep(step).await;
        }
        if stop.is_some_and(|s| s.load(Ordering::Relaxed)) {
            return Err(NetError::Link(LinkError::Closed));
        }
    }
}

/// A new session, or why there will be none.
type Found = Result<Link, NetError>;

/// A reconnecting link's side of it, kept in its [`Link`].
pub(crate) struct Redial {
    addr: SocketAddr,
    /// The link's configuration, on its hub, taking over its handle.
    config: LinkConfig,
    pub(crate) sessions: Sessions,
    /// The attempts in flight while the link is down.
    search: Option<Search>,
    /// The current session's watchdog announced a loss, at this time (on
    /// the link's clock): the outage started then.
    pub(crate) silent_since: Option<Instant>,
    /// The last fresh release, on the link's clock.
    pub(crate) last_fresh: Option<Instant>,
}

/// The thread that looks for the remote while the link is down.
struct Search {
    found: Receiver<Found>,
    stop: Arc<AtomicBool>,
    notify: Arc<Notify>,
}

impl Drop for Search {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// What waiting for the new session gave.
pub(crate) enum Resumed {
    /// It is here.
    Link(Box<Link>),
    /// Not yet.
    NotYet,
    /// There will be none: the link ends with this.
    Failed(NetError),
}

impl Redial {
    /// The redial state of a link to `addr` made with `config`, driven by
    /// `hub`, its handle's state `shared`.
    pub(crate) fn new(
        addr: SocketAddr,
        mut config: LinkConfig,
        hub: &Hub,
        shared: &Arc<Shared>,
    ) -> Self {
        config.hub = HubChoice::Shared(hub.clone());
        config.rejoin = Rejoin {
            shared: Some(Arc::clone(shared)),
            ..Rejoin::default()
        };
        Redial {
            addr,
            config,
            sessions: Sessions::new(),
            search: None,
            silent_since: None,
            last_fresh: None,
        }
    }

    /// Keeps `handler` for the sessions to come; the one for this session.
    pub(crate) fn keep_handler(&mut self, handler: crate::hub::Handler) -> crate::hub::Handler {
        self.config.rejoin.handler = Some(Arc::new(std::sync::Mutex::new(handler)));
        self.config
            .rejoin
            .handler()
            .unwrap_or_else(|| Box::new(|_| {}))
    }

    /// Keeps `tap` for the sessions to come; the one for this session.
    pub(crate) fn keep_tap(&mut self, tap: crate::hub::Tap) -> crate::hub::Tap {
        self.config.rejoin.tap = Some(Arc::new(std::sync::Mutex::new(tap)));
        self.config.rejoin.tap().unwrap_or_else(|| Box::new(|_| {}))
    }

    /// Whether the link is down, a search running.
    pub(crate) fn down(&self) -> bool {
        self.search.is_some()
    }

    /// The link lost its peer at `now`: starts looking for it again. The
    /// outage started when the watchdog first saw the silence, if it did.
    /// Returns the silence to announce, `None` if the watchdog did.
    pub(crate) fn lost(&mut self, now: Instant, hub: &Hub) -> Result<Option<Duration>, NetError> {
        let announce = match self.silent_since {
            Some(_) => None,
            None => Some(self.last_fresh.map_or(Duration::ZERO, |f| now - f)),
        };
        let _ = self.sessions.lost(self.silent_since.unwrap_or(now));
        self.silent_since = None;
        let (tx, found) = mpsc::channel();
        let stop = Arc::new(AtomicBool::new(false));
        let notify = Arc::new(Notify::new());
        let (addr, config, hub) = (self.addr, self.config.clone(), hub.clone());
        let (stopped, woken) = (Arc::clone(&stop), Arc::clone(&notify));
        std::thread::Builder::new()
            .name("ndr-redial".into())
            .spawn(move || {
                let found = search(&hub, addr, &config, &stopped);
                if stopped.load(Ordering::Relaxed) {
                    // The link was closed meanwhile: a session found is
                    // dropped, which closes it.
                    return;
                }
                let _ = tx.send(found);
                woken.notify_one();
            })?;
        self.search = Some(Search {
            found,
            stop,
            notify,
        });
        Ok(announce)
    }

    /// Waits for the new session until `until` (`None`: as long as it
    /// takes; a time passed: not at all).
    pub(crate) fn resume(&mut self, until: Option<StdInstant>) -> Resumed {
        let Some(search) = &self.search else {
            return Resumed::NotYet;
        };
        let got = match until {
            None => search
                .found
                .recv()
                .map_err(|_| RecvTimeoutError::Disconnected),
            Some(u) => {
                let left = u.saturating_duration_since(StdInstant::now());
                if left.is_zero() {
                    search.found.try_recv().map_err(|e| match e {
                        TryRecvError::Empty => RecvTimeoutError::Timeout,
                        TryRecvError::Disconnected => RecvTimeoutError::Disconnected,
                    })
                } else {
                    search.found.recv_timeout(left)
                }
            }
        };
        match got {
            Ok(found) => {
                self.search = None;
                match found {
                    Ok(link) => {
                        let _ = self.sessions.resumed();
                        Resumed::Link(Box::new(link))
                    }
                    Err(e) => Resumed::Failed(e),
                }
            }
            Err(RecvTimeoutError::Timeout) => Resumed::NotYet,
            Err(RecvTimeoutError::Disconnected) => {
                self.search = None;
                Resumed::Failed(NetError::Io(io::Error::other(
                    "the thread that reconnects the link has stopped",
                )))
            }
        }
    }

    /// What wakes an async receiver when the new session is found.
    pub(crate) fn notify(&self) -> Option<Arc<Notify>> {
        self.search.as_ref().map(|s| Arc::clone(&s.notify))
    }

    /// Stops looking (the application closes the link).
    pub(crate) fn stop(&mut self) {
        self.search = None;
    }
}

/// Looks for the remote until it is reached, it refuses the link, or
/// `stop` is set.
fn search(hub: &Hub, addr: SocketAddr, config: &LinkConfig, stop: &AtomicBool) -> Found {
    let rt = crate::runtime::own_runtime()?;
    let found = rt.block_on(dial_waiting(hub, addr, config, None, Some(stop)));
    found.map(|(link, _)| link)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_remote_not_there_yet_is_waited_for_a_refusal_is_not() {
        let refused = NetError::Io(io::Error::from(io::ErrorKind::ConnectionRefused));
        assert!(waitable(&refused));
        assert!(waitable(&NetError::Link(LinkError::Disconnected)));
        let mismatch = NetError::Link(LinkError::PeerClosed {
            reason: CloseReason::PeriodMismatch,
        });
        assert!(!waitable(&mismatch));
        assert!(!waitable(&NetError::Link(LinkError::CertificateRefused)));
        assert!(recoverable(&LinkError::PeerClosed {
            reason: CloseReason::Normal
        }));
        assert!(!recoverable(&LinkError::Closed));
    }

    #[test]
    fn attempts_wait_longer_as_they_fail_within_the_time_left() {
        assert_eq!(attempt_limit(0, None), StdDuration::from_secs(1));
        assert_eq!(attempt_limit(9, None), StdDuration::from_secs(8));
        let left = Some(StdDuration::from_millis(300));
        assert_eq!(attempt_limit(2, left), StdDuration::from_millis(300));
    }
}
