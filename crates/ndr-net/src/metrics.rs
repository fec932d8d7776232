//! Prometheus metrics of links and listeners (feature `metrics`).
//!
//! [`Metrics`] is a [`prometheus_client`] collector: it holds the links and
//! listeners it watches and, at each scrape, reads the snapshot each one's
//! hub already publishes ([`LinkSender::stats`], [`Listener::stats`]) and
//! encodes it. Nothing is counted twice and nothing runs on a hub's thread:
//! a scrape takes each link's stats lock for the copy of its snapshot,
//! as [`Link::stats`](crate::Link::stats) does.
//!
//! An application with its own exporter registers it into its registry
//! ([`Metrics::register`]); one without any gets the Prometheus text from
//! [`Metrics::encode`]. The names (`ndr_` prefix) and what each one maps
//! are listed in `docs/guide/metrics.md`.
//!
//! ```
//! use ndr_net::metrics::{LinkLabels, Metrics};
//! # fn watch(link: &ndr_net::Link) {
//! let metrics = Metrics::new();
//! let mut registry = prometheus_client::registry::Registry::default();
//! metrics.register(&mut registry);
//! let labels = LinkLabels::new(
//!     link.peer_addr().to_string(),
//!     ndr_core::wire::Role::Remote,
//!     ndr_net::Transport::Tcp,
//! );
//! let _id = metrics.watch_link(labels, &link.sender());
//! # }
//! ```

use std::fmt;
use std::sync::{Arc, Mutex, PoisonError, Weak};

use ndr_core::wire::Role;
use prometheus_client::collector::Collector;
use prometheus_client::encoding::{DescriptorEncoder, EncodeMetric, NoLabelSet};
use prometheus_client::metrics::MetricType;
use prometheus_client::metrics::counter::ConstCounter;
use prometheus_client::metrics::gauge::ConstGauge;
use prometheus_client::registry::Registry;

use crate::clock::LATENESS_BOUNDS_MICROS;
use crate::{LinkSender, LinkStats, Listener, ListenerStats, Transport};

/// The crate the metrics are encoded with, at the version they need.
pub use prometheus_client;

/// The `Content-Type` of [`Metrics::encode`]'s text (Prometheus text 0.0.4).
pub const CONTENT_TYPE: &str = prometheus_client::encoding::prometheus_text::CONTENT_TYPE;

/// The labels of one link's series: `peer` (its address), `role` (`base`
/// or `remote`, this side's) and `transport` (`tcp`, `udp` or `quic`).
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct LinkLabels {
    /// The peer's address as the application names it.
    pub peer: String,
    /// This side's role.
    pub role: Role,
    /// The link's transport (its kind only: `udp`, not `udp:3:1`).
    pub transport: Transport,
}

impl LinkLabels {
    /// The labels of a link to `peer`, on this side's `role`, over `transport`.
    #[must_use]
    pub fn new(peer: impl Into<String>, role: Role, transport: Transport) -> Self {
        LinkLabels {
            peer: peer.into(),
            role,
            transport,
        }
    }

    fn pairs(&self) -> [(&'static str, &'static str); 2] {
        [
            ("role", role_name(self.role)),
            ("transport", transport_name(self.transport)),
        ]
    }
}

/// Which watched link or listener ([`Metrics::unwatch`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct WatchId(u64);

/// The links and listeners whose figures a scrape shows: a
/// [`Collector`], cheap to clone (the clones share what they watch).
#[derive(Clone, Default)]
pub struct Metrics {
    inner: Arc<Mutex<Watched>>,
}

#[derive(Default)]
struct Watched {
    next: u64,
    links: Vec<(WatchId, LinkLabels, LinkSender)>,
    listeners: Vec<(WatchId, LinkLabels, Weak<Listener>)>,
    #[cfg(feature = "relay")]
    relays: Vec<(WatchId, RelayLabels, crate::relay::RelayStatsReader)>,
}

/// The labels of a relay's series: `listen` (where clients connect) and
/// `upstream` (where it relays them).
#[cfg(feature = "relay")]
#[derive(Clone, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub struct RelayLabels {
    /// The address clients connect to.
    pub listen: String,
    /// The address each client is relayed to.
    pub upstream: String,
}

#[cfg(feature = "relay")]
impl RelayLabels {
    /// The labels of a relay from `listen` to `upstream`.
    #[must_use]
    pub fn new(listen: impl Into<String>, upstream: impl Into<String>) -> Self {
        RelayLabels {
            listen: listen.into(),
            upstream: upstream.into(),
        }
    }
}

impl fmt::Debug for Metrics {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let w = self.lock();
        f.debug_struct("Metrics")
            .field("links", &w.links.len())
            .field("listeners", &w.listeners.len())
            .finish()
    }
}

impl Metrics {
    /// Watches nothing yet.
    #[must_use]
    pub fn new() -> Self {
        Metrics::default()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Watched> {
        self.inner.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// Shows `link`'s figures under `labels` from now on, until
    /// [`unwatch`](Self::unwatch): an ended link keeps showing its last
    /// figures (its final counts stay readable).
    pub fn watch_link(&self, labels: LinkLabels, link: &LinkSender) -> WatchId {
        let mut w = self.lock();
        let id = WatchId(w.next);
        w.next += 1;
        w.links.push((id, labels, link.clone()));
        id
    }

    /// Shows `listener`'s refusals under `labels` (its `peer` label is the
    /// address it listens on) while it lives; holds no reference that
    /// keeps it open.
    pub fn watch_listener(&self, labels: LinkLabels, listener: &Arc<Listener>) -> WatchId {
        let mut w = self.lock();
        let id = WatchId(w.next);
        w.next += 1;
        w.listeners.push((id, labels, Arc::downgrade(listener)));
        id
    }

    /// Shows a relay's counters (`ndr_relay_*`) under `labels`.
    #[cfg(feature = "relay")]
    pub fn watch_relay(
        &self,
        labels: RelayLabels,
        relay: &crate::relay::RelayStatsReader,
    ) -> WatchId {
        let mut w = self.lock();
        let id = WatchId(w.next);
        w.next += 1;
        w.relays.push((id, labels, relay.clone()));
        id
    }

    /// Stops showing a link, listener or relay (its series end).
    pub fn unwatch(&self, id: WatchId) {
        let mut w = self.lock();
        w.links.retain(|(i, ..)| *i != id);
        w.listeners.retain(|(i, ..)| *i != id);
        #[cfg(feature = "relay")]
        w.relays.retain(|(i, ..)| *i != id);
    }

    /// Registers these metrics into an application's registry: each scrape
    /// of it then reads the watched links' snapshots.
    pub fn register(&self, registry: &mut Registry) {
        registry.register_collector(Box::new(self.clone()));
    }

    /// The Prometheus text (version 0.0.4, [`CONTENT_TYPE`]) of what is
    /// watched now.
    #[must_use]
    pub fn encode(&self) -> String {
        let mut registry = Registry::default();
        self.register(&mut registry);
        let mut text = String::new();
        // Writing to a String fails only if a metric's encoding does,
        // which ours never do.
        let _ = prometheus_client::encoding::prometheus_text::encode(&mut text, &registry);
        text
    }

    /// The snapshots to encode: taken once per scrape, outside the lock of
    /// the set (a link's stats lock is held only for its copy).
    fn snapshot(&self) -> Snapshot {
        #[cfg(feature = "relay")]
        let relays = {
            let w = self.lock();
            w.relays
                .iter()
                .map(|(_, l, r)| (l.clone(), r.stats()))
                .collect()
        };
        let (links, listeners) = {
            let w = self.lock();
            (
                w.links
                    .iter()
                    .map(|(_, l, s)| (l.clone(), s.clone()))
                    .collect::<Vec<_>>(),
                w.listeners
                    .iter()
                    .map(|(_, l, s)| (l.clone(), s.clone()))
                    .collect::<Vec<_>>(),
            )
        };
        Snapshot {
            links: links
                .into_iter()
                .filter_map(|(l, s)| Some((l, s.stats()?)))
                .collect(),
            listeners: listeners
                .into_iter()
                .filter_map(|(l, s)| Some((l, s.upgrade()?.stats())))
                .collect(),
            #[cfg(feature = "relay")]
            relays,
        }
    }
}

struct Snapshot {
    links: Vec<(LinkLabels, LinkStats)>,
    listeners: Vec<(LinkLabels, ListenerStats)>,
    #[cfg(feature = "relay")]
    relays: Vec<(RelayLabels, crate::relay::RelayStats)>,
}

fn role_name(role: Role) -> &'static str {
    match role {
        Role::Base => "base",
        Role::Remote => "remote",
    }
}

fn transport_name(t: Transport) -> &'static str {
    match t {
        Transport::Tcp => "tcp",
        Transport::Udp { .. } => "udp",
        Transport::Quic { .. } => "quic",
        Transport::Zenoh { .. } => "zenoh",
    }
}

/// What a side releases: commands at the remote, states at the base.
fn received(role: Role) -> &'static str {
    match role {
        Role::Base => "states",
        Role::Remote => "commands",
    }
}

type Labels<'a> = Vec<(&'static str, &'a str)>;

fn link_labels<'a>(l: &'a LinkLabels, extra: &[(&'static str, &'a str)]) -> Labels<'a> {
    let mut v: Labels<'a> = vec![("peer", l.peer.as_str())];
    v.extend(l.pairs());
    v.extend_from_slice(extra);
    v
}

type Rows<'a, T> = Vec<(Labels<'a>, T)>;

/// A label value and the count a link's stats give for it.
type Reason = (&'static str, fn(&LinkStats) -> u64);

fn per_link(links: &[(LinkLabels, LinkStats)], f: fn(&LinkStats) -> u64) -> Rows<'_, u64> {
    links
        .iter()
        .map(|(l, s)| (link_labels(l, &[]), f(s)))
        .collect()
}

fn per_link_f(links: &[(LinkLabels, LinkStats)], f: fn(&LinkStats) -> f64) -> Rows<'_, f64> {
    links
        .iter()
        .map(|(l, s)| (link_labels(l, &[]), f(s)))
        .collect()
}

/// One value per link and reason, the reason as label `key`.
fn by_reason<'a>(
    links: &'a [(LinkLabels, LinkStats)],
    key: &'static str,
    reasons: &[Reason],
) -> Rows<'a, u64> {
    let mut rows = Vec::new();
    for (l, s) in links {
        for &(reason, f) in reasons {
            rows.push((link_labels(l, &[(key, reason)]), f(s)));
        }
    }
    rows
}

/// A counter family: one value per link (and per `extra` label).
fn counter(
    enc: &mut DescriptorEncoder,
    name: &str,
    help: &str,
    rows: &[(Labels<'_>, u64)],
) -> fmt::Result {
    let mut family = enc.encode_descriptor(name, help, None, MetricType::Counter)?;
    for (labels, v) in rows {
        ConstCounter::new(*v).encode(family.encode_family(labels)?)?;
    }
    Ok(())
}

fn gauge(
    enc: &mut DescriptorEncoder,
    name: &str,
    help: &str,
    rows: &[(Labels<'_>, f64)],
) -> fmt::Result {
    let mut family = enc.encode_descriptor(name, help, None, MetricType::Gauge)?;
    for (labels, v) in rows {
        ConstGauge::new(*v).encode(family.encode_family(labels)?)?;
    }
    Ok(())
}

impl Collector for Metrics {
    fn encode(&self, mut enc: DescriptorEncoder) -> fmt::Result {
        let snap = self.snapshot();
        let links = &snap.links;
        counter(
            &mut enc,
            "ndr_samples_sent",
            "Samples this side sent (repeats of the previous one included).",
            &per_link(links, |s| s.endpoint.samples_sent),
        )?;
        counter(
            &mut enc,
            "ndr_samples_received",
            "Samples received from the peer.",
            &per_link(links, |s| s.endpoint.samples_received),
        )?;
        counter(
            &mut enc,
            "ndr_samples_released",
            "Samples released fresh to the application.",
            &per_link(links, |s| s.endpoint.released_fresh),
        )?;
        counter(
            &mut enc,
            "ndr_ticks_held",
            "Ticks that repeated the last sample, the due one missing.",
            &per_link(links, |s| s.endpoint.released_held),
        )?;
        counter(
            &mut enc,
            "ndr_late_samples",
            "Samples that arrived after their release slot (a lost datagram counts).",
            &per_link(links, |s| s.endpoint.late),
        )?;
        counter(
            &mut enc,
            "ndr_underflows",
            "Running ticks whose due sample was missing.",
            &per_link(links, |s| s.endpoint.underflows),
        )?;
        counter(
            &mut enc,
            "ndr_samples_lost",
            "Datagram transport: samples never received, neither in their datagram nor in a later one's copies.",
            &per_link(links, |s| s.endpoint.samples_lost),
        )?;
        counter(
            &mut enc,
            "ndr_samples_recovered",
            "Datagram transport: samples taken from a later datagram's copy (via=copy) or a repeat of their datagram (via=repeat).",
            &by_reason(
                links,
                "via",
                &[
                    ("copy", |s| s.endpoint.samples_recovered),
                    ("repeat", |s| s.endpoint.samples_from_repeats),
                ],
            ),
        )?;
        counter(
            &mut enc,
            "ndr_samples_dropped",
            "Samples received and not released, by reason: queue_full (regulator full), stale (a paused stream's, or past their slot after an outage), skipped (the target delay fell).",
            &by_reason(
                links,
                "reason",
                &[
                    ("queue_full", |s| s.endpoint.rejected),
                    ("stale", |s| s.endpoint.discarded),
                    ("skipped", |s| s.endpoint.skipped),
                ],
            ),
        )?;
        counter(
            &mut enc,
            "ndr_datagrams_dropped",
            "Datagram transport: datagrams dropped on arrival, by reason: stale (after a newer one), foreign (another session's token), refused (invalid), off_path (from an address not validated), stray (no link's token; counted per socket, shared by its links).",
            &by_reason(
                links,
                "reason",
                &[
                    ("stale", |s| s.endpoint.datagrams_stale),
                    ("foreign", |s| s.endpoint.datagrams_foreign),
                    ("refused", |s| s.endpoint.datagrams_refused),
                    ("off_path", |s| s.endpoint.datagrams_off_path),
                    ("stray", |s| s.datagrams_stray),
                ],
            ),
        )?;
        counter(
            &mut enc,
            "ndr_datagrams_unsent",
            "Datagram transport: datagrams not sent (no peer address yet, or the socket refused them).",
            &per_link(links, |s| s.datagrams_unsent),
        )?;
        counter(
            &mut enc,
            "ndr_app_dropped",
            "Samples and events dropped because the application did not read them.",
            &per_link(links, |s| {
                s.app_dropped + s.events_dropped + s.endpoint_events_dropped
            }),
        )?;
        counter(
            &mut enc,
            "ndr_link_lost",
            "Watchdog alarms: times no fresh sample came for the watchdog time.",
            &per_link(links, |s| s.endpoint.link_lost),
        )?;
        counter(
            &mut enc,
            "ndr_deadlines_late",
            "Deadlines of the link's hub (all its links) served 1 ms late or more.",
            &per_link(links, |s| s.release_lateness.missed),
        )?;

        gauge(
            &mut enc,
            "ndr_link_running",
            "1 while samples flow and the regulator releases them, else 0.",
            &per_link_f(links, |s| {
                f64::from(u8::from(s.phase == ndr_core::endpoint::Phase::Running))
            }),
        )?;
        gauge(
            &mut enc,
            "ndr_period_seconds",
            "The link's period.",
            &per_link_f(links, |s| s.period.as_secs_f64()),
        )?;
        gauge(
            &mut enc,
            "ndr_nrtt_seconds",
            "The latest network round trip measured.",
            &per_link_f(links, |s| s.last_nrtt.map_or(0.0, |d| d.as_secs_f64())),
        )?;
        gauge(
            &mut enc,
            "ndr_grtt_seconds",
            "The mean round trip as the application sees it (both regulators included), over the link's life.",
            &per_link_f(links, |s| s.endpoint.grtt.mean()),
        )?;
        gauge(
            &mut enc,
            "ndr_grtt_std_seconds",
            "The standard deviation of the round trip as the application sees it: the residual jitter.",
            &per_link_f(links, |s| s.endpoint.grtt.std()),
        )?;
        let playout: Vec<_> = links
            .iter()
            .map(|(l, s)| {
                (
                    link_labels(l, &[("direction", received(l.role))]),
                    s.endpoint.playout_delay_s,
                )
            })
            .collect();
        gauge(
            &mut enc,
            "ndr_playout_delay_seconds",
            "The end-to-end delay of the samples this side releases now (direction: commands at the remote, states at the base).",
            &playout,
        )?;
        gauge(
            &mut enc,
            "ndr_queue_samples",
            "Samples waiting in the regulator for their release.",
            &per_link_f(links, |s| s.queue_len as f64),
        )?;
        gauge(
            &mut enc,
            "ndr_queue_nominal_samples",
            "The regulator's nominal size.",
            &per_link_f(links, |s| s.ns as f64),
        )?;
        gauge(
            &mut enc,
            "ndr_clock_offset_seconds",
            "The clock offset estimate, local minus peer.",
            &per_link_f(links, |s| s.endpoint.clock_offset_s),
        )?;
        gauge(
            &mut enc,
            "ndr_clock_skew_ratio",
            "The clock skew estimate d(local - peer)/dt (ppm times 1e-6).",
            &per_link_f(links, |s| s.endpoint.clock_skew_ppm * 1e-6),
        )?;

        {
            let mut family = enc.encode_descriptor(
                "ndr_release_lateness_seconds",
                "How late the link's hub served its deadlines (the release's stamp), over all the hub's links; 1 us resolution.",
                None,
                MetricType::Histogram,
            )?;
            for (l, s) in links {
                let r = &s.release_lateness;
                let mut buckets = [(0.0, 0u64); LATENESS_BOUNDS_MICROS.len()];
                let mut before = 0;
                for ((slot, &bound), &below) in buckets
                    .iter_mut()
                    .zip(&LATENESS_BOUNDS_MICROS)
                    .zip(&r.below)
                {
                    *slot = (bound as f64 / 1e6, below.saturating_sub(before));
                    before = below;
                }
                let labels = link_labels(l, &[]);
                family
                    .encode_family(&labels)?
                    .encode_histogram::<NoLabelSet>(r.sum.as_secs_f64(), r.count, &buckets, None)?;
            }
        }

        let mut refusals = Vec::new();
        for (l, s) in &snap.listeners {
            for (reason, n) in refusal_reasons(s) {
                refusals.push((link_labels(l, &[("reason", reason)]), n));
            }
        }
        counter(
            &mut enc,
            "ndr_refusals",
            "Peers a listener refused or dropped before handing them over, by reason (peer: the address it listens on).",
            &refusals,
        )?;
        let accepted: Vec<_> = snap
            .listeners
            .iter()
            .map(|(l, s)| (link_labels(l, &[]), s.accepted))
            .collect();
        counter(
            &mut enc,
            "ndr_links_accepted",
            "Links a listener handed to the application (peer: the address it listens on).",
            &accepted,
        )?;
        #[cfg(feature = "relay")]
        relay::encode(&mut enc, &snap.relays)?;
        Ok(())
    }
}

/// The relay's counters (`ndr_relay_*`), per relay and direction.
#[cfg(feature = "relay")]
mod relay {
    use super::{RelayLabels, counter, gauge};
    use crate::relay::RelayStats;
    use core::fmt;
    use prometheus_client::encoding::DescriptorEncoder;

    type Rows<'a, T> = Vec<(Vec<(&'static str, &'a str)>, T)>;

    fn labels<'a>(
        l: &'a RelayLabels,
        extra: &[(&'static str, &'static str)],
    ) -> Vec<(&'static str, &'a str)> {
        let mut v = vec![
            ("listen", l.listen.as_str()),
            ("upstream", l.upstream.as_str()),
        ];
        v.extend_from_slice(extra);
        v
    }

    /// One row per relay, direction and value of `f`'s reasons.
    fn rows<'a>(
        relays: &'a [(RelayLabels, RelayStats)],
        f: impl Fn(&RelayStats, &mut dyn FnMut(&[(&'static str, &'static str)], u64)),
    ) -> Rows<'a, u64> {
        let mut out = Vec::new();
        for (l, s) in relays {
            f(s, &mut |extra, v| out.push((labels(l, extra), v)));
        }
        out
    }

    pub(super) fn encode(
        enc: &mut DescriptorEncoder,
        relays: &[(RelayLabels, RelayStats)],
    ) -> fmt::Result {
        counter(
            enc,
            "ndr_relay_connections",
            "Client connections the relay accepted.",
            &rows(relays, |s, row| row(&[], s.connections)),
        )?;
        counter(
            enc,
            "ndr_relay_connections_ended",
            "Connections that ended, by how: finished, upstream_failure, framing_error, queue_overflow, io_error, shutdown.",
            &rows(relays, |s, row| {
                for (how, n) in [
                    ("finished", s.finished),
                    ("upstream_failure", s.upstream_failures),
                    ("framing_error", s.framing_errors),
                    ("queue_overflow", s.queue_overflows),
                    ("io_error", s.io_errors),
                    ("shutdown", s.closed_by_shutdown),
                ] {
                    row(&[("how", how)], n);
                }
            }),
        )?;
        let by_direction = |f: fn(&crate::relay::DirectionStats) -> u64| {
            rows(relays, move |s, row| {
                row(&[("direction", "forward")], f(&s.forward));
                row(&[("direction", "backward")], f(&s.backward));
            })
        };
        counter(
            enc,
            "ndr_relay_frames_received",
            "TCP frames read from the sending side (forward: client to upstream).",
            &by_direction(|d| d.frames_received),
        )?;
        counter(
            enc,
            "ndr_relay_frames_delivered",
            "TCP frames written to the receiving side after their delay.",
            &by_direction(|d| d.frames_delivered),
        )?;
        let by_datagram_direction = |f: fn(&crate::relay::DatagramDirectionStats) -> u64| {
            rows(relays, move |s, row| {
                row(&[("direction", "forward")], f(&s.datagrams.forward));
                row(&[("direction", "backward")], f(&s.datagrams.backward));
            })
        };
        counter(
            enc,
            "ndr_relay_datagrams_received",
            "Datagrams read from the sending side into a flow.",
            &by_datagram_direction(|d| d.received),
        )?;
        counter(
            enc,
            "ndr_relay_datagrams_delivered",
            "Datagrams sent on after their delay.",
            &by_datagram_direction(|d| d.delivered),
        )?;
        counter(
            enc,
            "ndr_relay_datagrams_dropped",
            "Datagrams dropped, by reason: lost (the loss model), queue_full, send_failed, evicted (their flow's).",
            &rows(relays, |s, row| {
                for (dir, d) in [
                    ("forward", &s.datagrams.forward),
                    ("backward", &s.datagrams.backward),
                ] {
                    for (reason, n) in [
                        ("lost", d.lost),
                        ("queue_full", d.queue_full),
                        ("send_failed", d.send_failed),
                        ("evicted", d.evicted),
                    ] {
                        row(&[("direction", dir), ("reason", reason)], n);
                    }
                }
            }),
        )?;
        let active = |f: fn(&RelayStats) -> u64| -> Rows<'_, f64> {
            relays
                .iter()
                .map(|(l, s)| (labels(l, &[]), f(s) as f64))
                .collect()
        };
        gauge(
            enc,
            "ndr_relay_connections_active",
            "Connections open now.",
            &active(|s| s.active),
        )?;
        gauge(
            enc,
            "ndr_relay_flows_active",
            "Datagram flows open now.",
            &active(|s| s.datagrams.flows_active),
        )
    }
}

/// Each reason a listener counts a refusal for, by its label.
fn refusal_reasons(s: &ListenerStats) -> [(&'static str, u64); 17] {
    [
        ("certificate", s.refused_certificate),
        ("no_certificate", s.refused_no_certificate),
        ("tls_version", s.refused_version),
        ("timeout", s.timeouts),
        ("handshake_failed", s.failed_other),
        ("role", s.refused_role),
        ("layout", s.refused_layout),
        ("settings", s.refused_settings),
        ("wire_version", s.refused_wire_version),
        ("protocol", s.refused_protocol),
        ("transport", s.refused_transport),
        ("evicted", s.evicted),
        ("per_source", s.refused_per_source),
        ("busy", s.refused_busy),
        ("unclaimed", s.unclaimed),
        ("accept_error", s.accept_errors),
        ("stray_datagram", s.datagrams_stray),
    ]
}
