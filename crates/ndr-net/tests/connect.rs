//! One way to connect and one to listen: the transport, TLS and the hub
//! that drives a link are in its `LinkConfig`.

use std::net::SocketAddr;

use ndr_core::endpoint::{Config, Transport as Carriage};
use ndr_core::wire::Role;
use ndr_net::clock::DEFAULT_SPIN_MARGIN;
use ndr_net::{
    Hub, HubChoice, HubPool, Link, LinkConfig, Listener, NetError, Transport, TransportError,
};

fn config() -> LinkConfig {
    let mut c = Config::new(Role::Base);
    c = c.with_width(2);
    LinkConfig::new(c)
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime")
}

fn loopback() -> SocketAddr {
    "127.0.0.1:0".parse().expect("address")
}

#[test]
fn a_link_and_a_listener_run_on_the_hub_their_configuration_names() {
    let rt = runtime();
    let (bases, remotes) = (
        Hub::new(DEFAULT_SPIN_MARGIN).expect("hub"),
        HubPool::new(2, DEFAULT_SPIN_MARGIN).expect("pool"),
    );
    assert!(matches!(config().hub, HubChoice::Own));
    let listener = rt
        .block_on(Listener::listen(
            loopback(),
            config().on_pool(remotes.clone()),
        ))
        .expect("bind");
    let addr = listener.local_addr().expect("address");
    let mut links = Vec::new();
    for _ in 0..4 {
        let base = Link::connect(addr, config().on_hub(bases.clone()));
        let (remote, base) = rt.block_on(async { tokio::join!(listener.accept(), base) });
        links.push((base.expect("connected"), remote.expect("accepted")));
    }
    assert_eq!(bases.links(), 4);
    let per_hub: Vec<usize> = remotes.hubs().iter().map(Hub::links).collect();
    assert_eq!(per_hub, [2, 2]);
    // A blocking link takes the named hub too.
    let blocking = std::thread::scope(|s| {
        s.spawn(|| Link::connect_blocking(addr, config().on_hub(bases.clone())))
            .join()
            .expect("thread")
    });
    let accepted = rt.block_on(listener.accept()).expect("accepted");
    assert!(blocking.is_ok());
    assert_eq!(bases.links(), 5);
    drop((links, accepted, blocking));
}

#[test]
fn a_plain_link_off_loopback_is_refused_before_any_socket() {
    let rt = runtime();
    let far: SocketAddr = "192.0.2.7:7300".parse().expect("address");
    let refused = rt.block_on(Link::connect(far, config()));
    assert!(matches!(refused, Err(NetError::Insecure(a)) if a == far));
    let any: SocketAddr = "0.0.0.0:0".parse().expect("address");
    let refused = rt.block_on(Listener::listen(any, config()));
    assert!(matches!(refused, Err(NetError::Insecure(_))));
}

#[test]
fn a_transport_that_does_not_fit_is_refused_before_any_socket() {
    let rt = runtime();
    // Off loopback: the transport is named before the missing TLS.
    let far: SocketAddr = "192.0.2.7:7300".parse().expect("address");
    let quic = config().with_transport(Transport::QUIC);
    let refused = rt.block_on(Link::connect(far, quic.clone()));
    assert!(
        matches!(
            refused,
            Err(NetError::Transport(TransportError::QuicWithoutTls))
        ),
        "{refused:?}"
    );
    let any: SocketAddr = "0.0.0.0:0".parse().expect("address");
    let refused = rt.block_on(Listener::listen(any, quic));
    assert!(
        matches!(
            refused,
            Err(NetError::Transport(TransportError::QuicWithoutTls))
        ),
        "{:?}",
        refused.err()
    );
    // The endpoint's transport changed behind the link's back.
    let mut mismatched = config().with_transport(Transport::UDP);
    mismatched.endpoint.transport = Carriage::Stream;
    let refused = rt.block_on(Link::connect(loopback(), mismatched));
    assert!(
        matches!(
            refused,
            Err(NetError::Transport(TransportError::Mismatch {
                link: Transport::UDP,
                endpoint: Carriage::Stream,
            }))
        ),
        "{refused:?}"
    );
}

#[test]
fn the_endpoint_carries_what_the_transport_says() {
    let udp = LinkConfig::new(Config::new(Role::Base)).with_transport("udp:2:1".parse().unwrap());
    assert_eq!(
        udp.endpoint.transport,
        Carriage::Datagram {
            redundancy: 2,
            repeats: 1
        }
    );
    let quic = udp.with_transport(Transport::QUIC);
    assert_eq!(quic.endpoint.transport, Carriage::DATAGRAM);
    // A configuration made around an endpoint takes tcp or udp from it.
    let mut c = Config::new(Role::Base);
    c.transport = Carriage::DATAGRAM;
    assert_eq!(LinkConfig::new(c).transport, Transport::UDP);
    assert_eq!(config().transport, Transport::Tcp);
}

#[test]
fn links_are_spread_over_the_hubs_and_leave_them_when_closed() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime");
    let mut c = Config::paper(Role::Base);
    c = c.with_width(1);
    let config = LinkConfig::new(c);
    let bases = HubPool::new(2, DEFAULT_SPIN_MARGIN).expect("hubs");
    let remotes = HubPool::new(2, DEFAULT_SPIN_MARGIN).expect("hubs");
    let links = rt.block_on(async {
        let any: SocketAddr = "127.0.0.1:0".parse().expect("address");
        let listener = Listener::listen(any, config.clone().on_pool(remotes.clone()))
            .await
            .expect("bind");
        let addr = listener.local_addr().expect("address");
        let mut links = Vec::new();
        for _ in 0..4 {
            let base = Link::connect(addr, config.clone().on_pool(bases.clone()));
            let (r, b) = tokio::join!(listener.accept(), base);
            links.push(r.expect("accepted"));
            links.push(b.expect("connected"));
        }
        links
    });
    for pool in [&bases, &remotes] {
        let per_hub: Vec<usize> = pool.hubs().iter().map(Hub::links).collect();
        assert_eq!(per_hub, [2, 2]);
    }
    for link in links {
        let _ = link.close();
    }
    assert_eq!(bases.links() + remotes.links(), 0);
}
