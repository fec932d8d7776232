//! The soak itself: the base's link through the relay, the faults in
//! turn, the memory sampled, until the time is up or a signal comes.

use std::net::{SocketAddr, TcpListener as StdListener};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::endpoint::Transport;
use ndr::net::{Hub, Link, LinkConfig, NetError, Relay, RelayConfig, RelayHandle};
use ndr::sim::delay::DelayModel;

use super::args::SoakArgs;
use super::check::{Check, Conn, add_relay, check, finish_conn, join_checks, link_up};
use super::faults::{
    FAKE_SESSION, garbage_datagrams, hung_base, idle_crowd, inject_garbage, stale_frame,
};
use super::link::LIVENESS;
use super::memory::rss_kib;
use super::quic::{Quic, quic_hung_base, quic_replay, stranger_refused};
use super::remote::Remote;
use super::report::{SoakReport, summarize};
use super::trace::{SPIKE_EVERY_FAULTS, spike_trace, spikes_within};
use crate::runtime::runtime;

pub(super) fn soak(args: &SoakArgs, config: LinkConfig) -> Result<SoakReport, String> {
    // First made, last dropped: the identities' directory outlives the
    // remote, and goes however the soak ends.
    let quic = if args.transport.quic {
        Some(Quic::new(&config)?)
    } else {
        None
    };
    let base_config = quic
        .as_ref()
        .map_or_else(|| config.clone(), |q| q.base.clone());
    let remote_tls = quic.as_ref().map(|q| q.remote.clone()).unwrap_or_default();
    let panics = Arc::new(AtomicU64::new(0));
    {
        let panics = Arc::clone(&panics);
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            panics.fetch_add(1, Ordering::Relaxed);
            default(info);
        }));
    }
    let rt = runtime()?;
    // Stopped early, it still reports, stops its remote and removes its
    // identities.
    let interrupted = crate::signals::interrupts(&rt, "ndr soak")?;
    let hub = Hub::new(config.spin_margin).map_err(|e| e.to_string())?;
    let remote_addr = free_port()?;
    let relay_addr = free_port()?;
    let mut remote = Remote::start(remote_addr, args.period_ms, args.transport, remote_tls)?;
    let spike_every = args.fault_every_s * SPIKE_EVERY_FAULTS;
    let trace = Arc::new(spike_trace(args.duration_s, spike_every)?);
    let relay_config = RelayConfig {
        loss: args.loss,
        ..RelayConfig::default()
    };
    // Each relay started draws other losses (`seed`): the same delays, but
    // not the same datagrams lost after each restart.
    let start_relay = |rt: &tokio::runtime::Runtime, seed: u64| -> Result<RelayHandle, String> {
        let deadline = StdInstant::now() + StdDuration::from_secs(5);
        loop {
            let bound = rt.block_on(async {
                Relay::bind(
                    relay_addr,
                    remote_addr,
                    DelayModel::Trace(Arc::clone(&trace)),
                    seed,
                )
                .await?
                .with_config(relay_config.clone())
                .spawn()
            });
            match bound {
                Ok(h) => return Ok(h),
                Err(_) if StdInstant::now() < deadline => {
                    std::thread::sleep(StdDuration::from_millis(20));
                }
                Err(e) => return Err(format!("cannot start the relay: {e}")),
            }
        }
    };
    let mut relay = Some(start_relay(&rt, 1)?);
    let mut relay_started = StdInstant::now();
    let datagrams = args.transport.transport != Transport::Stream;
    // What the hung and stale-frame bases say in their Hello: a token on
    // datagrams (0 would be a stream, which the remote refuses).
    let session = if datagrams { FAKE_SESSION } else { 0 };
    let mut r = SoakReport {
        command: "soak",
        duration_s: args.duration_s,
        period_s: config.endpoint.period.as_secs_f64(),
        // As `--transport` was given: tcp, udp, udp:K, udp:K:R, quic, …
        transport: args
            .transport
            .transport
            .to_string()
            .replacen("stream", "tcp", 1)
            .replacen("datagram", if quic.is_some() { "quic" } else { "udp" }, 1),
        loss: args.loss.to_string(),
        rss_start_kib: rss_kib("/proc/self/statm"),
        ..SoakReport::default()
    };
    let start = StdInstant::now();
    let end = start + StdDuration::from_secs_f64(args.duration_s);
    let every = StdDuration::from_secs_f64(args.fault_every_s);
    let warm = start + StdDuration::from_secs_f64((args.duration_s * 0.1).min(30.0));
    let mut rss_after_warm: Option<u64> = None;
    let mut next_fault = start + every;
    let mut next_sample = start;
    let mut fault = 0u64;
    let mut link: Option<(Link, Conn)> = None;
    let mut command = 0.0f64;
    let period = config.endpoint.period;
    // The idle crowd, held until the next fault; the checks that run on
    // their own threads (the hung base's, over QUIC the replay's), each
    // with what it adds to the report once it passed.
    let mut idle: Vec<tokio::net::TcpStream> = Vec::new();
    let mut checks: Vec<Check> = Vec::new();
    while StdInstant::now() < end && !interrupted.load(Ordering::Relaxed) {
        join_checks(&mut r, &mut checks, false);
        let now = StdInstant::now();
        if now >= next_sample {
            next_sample += StdDuration::from_secs(1);
            let rss = rss_kib("/proc/self/statm");
            r.rss_peak_kib = r.rss_peak_kib.max(rss);
            r.remote_rss_peak_kib = r.remote_rss_peak_kib.max(remote.rss_kib());
            if now >= warm && rss_after_warm.is_none() {
                rss_after_warm = Some(rss);
            }
        }
        if now >= next_fault {
            next_fault += every;
            match fault % 6 {
                0 => {
                    if let Some(h) = relay.take() {
                        r.faults_spikes += spikes_within(relay_started.elapsed(), spike_every);
                        add_relay(&mut r, &rt.block_on(h.shutdown()));
                    }
                    r.faults_relay_restarts += 1;
                    relay = Some(start_relay(&rt, 1 + r.faults_relay_restarts)?);
                    relay_started = StdInstant::now();
                }
                1 => {
                    r.faults_garbage += 1;
                    let cut_off = match &quic {
                        // No TCP port to send garbage to: a stranger's handshake.
                        Some(q) => stranger_refused(&rt, remote_addr, q.stranger.clone()),
                        None => inject_garbage(remote_addr, fault / 3),
                    };
                    if cut_off {
                        r.garbage_cut_off += 1;
                    }
                    if datagrams {
                        let was_up = link_up(link.as_ref());
                        let (sent, counted) = garbage_datagrams(&mut remote, fault / 3);
                        r.garbage_datagrams += sent;
                        r.garbage_datagrams_counted += counted;
                        if was_up && !link_up(link.as_ref()) {
                            r.garbage_datagrams_harmed += 1;
                        }
                    }
                }
                2 => {
                    if remote.restart()? {
                        r.remote_crashes += 1;
                    }
                    r.faults_remote_killed += 1;
                }
                // Over QUIC, none: the remote has no TCP port, and the
                // crowd's QUIC form, strangers that never finish their
                // handshake, needs a QUIC client that stops halfway, which
                // the link does not offer (tests/link_quic.rs holds one off
                // with a path that passes its first packet only).
                3 if quic.is_some() => {}
                3 => {
                    r.faults_idle_crowds += 1;
                    idle = idle_crowd(&rt, remote_addr);
                    r.idle_connections_held += idle.len() as u64;
                }
                4 => {
                    idle.clear();
                    r.faults_hung_bases += 1;
                    let side = quic.as_ref().map(|q| (rt.handle().clone(), q.side.clone()));
                    let check = std::thread::spawn(move || match side {
                        Some((rt, side)) => quic_hung_base(&rt, remote_addr, side),
                        None => hung_base(remote_addr, period, session, LIVENESS),
                    });
                    checks.push((check, |r| r.hung_bases_dropped += 1));
                }
                _ => {
                    r.faults_stale_frames += 1;
                    if let Some(q) = &quic {
                        let (rt, side) = (rt.handle().clone(), q.side.clone());
                        let check = std::thread::spawn(move || quic_replay(&rt, remote_addr, side));
                        checks.push((check, |r| r.stale_frames_refused += 1));
                    } else if stale_frame(remote_addr, period, session) {
                        r.stale_frames_refused += 1;
                    }
                }
            }
            fault += 1;
        }
        let Some((l, conn)) = link.as_mut() else {
            match rt.block_on(Link::connect(
                relay_addr,
                base_config.clone().on_hub(hub.clone()),
            )) {
                Ok(l) => {
                    r.connections += 1;
                    if r.connections > 1 {
                        r.reconnections += 1;
                    }
                    link = Some((l, Conn::default()));
                }
                Err(_) => {
                    r.connect_failures += 1;
                    std::thread::sleep(StdDuration::from_millis(20));
                }
            }
            continue;
        };
        match l.recv_timeout(StdDuration::from_millis(100)) {
            Ok(s) => {
                check(&mut r, conn, s.status, s.seq, s.values());
                command += 1.0;
                let _ = l.send(&[command, 0.0, 0.0, 0.0]);
            }
            Err(NetError::Timeout) => {}
            Err(e) => {
                r.ended_by.push(e.to_string());
                if let Some((l, conn)) = link.take() {
                    finish_conn(&mut r, &conn, l.close());
                }
            }
        }
    }
    if let Some((l, conn)) = link.take() {
        finish_conn(&mut r, &conn, l.close());
    }
    drop(idle);
    join_checks(&mut r, &mut checks, true);
    if let Some(h) = relay.take() {
        r.faults_spikes += spikes_within(relay_started.elapsed(), spike_every);
        add_relay(&mut r, &rt.block_on(h.shutdown()));
    }
    if matches!(remote.child.try_wait(), Ok(Some(_))) {
        r.remote_crashes += 1;
    }
    drop(remote);
    r.interrupted = interrupted.load(Ordering::Relaxed);
    r.ran_s = start.elapsed().as_secs_f64();
    r.rss_end_kib = rss_kib("/proc/self/statm");
    r.rss_growth_kib = r.rss_end_kib as i64 - rss_after_warm.unwrap_or(r.rss_start_kib) as i64;
    r.panics = panics.load(Ordering::Relaxed);
    // Collapse the reasons connections ended into counts.
    r.ended_by = summarize(&r.ended_by);
    r.ok = r.lost + r.duplicated + r.reordered + r.corrupted + r.remote_anomalies == 0
        && r.hung_bases_dropped == r.faults_hung_bases
        && r.stale_frames_refused == r.faults_stale_frames
        && r.garbage_datagrams_counted == r.garbage_datagrams
        && r.garbage_datagrams_harmed == 0
        && r.panics == 0
        && r.remote_crashes == 0
        && r.samples_released > 0
        && r.rss_growth_kib < 16 * 1024;
    Ok(r)
}

fn free_port() -> Result<SocketAddr, String> {
    let l = StdListener::bind("127.0.0.1:0").map_err(|e| e.to_string())?;
    l.local_addr().map_err(|e| e.to_string())
}
