//! The faults a base or a stranger brings on the remote over TCP and UDP:
//! garbage, an idle crowd, a hung base, a stale frame.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream as StdStream, UdpSocket};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::time::{Duration, Instant};
use ndr::core::wire::{self, CloseReason, Header, Hello, Message, Role};
use ndr::net::Deframer;

use super::link::{COMMAND_WIDTH, STATE_WIDTH};
use super::remote::Remote;

/// Idle connections held open on the remote during that fault.
const IDLE_CONNECTIONS: usize = 200;

/// The token a hung or stale-frame base gives in its Hello over datagrams
/// (any but 0: it sends no datagram).
pub(super) const FAKE_SESSION: u64 = 0x50a4_50a4_50a4_50a4;

/// Sends one kind of garbage to the remote; `true` if it cut the connection
/// off within a second.
pub(super) fn inject_garbage(addr: SocketAddr, kind: u64) -> bool {
    let Ok(mut s) = StdStream::connect_timeout(&addr, StdDuration::from_secs(1)) else {
        return false;
    };
    let mut bytes: Vec<u8> = match kind % 3 {
        // A random stream (a xorshift of the fault's index: reproducible).
        0 => {
            let mut x = 0x9E37_79B9_7F4A_7C15u64 ^ kind;
            (0..256)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    x as u8
                })
                .collect()
        }
        // A Hello-sized frame from another wire version.
        1 => {
            let mut f = vec![0u8; 64];
            f[..4].copy_from_slice(&64u32.to_le_bytes());
            f[4] = 99;
            f[5] = 2;
            f
        }
        // A length prefix no frame can have.
        _ => u32::MAX.to_le_bytes().to_vec(),
    };
    bytes.extend_from_slice(&[0u8; 64]);
    let _ = s.set_read_timeout(Some(StdDuration::from_secs(1)));
    if s.write_all(&bytes).is_err() {
        return true; // already cut off
    }
    let mut buf = [0u8; 512];
    let deadline = StdInstant::now() + StdDuration::from_secs(1);
    while StdInstant::now() < deadline {
        match s.read(&mut buf) {
            Ok(0) | Err(_) => return true,
            Ok(_) => {} // a Close frame, then the end
        }
    }
    false
}

/// Sends garbage datagrams to the remote's UDP port (its TCP listener's;
/// over QUIC, its QUIC port) from a stranger's socket: random bytes, an
/// empty datagram, a Hello, a Bundle cut short, one longer than any
/// Bundle, Bundles of commands with guessed session tokens (spoofs), and
/// two first packets of a QUIC client that are not. Then waits, a second
/// at most, for its listener to count them all as strays (over QUIC,
/// packets that no connection took and that opened none): (sent,
/// counted).
pub(super) fn garbage_datagrams(remote: &mut Remote, kind: u64) -> (u64, u64) {
    let Some(before) = remote.datagrams_stray() else {
        return (0, 0);
    };
    let mut x = 0x2545_F491_4F6C_DD1Du64 ^ kind;
    let mut next = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let spoof = |session: u64, seq: u64| {
        let header = Header::new(seq, Instant::ZERO + Duration::from_millis(seq));
        let command = [1.0; COMMAND_WIDTH as usize];
        let msg = Message::Bundle {
            session,
            repeat: 0,
            missed: 0,
            newest: &command,
            older: &[],
        };
        let mut buf = [0u8; wire::MAX_FRAME_LEN];
        let n = wire::encode(&header, &msg, &mut buf).unwrap_or(0);
        buf[..n].to_vec()
    };
    let mut all: Vec<Vec<u8>> = vec![
        (0..256).map(|_| next() as u8).collect(),
        Vec::new(),
        base_hello(Duration::from_millis(1), FAKE_SESSION),
        spoof(0, 1),
        spoof(1, 2),
        spoof(u64::MAX, 3),
        spoof(next(), 4),
        spoof(next(), 5),
    ];
    let bundle = spoof(next(), 6);
    all.push(bundle[..bundle.len().min(wire::HEADER_LEN + 4)].to_vec());
    let mut long = bundle;
    long.resize(5000, 0xA5);
    all.push(long);
    // Two that a QUIC remote reads as QUIC (to a UDP one, strays as the
    // rest): a long header of a version no one speaks, as long as a client's
    // first packet, which quinn answers with a version negotiation; and a
    // version 1 Initial (a random connection id) whose 1182 bytes of
    // payload do not decrypt.
    for version in [0x0a1a_2a3au32, 1] {
        let mut d = vec![0xc3];
        d.extend(version.to_be_bytes());
        d.push(8);
        d.extend(next().to_be_bytes());
        d.extend([0, 0, 0x44, 0x9e]);
        d.extend((d.len()..1200).map(|_| next() as u8));
        all.push(d);
    }
    let Ok(socket) = UdpSocket::bind("127.0.0.1:0") else {
        return (0, 0);
    };
    let sent = all
        .iter()
        .filter(|d| socket.send_to(d, remote.addr).is_ok())
        .count() as u64;
    let deadline = StdInstant::now() + StdDuration::from_secs(1);
    let mut counted = 0;
    while StdInstant::now() < deadline {
        // Other strays may come too (a late datagram of a link that just
        // ended): the rise counts up to what was sent.
        counted = remote
            .datagrams_stray()
            .map_or(0, |n| n.saturating_sub(before).min(sent));
        if counted == sent {
            break;
        }
        std::thread::sleep(StdDuration::from_millis(5));
    }
    (sent, counted)
}

/// Opens [`IDLE_CONNECTIONS`] connections to the remote that send nothing,
/// from 25 addresses other than the base's (127.0.0.2 to .26: strangers
/// that fill the remote's pending handshakes); those that connected.
pub(super) fn idle_crowd(
    rt: &tokio::runtime::Runtime,
    addr: SocketAddr,
) -> Vec<tokio::net::TcpStream> {
    rt.block_on(async {
        let mut held = Vec::new();
        for i in 0..IDLE_CONNECTIONS {
            let Ok(socket) = tokio::net::TcpSocket::new_v4() else {
                break;
            };
            let host = 2 + u8::try_from(i % 25).unwrap_or(0);
            if socket.bind(([127, 0, 0, host], 0).into()).is_err() {
                break;
            }
            let connect = tokio::time::timeout(StdDuration::from_millis(200), socket.connect(addr));
            if let Ok(Ok(stream)) = connect.await {
                held.push(stream);
            }
        }
        held
    })
}

/// A base's Hello for the soak's link (its widths at `period`, the paper's
/// static mode, on datagrams if `session` is not 0), framed.
fn base_hello(period: Duration, session: u64) -> Vec<u8> {
    let header = Header::new(0, Instant::ZERO);
    let hello = Hello {
        seat: ndr_core::wire::Seat::Control,
        role: Role::Base,
        mode: wire::ModeCode::PaperStatic,
        underflow: wire::UnderflowCode::DropLate,
        command_width: COMMAND_WIDTH,
        state_width: STATE_WIDTH,
        period,
        layout: 0,
        session,
        regulation: ndr::core::wire::RegulationName::NONE,
    };
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let n = wire::encode(&header, &Message::Hello(hello), &mut buf).unwrap_or(0);
    buf[..n].to_vec()
}

/// Connects to the remote and completes the handshake as a base: the
/// stream, once the remote's Hello has come.
fn handshake(addr: SocketAddr, period: Duration, session: u64) -> Option<(StdStream, Deframer)> {
    let mut s = StdStream::connect_timeout(&addr, StdDuration::from_secs(1)).ok()?;
    s.write_all(&base_hello(period, session)).ok()?;
    let mut deframer = Deframer::new();
    let _ = s.set_read_timeout(Some(StdDuration::from_secs(2)));
    let mut buf = [0u8; 512];
    loop {
        match deframer.next_frame() {
            Ok(Some(f)) if matches!(f.payload(), wire::Payload::Hello(_)) => {
                return Some((s, deframer));
            }
            Ok(Some(_)) => {}
            Ok(None) => {
                let n = s.read(&mut buf).ok().filter(|&n| n > 0)?;
                if deframer.extend(&buf[..n]) < n {
                    return None;
                }
            }
            Err(_) => return None,
        }
    }
}

/// Reads until the remote ends the connection; the Close reason it sent,
/// if any, and `None` if it did not end it by `deadline`.
fn await_close(
    s: &mut StdStream,
    deframer: &mut Deframer,
    deadline: StdInstant,
) -> Option<Option<CloseReason>> {
    let mut buf = [0u8; 512];
    let mut reason = None;
    while StdInstant::now() < deadline {
        while let Ok(Some(f)) = deframer.next_frame() {
            if let wire::Payload::Close(c) = f.payload() {
                reason = Some(c.reason);
            }
        }
        let left = deadline.saturating_duration_since(StdInstant::now());
        let _ = s.set_read_timeout(Some(left.max(StdDuration::from_millis(1))));
        match s.read(&mut buf) {
            Ok(0) => return Some(reason),
            Ok(n) => {
                // Frames past a full deframer do not matter here: only the end does.
                let _ = deframer.extend(&buf[..n]);
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(_) => return Some(reason),
        }
    }
    None
}

/// A base that completes its handshake and then sends nothing (a hung
/// operator): `true` if the remote ended the connection within its
/// liveness time and 3 s.
pub(super) fn hung_base(
    addr: SocketAddr,
    period: Duration,
    session: u64,
    liveness: Duration,
) -> bool {
    let Some((mut s, mut deframer)) = handshake(addr, period, session) else {
        return false;
    };
    let deadline = StdInstant::now() + StdDuration::from(liveness) + StdDuration::from_secs(3);
    await_close(&mut s, &mut deframer, deadline).is_some()
}

/// A base that completes its handshake, sends a probe, then the same
/// probe again: `true` if the remote refused it with Close "frame out of
/// sequence" within a second.
pub(super) fn stale_frame(addr: SocketAddr, period: Duration, session: u64) -> bool {
    let Some((mut s, mut deframer)) = handshake(addr, period, session) else {
        return false;
    };
    let header = Header::new(0, Instant::ZERO + period);
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let Ok(n) = wire::encode(&header, &Message::Data(&[]), &mut buf) else {
        return false;
    };
    let probe = buf[..n].to_vec();
    if s.write_all(&probe)
        .and_then(|()| s.write_all(&probe))
        .is_err()
    {
        return false;
    }
    let deadline = StdInstant::now() + StdDuration::from_secs(1);
    await_close(&mut s, &mut deframer, deadline) == Some(Some(CloseReason::Sequence))
}
