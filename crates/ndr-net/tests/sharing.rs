//! A robot shared in real time: base A controls, an observer watches, base
//! B waits for control and gets it when A leaves. Margins are wide: what
//! is checked is order and fencing, not timing accuracy.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr_core::endpoint::{Config, Event, Status, Transport as Carriage};
use ndr_core::time::Duration;
use ndr_core::wire::{Role, Seat};
use ndr_net::{Link, LinkConfig, Listener, TlsConfig, Transport};

const PERIOD_MS: u64 = 10;

fn config(role: Role, seat: Seat, transport: Transport, tls: Option<&TlsConfig>) -> LinkConfig {
    let mut c = Config::new(role).with_width(1);
    c.period = Duration::from_millis(PERIOD_MS);
    c.seat = seat;
    if transport.datagrams() {
        c.transport = Carriage::DATAGRAM;
    }
    let mut lc = LinkConfig::new(c);
    lc.transport = transport;
    lc.admission.observers = Some(2);
    match tls {
        Some(tls) => lc.with_tls(tls.clone()),
        None => lc,
    }
}

/// What the robot applied: (the command, when).
type Applied = Arc<Mutex<Vec<(f64, StdInstant)>>>;

/// A robot serving every link it accepts, each on a thread: it applies
/// whatever a link releases (the endpoints have fenced it) and sends its
/// state, the last command, on every link. Its threads end with the test.
fn robot(listener: &Arc<Listener>, stop: &Arc<AtomicBool>) -> Applied {
    let applied: Applied = Arc::default();
    let state = Arc::new(Mutex::new(0.0));
    let (listener, stop, applied_) = (Arc::clone(listener), Arc::clone(stop), Arc::clone(&applied));
    thread::spawn(move || {
        while let Ok(mut link) = listener.accept_blocking() {
            let (applied, state, stop) =
                (Arc::clone(&applied_), Arc::clone(&state), Arc::clone(&stop));
            thread::spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    let now = *state.lock().unwrap();
                    if link.send(&[now]).is_err() {
                        return;
                    }
                    match link.recv_timeout(StdDuration::from_millis(PERIOD_MS / 2)) {
                        Ok(s) if s.status == Status::Fresh => {
                            let v = s.values()[0];
                            applied.lock().unwrap().push((v, StdInstant::now()));
                            *state.lock().unwrap() = v;
                        }
                        Ok(_) | Err(ndr_net::NetError::Timeout) => {}
                        Err(_) => return,
                    }
                }
            });
        }
    });
    applied
}

/// A base that sends `tag·1000 + k` at each release while it holds
/// control, for `run`; what it saw.
#[derive(Default)]
struct Seen {
    states: Vec<(u64, u16)>,
    granted: Vec<(u16, StdInstant)>,
    applied_terms: Vec<u16>,
    ended: Option<StdInstant>,
}

fn base(addr: SocketAddr, seat: Seat, at: &At, tag: f64, run: StdDuration) -> Seen {
    let config = config(
        Role::Base,
        seat,
        at.transport,
        at.tls.as_ref().map(|t| &t.1),
    );
    let mut link = Link::connect_blocking(addr, config).unwrap();
    let mut seen = Seen::default();
    let start = StdInstant::now();
    let mut k = 0.0;
    while start.elapsed() < run {
        match link.recv_timeout(StdDuration::from_millis(100)) {
            Ok(s) => {
                if s.status == Status::Fresh {
                    seen.states.push((s.seq, s.term));
                }
                k += 1.0;
                link.send(&[tag * 1000.0 + k]).unwrap();
            }
            Err(ndr_net::NetError::Timeout) => {}
            Err(e) => panic!("base {tag}: {e}"),
        }
        for e in link.drain_events() {
            match e {
                Event::ControlGranted { term } => seen.granted.push((term, StdInstant::now())),
                Event::Applied(a) => seen.applied_terms.push(a.term),
                _ => {}
            }
        }
    }
    let _ = link.close();
    seen.ended = Some(StdInstant::now());
    seen
}

/// How the bases reach the robot: the transport, and TLS (the remote's,
/// the bases').
#[derive(Clone)]
struct At {
    transport: Transport,
    tls: Option<(TlsConfig, TlsConfig)>,
}

fn hand_over(at: &At) {
    let remote = config(
        Role::Remote,
        Seat::Control,
        at.transport,
        at.tls.as_ref().map(|t| &t.0),
    );
    let listener = Listener::listen_blocking("127.0.0.1:0".parse().unwrap(), remote)
        .unwrap()
        .with_max_links(1);
    let addr = listener.local_addr().unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let listener = Arc::new(listener);
    let applied = robot(&listener, &stop);

    let spawn = |seat, tag, secs| {
        let at = at.clone();
        thread::spawn(move || base(addr, seat, &at, tag, StdDuration::from_secs(secs)))
    };
    let a = spawn(Seat::Control, 1.0, 3);
    thread::sleep(StdDuration::from_millis(300));
    let o = spawn(Seat::Observe, 9.0, 6);
    let b = spawn(Seat::WaitForControl, 2.0, 5);
    let (a, o, b) = (a.join().unwrap(), o.join().unwrap(), b.join().unwrap());
    stop.store(true, Ordering::Relaxed);

    let a_end = a.ended.unwrap();
    assert_eq!(a.granted.first().map(|g| g.0), Some(1), "A held term 1");
    let (term, granted) = *b.granted.first().expect("B was granted control");
    assert_eq!(term, 2);
    // Within the time A's Close takes to arrive and the grant to go back.
    let after = granted.saturating_duration_since(a_end);
    assert!(after < StdDuration::from_millis(1500), "{after:?}");
    // The robot applied A's commands, then B's, never one of A's after.
    let applied = applied.lock().unwrap();
    let first_b = applied
        .iter()
        .position(|&(v, _)| v >= 2000.0)
        .expect("B commanded");
    assert!(first_b > 50, "A commanded first");
    // (A base's sample is zeros until its application sets one.)
    let odd =
        |r: std::ops::Range<f64>| move |&&(v, _): &&(f64, StdInstant)| v != 0.0 && !r.contains(&v);
    let a_odd: Vec<_> = applied[..first_b]
        .iter()
        .filter(odd(1000.0..2000.0))
        .collect();
    assert!(a_odd.is_empty(), "{a_odd:?}");
    let b_odd: Vec<_> = applied[first_b..]
        .iter()
        .filter(odd(2000.0..3000.0))
        .collect();
    assert!(b_odd.is_empty(), "{b_odd:?}");
    assert!(applied[first_b..].len() > 50);
    // The observer: states in order, both terms, the applied commands of
    // both; it never commanded.
    assert!(o.states.windows(2).all(|w| w[1].0 > w[0].0));
    assert!(o.states.iter().any(|s| s.1 == 1) && o.states.iter().any(|s| s.1 == 2));
    assert!(o.applied_terms.contains(&1) && o.applied_terms.contains(&2));
    assert!(applied.iter().all(|&(v, _)| v < 9000.0));
    let sharing = listener.sharing().expect("a shared robot");
    assert_eq!(sharing.floor.handovers, 1);
    assert!(sharing.floor.observers_max >= 2);
}

#[test]
fn control_passes_to_the_waiting_base_over_tcp() {
    hand_over(&At {
        transport: Transport::Tcp,
        tls: None,
    });
}

#[test]
fn control_passes_to_the_waiting_base_over_udp() {
    hand_over(&At {
        transport: Transport::UDP,
        tls: None,
    });
}

#[cfg(feature = "keygen")]
#[test]
fn control_passes_to_the_waiting_base_over_quic() {
    let dir = std::env::temp_dir().join(format!("ndr-sharing-{}", std::process::id()));
    let base = ndr_net::keygen::write(&dir, "base").expect("a certificate");
    let remote = ndr_net::keygen::write(&dir, "remote").expect("a certificate");
    let tls = |own: &ndr_net::keygen::KeyPair, peer: &ndr_net::keygen::KeyPair| {
        TlsConfig::from_files(&own.cert, &own.key, &peer.cert).expect("TLS")
    };
    hand_over(&At {
        transport: Transport::QUIC,
        tls: Some((tls(&remote, &base), tls(&base, &remote))),
    });
    let _ = std::fs::remove_dir_all(&dir);
}

/// Over QUIC with mutual TLS, the robot trusts a controller's identity and
/// an observer's: the observer's may watch, not take control.
#[cfg(feature = "keygen")]
#[test]
fn an_observers_identity_cannot_take_control() {
    use ndr_core::endpoint::LinkError;
    use ndr_core::wire::CloseReason;
    use ndr_net::{NetError, Trust};

    let dir = std::env::temp_dir().join(format!("ndr-sharing-id-{}", std::process::id()));
    let pair = |name| ndr_net::keygen::write(&dir, name).expect("a certificate");
    let (controller, watcher, remote) = (pair("controller"), pair("watcher"), pair("remote"));
    let tls = |own: &ndr_net::keygen::KeyPair, peer: &ndr_net::keygen::KeyPair| {
        TlsConfig::from_files(&own.cert, &own.key, &peer.cert).expect("TLS")
    };
    let robot_tls = tls(&remote, &controller)
        .with_observers(Trust::Pinned(vec![watcher.fingerprint]))
        .expect("observers' trust");
    let at = |tls| At {
        transport: Transport::QUIC,
        tls: Some((robot_tls.clone(), tls)),
    };
    let remote_config = config(
        Role::Remote,
        Seat::Control,
        Transport::QUIC,
        Some(&robot_tls),
    );
    let listener =
        Listener::listen_blocking("127.0.0.1:0".parse().unwrap(), remote_config).unwrap();
    let addr = listener.local_addr().unwrap();
    let listener = Arc::new(listener);
    let stop = Arc::new(AtomicBool::new(false));
    let applied = robot(&listener, &stop);

    // The watcher asks for control: refused, and told why.
    let watcher_at = at(tls(&watcher, &remote));
    let asks = config(
        Role::Base,
        Seat::Control,
        Transport::QUIC,
        watcher_at.tls.as_ref().map(|t| &t.1),
    );
    let mut link = Link::connect_blocking(addr, asks).expect("its handshake");
    let until = StdInstant::now() + StdDuration::from_secs(5);
    let refused = loop {
        match link.recv_timeout(StdDuration::from_millis(500)) {
            Ok(_) | Err(NetError::Timeout) => {
                assert!(
                    StdInstant::now() < until,
                    "the watcher was not refused control"
                );
            }
            Err(e) => break e,
        }
    };
    assert!(
        matches!(
            refused,
            NetError::Link(LinkError::PeerClosed {
                reason: CloseReason::ObserverOnly
            })
        ),
        "{refused}"
    );
    assert!(
        refused.to_string().contains("observers' allow-list"),
        "{refused}"
    );
    // The same identity observes; the controller's controls.
    let o = thread::spawn(move || {
        base(
            addr,
            Seat::Observe,
            &watcher_at,
            9.0,
            StdDuration::from_secs(2),
        )
    });
    let c_at = at(tls(&controller, &remote));
    let c = base(addr, Seat::Control, &c_at, 1.0, StdDuration::from_secs(2));
    let o = o.join().unwrap();
    stop.store(true, Ordering::Relaxed);
    assert_eq!(c.granted.first().map(|g| g.0), Some(1));
    assert!(o.granted.is_empty() && !o.states.is_empty());
    assert!(applied.lock().unwrap().iter().all(|&(v, _)| v < 2000.0));
    assert_eq!(listener.stats().refused_observer_only, 1);
    let _ = std::fs::remove_dir_all(&dir);
}
