//! The delay relay over real loopback TCP: delays, order, bad framing,
//! a refused upstream, a side that resets, and a relay killed mid-run.
//!
//! The machine may be loaded: timing assertions are bounds with margins,
//! never exact timings.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr_core::time::{Duration, Instant};
use ndr_core::wire::{self, Header, MAX_FRAME_LEN, Message, PREFIX_LEN};
use ndr_net::relay::{ConnectionEnd, Relay, RelayConfig, RelayEvent, RelayHandle, RelayStats};
use ndr_netem::{DelayModel, Trace};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;
use tokio::time::timeout;

const LOOPBACK: &str = "127.0.0.1:0";

fn ms(n: u64) -> StdDuration {
    StdDuration::from_millis(n)
}

/// A Data frame whose channels make its bytes depend on `seq`.
fn data_frame(seq: u64) -> Vec<u8> {
    let header = Header {
        term: 0,
        seq,
        sent_at: Instant::from_millis(seq),
        echo: None,
        released: None,
    };
    let values = [seq as f64, -0.5 * seq as f64, 1.0 / (seq as f64 + 1.0)];
    let mut buf = vec![0; MAX_FRAME_LEN];
    let n = wire::encode(&header, &Message::Data(&values), &mut buf).expect("valid frame");
    buf.truncate(n);
    buf
}

fn seq_of(frame: &[u8]) -> u64 {
    wire::Frame::new_checked(frame).expect("valid frame").seq()
}

/// The next whole frame, `None` at end of stream (or a reset).
async fn read_frame<R: AsyncRead + Unpin>(r: &mut R) -> Option<Vec<u8>> {
    let mut prefix = [0u8; PREFIX_LEN];
    r.read_exact(&mut prefix).await.ok()?;
    let len = wire::frame_len(&prefix).ok()??;
    let mut frame = vec![0u8; len];
    frame[..PREFIX_LEN].copy_from_slice(&prefix);
    r.read_exact(&mut frame[PREFIX_LEN..]).await.ok()?;
    Some(frame)
}

/// An upstream that echoes every frame back and reports when each arrived.
async fn echo_server() -> (SocketAddr, mpsc::UnboundedReceiver<(u64, StdInstant)>) {
    let listener = TcpListener::bind(LOOPBACK).await.expect("bind echo");
    let addr = listener.local_addr().expect("echo address");
    let (tx, rx) = mpsc::unbounded_channel();
    tokio::spawn(async move {
        while let Ok((stream, _)) = listener.accept().await {
            let tx = tx.clone();
            tokio::spawn(async move {
                stream.set_nodelay(true).expect("nodelay");
                let (mut r, mut w) = stream.into_split();
                while let Some(frame) = read_frame(&mut r).await {
                    let _ = tx.send((seq_of(&frame), StdInstant::now()));
                    if w.write_all(&frame).await.is_err() {
                        break;
                    }
                }
            });
        }
    });
    (addr, rx)
}

async fn start(model: DelayModel, upstream: SocketAddr) -> RelayHandle {
    Relay::listen(LOOPBACK.parse().unwrap(), upstream, model, 7)
        .await
        .expect("bind relay")
        .spawn()
        .expect("spawn relay")
}

async fn connect(addr: SocketAddr) -> TcpStream {
    let stream = TcpStream::connect(addr).await.expect("connect to relay");
    stream.set_nodelay(true).expect("nodelay");
    stream
}

/// Waits (up to 1 s) until the relay's counters satisfy `ok`.
async fn stats_until(handle: &RelayHandle, ok: impl Fn(&RelayStats) -> bool) -> RelayStats {
    let deadline = StdInstant::now() + ms(1000);
    loop {
        let stats = handle.stats();
        if ok(&stats) || StdInstant::now() > deadline {
            return stats;
        }
        tokio::time::sleep(ms(5)).await;
    }
}

/// `true` once the peer has closed or reset: a read returns 0 or fails.
async fn sees_end(stream: &mut TcpStream) -> bool {
    let mut buf = [0u8; 4096];
    let deadline = tokio::time::Instant::now() + ms(1000);
    loop {
        match tokio::time::timeout_at(deadline, stream.read(&mut buf)).await {
            Err(_) => return false,
            Ok(Ok(0) | Err(_)) => return true,
            Ok(Ok(_)) => {} // echoes still in flight
        }
    }
}

/// Sends `n` frames every `gap`, half-closes, and reads until the end of
/// stream; returns the send times, the frames echoed back and when each came
/// back.
async fn exchange(
    relay: SocketAddr,
    n: u64,
    gap: StdDuration,
) -> (Vec<StdInstant>, Vec<(Vec<u8>, StdInstant)>) {
    let (mut r, mut w) = connect(relay).await.into_split();
    // Reads to the end of stream: the relay passes the client's half-close
    // on only after the frames in flight, and the echo server's close back.
    let reader = tokio::spawn(async move {
        let mut back = Vec::new();
        while let Some(frame) = read_frame(&mut r).await {
            back.push((frame, StdInstant::now()));
        }
        back
    });
    let mut sent = Vec::new();
    let mut tick = tokio::time::interval(gap);
    for seq in 0..n {
        tick.tick().await;
        sent.push(StdInstant::now());
        w.write_all(&data_frame(seq)).await.expect("send");
    }
    w.shutdown().await.expect("half-close");
    let back = timeout(ms(3000), reader)
        .await
        .expect("every echo within 3 s")
        .expect("reader task");
    (sent, back)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn constant_delays_each_way_and_bytes_unchanged() {
    let (upstream, mut arrivals) = echo_server().await;
    let model = DelayModel::Constant {
        fwd: Duration::from_millis(40),
        bwd: Duration::from_millis(60),
    };
    let relay = start(model, upstream).await;
    let n = 30;
    let (sent, back) = exchange(relay.local_addr(), n, ms(10)).await;

    // No frame comes early, whatever the host does; a paused host makes the
    // frames in flight late, so the delay the relay adds is judged on the
    // median, which a pause would have to span most of the run to move. A
    // relay that added each frame's delay to the last one's would put it
    // hundreds of milliseconds out. That each delay is the model's is the
    // sampler's and the in-order path's, tested in ndr-netem.
    assert_eq!(back.len() as u64, n);
    let mut rtts = Vec::new();
    for (seq, (frame, at)) in back.iter().enumerate() {
        assert_eq!(frame, &data_frame(seq as u64), "frame {seq} changed");
        let rtt = at.duration_since(sent[seq]);
        assert!(rtt >= ms(100), "frame {seq}: round trip {rtt:?}");
        rtts.push(rtt);
    }
    let mut fwds = Vec::new();
    for seq in 0..n {
        let (got, at) = arrivals.recv().await.expect("arrival at the echo server");
        assert_eq!(got, seq, "forward order");
        let fwd = at.duration_since(sent[seq as usize]);
        assert!(fwd >= ms(40), "frame {seq}: forward delay {fwd:?}");
        fwds.push(fwd);
    }
    let median = |mut v: Vec<StdDuration>| {
        v.sort();
        v[v.len() / 2]
    };
    let (rtt, fwd) = (median(rtts), median(fwds));
    assert!(rtt < ms(150), "median round trip {rtt:?}");
    assert!(fwd < ms(65), "median forward delay {fwd:?}");

    // Both ends closed after the last frame: the connection finished.
    let stats = stats_until(&relay, |s| s.finished == 1).await;
    assert_eq!((stats.connections, stats.finished, stats.active), (1, 1, 0));
    for dir in [stats.forward, stats.backward] {
        assert_eq!(dir.frames_received, n);
        assert_eq!(dir.frames_delivered, n);
        assert_eq!(
            dir.bytes_delivered,
            back.iter().map(|(f, _)| f.len() as u64).sum::<u64>()
        );
        assert_eq!(dir.held_back, 0);
    }
    let _ = relay.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn order_is_kept_when_delays_fall_faster_than_time() {
    // A sawtooth for 5 s: the forward delay falls by 40 ms every 20 ms
    // (later frames would overtake), then jumps back up every 100 ms.
    let mut csv = String::from("t_s,fwd_ms,bwd_ms\n");
    for k in 0..250 {
        csv += &format!("{},{},5\n", 0.02 * k as f64, 200 - 40 * (k % 5));
    }
    let model = DelayModel::Trace(Arc::new(Trace::parse(&csv).expect("trace")));
    let (upstream, _arrivals) = echo_server().await;
    let relay = start(model, upstream).await;
    let (_, back) = exchange(relay.local_addr(), 40, ms(5)).await;
    let seqs: Vec<u64> = back.iter().map(|(f, _)| seq_of(f)).collect();
    assert_eq!(seqs, (0..40).collect::<Vec<_>>());
    let stats = relay.shutdown().await;
    assert!(stats.forward.held_back > 0, "{stats:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn order_is_kept_under_lan_jitter() {
    let (upstream, _arrivals) = echo_server().await;
    let relay = start(DelayModel::Lan75km, upstream).await;
    // 1 ms apart: the 7–22 ms jitter would reorder them without the path.
    let (_, back) = exchange(relay.local_addr(), 200, ms(1)).await;
    let seqs: Vec<u64> = back.iter().map(|(f, _)| seq_of(f)).collect();
    assert_eq!(seqs, (0..200).collect::<Vec<_>>());
    let stats = relay.shutdown().await;
    assert!(
        stats.forward.held_back + stats.backward.held_back > 0,
        "{stats:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_absurd_length_prefix_cuts_only_that_connection() {
    let (upstream, _arrivals) = echo_server().await;
    let (relay, ends) = watched_relay(upstream, 5).await;

    let mut bad = connect(relay.local_addr()).await;
    bad.write_all(&data_frame(0)).await.expect("send");
    bad.write_all(&u32::MAX.to_le_bytes()).await.expect("send");
    bad.write_all(&[0xAB; 64]).await.expect("send");
    assert!(sees_end(&mut bad).await, "the bad client is cut within 1 s");
    let stats = stats_until(&relay, |s| s.framing_errors == 1).await;
    assert_eq!(stats.framing_errors, 1, "{stats:?}");
    assert_eq!(stats.active, 0, "{stats:?}");
    assert!(matches!(
        ends.lock().unwrap().as_slice(),
        [ConnectionEnd::Framing {
            error: wire::WireError::LengthOutOfRange(u32::MAX),
            ..
        }]
    ));

    // The next client is served as usual.
    let (_, back) = exchange(relay.local_addr(), 5, ms(2)).await;
    assert_eq!(back.len(), 5);
    let stats = relay.shutdown().await;
    assert_eq!(
        (stats.connections, stats.framing_errors),
        (2, 1),
        "{stats:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_refused_upstream_drops_the_client_and_the_relay_goes_on() {
    let closed = TcpListener::bind(LOOPBACK).await.expect("bind");
    let nowhere = closed.local_addr().expect("address");
    drop(closed);
    let relay = start(DelayModel::profile("constant:1").unwrap(), nowhere).await;
    for _ in 0..2 {
        let mut client = connect(relay.local_addr()).await;
        // The relay connects when the first frame is due.
        client.write_all(&data_frame(0)).await.expect("send");
        assert!(sees_end(&mut client).await, "dropped within 1 s");
    }
    let stats = stats_until(&relay, |s| s.upstream_failures == 2).await;
    assert_eq!(
        (stats.connections, stats.upstream_failures, stats.active),
        (2, 2, 0)
    );
    let _ = relay.shutdown().await;
}

/// When an upstream accepted a connection, and when its first frame came.
type Times = mpsc::UnboundedReceiver<StdInstant>;

/// An upstream that reports when it accepts each connection and when the
/// first frame of each comes.
async fn accept_times() -> (SocketAddr, Times, Times) {
    let listener = TcpListener::bind(LOOPBACK).await.expect("bind upstream");
    let addr = listener.local_addr().expect("upstream address");
    let (accepted_tx, accepted) = mpsc::unbounded_channel();
    let (first_tx, first) = mpsc::unbounded_channel();
    tokio::spawn(async move {
        while let Ok((mut stream, _)) = listener.accept().await {
            let _ = accepted_tx.send(StdInstant::now());
            let first_tx = first_tx.clone();
            tokio::spawn(async move {
                if read_frame(&mut stream).await.is_some() {
                    let _ = first_tx.send(StdInstant::now());
                }
            });
        }
    });
    (addr, accepted, first)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_upstream_is_connected_when_the_first_frame_is_due_or_after_a_silent_second() {
    let (upstream, mut seen, mut first_frames) = accept_times().await;
    let relay = start(DelayModel::profile("constant:300").unwrap(), upstream).await;
    // A client that speaks at once: its connection reaches the upstream
    // with its first frame, 300 ms later.
    let asked = StdInstant::now();
    let mut speaker = connect(relay.local_addr()).await;
    speaker.write_all(&data_frame(0)).await.expect("send");
    speaker.shutdown().await.expect("half-close");
    let accepted = timeout(ms(3000), seen.recv())
        .await
        .expect("connected upstream within 3 s")
        .expect("an upstream connection");
    assert!(
        accepted.duration_since(asked) >= ms(295),
        "{:?}",
        accepted.duration_since(asked)
    );
    let first = timeout(ms(3000), first_frames.recv())
        .await
        .expect("its first frame within 3 s")
        .expect("its first frame");
    assert!(
        first.duration_since(accepted) < ms(200),
        "{:?}",
        first.duration_since(accepted)
    );

    // A client that says nothing gets its upstream after a second (a
    // protocol whose server speaks first still works).
    let asked = StdInstant::now();
    let silent = connect(relay.local_addr()).await;
    let accepted = timeout(ms(5000), seen.recv())
        .await
        .expect("connected upstream within 5 s")
        .expect("an upstream connection");
    assert!(
        accepted.duration_since(asked) >= ms(990),
        "{:?}",
        accepted.duration_since(asked)
    );
    drop(silent);

    // One that leaves without a word never reaches the upstream, and ends
    // as finished.
    let quiet = connect(relay.local_addr()).await;
    drop(quiet);
    let stats = stats_until(&relay, |s| s.active == 0 && s.finished == 3).await;
    assert_eq!((stats.connections, stats.finished), (3, 3), "{stats:?}");
    assert!(seen.try_recv().is_err(), "no third upstream connection");
    let _ = relay.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shutdown_mid_run_closes_every_connection() {
    let (upstream, _arrivals) = echo_server().await;
    // Long delays: plenty of frames in flight when the relay is killed.
    let relay = start(DelayModel::profile("constant:300").unwrap(), upstream).await;
    let addr = relay.local_addr();
    let mut clients = Vec::new();
    for _ in 0..2 {
        let mut client = connect(addr).await;
        for seq in 0..10 {
            client.write_all(&data_frame(seq)).await.expect("send");
        }
        clients.push(client);
    }
    stats_until(&relay, |s| s.forward.frames_received == 20).await;

    let killed = StdInstant::now();
    let stats = timeout(ms(1000), relay.shutdown())
        .await
        .expect("shutdown within 1 s");
    for client in &mut clients {
        assert!(sees_end(client).await, "client cut within 1 s");
    }
    assert!(killed.elapsed() < ms(1000));
    assert_eq!(
        (stats.closed_by_shutdown, stats.active),
        (2, 0),
        "{stats:?}"
    );
    assert_eq!(stats.forward.frames_delivered, 0, "{stats:?}");
    // The listener is closed too.
    assert!(TcpStream::connect(addr).await.is_err(), "still listening");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_queue_over_its_bound_cuts_the_connection() {
    let (upstream, _arrivals) = echo_server().await;
    let mut config = RelayConfig::default();
    config.max_queue_frames = 4;
    let relay = Relay::listen(
        LOOPBACK.parse().unwrap(),
        upstream,
        DelayModel::profile("constant:1000").unwrap(),
        1,
    )
    .await
    .expect("bind relay")
    .with_config(config)
    .spawn()
    .expect("spawn relay");
    let mut client = connect(relay.local_addr()).await;
    for seq in 0..10 {
        // The relay may already have cut the connection.
        let _ = client.write_all(&data_frame(seq)).await;
    }
    assert!(sees_end(&mut client).await, "cut within 1 s");
    let stats = stats_until(&relay, |s| s.queue_overflows == 1).await;
    assert_eq!((stats.queue_overflows, stats.active), (1, 0), "{stats:?}");
    // 4 queued, maybe 1 more already taken by the writer, then 1 refused.
    let received = stats.forward.frames_received;
    assert!((5..=6).contains(&received), "{stats:?}");
    assert_eq!(stats.forward.frames_delivered, 0, "{stats:?}");
    let _ = relay.shutdown().await;
}

/// What a [`talker`] saw of one connection: the frames it read, then its
/// end (`None`).
type Heard = mpsc::UnboundedReceiver<Option<u64>>;

/// An upstream that sends a frame every millisecond from the moment it
/// accepts until a write fails (a remote streaming its states), and reports
/// each frame it reads and the end of its input.
async fn talker() -> (SocketAddr, Heard) {
    let listener = TcpListener::bind(LOOPBACK).await.expect("bind talker");
    let addr = listener.local_addr().expect("talker address");
    let (tx, rx) = mpsc::unbounded_channel();
    tokio::spawn(async move {
        let (stream, _) = listener.accept().await.expect("accept");
        stream.set_nodelay(true).expect("nodelay");
        let (mut r, mut w) = stream.into_split();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(ms(1));
            for seq in 1000.. {
                tick.tick().await;
                if w.write_all(&data_frame(seq)).await.is_err() {
                    break;
                }
            }
        });
        while let Some(frame) = read_frame(&mut r).await {
            let _ = tx.send(Some(seq_of(&frame)));
        }
        let _ = tx.send(None);
    });
    (addr, rx)
}

/// A relay with a constant delay of `delay_ms` each way whose connection
/// ends are collected.
async fn watched_relay(
    upstream: SocketAddr,
    delay_ms: u64,
) -> (RelayHandle, Arc<std::sync::Mutex<Vec<ConnectionEnd>>>) {
    let ends = Arc::new(std::sync::Mutex::new(Vec::new()));
    let seen = Arc::clone(&ends);
    let relay = Relay::listen(
        LOOPBACK.parse().unwrap(),
        upstream,
        DelayModel::profile(&format!("constant:{delay_ms}")).unwrap(),
        1,
    )
    .await
    .expect("bind relay")
    .on_event(move |event| {
        if let RelayEvent::Closed(summary) = event {
            seen.lock().unwrap().push(summary.end.clone());
        }
    })
    .spawn()
    .expect("spawn relay");
    (relay, ends)
}

/// Everything the talker reads until its input ends (within 3 s).
async fn heard_until_end(heard: &mut Heard) -> Vec<u64> {
    let mut seqs = Vec::new();
    loop {
        match timeout(ms(3000), heard.recv()).await {
            Ok(Some(Some(seq))) => seqs.push(seq),
            Ok(Some(None) | None) => return seqs,
            Err(_) => panic!("the talker's input did not end within 3 s: {seqs:?}"),
        }
    }
}

/// The talker heard the client's five frames and then its end, and the
/// relay counted one connection ended by a failed side; how it ended.
async fn delivered_then_ended(
    relay: &RelayHandle,
    heard: &mut Heard,
    ends: &std::sync::Mutex<Vec<ConnectionEnd>>,
) -> Vec<ConnectionEnd> {
    assert_eq!(heard_until_end(heard).await, [0, 1, 2, 3, 4]);
    let stats = stats_until(relay, |s| s.active == 0).await;
    assert_eq!((stats.io_errors, stats.active), (1, 0), "{stats:?}");
    assert_eq!(stats.forward.frames_delivered, 5, "{stats:?}");
    ends.lock().unwrap().clone()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_side_that_closes_while_the_other_still_sends_has_its_frames_delivered() {
    // The base's way out: its last frames (a Close), its end of stream, and
    // its socket dropped while the remote's states are still on their way;
    // they reach a closed socket, whose kernel answers with a reset, and
    // the relay's writes towards it fail while the last frames are in
    // flight the other way.
    let (upstream, mut heard) = talker().await;
    let (relay, ends) = watched_relay(upstream, 200).await;
    let mut client = connect(relay.local_addr()).await;
    // Before the first state comes back (200 ms): the close sends a FIN.
    tokio::time::sleep(ms(50)).await;
    for seq in 0..5 {
        client.write_all(&data_frame(seq)).await.expect("send");
    }
    client.shutdown().await.expect("half-close");
    drop(client);

    let ends = delivered_then_ended(&relay, &mut heard, &ends).await;
    assert!(
        matches!(
            ends.as_slice(),
            [ConnectionEnd::Io {
                dir: ndr_netem::Direction::Backward,
                ..
            }]
        ),
        "{ends:?}"
    );
    let _ = relay.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_side_that_resets_has_what_it_sent_before_delivered() {
    let (upstream, mut heard) = talker().await;
    let (relay, ends) = watched_relay(upstream, 100).await;
    let mut client = connect(relay.local_addr()).await;
    for seq in 0..5 {
        client.write_all(&data_frame(seq)).await.expect("send");
    }
    stats_until(&relay, |s| s.forward.frames_received == 5).await;
    // An abortive close: a reset, no end of stream.
    client.set_zero_linger().expect("SO_LINGER 0");
    drop(client);

    // The reset itself, or the writes towards the gone side, whichever the
    // relay met first.
    let ends = delivered_then_ended(&relay, &mut heard, &ends).await;
    assert!(
        matches!(ends.as_slice(), [ConnectionEnd::Io { .. }]),
        "{ends:?}"
    );
    let _ = relay.shutdown().await;
}

#[tokio::test]
async fn a_relay_off_loopback_needs_bind_insecure() {
    // The relay passes plain links through: off loopback it would put a
    // remote that trusts its loopback on the network.
    let any: SocketAddr = "0.0.0.0:0".parse().unwrap();
    let upstream: SocketAddr = "127.0.0.1:9".parse().unwrap();
    let e = Relay::listen(any, upstream, DelayModel::Lan75km, 1)
        .await
        .expect_err("refused off loopback");
    assert_eq!(e.kind(), std::io::ErrorKind::PermissionDenied);
    assert!(e.to_string().contains("insecure"), "{e}");
    let relay = Relay::listen_insecure(any, upstream, DelayModel::Lan75km, 1)
        .await
        .expect("bind_insecure listens anywhere");
    assert!(relay.local_addr().ip().is_unspecified());
    let lo: SocketAddr = "127.0.0.1:0".parse().unwrap();
    assert!(
        Relay::listen(lo, upstream, DelayModel::Lan75km, 1)
            .await
            .is_ok()
    );
}
