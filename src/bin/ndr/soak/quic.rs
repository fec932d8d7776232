//! The soak over QUIC: its throwaway identities, and the QUIC forms of
//! the faults aimed at one base.

use std::collections::VecDeque;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::endpoint::LinkError;
use ndr::core::wire::CloseReason;
use ndr::net::{HandshakeError, Hub, Link, LinkConfig, NetError};

use super::check::{Conn, check, finish_conn};
use super::link::LIVENESS;
use super::report::SoakReport;
use crate::throwaway::Throwaway;

/// Over QUIC, how long after its first copy the stale-frame fault's path
/// sends each packet again.
const REPLAY_AFTER: StdDuration = StdDuration::from_millis(20);
/// Over QUIC, how long the stale-frame fault's base runs on its replaying
/// path, and the states it must release in that time at least.
const REPLAY_RUN: StdDuration = StdDuration::from_secs(1);
const REPLAY_MIN_STATES: u64 = 100;

/// What a soak over QUIC runs with: the throwaway identities (their
/// directory goes with this), the base's link configuration (`config`
/// with its TLS), the same for the faults' own bases, and a stranger's (a
/// certificate the remote does not pin; it pins the remote), and the
/// remote's options.
pub(super) struct Quic {
    _ids: Throwaway,
    pub(super) base: LinkConfig,
    pub(super) side: LinkConfig,
    pub(super) stranger: LinkConfig,
    pub(super) remote: Vec<String>,
}

impl Quic {
    pub(super) fn new(config: &LinkConfig) -> Result<Quic, String> {
        // The faults' own links share one hub for the whole soak: a hub
        // each (a thread each) would leave the process a little larger at
        // each fault (each new thread's malloc arena keeps what it freed),
        // which the memory check would take for the link's.
        let hub = Hub::new(config.spin_margin).map_err(|e| e.to_string())?;
        let made = (|| {
            let ids = Throwaway::new("soak-quic")?;
            let (base, _) = ids.pair()?;
            let base = config.clone().with_tls(base);
            let side = base.clone().on_hub(hub.clone());
            let stranger = Throwaway::tls(&ids.another("stranger")?, &ids.remote)?;
            let stranger = config.clone().with_tls(stranger).on_hub(hub);
            let path = |p: &std::path::Path| p.display().to_string();
            let remote = vec![
                "--cert".into(),
                path(&ids.remote.cert),
                "--key".into(),
                path(&ids.remote.key),
                "--pin".into(),
                ids.base.fingerprint.to_string(),
            ];
            Ok::<_, String>(Quic {
                _ids: ids,
                base,
                side,
                stranger,
                remote,
            })
        })();
        made.map_err(|e| format!("cannot make the soak's QUIC certificates: {e}"))
    }
}

/// Over QUIC, the garbage connection's form: a stranger (`config`), whose
/// certificate the remote does not pin (it pins the remote's), tries the
/// handshake; `true` if the remote refused it for its certificate.
pub(super) fn stranger_refused(
    rt: &tokio::runtime::Runtime,
    addr: SocketAddr,
    config: LinkConfig,
) -> bool {
    let attempt = rt.block_on(async {
        tokio::time::timeout(StdDuration::from_secs(1), Link::connect(addr, config)).await
    });
    matches!(
        attempt,
        Ok(Err(NetError::Handshake(
            HandshakeError::UnknownCertificate(_)
        )))
    )
}

/// A UDP path of its own from one base to the remote's QUIC port (the hung
/// and stale-frame faults over QUIC, whose bases are whole links: they
/// cannot go silent or send a frame twice inside QUIC's encryption, as
/// those faults' bases do on a TCP stream). It passes the base's datagrams
/// until [`cut`](Self::cut) (the remote's always come back), and if
/// `replay`, sends each again [`REPLAY_AFTER`] later.
struct SidePath {
    addr: SocketAddr,
    cut: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl SidePath {
    fn open(remote: SocketAddr, replay: bool) -> std::io::Result<SidePath> {
        let front = UdpSocket::bind("127.0.0.1:0")?;
        let up = UdpSocket::bind("127.0.0.1:0")?;
        up.connect(remote)?;
        front.set_read_timeout(Some(StdDuration::from_millis(2)))?;
        up.set_read_timeout(Some(StdDuration::from_millis(20)))?;
        let (back_front, back_up) = (front.try_clone()?, up.try_clone()?);
        let addr = front.local_addr()?;
        let cut = Arc::new(AtomicBool::new(false));
        let stop = Arc::new(AtomicBool::new(false));
        let base = Arc::new(Mutex::new(None::<SocketAddr>));
        let forward = {
            let (cut, stop, base) = (Arc::clone(&cut), Arc::clone(&stop), Arc::clone(&base));
            std::thread::spawn(move || {
                let mut buf = [0u8; 1 << 16];
                let mut stale: VecDeque<(StdInstant, Vec<u8>)> = VecDeque::new();
                while !stop.load(Ordering::Relaxed) {
                    let now = StdInstant::now();
                    while stale.front().is_some_and(|(at, _)| *at <= now) {
                        if let Some((_, d)) = stale.pop_front() {
                            let _ = up.send(&d);
                        }
                    }
                    let Ok((n, from)) = front.recv_from(&mut buf) else {
                        continue;
                    };
                    *base.lock().unwrap_or_else(PoisonError::into_inner) = Some(from);
                    if !cut.load(Ordering::Relaxed) {
                        let _ = up.send(&buf[..n]);
                        if replay {
                            stale.push_back((now + REPLAY_AFTER, buf[..n].to_vec()));
                        }
                    }
                }
            })
        };
        let backward = {
            let stop = Arc::clone(&stop);
            std::thread::spawn(move || {
                let mut buf = [0u8; 1 << 16];
                while !stop.load(Ordering::Relaxed) {
                    if let Ok(n) = back_up.recv(&mut buf)
                        && let Some(to) = *base.lock().unwrap_or_else(PoisonError::into_inner)
                    {
                        let _ = back_front.send_to(&buf[..n], to);
                    }
                }
            })
        };
        Ok(SidePath {
            addr,
            cut,
            stop,
            threads: vec![forward, backward],
        })
    }

    /// Passes nothing more from the base.
    fn cut(&self) {
        self.cut.store(true, Ordering::Relaxed);
    }
}

impl Drop for SidePath {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Over QUIC, a hung base: a base (`config`: the soak's, with its TLS) on
/// a [`SidePath`] completes its handshakes, then the path passes nothing
/// more of it. `true` if the remote ended it with Close "timeout" (its
/// liveness) within its liveness time and 3 s.
pub(super) fn quic_hung_base(
    rt: &tokio::runtime::Handle,
    remote: SocketAddr,
    config: LinkConfig,
) -> bool {
    let Ok(path) = SidePath::open(remote, false) else {
        return false;
    };
    let Ok(mut link) = rt.block_on(Link::connect(path.addr, config)) else {
        return false;
    };
    path.cut();
    let deadline = StdInstant::now() + StdDuration::from(LIVENESS) + StdDuration::from_secs(3);
    while StdInstant::now() < deadline {
        match link.recv_timeout(StdDuration::from_millis(100)) {
            Ok(_) | Err(NetError::Timeout) => {}
            Err(e) => {
                return matches!(
                    e,
                    NetError::Link(LinkError::PeerClosed {
                        reason: CloseReason::Timeout
                    })
                );
            }
        }
    }
    false
}

/// Over QUIC, the stale-frame fault: a stale frame is a replayed packet. A
/// base (`config`: the soak's, with its TLS) on a [`SidePath`] that sends
/// each of its packets again [`REPLAY_AFTER`] later runs for
/// [`REPLAY_RUN`], checked as the soak's link is. QUIC drops a replayed
/// packet (its packet number was seen); one that got through would be a
/// stale datagram, dropped whole by the endpoint. `true` if no replay
/// harmed the link: it stayed up, released [`REPLAY_MIN_STATES`] states
/// at least, none repeated, reordered or lost without a counter, and the
/// remote saw no command repeated or reordered. (Not that the remote
/// counted no stale datagram: over QUIC a few come now and then without
/// any replay, as the soak's own link counts at the base.)
pub(super) fn quic_replay(
    rt: &tokio::runtime::Handle,
    remote: SocketAddr,
    config: LinkConfig,
) -> bool {
    let Ok(path) = SidePath::open(remote, true) else {
        return false;
    };
    let Ok(mut link) = rt.block_on(Link::connect(path.addr, config)) else {
        return false;
    };
    let mut r = SoakReport::default();
    let mut conn = Conn::default();
    let mut command = 0.0;
    let until = StdInstant::now() + REPLAY_RUN;
    while StdInstant::now() < until {
        match link.recv_timeout(StdDuration::from_millis(100)) {
            Ok(s) => {
                check(&mut r, &mut conn, s.status, s.seq, s.values());
                command += 1.0;
                let _ = link.send(&[command, 0.0, 0.0, 0.0]);
            }
            Err(NetError::Timeout) => {}
            Err(_) => return false,
        }
    }
    finish_conn(&mut r, &conn, link.close());
    r.samples_released >= REPLAY_MIN_STATES
        && r.lost + r.duplicated + r.reordered + r.corrupted + r.remote_anomalies == 0
}
