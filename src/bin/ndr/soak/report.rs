//! What `ndr soak` reports: its counters, in JSON or as a table.

use serde::Serialize;

/// What `ndr soak --json` prints.
#[derive(Serialize, Default)]
pub(super) struct SoakReport {
    pub(super) command: &'static str,
    pub(super) duration_s: f64,
    pub(super) period_s: f64,
    pub(super) connections: u64,
    pub(super) reconnections: u64,
    pub(super) connect_failures: u64,
    pub(super) samples_sent: u64,
    pub(super) samples_released: u64,
    pub(super) held: u64,
    pub(super) underflows: u64,
    pub(super) late: u64,
    /// Fresh samples missing in a connection's sequence that no counter
    /// (late, rejected, discarded, never sent) accounts for.
    pub(super) lost: u64,
    /// Fresh samples missing in a connection's sequence, each counted by the
    /// link as late (dropped under `drop-late`), rejected, discarded, not
    /// read in time by the application, or never sent by the peer.
    pub(super) dropped_with_counter: u64,
    /// Samples refused by a full regulator.
    pub(super) rejected: u64,
    /// Releases dropped because the application's queue was full.
    pub(super) app_dropped: u64,
    /// Fresh samples released twice.
    pub(super) duplicated: u64,
    /// Fresh samples released out of order.
    pub(super) reordered: u64,
    /// States whose echoed command went backwards.
    pub(super) corrupted: u64,
    /// Gaps, repeats or reorderings the remote saw in the commands that its
    /// counters do not account for.
    pub(super) remote_anomalies: u64,
    /// `tcp`, `udp[:K[:R]]` or `quic[:K[:R]]`.
    pub(super) transport: String,
    /// The relay's datagram loss model.
    pub(super) loss: String,
    /// Datagram transport, the base's side (the states), summed over the
    /// connections: datagrams taken, samples taken from a later datagram's
    /// copies, samples lost for good (each a gap the check accepts),
    /// datagrams dropped as older than one taken, repeats sent, datagrams
    /// of another session or refused, datagrams not sent, path changes,
    /// strays on the base's socket.
    pub(super) datagrams_received: u64,
    pub(super) samples_recovered: u64,
    pub(super) samples_lost: u64,
    pub(super) datagrams_stale: u64,
    pub(super) datagrams_repeated: u64,
    pub(super) datagrams_foreign: u64,
    pub(super) datagrams_refused: u64,
    pub(super) datagrams_unsent: u64,
    pub(super) datagram_path_changes: u64,
    pub(super) datagrams_stray: u64,
    /// Frames the base's hub gave up (its transmit queue full while it
    /// stalled): the remote counts them in `frames_missing` over TCP, in
    /// `samples_lost` over datagrams.
    pub(super) tx_dropped: u64,
    /// The same of the commands at the remote, from its last report in
    /// each connection.
    pub(super) remote_samples_lost: u64,
    pub(super) remote_samples_recovered: u64,
    pub(super) remote_datagrams_stale: u64,
    /// The relay's datagrams, both ways: read, dropped by the loss model,
    /// dropped on a full queue.
    pub(super) relay_datagrams: u64,
    pub(super) relay_datagrams_lost: u64,
    pub(super) relay_datagrams_queue_full: u64,
    /// Garbage, stray and spoofed datagrams sent to the remote's UDP port
    /// (over QUIC, its QUIC port).
    pub(super) garbage_datagrams: u64,
    /// Of those, the ones its listener counted as strays (the check waits
    /// for all of them).
    pub(super) garbage_datagrams_counted: u64,
    /// Garbage datagram faults after which the base's link had ended.
    pub(super) garbage_datagrams_harmed: u64,
    pub(super) faults_relay_restarts: u64,
    pub(super) faults_garbage: u64,
    pub(super) faults_remote_killed: u64,
    pub(super) faults_spikes: u64,
    /// Garbage connections the remote cut off within a second; over QUIC,
    /// strangers' handshakes it refused for their certificate.
    pub(super) garbage_cut_off: u64,
    /// Crowds of idle connections held open on the remote (none over QUIC).
    pub(super) faults_idle_crowds: u64,
    /// Connections of those crowds that connected (the remote refuses most:
    /// one source may hold only a few pending handshakes).
    pub(super) idle_connections_held: u64,
    pub(super) faults_hung_bases: u64,
    /// Hung bases the remote closed within its liveness time and 3 s.
    pub(super) hung_bases_dropped: u64,
    pub(super) faults_stale_frames: u64,
    /// Stale frames the remote refused with Close "frame out of sequence";
    /// over QUIC, runs of replayed packets of which nothing reached the
    /// released sequences.
    pub(super) stale_frames_refused: u64,
    pub(super) panics: u64,
    pub(super) remote_crashes: u64,
    pub(super) rss_start_kib: u64,
    pub(super) rss_peak_kib: u64,
    pub(super) rss_end_kib: u64,
    pub(super) rss_growth_kib: i64,
    pub(super) remote_rss_peak_kib: u64,
    pub(super) ended_by: Vec<String>,
    /// Stopped early by SIGINT or SIGTERM, after `ran_s` of the
    /// `duration_s` asked: the counters cover that time.
    pub(super) interrupted: bool,
    pub(super) ran_s: f64,
    pub(super) ok: bool,
}

pub(super) fn summarize(reasons: &[String]) -> Vec<String> {
    let mut counts: Vec<(String, u64)> = Vec::new();
    for reason in reasons {
        match counts.iter_mut().find(|(r, _)| r == reason) {
            Some((_, n)) => *n += 1,
            None => counts.push((reason.clone(), 1)),
        }
    }
    counts
        .into_iter()
        .map(|(r, n)| format!("{n} × {r}"))
        .collect()
}

pub(super) fn print_table(r: &SoakReport) {
    println!(
        "ndr soak · {:.0} s at T = {:.3} ms · {}",
        r.duration_s,
        r.period_s * 1e3,
        if r.ok { "OK" } else { "PROBLEM" }
    );
    println!(
        "  samples      {} sent · {} released · {} held · {} underflows · {} late",
        r.samples_sent, r.samples_released, r.held, r.underflows, r.late
    );
    println!(
        "  integrity    {} lost · {} duplicated · {} reordered · {} corrupted · {} seen by the remote \
         (and {} dropped with a counter: {} late, {} rejected, {} not read in time, {} never \
         received over datagrams)",
        r.lost,
        r.duplicated,
        r.reordered,
        r.corrupted,
        r.remote_anomalies,
        r.dropped_with_counter,
        r.late,
        r.rejected,
        r.app_dropped,
        r.samples_lost
    );
    if r.transport != "tcp" {
        println!(
            "  datagrams    {}, loss {} · relay read {}, lost {}, {} on a full queue",
            r.transport,
            r.loss,
            r.relay_datagrams,
            r.relay_datagrams_lost,
            r.relay_datagrams_queue_full
        );
        println!(
            "               states at the base: {} taken · {} recovered · {} lost · {} stale · \
             {} foreign · {} refused · {} strays; {} repeats sent · {} unsent · {} given up · \
             {} path changes",
            r.datagrams_received,
            r.samples_recovered,
            r.samples_lost,
            r.datagrams_stale,
            r.datagrams_foreign,
            r.datagrams_refused,
            r.datagrams_stray,
            r.datagrams_repeated,
            r.datagrams_unsent,
            r.tx_dropped,
            r.datagram_path_changes
        );
        println!(
            "               commands at the remote: {} recovered · {} lost · {} stale · \
             garbage {} sent to it, {} counted as strays, {} links harmed",
            r.remote_samples_recovered,
            r.remote_samples_lost,
            r.remote_datagrams_stale,
            r.garbage_datagrams,
            r.garbage_datagrams_counted,
            r.garbage_datagrams_harmed
        );
    }
    // Over QUIC, the faults' QUIC forms (see the soak module's doc).
    let (garbage, idle, stale) = if r.transport.starts_with("quic") {
        (
            "strangers refused",
            "none over QUIC".to_string(),
            "runs of replayed packets",
        )
    } else {
        (
            "cut off",
            format!(
                "{} idle crowds ({} connections held)",
                r.faults_idle_crowds, r.idle_connections_held
            ),
            "stale frames",
        )
    };
    println!(
        "  faults       {} relay restarts · {} garbage ({} {garbage}) · {} remote kills · {} delay spikes",
        r.faults_relay_restarts,
        r.faults_garbage,
        r.garbage_cut_off,
        r.faults_remote_killed,
        r.faults_spikes
    );
    println!(
        "               idle crowds: {idle} · {} hung bases ({} dropped) · {} {stale} ({} refused)",
        r.faults_hung_bases, r.hung_bases_dropped, r.faults_stale_frames, r.stale_frames_refused
    );
    println!(
        "  connections  {} ({} reconnections, {} failed attempts) · ended by: {}",
        r.connections,
        r.reconnections,
        r.connect_failures,
        if r.ended_by.is_empty() {
            "–".to_string()
        } else {
            r.ended_by.join("; ")
        }
    );
    println!(
        "  memory       base+relay {} → peak {} → {} KiB (growth after warm-up {} KiB) · remote peak {} KiB",
        r.rss_start_kib, r.rss_peak_kib, r.rss_end_kib, r.rss_growth_kib, r.remote_rss_peak_kib
    );
    println!(
        "  panics       {} · remote crashes {}",
        r.panics, r.remote_crashes
    );
}
