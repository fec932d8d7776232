//! The link over mutual TLS 1.3 on loopback: the same constant round trip
//! as the plain link, peers without a trusted certificate refused before
//! they become links, and plain links refused off loopback.

mod common;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration as StdDuration;

use ndr::core::endpoint::{Config, LinkError, Status};
use ndr::core::time::Duration;
use ndr::core::wire::Role;
use ndr::keygen::{self, KeyPair};
use ndr::net::{HandshakeError, Link, LinkConfig, Listener, NetError, TlsConfig};

fn config() -> LinkConfig {
    let mut c = Config::paper(Role::Base);
    c = c.with_width(2);
    c.period = Duration::from_millis(10);
    LinkConfig::new(c)
}

/// A fresh directory of throwaway certificates for one test.
fn certs(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("ndr-link-tls-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn pair_of(dir: &std::path::Path, name: &str) -> KeyPair {
    keygen::write(dir, name).unwrap()
}

/// `own` trusting `peer` by its certificate file.
fn tls(own: &KeyPair, peer: &KeyPair) -> TlsConfig {
    TlsConfig::from_files(&own.cert, &own.key, &peer.cert).unwrap()
}

fn loopback() -> SocketAddr {
    "127.0.0.1:0".parse().unwrap()
}

/// Three throwaway certificates and a TLS listener for the remote, which
/// trusts the base only.
struct Lab {
    dir: PathBuf,
    base: KeyPair,
    remote: KeyPair,
    other: KeyPair,
    rt: tokio::runtime::Runtime,
    listener: Listener,
    addr: SocketAddr,
}

fn lab(test: &str, handshake_timeout: Option<StdDuration>) -> Lab {
    let dir = certs(test);
    let (base, remote, other) = (
        pair_of(&dir, "base"),
        pair_of(&dir, "remote"),
        pair_of(&dir, "other"),
    );
    let rt = common::runtime();
    let mut remote_tls = tls(&remote, &base);
    if let Some(t) = handshake_timeout {
        remote_tls.handshake_timeout = t;
    }
    let listener = rt
        .block_on(Listener::listen(loopback(), config().with_tls(remote_tls)))
        .unwrap();
    let addr = listener.local_addr().unwrap();
    Lab {
        dir,
        base,
        remote,
        other,
        rt,
        listener,
        addr,
    }
}

impl Drop for Lab {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

#[test]
fn tls_on_loopback_delivers_every_sample_in_order_with_a_constant_grtt() {
    let _serial = common::serial();
    common::assert_regulated(|| {
        let Lab {
            base: b,
            remote: r,
            rt,
            listener,
            addr,
            ..
        } = &lab("grtt", None);
        let base_tls = tls(b, r);
        let (remote, base) = rt.block_on(async {
            tokio::join!(
                listener.accept(),
                Link::connect(*addr, config().with_tls(base_tls))
            )
        });
        // The echo is the command sent ns ticks before (checked by `drive_base`).
        let run = common::echo_run(base.unwrap(), remote.unwrap());
        assert_eq!(listener.stats().accepted, 1);
        run
    });
}

#[test]
fn peers_without_a_trusted_certificate_never_become_links() {
    let _serial = common::serial();
    let Lab {
        base: b,
        remote: r,
        other: stranger,
        rt,
        listener,
        addr,
        ..
    } = &lab("refused", None);
    let (addr, good) = (*addr, tls(b, r));
    rt.block_on(async {
        // One after the other: the stranger, the peer without a
        // certificate, a plain peer, then the good one.
        let accepting = listener.accept();
        let attempts = async {
            let unknown = Link::connect(addr, config().with_tls(tls(stranger, r))).await;
            let none =
                Link::connect(addr, config().with_tls(good.without_client_certificate())).await;
            let plain = Link::connect(addr, config()).await;
            let ok = Link::connect(addr, config().with_tls(good.clone())).await;
            (unknown, none, plain, ok)
        };
        let (accepted, (unknown, none, plain, ok)) = tokio::join!(accepting, attempts);
        // In TLS 1.3 the client finishes before the server has checked its
        // certificate: a refused client sees the server's alert at its first
        // read, not always at connect, and says what it means.
        for (name, attempt) in [("unknown", unknown), ("none", none)] {
            if let Ok(mut link) = attempt {
                let err = link.recv_timeout(StdDuration::from_secs(2)).unwrap_err();
                assert!(
                    matches!(err, NetError::Link(LinkError::CertificateRefused)),
                    "{name}: {err:?}"
                );
            }
        }
        // The plain peer's frames are not TLS: the listener refuses it with
        // an alert, which the plain peer reads as a frame and names.
        if let Ok(mut link) = plain {
            let err = link.recv_timeout(StdDuration::from_secs(2)).unwrap_err();
            assert!(err.to_string().contains("the peer speaks TLS"), "{err}");
        }
        let mut accepted = accepted.unwrap();
        let ok = ok.unwrap();
        let got = tokio::task::spawn_blocking(move || {
            ok.send(&[1.0, 2.0]).unwrap();
            accepted.send(&[3.0, 4.0]).unwrap();
            let s = accepted.recv_timeout(StdDuration::from_secs(3));
            (s.map(|s| s.values().to_vec()), ok, accepted)
        })
        .await
        .unwrap();
        assert!(got.0.is_ok(), "{:?}", got.0);
    });
    let stats = listener.stats();
    assert_eq!(stats.accepted, 1, "{stats:?}");
    assert_eq!(stats.refused_certificate, 1, "{stats:?}");
    assert_eq!(stats.refused_no_certificate, 1, "{stats:?}");
    assert_eq!(stats.refused_version, 1, "{stats:?}");
}

#[test]
fn a_pin_mismatch_is_refused_by_the_client() {
    let _serial = common::serial();
    let Lab {
        base: b,
        remote: r,
        other,
        rt,
        listener,
        addr,
        ..
    } = &lab("pin", None);
    let addr = *addr;
    // The base pins another certificate than the remote's.
    let wrong = TlsConfig::from_files_pinned(&b.cert, &b.key, vec![other.fingerprint]).unwrap();
    let right = TlsConfig::from_files_pinned(&b.cert, &b.key, vec![r.fingerprint]).unwrap();
    rt.block_on(async {
        let attempts = async {
            let wrong = Link::connect(addr, config().with_tls(wrong.clone())).await;
            let right = Link::connect(addr, config().with_tls(right.clone())).await;
            (wrong, right)
        };
        let (accepted, (wrong, right)) = tokio::join!(listener.accept(), attempts);
        match wrong {
            Err(NetError::Handshake(HandshakeError::UnknownCertificate(_))) => {}
            other => panic!("expected an unknown certificate, got {other:?}"),
        }
        assert!(right.is_ok() && accepted.is_ok());
    });
    // The remote saw the base's alert about its certificate.
    let stats = listener.stats();
    assert_eq!(stats.accepted, 1, "{stats:?}");
    assert_eq!(
        stats.refused_certificate + stats.failed_other,
        1,
        "{stats:?}"
    );
}

#[test]
fn plain_links_off_loopback_are_refused_unless_insecure() {
    let _serial = common::serial();
    let rt = common::runtime();
    // TEST-NET-1: never routed; the refusal must come before any connect.
    let far: SocketAddr = "192.0.2.1:9".parse().unwrap();
    let start = std::time::Instant::now();
    match rt.block_on(Link::connect(far, config())) {
        Err(e @ NetError::Insecure(_)) => {
            let text = e.to_string();
            assert!(
                text.contains("--insecure") && text.contains("TLS"),
                "{text}"
            );
        }
        other => panic!("expected the insecure refusal, got {other:?}"),
    }
    assert!(Matches::insecure(Link::connect_blocking(far, config())));
    assert!(start.elapsed() < StdDuration::from_millis(500));
    let any: SocketAddr = "0.0.0.0:0".parse().unwrap();
    assert!(Matches::insecure(
        rt.block_on(Listener::listen(any, config()))
    ));
    let mut insecure = config();
    insecure.insecure = true;
    let listener = rt.block_on(Listener::listen(any, insecure)).unwrap();
    let port = listener.local_addr().unwrap().port();
    assert_ne!(port, 0);
    // Loopback stays plain without asking.
    assert!(rt.block_on(Listener::listen(loopback(), config())).is_ok());
}

struct Matches;
impl Matches {
    fn insecure<T>(r: Result<T, NetError>) -> bool {
        matches!(r, Err(NetError::Insecure(_)))
    }
}

#[test]
fn keygen_writes_a_pair_whose_fingerprint_pins_it() {
    let _serial = common::serial();
    let dir = certs("keygen");
    let pair = pair_of(&dir, "lab");
    let text = std::fs::read_to_string(&pair.cert).unwrap();
    assert!(text.starts_with("-----BEGIN CERTIFICATE-----"));
    let config = TlsConfig::from_files(&pair.cert, &pair.key, &pair.cert).unwrap();
    assert_eq!(config.fingerprint(), pair.fingerprint);
    // A key is never overwritten.
    assert!(keygen::write(&dir, "lab").is_err());
    assert!(keygen::write(&dir, "../escape").is_err());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_silent_peer_times_out_and_the_next_one_is_served() {
    let _serial = common::serial();
    let Lab {
        base: b,
        remote: r,
        rt,
        listener,
        addr,
        ..
    } = &lab("timeout", Some(StdDuration::from_millis(200)));
    let (addr, good) = (*addr, tls(b, r));
    // Connects, says nothing, holds the socket open past the timeout.
    let silent = rt.block_on(tokio::net::TcpStream::connect(addr)).unwrap();
    let (accepted, ok) = rt.block_on(async {
        tokio::join!(
            listener.accept(),
            Link::connect(addr, config().with_tls(good))
        )
    });
    assert!(accepted.is_ok() && ok.is_ok());
    // Handshakes run side by side: the good peer did not wait for the
    // silent one, whose timeout comes later.
    let end = std::time::Instant::now() + StdDuration::from_secs(3);
    while listener.stats().timeouts == 0 && std::time::Instant::now() < end {
        std::thread::sleep(StdDuration::from_millis(20));
    }
    drop(silent);
    let stats = listener.stats();
    assert_eq!((stats.timeouts, stats.accepted), (1, 1), "{stats:?}");
}

#[test]
fn the_relay_delays_tls_records_in_order_and_the_link_stays_regulated() {
    use ndr::net::Relay;
    use ndr::sim::delay::DelayModel;

    let _serial = common::serial();
    let dir = certs("relay");
    let (b, r) = (pair_of(&dir, "base"), pair_of(&dir, "remote"));
    let rt = common::runtime();
    let model = DelayModel::Constant {
        fwd: Duration::from_millis(15),
        bwd: Duration::from_millis(15),
    };
    // One run, judged as every regulated link is (`common::judge_grtts`):
    // a host that holds a hub or the relay past the FIFO's slack makes its
    // delay step up a period, by design (an underflow or a missed tick,
    // counted).
    let base_tls = tls(&b, &r);
    let (mut base, mut remote, relay) = rt.block_on(async {
        let listener = Listener::listen(loopback(), config().with_tls(tls(&r, &b)))
            .await
            .unwrap();
        let relay = Relay::listen(loopback(), listener.local_addr().unwrap(), model.clone(), 1)
            .await
            .unwrap()
            .spawn()
            .unwrap();
        let (r, b) = tokio::join!(
            listener.accept(),
            Link::connect(relay.local_addr(), config().with_tls(base_tls))
        );
        (b.unwrap(), r.unwrap(), relay)
    });
    let robot = std::thread::spawn(move || {
        while let Ok(s) = remote.recv_timeout(StdDuration::from_secs(2)) {
            let _ = remote.send(s.values());
        }
        remote.stats()
    });
    let (mut seqs, mut grtts) = (Vec::new(), Vec::new());
    for k in 0..200 {
        base.send(&[f64::from(k), 0.0]).unwrap();
        let s = base.recv_timeout(StdDuration::from_secs(5)).unwrap();
        if s.status == Status::Fresh {
            seqs.push(s.seq);
            grtts.extend(s.grtt.map(|g| (s.released_at.as_nanos(), g.as_secs_f64())));
        }
    }
    let stats = base.close().unwrap();
    let remote_stats = robot.join().unwrap();
    let relayed = rt.block_on(relay.shutdown());
    assert!(seqs.len() > 150, "{}", seqs.len());
    // None twice or out of order, none missing but those a hub the host
    // held past its transmit queue dropped, and counted.
    let missing: u64 = seqs.windows(2).map(|w| w[1].saturating_sub(w[0] + 1)).sum();
    let dropped = remote_stats.as_ref().map_or(0, |s| s.endpoint.tx_dropped);
    assert!(
        seqs.windows(2).all(|w| w[1] > w[0]) && missing <= dropped,
        "repeat or {missing} missing, {dropped} counted: {seqs:?}"
    );
    // Records, not frames, went through, unchanged (else TLS would fail).
    assert_eq!(relayed.framing_errors, 0, "{relayed:?}");
    assert!(relayed.forward.frames_delivered > 150, "{relayed:?}");
    // The relay's 15 ms each way on every round trip; a host that held
    // one may lengthen it, not all.
    let nrtt = stats.endpoint.nrtt;
    assert!(nrtt.min() >= 0.030 && nrtt.min() < 0.045, "NRTT {nrtt:?}");
    let sides: Vec<&ndr::net::LinkStats> = std::iter::once(&stats).chain(&remote_stats).collect();
    let (_, std) = common::judge_grtts(&grtts, &sides);
    assert!(
        std <= 1e-3,
        "GRTT std {std}; base {stats:?}; remote {remote_stats:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn peers_trusted_through_a_ca_link_and_a_wrong_server_name_is_refused() {
    use rcgen::{BasicConstraints, CertificateParams, CertifiedIssuer, IsCa, KeyPair as Key};

    let _serial = common::serial();
    let dir = certs("ca");
    std::fs::create_dir_all(&dir).unwrap();
    let mut ca_params = CertificateParams::new(Vec::<String>::new()).unwrap();
    ca_params.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
    let ca = CertifiedIssuer::self_signed(ca_params, Key::generate().unwrap()).unwrap();
    std::fs::write(dir.join("ca.crt"), ca.pem()).unwrap();
    // A leaf signed by the CA, named `name`: its (cert, key) files.
    let leaf = |name: &str| {
        let key = Key::generate().unwrap();
        let cert = CertificateParams::new(vec![name.to_owned()])
            .unwrap()
            .signed_by(&key, &ca)
            .unwrap();
        let (c, k) = (
            dir.join(format!("{name}.crt")),
            dir.join(format!("{name}.key")),
        );
        std::fs::write(&c, cert.pem()).unwrap();
        std::fs::write(&k, key.serialize_pem()).unwrap();
        (c, k)
    };
    let ((rc, rk), (bc, bk)) = (leaf("ndr"), leaf("operator"));
    let ca_file = dir.join("ca.crt");
    let remote = TlsConfig::from_files_with_ca(&rc, &rk, &ca_file, "ndr").unwrap();
    let base = TlsConfig::from_files_with_ca(&bc, &bk, &ca_file, "ndr").unwrap();
    let misnamed = TlsConfig::from_files_with_ca(&bc, &bk, &ca_file, "robot").unwrap();
    let rt = common::runtime();
    rt.block_on(async {
        let listener = Listener::listen(loopback(), config().with_tls(remote.clone()))
            .await
            .unwrap();
        let addr = listener.local_addr().unwrap();
        let attempts = async {
            let misnamed = Link::connect(addr, config().with_tls(misnamed.clone())).await;
            let ok = Link::connect(addr, config().with_tls(base.clone())).await;
            (misnamed, ok)
        };
        let (accepted, (misnamed, ok)) = tokio::join!(listener.accept(), attempts);
        match misnamed {
            Err(NetError::Handshake(HandshakeError::UnknownCertificate(_))) => {}
            other => panic!("expected a refused server name, got {other:?}"),
        }
        assert!(accepted.is_ok() && ok.is_ok());
        assert_eq!(listener.stats().accepted, 1);
    });
    let _ = std::fs::remove_dir_all(&dir);
}
