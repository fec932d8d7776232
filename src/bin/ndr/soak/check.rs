//! The judge: each connection's released sequence checked against the
//! counters that may explain a gap.

use ndr::core::endpoint::{Phase, Status};
use ndr::net::{Link, LinkStats, RelayStats};

use super::report::SoakReport;

/// One connection's checks.
#[derive(Default)]
pub(super) struct Conn {
    prev_seq: Option<u64>,
    prev_echo: f64,
    /// Fresh samples missing from the sequence.
    gaps: u64,
    /// The remote's last report: its gaps, and the samples its counters say
    /// never reached it.
    remote_gaps: f64,
    remote_dropped: f64,
    /// Its datagram counters: samples lost, recovered, stale datagrams.
    remote_datagrams: [f64; 3],
}

/// Samples a link's counters say never reached the application: dropped
/// late, refused by a full regulator, discarded by a pause, dropped because
/// the application's queue was full (that counter also counts events, so it
/// bounds the samples from above), never sent by the peer, whose
/// transmit queue overflowed while its driver stalled (`frames_missing`:
/// counted here when the next frame came, so before any later sample was
/// released; the peer's own count would reach us only with a later sample),
/// or, over datagrams, lost by the network for good (`samples_lost`: in
/// none of the datagrams taken, counted when a newer one was taken, so
/// also before any later sample was released), or dropped by the endpoint
/// itself when its driver ran more missed ticks at once than it queues
/// events for (`endpoint_events_dropped`). Nothing else explains a
/// gap: a repeated or reordered datagram is dropped whole, so a repeat or
/// a reordering in the released sequence is an error on any transport.
pub(super) fn dropped(s: &LinkStats) -> u64 {
    s.endpoint.late
        + s.endpoint.rejected
        + s.endpoint.discarded
        + s.app_dropped
        + s.endpoint.frames_missing
        + s.endpoint.samples_lost
        + s.endpoint_events_dropped
}

/// A check on a thread of its own (`true`: it passed), and what it adds to
/// the report once it passed.
pub(super) type Check = (std::thread::JoinHandle<bool>, fn(&mut SoakReport));

/// Joins the checks that have finished (all of them, waiting, if `all`),
/// adding what each that passed adds to the report.
pub(super) fn join_checks(r: &mut SoakReport, checks: &mut Vec<Check>, all: bool) {
    let mut i = 0;
    while i < checks.len() {
        if all || checks[i].0.is_finished() {
            let (check, passed) = checks.swap_remove(i);
            if check.join().unwrap_or(false) {
                passed(r);
            }
        } else {
            i += 1;
        }
    }
}

pub(super) fn check(r: &mut SoakReport, conn: &mut Conn, status: Status, seq: u64, values: &[f64]) {
    if status != Status::Fresh {
        return;
    }
    match conn.prev_seq {
        Some(p) if seq == p + 1 => {}
        Some(p) if seq == p => r.duplicated += 1,
        Some(p) if seq < p => r.reordered += 1,
        Some(p) => conn.gaps += seq - p - 1,
        None => {}
    }
    conn.prev_seq = Some(seq);
    if let [echo, gaps, dropped, lost, recovered, stale, ..] = *values {
        if echo < conn.prev_echo {
            r.corrupted += 1;
        }
        conn.prev_echo = echo;
        conn.remote_gaps = conn.remote_gaps.max(gaps);
        conn.remote_dropped = conn.remote_dropped.max(dropped);
        for (mine, theirs) in conn
            .remote_datagrams
            .iter_mut()
            .zip([lost, recovered, stale])
        {
            *mine = mine.max(theirs);
        }
    }
}

pub(super) fn finish_conn(r: &mut SoakReport, conn: &Conn, stats: Option<LinkStats>) {
    // The remote's last report may predate its last drops: only gaps beyond
    // what its counters said are anomalies.
    r.remote_anomalies += (conn.remote_gaps - conn.remote_dropped).max(0.0) as u64;
    let [lost, recovered, stale] = conn.remote_datagrams.map(|v| v as u64);
    r.remote_samples_lost += lost;
    r.remote_samples_recovered += recovered;
    r.remote_datagrams_stale += stale;
    let counted = stats.as_ref().map_or(0, dropped);
    r.dropped_with_counter += conn.gaps.min(counted);
    r.lost += conn.gaps.saturating_sub(counted);
    if let Some(s) = stats {
        let e = s.endpoint;
        r.rejected += e.rejected;
        r.app_dropped += s.app_dropped;
        r.samples_sent += e.samples_sent;
        r.samples_released += e.released_fresh;
        r.held += e.released_held;
        r.underflows += e.underflows;
        r.late += e.late;
        r.tx_dropped += e.tx_dropped;
        r.datagrams_received += e.datagrams_received;
        r.samples_recovered += e.samples_recovered;
        r.samples_lost += e.samples_lost;
        r.datagrams_stale += e.datagrams_stale;
        r.datagrams_repeated += e.datagrams_repeated;
        r.datagrams_foreign += e.datagrams_foreign;
        r.datagrams_refused += e.datagrams_refused;
        r.datagrams_unsent += s.datagrams_unsent;
        r.datagram_path_changes += s.datagram_path_changes;
        // Each connection has a socket of its own on the hub (it closes
        // with its last link), so its strays add up.
        r.datagrams_stray += s.datagrams_stray;
    }
}

/// A relay's datagram counters, added when it stops.
pub(super) fn add_relay(r: &mut SoakReport, s: &RelayStats) {
    for d in [&s.datagrams.forward, &s.datagrams.backward] {
        r.relay_datagrams += d.received;
        r.relay_datagrams_lost += d.lost;
        r.relay_datagrams_queue_full += d.queue_full;
    }
}

pub(super) fn link_up(link: Option<&(Link, Conn)>) -> bool {
    link.and_then(|(l, _)| l.stats())
        .is_some_and(|s| s.phase != Phase::Closed)
}
