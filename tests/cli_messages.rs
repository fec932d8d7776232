//! What `ndr base` and `ndr remote` say when a link ends or never comes up,
//! end to end: the cause and the fix, on the side that meets it. The
//! messages' words are checked where they are built (unit tests); these
//! runs check that each reaches the user in its case.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream, UdpSocket};
use std::path::PathBuf;
use std::time::Duration;

mod cli_proc;

use cli_proc::{Proc, serial};

/// `ndr remote` on a free loopback port, with `extra` arguments; its address.
fn remote(extra: &[&str]) -> (Proc, SocketAddr) {
    let mut args = vec!["remote", "--listen", "127.0.0.1:0", "--period-ms", "20"];
    args.extend_from_slice(extra);
    let mut remote = Proc::spawn(&args);
    let line = remote.line_with("waiting for a base on", Duration::from_secs(20));
    let at = line.find(" on ").unwrap() + 4;
    let addr = line[at..]
        .split_whitespace()
        .next()
        .unwrap()
        .parse()
        .unwrap();
    (remote, addr)
}

fn csv_path(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!(
        "ndr-cli-messages-{name}-{}.csv",
        std::process::id()
    ))
}

/// `ndr base --json` to `addr` for `seconds`, started: the process.
fn base(addr: SocketAddr, seconds: &str, name: &str, extra: &[&str]) -> Proc {
    let addr = addr.to_string();
    let csv = csv_path(name);
    let mut args = vec![
        "base",
        "--connect",
        &addr,
        "--duration-s",
        seconds,
        "--period-ms",
        "20",
        "--json",
        "--out",
        csv.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    Proc::spawn(&args)
}

/// The base's exit, its report's `end` and its stderr.
fn ended(base: Proc) -> (bool, String, String) {
    let (status, stdout, stderr) = base.wait(Duration::from_secs(60));
    let report: serde_json::Value = serde_json::from_str(&stdout)
        .unwrap_or_else(|e| panic!("no JSON report ({e}): {stdout:?}; stderr:\n{stderr}"));
    let end = report["end"].as_str().unwrap().to_string();
    (status.success(), end, stderr)
}

#[test]
fn a_remote_stopped_by_sigterm_ended_the_link_in_order() {
    let _serial = serial();
    let (mut remote, addr) = remote(&[]);
    let base = base(addr, "20", "sigterm", &[]);
    remote.line_with("handshake done", Duration::from_secs(20));
    remote.signal("TERM");
    let (ok, end, stderr) = ended(base);
    // The run was cut short (a non-zero status), but nothing failed.
    assert!(!ok, "{end}");
    assert!(
        end.starts_with("ended early: the peer ended the link in order"),
        "{end}\n{stderr}"
    );
    assert!(!end.contains("failed"), "{end}");
    let (status, _, stderr) = remote.wait(Duration::from_secs(20));
    assert!(status.success(), "{stderr}");
}

/// Forwards TCP from a port of its own to `to`, and drops every datagram
/// to that port: a firewall that lets TCP through and not UDP. Its port.
fn tcp_only_path(to: SocketAddr) -> SocketAddr {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let at = listener.local_addr().unwrap();
    // Bound so that the datagrams are taken (and dropped), not refused.
    let sink = UdpSocket::bind(at).unwrap();
    std::thread::spawn(move || {
        let mut buf = [0; 2048];
        while sink.recv(&mut buf).is_ok() {}
    });
    std::thread::spawn(move || {
        for inbound in listener.incoming() {
            let Ok(inbound) = inbound else { return };
            let Ok(outbound) = TcpStream::connect(to) else {
                return;
            };
            for (mut from, mut into) in [
                (inbound.try_clone().unwrap(), outbound.try_clone().unwrap()),
                (outbound, inbound),
            ] {
                std::thread::spawn(move || {
                    let mut buf = [0; 4096];
                    while let Ok(n @ 1..) = from.read(&mut buf) {
                        if into.write_all(&buf[..n]).is_err() {
                            break;
                        }
                    }
                    let _ = into.shutdown(std::net::Shutdown::Write);
                });
            }
        }
    });
    at
}

#[test]
fn a_udp_link_whose_datagrams_are_dropped_names_the_udp_port_on_both_sides() {
    let _serial = serial();
    let (remote, addr) = remote(&["--once", "--transport", "udp"]);
    let path = tcp_only_path(addr);
    let (ok, end, stderr) = ended(base(path, "2", "udp-dropped", &["--transport", "udp"]));
    assert!(!ok, "{end}");
    assert!(
        end.contains("no datagram came back over UDP")
            && end.contains(&format!("open UDP port {}", path.port())),
        "{end}\n{stderr}"
    );
    let (_, _, stderr) = remote.wait(Duration::from_secs(20));
    assert!(!stderr.contains(" connected"), "{stderr}");
    assert!(
        stderr.contains("never linked")
            && stderr.contains(&format!(
                "no datagram of the base reached UDP port {}",
                addr.port()
            )),
        "{stderr}"
    );
}

#[test]
fn a_tcp_base_refused_by_a_quic_remote_is_told_of_quic() {
    let _serial = serial();
    let dir = std::env::temp_dir().join(format!("ndr-cli-messages-keys-{}", std::process::id()));
    let keys = dir.to_str().unwrap();
    for name in ["base", "remote"] {
        let (status, _, stderr) =
            Proc::spawn(&["keygen", "--out", keys, "--name", name]).wait(Duration::from_secs(20));
        assert!(status.success(), "{stderr}");
    }
    let file = |name: &str| dir.join(name).to_str().unwrap().to_string();
    let (remote, addr) = remote(&[
        "--transport",
        "quic",
        "--cert",
        &file("remote.crt"),
        "--key",
        &file("remote.key"),
        "--peer-cert",
        &file("base.crt"),
    ]);
    let tls = [
        "--cert",
        &file("base.crt"),
        "--key",
        &file("base.key"),
        "--peer-cert",
        &file("remote.crt"),
    ];
    let (ok, end, stderr) = ended(base(addr, "2", "tcp-to-quic", &tls));
    assert!(!ok, "{end}");
    assert!(
        end.contains("nothing accepts TCP connections there")
            && end.contains("--transport quic listens on UDP only"),
        "{end}\n{stderr}"
    );
    drop(remote);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn a_mode_mismatch_names_the_peer_s_real_regulation_on_both_sides() {
    let _serial = serial();
    let (mut remote, addr) = remote(&["--regulation", "paper-dynamic"]);
    let (ok, end, stderr) = ended(base(
        addr,
        "2",
        "mode-mismatch",
        &["--regulation", "fixed:120"],
    ));
    assert!(!ok, "{end}");
    assert!(
        end.contains(
            "mode mismatch: the peer runs paper-dynamic (its FIFO resized, with a pause, as \
             the network changes), this side fixed:120 (its regulator sized once"
        ) && end.contains("run both with the same --regulation"),
        "{end}\n{stderr}"
    );
    // The remote refused the base in its handshake, and says why.
    let line = remote.line_with("mode mismatch", Duration::from_secs(10));
    assert!(
        line.contains(
            "mode mismatch: the peer runs fixed:120 (its regulator sized once, at the \
             handshake), this side paper-dynamic"
        ),
        "{line}"
    );
}
