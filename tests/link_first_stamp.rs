//! A base written from `docs/wire.md` alone, over a plain TCP socket, against
//! a real listener that has been up for a while: its clock starts at 0 just
//! before its Hello, so its first probe (the tick scheduled at its clock's
//! start, run once the remote's Hello has come) is stamped 0 and echoes
//! nothing. The remote serves it.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::sync::mpsc;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::endpoint::{Config, Status};
use ndr::core::time::{Duration, Instant};
use ndr::core::wire::{
    self, Control, ControlOp, Echo, Frame, Header, Hello, MAX_FRAME_LEN, Message, Payload, Role,
};
use ndr::net::{LinkConfig, Listener, NetError};

const PERIOD: Duration = Duration::from_millis(20);
/// Commands the base sends and the remote must release most of.
const COMMANDS: u64 = 100;
/// Ticks of commands after those, so that the last of them are released
/// before the base closes: 1 s, far more than any delay a loaded host adds.
const AFTER: u64 = 50;

/// A frame from the remote and when it was read, on the base's clock.
type Heard = (Vec<u8>, Instant);

/// Reads frames off `stream` until it ends, each stamped on the clock that
/// started at `origin`.
fn reader(mut stream: TcpStream, origin: StdInstant, out: mpsc::Sender<Heard>) {
    loop {
        let mut frame = vec![0; 4];
        if stream.read_exact(&mut frame).is_err() {
            return;
        }
        let Ok(Some(len)) = wire::frame_len(&frame) else {
            return;
        };
        frame.resize(len, 0);
        if stream.read_exact(&mut frame[4..]).is_err() {
            return;
        }
        if out
            .send((frame, Instant::from_std(origin, StdInstant::now())))
            .is_err()
        {
            return;
        }
    }
}

fn encode(header: &Header, msg: &Message<'_>) -> Vec<u8> {
    let mut buf = vec![0; MAX_FRAME_LEN];
    let n = wire::encode(header, msg, &mut buf).expect("a valid frame");
    buf.truncate(n);
    buf
}

/// The base: Hello, then a frame per tick on `k·T` of its clock, each
/// echoing the newest remote frame that had come by its stamp; RESUME after
/// 10 round trips, then `COMMANDS + AFTER` commands numbered from 1; Close.
fn hand_written_base(addr: std::net::SocketAddr) {
    let mut stream = TcpStream::connect(addr).expect("the listener accepts");
    stream.set_nodelay(true).expect("nodelay");
    let origin = StdInstant::now();
    let now = || Instant::from_std(origin, StdInstant::now());
    let (tx, rx) = mpsc::channel();
    let read_half = stream.try_clone().expect("a second handle");
    std::thread::spawn(move || reader(read_half, origin, tx));
    let hello = Hello {
        seat: ndr_core::wire::Seat::Control,
        role: Role::Base,
        mode: wire::ModeCode::PaperStatic,
        underflow: wire::UnderflowCode::Hold,
        command_width: 1,
        state_width: 1,
        period: PERIOD,
        layout: 0,
        session: 0,
        regulation: ndr::core::wire::RegulationName::NONE,
    };
    stream
        .write_all(&encode(&Header::new(0, now()), &Message::Hello(hello)))
        .expect("the Hello goes");
    // (remote stamp, arrival), newest last.
    let mut heard: Vec<(Instant, Instant)> = Vec::new();
    let echo_at = |heard: &[(Instant, Instant)], stamp: Instant| {
        heard
            .iter()
            .rev()
            .find(|&&(_, arrived)| arrived <= stamp)
            .map(|&(sent_at, arrived)| Echo {
                sent_at,
                hold: stamp - arrived,
            })
    };
    let (mut handshaken, mut nrtts, mut running) = (false, Vec::new(), false);
    let mut term = 0;
    let (mut seq, mut sent, mut newest_state) = (0u64, 0u64, None);
    for k in 0.. {
        let tick = Instant::ZERO + PERIOD * k;
        // What came before this tick (before the remote's Hello, whatever
        // the tick: its first ticks run late).
        loop {
            let wait = if handshaken {
                let left = tick.checked_duration_since(now());
                match left {
                    Some(d) if !d.is_zero() => StdDuration::from_nanos(d.as_nanos()),
                    _ => break,
                }
            } else {
                StdDuration::from_secs(5)
            };
            let (bytes, at) = match rx.recv_timeout(wait) {
                Ok(heard) => heard,
                Err(mpsc::RecvTimeoutError::Timeout) if handshaken => break,
                Err(e) => panic!("the remote said nothing: {e}"),
            };
            let frame = Frame::new_checked(&bytes[..]).expect("the remote sends valid frames");
            if let Some(echo) = frame.echo()
                && handshaken
                && !running
                && nrtts.len() < 10
            {
                nrtts.push((at - echo.sent_at).saturating_sub(echo.hold));
            }
            heard.push((frame.sent_at(), at));
            match frame.payload() {
                Payload::Hello(h) => {
                    assert_eq!(h.role, Role::Remote);
                    handshaken = true;
                    // The term its commands are applied in.
                    term = frame.term();
                }
                Payload::Data(values) if !values.is_empty() => newest_state = Some(frame.seq()),
                Payload::Close(c) => panic!("the remote closed the link: {c}"),
                _ => {}
            }
            if !running && nrtts.len() == 10 {
                let lo = nrtts.iter().min().expect("10 round trips").as_secs_f64();
                let hi = nrtts.iter().max().expect("10 round trips").as_secs_f64();
                let ns = 2 + (1.3 * (hi - lo) / PERIOD.as_secs_f64()) as u16;
                let stamp = now();
                let header = Header {
                    term: 0,
                    seq,
                    sent_at: stamp,
                    echo: echo_at(&heard, stamp),
                    released: None,
                };
                let resume = Control {
                    op: ControlOp::Resume,
                    ns,
                    period: PERIOD,
                };
                stream
                    .write_all(&encode(&header, &Message::Control(resume)))
                    .expect("RESUME goes");
                running = true;
            }
        }
        let header = Header {
            term,
            seq,
            sent_at: tick,
            echo: echo_at(&heard, tick),
            released: newest_state.filter(|_| running),
        };
        seq += 1;
        let frame = if running {
            sent += 1;
            encode(&header, &Message::Data(&[sent as f64]))
        } else {
            encode(&header, &Message::Data(&[]))
        };
        stream.write_all(&frame).expect("the remote is there");
        if sent == COMMANDS + AFTER {
            break;
        }
    }
    let close = wire::Close {
        reason: wire::CloseReason::Normal,
    };
    let _ = stream.write_all(&encode(&Header::new(seq, now()), &Message::Close(close)));
}

#[test]
fn a_base_whose_first_probe_is_stamped_0_is_served() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("a runtime");
    let mut config = Config::new(Role::Remote);
    config.period = PERIOD;
    let listener = rt
        .block_on(Listener::listen(
            "127.0.0.1:0".parse().expect("an address"),
            LinkConfig::new(config),
        ))
        .expect("a listener");
    let addr = listener.local_addr().expect("its address");
    // The remote's clock starts with its listener: it has been up 1.4 s
    // when the base, whose clock starts now, says Hello.
    std::thread::sleep(StdDuration::from_millis(1400));
    let base = std::thread::spawn(move || hand_written_base(addr));
    let mut link = rt
        .block_on(async {
            tokio::time::timeout(StdDuration::from_secs(5), listener.accept()).await
        })
        .expect("the base connects in time")
        .expect("the base is accepted");
    let mut released = std::collections::BTreeSet::new();
    let end = loop {
        match link.recv_timeout(StdDuration::from_secs(5)) {
            Ok(s) => {
                let value = s.values()[0];
                if s.status == Status::Fresh && (1.0..=COMMANDS as f64).contains(&value) {
                    released.insert(value as u64);
                }
                let _ = link.send(s.values());
            }
            Err(e) => break e,
        }
    };
    base.join().expect("the base ran to its end");
    assert!(
        matches!(
            end,
            NetError::Link(ndr::core::endpoint::LinkError::PeerClosed {
                reason: ndr::core::wire::CloseReason::Normal
            })
        ),
        "{end:?}"
    );
    assert!(
        released.len() as u64 >= COMMANDS * 9 / 10,
        "{} of {COMMANDS} commands released: {:?}",
        released.len(),
        link.stats()
    );
}
