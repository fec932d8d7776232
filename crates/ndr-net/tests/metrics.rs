//! The metrics an application registers into its own prometheus-client
//! registry: a real link through the relay on loopback, its page read
//! back and compared with the link's and the relay's own stats.

use std::net::SocketAddr;
use std::time::Duration as StdDuration;

use ndr_core::endpoint::Config;
use ndr_core::time::Duration;
use ndr_core::wire::Role;
use ndr_net::metrics::prometheus_client::encoding::text::encode;
use ndr_net::metrics::prometheus_client::registry::Registry;
use ndr_net::metrics::{LinkLabels, Metrics, RelayLabels};
use ndr_net::relay::Relay;
use ndr_net::{Link, LinkConfig, Listener, Transport};
use ndr_netem::DelayModel;

fn loopback() -> SocketAddr {
    "127.0.0.1:0".parse().expect("address")
}

/// The value of the one line of `page` that starts with `series` and a space.
fn value(page: &str, series: &str) -> f64 {
    let found: Vec<&str> = page
        .lines()
        .filter_map(|l| l.strip_prefix(series)?.strip_prefix(' '))
        .collect();
    assert_eq!(found.len(), 1, "{series} in\n{page}");
    found[0].parse().expect("a number")
}

#[test]
fn a_link_and_its_relay_show_their_own_counts_in_the_applications_registry() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .expect("runtime");
    let mut c = Config::new(Role::Base).with_width(2);
    c.period = Duration::from_millis(10);
    let config = LinkConfig::new(c);
    let (mut base, mut remote, relay, upstream) = rt.block_on(async {
        let listener = Listener::listen(loopback(), config.clone())
            .await
            .expect("listen");
        let upstream = listener.local_addr().expect("address");
        let model = DelayModel::Constant {
            fwd: Duration::from_millis(1),
            bwd: Duration::from_millis(1),
        };
        let relay = Relay::listen(loopback(), upstream, model, 1)
            .await
            .expect("relay")
            .spawn()
            .expect("spawn");
        let (remote, base) =
            tokio::join!(listener.accept(), Link::connect(relay.local_addr(), config));
        (
            base.expect("base"),
            remote.expect("remote"),
            relay,
            upstream,
        )
    });

    let metrics = Metrics::new();
    let mut registry = Registry::default();
    metrics.register(&mut registry);
    let peer = base.peer_addr().to_string();
    let labels = LinkLabels::new(peer.clone(), Role::Base, Transport::Tcp);
    metrics.watch_link(labels, &base.sender());
    let relay_labels = RelayLabels::new(relay.local_addr().to_string(), upstream.to_string());
    let relay_id = metrics.watch_relay(relay_labels, &relay.stats_reader());

    for _ in 0..30 {
        let command = remote
            .recv_timeout(StdDuration::from_secs(5))
            .expect("a command");
        remote.send(command.values()).expect("state");
        base.recv_timeout(StdDuration::from_secs(5))
            .expect("a state");
    }
    let stats = base.close().expect("stats");
    remote.shutdown();

    let mut page = String::new();
    encode(&mut page, &registry).expect("encoded");
    let link = format!("{{peer=\"{peer}\",role=\"base\",transport=\"tcp\"}}");
    let released = value(&page, &format!("ndr_samples_released_total{link}"));
    assert!(stats.endpoint.released_fresh > 0);
    assert_eq!(released, stats.endpoint.released_fresh as f64);
    let sent = value(&page, &format!("ndr_samples_sent_total{link}"));
    assert_eq!(sent, stats.endpoint.samples_sent as f64);
    let count = value(&page, &format!("ndr_release_lateness_seconds_count{link}"));
    assert_eq!(count, stats.release_lateness.count as f64);
    assert_eq!(value(&page, &format!("ndr_link_running{link}")), 0.0);
    let relay_series = format!(
        "ndr_relay_connections_total{{listen=\"{}\",upstream=\"{upstream}\"}}",
        relay.local_addr()
    );
    assert_eq!(value(&page, &relay_series), 1.0);

    // Unwatched, its series end.
    metrics.unwatch(relay_id);
    let mut page = String::new();
    encode(&mut page, &registry).expect("encoded");
    assert!(!page.contains("ndr_relay_connections_total{"), "{page}");
    let relayed = rt.block_on(relay.shutdown());
    assert_eq!(relayed.connections, 1);
}
