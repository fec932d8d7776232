//! Strangers' QUIC handshakes, at a steady rate or in bursts: each from one
//! of several loopback addresses (127.0.0.x, distinct hosts to the
//! listener), with a
//! self-signed certificate nobody trusts, so that the listener runs the
//! whole TLS handshake (its key exchange and signature, the client's
//! certificate) and refuses it at the end. quinn-proto's client, driven
//! here on one thread of its own.

use std::collections::HashMap;
use std::net::{SocketAddr, UdpSocket};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use bytes::BytesMut;
use quinn_proto::{ClientConfig, Connection, ConnectionHandle, DatagramEvent, Endpoint};
use rustls::client::danger::{HandshakeSignatureValid, ServerCertVerified, ServerCertVerifier};
use rustls::pki_types::{CertificateDer, PrivateKeyDer, PrivatePkcs8KeyDer, ServerName, UnixTime};

/// A stranger's connection is dropped this long after it opened, whatever
/// became of it (a refused one is over within a few round trips).
const LIFETIME: Duration = Duration::from_secs(3);

/// When the strangers come.
#[derive(Clone, Copy, Debug)]
pub enum Schedule {
    /// `rate` handshakes a second, evenly spaced.
    Steady { rate: u32 },
    /// `count` bursts, `every` apart (the first at once), each of `size`
    /// handshakes whose first packets go back to back.
    Bursts {
        size: u32,
        every: Duration,
        count: u32,
    },
}

impl Schedule {
    /// Handshakes to open by `elapsed` since the start.
    fn due(&self, elapsed: Duration) -> u64 {
        match *self {
            Schedule::Steady { rate } => {
                (elapsed.as_secs_f64() * f64::from(rate)).floor() as u64 + 1
            }
            Schedule::Bursts { size, every, count } => {
                let bursts = (elapsed.as_secs_f64() / every.as_secs_f64()).floor() as u64 + 1;
                bursts.min(u64::from(count)) * u64::from(size)
            }
        }
    }
}

/// What the flood did.
#[derive(Clone, Copy, Debug, Default)]
pub struct Flooded {
    /// Handshakes opened.
    pub opened: u64,
}

/// A flood under way; stopped (and its thread joined) on drop.
pub struct Flood {
    stop: Arc<AtomicBool>,
    opened: Arc<AtomicU64>,
    thread: Option<JoinHandle<()>>,
}

impl Flood {
    /// Opens handshakes to `target` on `schedule`, round robin from
    /// `sources` addresses 127.0.0.2, 127.0.0.3, …
    pub fn start(target: SocketAddr, schedule: Schedule, sources: u8) -> Flood {
        let stop = Arc::new(AtomicBool::new(false));
        let opened = Arc::new(AtomicU64::new(0));
        let (s, o) = (Arc::clone(&stop), Arc::clone(&opened));
        let thread = std::thread::Builder::new()
            .name("flooder".into())
            .spawn(move || run(target, schedule, sources, &s, &o))
            .expect("the flooder's thread");
        Flood {
            stop,
            opened,
            thread: Some(thread),
        }
    }

    /// What it did so far.
    pub fn flooded(&self) -> Flooded {
        Flooded {
            opened: self.opened.load(Ordering::Relaxed),
        }
    }

    /// Stops it; what it did.
    pub fn stop(mut self) -> Flooded {
        self.halt();
        self.flooded()
    }

    fn halt(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for Flood {
    fn drop(&mut self) {
        self.halt();
    }
}

/// One source address: its socket, its QUIC endpoint, its connections.
struct Source {
    socket: UdpSocket,
    endpoint: Endpoint,
    conns: HashMap<ConnectionHandle, (Connection, Instant)>,
}

fn run(target: SocketAddr, schedule: Schedule, sources: u8, stop: &AtomicBool, opened: &AtomicU64) {
    let config = client_config();
    let mut all: Vec<Source> = (0..sources.max(1))
        .map(|i| {
            let ip = std::net::Ipv4Addr::new(127, 0, 0, 2 + i.min(250));
            let socket = UdpSocket::bind((ip, 0)).expect("a stranger's socket");
            socket.set_nonblocking(true).expect("non-blocking");
            Source {
                socket,
                endpoint: Endpoint::new(Default::default(), None, false, None),
                conns: HashMap::new(),
            }
        })
        .collect();
    let start = Instant::now();
    let mut k: u64 = 0;
    let mut buf = vec![0u8; 65_536];
    let mut out = Vec::with_capacity(2048);
    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        // Opened first, sent together below: a burst's first packets go
        // back to back.
        while k < schedule.due(now.duration_since(start)) {
            let i = (k % all.len() as u64) as usize;
            k += 1;
            let s = &mut all[i];
            if let Ok((h, conn)) = s.endpoint.connect(now, config.clone(), target, "ndr") {
                s.conns.insert(h, (conn, now));
                opened.fetch_add(1, Ordering::Relaxed);
            }
        }
        for s in &mut all {
            // What came back.
            while let Ok((n, from)) = s.socket.recv_from(&mut buf) {
                out.clear();
                let data = BytesMut::from(&buf[..n]);
                match s.endpoint.handle(now, from, None, None, data, &mut out) {
                    Some(DatagramEvent::ConnectionEvent(h, ev)) => {
                        if let Some((c, _)) = s.conns.get_mut(&h) {
                            c.handle_event(ev);
                        }
                    }
                    Some(DatagramEvent::Response(t)) => {
                        let _ = s.socket.send_to(&out[..t.size], t.destination);
                    }
                    Some(DatagramEvent::NewConnection(inc)) => s.endpoint.ignore(inc),
                    None => {}
                }
            }
            // Timers, packets out, and the end of each.
            let mut gone = Vec::new();
            for (&h, (c, since)) in &mut s.conns {
                if c.poll_timeout().is_some_and(|t| t <= now) {
                    c.handle_timeout(now);
                }
                while let Some(ev) = c.poll_endpoint_events() {
                    if let Some(back) = s.endpoint.handle_event(h, ev) {
                        c.handle_event(back);
                    }
                }
                // Its events say nothing the listener's counts do not.
                while c.poll().is_some() {}
                loop {
                    out.clear();
                    let Some(t) = c.poll_transmit(now, 1, &mut out) else {
                        break;
                    };
                    let _ = s.socket.send_to(&out[..t.size], t.destination);
                }
                if c.is_drained() || now.duration_since(*since) > LIFETIME {
                    gone.push(h);
                }
            }
            for h in gone {
                s.conns.remove(&h);
                let _ = s
                    .endpoint
                    .handle_event(h, quinn_proto::EndpointEvent::drained());
            }
        }
        std::thread::sleep(Duration::from_micros(500));
    }
}

/// A client that trusts any server and shows a certificate of its own
/// that no listener here trusts.
fn client_config() -> ClientConfig {
    let pair =
        rcgen::generate_simple_self_signed(vec!["stranger".to_owned()]).expect("a certificate");
    let cert = CertificateDer::from(pair.cert.der().to_vec());
    let key = PrivateKeyDer::Pkcs8(PrivatePkcs8KeyDer::from(pair.signing_key.serialize_der()));
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let mut tls = rustls::ClientConfig::builder_with_provider(Arc::clone(&provider))
        .with_protocol_versions(&[&rustls::version::TLS13])
        .expect("TLS 1.3")
        .dangerous()
        .with_custom_certificate_verifier(Arc::new(AnyServer(provider)))
        .with_client_auth_cert(vec![cert], key)
        .expect("a client certificate");
    tls.alpn_protocols = vec![ndr_net::quic::ALPN.to_vec()];
    let crypto = quinn_proto::crypto::rustls::QuicClientConfig::try_from(tls).expect("QUIC TLS");
    ClientConfig::new(Arc::new(crypto))
}

#[derive(Debug)]
struct AnyServer(Arc<rustls::crypto::CryptoProvider>);

impl ServerCertVerifier for AnyServer {
    fn verify_server_cert(
        &self,
        _: &CertificateDer<'_>,
        _: &[CertificateDer<'_>],
        _: &ServerName<'_>,
        _: &[u8],
        _: UnixTime,
    ) -> Result<ServerCertVerified, rustls::Error> {
        Ok(ServerCertVerified::assertion())
    }

    fn verify_tls12_signature(
        &self,
        _: &[u8],
        _: &CertificateDer<'_>,
        _: &rustls::DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        Ok(HandshakeSignatureValid::assertion())
    }

    fn verify_tls13_signature(
        &self,
        _: &[u8],
        _: &CertificateDer<'_>,
        _: &rustls::DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        Ok(HandshakeSignatureValid::assertion())
    }

    fn supported_verify_schemes(&self) -> Vec<rustls::SignatureScheme> {
        self.0.signature_verification_algorithms.supported_schemes()
    }
}
