//! Bad peers on a real listener: each is cut off with its own error and
//! counter, never reaches the application, and the listener goes on serving.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::Duration as StdDuration;

use ndr::core::endpoint::{Config, LinkError};
use ndr::core::time::{Duration, Instant};
use ndr::core::wire::{self, CloseReason, Header, Hello, MAX_FRAME_LEN, Message, Payload, Role};
use std::sync::Arc;

use ndr::net::{Link, LinkConfig, Listener, ListenerStats, NetError};

fn config() -> LinkConfig {
    let mut c = Config::paper(Role::Base);
    c = c.with_width(1);
    c.period = Duration::from_millis(10);
    LinkConfig::new(c)
}

/// What the remote side of each accepted link ended with, and the listener.
fn serve(
    rt: &tokio::runtime::Runtime,
    n: usize,
) -> (
    SocketAddr,
    std::sync::mpsc::Receiver<NetError>,
    Arc<Listener>,
) {
    let listener = Arc::new(
        rt.block_on(Listener::listen("127.0.0.1:0".parse().unwrap(), config()))
            .unwrap(),
    );
    let addr = listener.local_addr().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    let serving = Arc::clone(&listener);
    rt.spawn(async move {
        for _ in 0..n {
            let mut link = serving.accept().await.unwrap();
            let tx = tx.clone();
            std::thread::spawn(move || {
                let err = loop {
                    match link.recv_timeout(StdDuration::from_secs(5)) {
                        Ok(s) => {
                            let _ = link.send(s.values());
                        }
                        Err(e) => break e,
                    }
                };
                let _ = tx.send(err);
            });
        }
    });
    (addr, rx, listener)
}

/// Waits (3 s at most) until the listener's counter reaches `n`.
fn counted(listener: &Listener, counter: fn(&ListenerStats) -> u64, n: u64) {
    let end = std::time::Instant::now() + StdDuration::from_secs(3);
    while counter(&listener.stats()) < n {
        assert!(
            std::time::Instant::now() < end,
            "counter stuck: {:?}",
            listener.stats()
        );
        std::thread::sleep(StdDuration::from_millis(10));
    }
}

fn hello_bytes(version: u8) -> Vec<u8> {
    hello_from(version, Role::Base, 1)
}

fn hello_from(version: u8, role: Role, axes: u16) -> Vec<u8> {
    let header = Header::new(0, Instant::ZERO);
    let hello = Hello {
        seat: ndr_core::wire::Seat::Control,
        role,
        mode: wire::ModeCode::PaperStatic,
        underflow: wire::UnderflowCode::Hold,
        command_width: axes,
        state_width: axes,
        period: Duration::from_millis(10),
        layout: 0,
        session: 0,
        regulation: ndr::core::wire::RegulationName::NONE,
    };
    let mut buf = vec![0; MAX_FRAME_LEN];
    let n = wire::encode(&header, &Message::Hello(hello), &mut buf).unwrap();
    buf.truncate(n);
    buf[4] = version;
    buf
}

/// Sends `bytes`, then reads until the remote hangs up; returns what it sent back.
fn poke(addr: SocketAddr, bytes: &[u8]) -> Vec<u8> {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(StdDuration::from_secs(2))).unwrap();
    s.write_all(bytes).unwrap();
    let mut got = Vec::new();
    let _ = s.read_to_end(&mut got);
    got
}

/// The kinds of the frames in `bytes`, in order, and the reason of the
/// Close among them.
fn replies(mut bytes: &[u8]) -> (Vec<wire::Kind>, Option<CloseReason>) {
    let (mut kinds, mut reason) = (Vec::new(), None);
    while let Ok(Some(len)) = wire::frame_len(bytes) {
        let Some(frame) = bytes
            .get(..len)
            .and_then(|b| wire::Frame::new_checked(b).ok())
        else {
            break;
        };
        kinds.push(frame.kind());
        if let Payload::Close(c) = frame.payload() {
            reason = Some(c.reason);
        }
        bytes = &bytes[len..];
    }
    (kinds, reason)
}

fn close_reason_of(bytes: &[u8]) -> Option<CloseReason> {
    replies(bytes).1
}

#[test]
fn garbage_wrong_version_and_absurd_length_are_cut_off_and_the_listener_survives() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let (addr, errors, listener) = serve(&rt, 1);

    // Garbage: not even a plausible length prefix.
    let back = poke(addr, b"GET / HTTP/1.1\r\nHost: robot\r\n\r\n");
    assert_eq!(close_reason_of(&back), Some(CloseReason::ProtocolError));
    counted(&listener, |s| s.refused_protocol, 1);

    // An absurd length: refused before anything is buffered.
    let back = poke(addr, &u32::MAX.to_le_bytes());
    assert_eq!(close_reason_of(&back), Some(CloseReason::ProtocolError));
    counted(&listener, |s| s.refused_protocol, 2);

    // A Hello from a newer version of the protocol.
    let back = poke(addr, &hello_bytes(wire::VERSION + 1));
    assert_eq!(close_reason_of(&back), Some(CloseReason::VersionMismatch));
    counted(&listener, |s| s.refused_wire_version, 1);

    // A peer that claims the remote's role, and one with other axes.
    let back = poke(addr, &hello_from(wire::VERSION, Role::Remote, 1));
    assert_eq!(close_reason_of(&back), Some(CloseReason::RoleMismatch));
    counted(&listener, |s| s.refused_role, 1);
    let back = poke(addr, &hello_from(wire::VERSION, Role::Base, 3));
    // Its own Hello first, so that the base can name both widths.
    assert_eq!(
        replies(&back),
        (
            vec![wire::Kind::Hello, wire::Kind::Close],
            Some(CloseReason::WidthMismatch)
        )
    );
    counted(&listener, |s| s.refused_layout, 1);

    // None of them reached the application.
    assert_eq!(listener.stats().accepted, 0);
    assert!(errors.try_recv().is_err());

    // The listener still serves a real base.
    let mut base = rt.block_on(Link::connect(addr, config())).unwrap();
    for k in 0..30 {
        base.send(&[f64::from(k)]).unwrap();
        base.recv_timeout(StdDuration::from_secs(3)).unwrap();
    }
    drop(base);
    let e = errors.recv_timeout(StdDuration::from_secs(3)).unwrap();
    assert!(
        matches!(
            e,
            NetError::Link(LinkError::PeerClosed {
                reason: ndr::core::wire::CloseReason::Normal
            })
        ),
        "{e:?}"
    );
}

#[test]
fn a_peer_that_vanishes_is_reported_within_a_second() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let (addr, errors, _listener) = serve(&rt, 1);
    // A raw client that completes the handshake by hand, then drops the socket.
    let mut s = TcpStream::connect(addr).unwrap();
    s.write_all(&hello_bytes(wire::VERSION)).unwrap();
    std::thread::sleep(StdDuration::from_millis(200));
    let start = std::time::Instant::now();
    drop(s);
    let e = errors.recv_timeout(StdDuration::from_secs(3)).unwrap();
    assert!(start.elapsed() < StdDuration::from_secs(1));
    assert!(
        matches!(e, NetError::Link(LinkError::Disconnected)),
        "{e:?}"
    );
}

#[test]
fn silent_peers_of_one_source_are_capped_and_a_base_is_served_at_once() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let listener = rt
        .block_on(Listener::listen("127.0.0.1:0".parse().unwrap(), config()))
        .unwrap();
    let addr = listener.local_addr().unwrap();
    let cap = config().admission.max_pending_per_source as u64;
    // 70 silent peers from another address (another host): past its cap
    // of pending handshakes, the rest are refused at once, not queued
    // behind the first ones' timeouts.
    let silent = rt.block_on(async {
        let mut held = Vec::new();
        for _ in 0..70 {
            let socket = tokio::net::TcpSocket::new_v4().unwrap();
            socket.bind("127.0.0.2:0".parse().unwrap()).unwrap();
            // The listener may reset a refused one before its connect returns.
            if let Ok(stream) = socket.connect(addr).await {
                held.push(stream);
            }
        }
        held
    });
    counted(&listener, |s| s.refused_per_source, 70 - cap);
    // A base from its own address is served at once.
    let start = std::time::Instant::now();
    let accepted = rt.block_on(async {
        let mut base = Link::connect(addr, config()).await?;
        let accepted = tokio::time::timeout(StdDuration::from_secs(2), listener.accept())
            .await
            .map_err(|_| NetError::Timeout)??;
        base.handshake().await?;
        Ok::<_, NetError>(accepted)
    });
    let _accepted = accepted.unwrap_or_else(|e| panic!("{e:?} {:?}", listener.stats()));
    assert!(start.elapsed() < StdDuration::from_secs(2));
    assert_eq!(listener.stats().accepted, 1, "{:?}", listener.stats());
    assert_eq!(
        listener.stats().refused_per_source,
        70 - cap,
        "{:?}",
        listener.stats()
    );
    drop(silent);
}

#[test]
fn a_data_frame_with_more_channels_than_the_link_carries_ends_it_with_that_error() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let (addr, errors, listener) = serve(&rt, 2);
    // Past the handshake (one axis), a sample of 3 channels (caught by the
    // endpoint) and one of 200 (longer than any frame a link of at most
    // eight axes reads, caught by its deframer): the same error for both.
    for channels in [3, 200] {
        let mut s = TcpStream::connect(addr).unwrap();
        s.set_read_timeout(Some(StdDuration::from_secs(3))).unwrap();
        s.write_all(&hello_bytes(wire::VERSION)).unwrap();
        let header = Header::new(0, Instant::from_millis(1));
        let mut buf = vec![0; MAX_FRAME_LEN];
        let values = vec![0.5; channels];
        let n = wire::encode(&header, &Message::Data(&values), &mut buf).unwrap();
        std::thread::sleep(StdDuration::from_millis(100));
        s.write_all(&buf[..n]).unwrap();
        let e = errors.recv_timeout(StdDuration::from_secs(3)).unwrap();
        assert!(
            matches!(
                e,
                NetError::Link(LinkError::ChannelCount { expected: 1, got }) if got == channels
            ),
            "{channels}: {e:?}"
        );
        // Its last frame is a Close that says why.
        let mut back = Vec::new();
        let _ = s.read_to_end(&mut back);
        let mut last = &back[..];
        while let Ok(Some(len)) = wire::frame_len(last) {
            if len >= last.len() {
                break;
            }
            last = &last[len..];
        }
        assert_eq!(close_reason_of(last), Some(CloseReason::ProtocolError));
    }
    assert_eq!(listener.stats().accepted, 2);
}

/// How a base that ends in `end` is reported by the remote (`serve`).
fn remote_sees(end: impl FnOnce(Link) + Send + 'static) -> NetError {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let (addr, errors, _listener) = serve(&rt, 1);
    let mut base = rt.block_on(Link::connect(addr, config())).unwrap();
    // Running: a sample came back.
    base.send(&[1.0]).unwrap();
    base.recv_timeout(StdDuration::from_secs(5)).unwrap();
    end(base);
    errors.recv_timeout(StdDuration::from_secs(3)).unwrap()
}

#[test]
fn a_closed_link_is_a_normal_end_for_the_peer() {
    let e = remote_sees(|mut base| {
        base.shutdown();
        assert!(matches!(
            base.recv_timeout(StdDuration::from_secs(1)),
            Err(NetError::Link(LinkError::Closed))
        ));
        assert!(
            base.drain_events()
                .any(|e| matches!(e, ndr::core::endpoint::Event::Closed { error: None }))
        );
    });
    assert!(
        matches!(
            e,
            NetError::Link(LinkError::PeerClosed {
                reason: CloseReason::Normal
            })
        ),
        "{e:?}"
    );
}

#[test]
fn an_aborted_link_or_one_dropped_in_a_panic_is_an_application_failure_for_the_peer() {
    let application_failure = |e: &NetError| {
        matches!(
            e,
            NetError::Link(LinkError::PeerClosed {
                reason: CloseReason::Application
            })
        )
    };
    let e = remote_sees(|mut base| {
        base.abort();
        // This side then says how it ended, in its receive and its events.
        assert!(matches!(
            base.recv_timeout(StdDuration::from_secs(1)),
            Err(NetError::Link(LinkError::Abandoned))
        ));
        assert!(base.drain_events().any(|e| matches!(
            e,
            ndr::core::endpoint::Event::Closed {
                error: Some(LinkError::Abandoned)
            }
        )));
    });
    assert!(application_failure(&e), "{e:?}");
    let e = remote_sees(|base| {
        let panicked = std::thread::spawn(move || {
            let _owned = base;
            panic!("the operator's control loop failed (expected by the test)");
        })
        .join();
        assert!(panicked.is_err());
    });
    assert!(application_failure(&e), "{e:?}");
}
