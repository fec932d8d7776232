//! A hub's thread ends with its last handle: listeners and links leave no
//! `ndr-hub` thread behind.

use ndr_core::endpoint::Config;
use ndr_core::wire::Role;
use ndr_net::{Link, LinkConfig, Listener};

/// The tests count the process's threads: one at a time, or one test's
/// hubs would show in (or vanish from) another's count.
fn serial() -> std::sync::MutexGuard<'static, ()> {
    static LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());
    LOCK.lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// `ndr-hub` threads of this process, counting those this thread spawned
/// that have not named themselves yet: a new thread carries its parent's
/// name until it sets its own, so a hub dropped at once may still be
/// starting (and later show as `ndr-hub`) when the count is taken.
fn hub_threads() -> usize {
    let comm = |path: std::path::PathBuf| std::fs::read_to_string(path).unwrap_or_default();
    let me = comm("/proc/thread-self/comm".into());
    let mine = std::fs::read_dir("/proc/self/task").map_or(0, |tasks| {
        tasks
            .filter_map(Result::ok)
            .map(|t| comm(t.path().join("comm")))
            .filter(|c| c.trim() == "ndr-hub" || *c == me)
            .count()
    });
    // This thread is one of those named like it.
    mine.saturating_sub(1)
}

/// Threads of this process named `name`.
fn threads_named(name: &str) -> usize {
    std::fs::read_dir("/proc/self/task").map_or(0, |tasks| {
        tasks
            .filter_map(Result::ok)
            .filter(|t| {
                std::fs::read_to_string(t.path().join("comm")).is_ok_and(|c| c.trim() == name)
            })
            .count()
    })
}

/// Waits (2 s at most) for the count of hub threads to come down to `n`,
/// and fails if it does not.
fn settles_to(n: usize) {
    let end = std::time::Instant::now() + std::time::Duration::from_secs(2);
    loop {
        let now = hub_threads();
        if now <= n {
            return;
        }
        assert!(
            std::time::Instant::now() <= end,
            "{now} hub threads, {n} before"
        );
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

#[test]
fn a_dropped_listener_ends_its_hub_thread() {
    let _serial = serial();
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    let before = hub_threads();
    for _ in 0..5 {
        let l = rt
            .block_on(Listener::listen(
                "127.0.0.1:0".parse().expect("addr"),
                LinkConfig::new(Config::new(Role::Remote)),
            ))
            .expect("bind");
        drop(l);
    }
    settles_to(before);
}

#[test]
fn a_dropped_hub_ends_its_thread() {
    let _serial = serial();
    let before = hub_threads();
    for _ in 0..5 {
        drop(ndr_net::Hub::with_defaults().expect("hub"));
    }
    settles_to(before);
}

#[test]
fn closed_links_and_their_listener_leave_no_hub_thread() {
    let _serial = serial();
    // Counted before the runtime starts: its worker is named like this
    // thread until it names itself, and may not have yet.
    let before = hub_threads();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime");
    for _ in 0..3 {
        let listener = rt
            .block_on(Listener::listen(
                "127.0.0.1:0".parse().expect("addr"),
                LinkConfig::new(Config::new(Role::Remote)),
            ))
            .expect("bind");
        let addr = listener.local_addr().expect("address");
        let (base, remote) = rt.block_on(async {
            tokio::join!(
                Link::connect(addr, LinkConfig::new(Config::new(Role::Base))),
                listener.accept()
            )
        });
        // Both handshakes are done: each hub drives a link.
        let (base, remote) = (base.expect("connect"), remote.expect("accept"));
        drop(listener);
        let _ = remote.close();
        let _ = base.close();
    }
    settles_to(before);
}

#[cfg(feature = "keygen")]
#[test]
fn a_quic_listener_and_its_closed_links_leave_no_hub_thread() {
    use ndr_net::{TlsConfig, Transport};

    let _serial = serial();
    let dir = std::env::temp_dir().join(format!("ndr-hub-threads-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let base = ndr_net::keygen::write(&dir, "base").expect("a certificate");
    let remote = ndr_net::keygen::write(&dir, "remote").expect("a certificate");
    let quic = |role, own: &ndr_net::keygen::KeyPair, peer: &ndr_net::keygen::KeyPair| {
        let tls = TlsConfig::from_files(&own.cert, &own.key, &peer.cert).expect("TLS");
        LinkConfig::new(Config::new(role))
            .with_transport(Transport::QUIC)
            .with_tls(tls)
    };
    let before = hub_threads();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime");
    for _ in 0..3 {
        // Its endpoint's hub and its links' hub.
        let listener = rt
            .block_on(Listener::listen(
                "127.0.0.1:0".parse().expect("addr"),
                quic(Role::Remote, &remote, &base),
            ))
            .expect("bind");
        let addr = listener.local_addr().expect("address");
        let (b, r) = rt.block_on(async {
            tokio::join!(
                Link::connect(addr, quic(Role::Base, &base, &remote)),
                listener.accept()
            )
        });
        let (b, r) = (b.expect("connect"), r.expect("accept"));
        // The link, moved to the links' hub, keeps its endpoint's hub
        // until it ends.
        drop(listener);
        let _ = r.close();
        let _ = b.close();
    }
    settles_to(before);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_dropped_blocking_listener_ends_its_threads() {
    let _serial = serial();
    let before = hub_threads();
    for _ in 0..5 {
        let l = Listener::listen_blocking(
            "127.0.0.1:0".parse().expect("addr"),
            LinkConfig::new(Config::new(Role::Remote)),
        )
        .expect("bind");
        drop(l);
    }
    settles_to(before);
}

#[test]
fn a_connected_blocking_link_keeps_no_runtime_of_its_own() {
    let _serial = serial();
    let listener = Listener::listen_blocking(
        "127.0.0.1:0".parse().expect("addr"),
        LinkConfig::new(Config::new(Role::Remote)),
    )
    .expect("bind");
    let addr = listener.local_addr().expect("address");
    // The listener's own runtime thread, and whatever else runs. A thread
    // takes its name once it runs: on a loaded host, wait for it.
    let end = std::time::Instant::now() + std::time::Duration::from_secs(2);
    while threads_named("ndr-io") == 0 && std::time::Instant::now() < end {
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    let before = threads_named("ndr-io");
    let mut links = Vec::new();
    for _ in 0..3 {
        let (base, remote) = std::thread::scope(|s| {
            let remote = s.spawn(|| listener.accept_blocking());
            let base = Link::connect_blocking(addr, LinkConfig::new(Config::new(Role::Base)));
            (base, remote.join().expect("accept thread"))
        });
        links.push((base.expect("connect"), remote.expect("accept")));
    }
    // Three links up, driven by their hubs: no runtime thread left behind
    // by their connections (each ends as its `connect_blocking` returns).
    let end = std::time::Instant::now() + std::time::Duration::from_secs(2);
    while threads_named("ndr-io") > before && std::time::Instant::now() < end {
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    assert_eq!(threads_named("ndr-io"), before);
    drop(links);
}
