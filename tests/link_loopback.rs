//! The real link over loopback TCP: every sample delivered once and in
//! order, and a constant round trip as the application sees it.

mod common;

use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::time::Duration as StdDuration;

use ndr::core::endpoint::{Config, LinkError, Status};
use ndr::core::time::Duration;
use ndr::core::wire::{CloseReason, Role};
use ndr::net::{Link, LinkConfig, Listener, NetError};

fn config() -> LinkConfig {
    let mut c = Config::paper(Role::Base);
    c = c.with_width(2);
    c.period = Duration::from_millis(10);
    LinkConfig::new(c)
}

fn pair(rt: &tokio::runtime::Runtime) -> (Link, Link) {
    pair_apart(rt, StdDuration::ZERO)
}

/// A pair whose base connects `gap` after the listener is bound: each
/// side's hub starts its tick grid when it is made (the listener's at bind,
/// the base's at connect).
fn pair_apart(rt: &tokio::runtime::Runtime, gap: StdDuration) -> (Link, Link) {
    let listener = rt
        .block_on(Listener::listen(
            "127.0.0.1:0".parse::<SocketAddr>().unwrap(),
            config(),
        ))
        .unwrap();
    let addr = listener.local_addr().unwrap();
    std::thread::sleep(gap);
    rt.block_on(async { tokio::join!(listener.accept(), Link::connect(addr, config())) })
        .pipe(|(r, b)| (b.unwrap(), r.unwrap()))
}

trait Pipe: Sized {
    fn pipe<T>(self, f: impl FnOnce(Self) -> T) -> T {
        f(self)
    }
}
impl<T> Pipe for T {}

#[test]
fn loopback_delivers_every_sample_once_in_order_with_a_constant_grtt() {
    let _serial = common::serial();
    let rt = common::runtime();
    let run = common::assert_regulated(|| {
        let (base, remote) = pair(&rt);
        common::echo_run(base, remote)
    });
    // The initialization pattern sizes the queue from the gaps it saw: 2
    // on a quiet loopback, more when the host held a reception (the round
    // trip was judged against the size chosen). The sizing itself is judged
    // in simulated time (crates/ndr-sim/tests/paper.rs, crates/ndr-core sizing).
    assert!(run.base.ns >= 2, "ns {}", run.base.ns);
    assert!(run.base.lateness.count > 250);
    // Nothing lost at the remote without a counter saying so.
    let remote = run.remote.expect("the remote's stats");
    let r = remote.endpoint;
    assert_eq!(
        r.samples_received,
        r.released_fresh + remote.queue_len as u64 + r.rejected + r.discarded
    );
}

#[test]
fn a_closed_peer_is_reported_and_recv_stops_waiting() {
    let _serial = common::serial();
    let rt = common::runtime();
    let (base, mut remote) = pair(&rt);
    // Let the link start, then close the base.
    std::thread::sleep(StdDuration::from_millis(300));
    drop(base);
    let start = std::time::Instant::now();
    let err = loop {
        match remote.recv_timeout(StdDuration::from_secs(3)) {
            Ok(_) => continue,
            Err(e) => break e,
        }
    };
    assert!(
        start.elapsed() < StdDuration::from_secs(1),
        "{:?}",
        start.elapsed()
    );
    assert!(
        matches!(
            err,
            NetError::Link(LinkError::PeerClosed {
                reason: ndr::core::wire::CloseReason::Normal
            })
        ),
        "{err:?}"
    );
    // The closed link's last stats count the release clock up to its end,
    // not as of the hub's periodic refresh (which a short run sees once).
    let last = remote.stats().expect("stats");
    assert!(last.lateness.count > 1, "{:?}", last.lateness);
    assert!(
        last.release_lateness.count > 1,
        "{:?}",
        last.release_lateness
    );
}

#[test]
fn a_release_handler_on_the_hub_thread_gets_every_sample_once_in_order_and_its_answers_go_out() {
    let _serial = common::serial();
    let rt = common::runtime();
    common::assert_regulated(|| {
        let (mut base, mut remote) = pair(&rt);
        // The remote's "plant" runs on its hub's thread: no thread woken per tick.
        let seen = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let tx = remote.sender();
        let log = std::sync::Arc::clone(&seen);
        remote
            .on_release(move |s| {
                if s.status == Status::Fresh {
                    log.lock().unwrap().push(s.seq);
                }
                tx.send(s.values()).unwrap();
            })
            .unwrap();
        // The remote echoes whole commands (checked by `drive_base`).
        let (base_seqs, grtts, echoed) = common::drive_base(&mut base);
        let base = base.close().unwrap();
        // With a handler, `recv` only waits for the end of the link.
        let end = remote.recv_timeout(StdDuration::from_secs(3));
        assert!(
            matches!(end, Err(NetError::Link(LinkError::PeerClosed { .. }))),
            "{end:?}"
        );
        let remote_seqs = seen.lock().unwrap().clone();
        common::Run {
            base_seqs,
            remote_seqs,
            grtts,
            echoed,
            answers_next_tick: false,
            base,
            remote: remote.stats(),
        }
    });
}

#[test]
fn a_panicking_release_handler_ends_its_own_link_and_the_hub_drives_the_others() {
    let _serial = common::serial();
    let rt = common::runtime();
    let hub = ndr::net::Hub::with_defaults().unwrap();
    let listener = rt
        .block_on(Listener::listen(
            "127.0.0.1:0".parse::<SocketAddr>().unwrap(),
            config().on_hub(hub),
        ))
        .unwrap();
    let addr = listener.local_addr().unwrap();
    let mut links = Vec::new();
    for _ in 0..2 {
        let (r, b) =
            rt.block_on(async { tokio::join!(listener.accept(), Link::connect(addr, config())) });
        links.push((b.unwrap(), r.unwrap()));
    }
    let [(mut base_a, mut remote_a), (_base_b, mut remote_b)] = <[_; 2]>::try_from(links).unwrap();
    let mut releases = 0;
    remote_a
        .on_release(move |_| {
            releases += 1;
            assert!(releases < 5, "the application's bug");
        })
        .unwrap();
    let count = std::sync::Arc::new(std::sync::atomic::AtomicU64::new(0));
    let counted = std::sync::Arc::clone(&count);
    remote_b
        .on_release(move |_| {
            counted.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        })
        .unwrap();
    let err = remote_a.recv_timeout(StdDuration::from_secs(5));
    assert!(
        matches!(err, Err(NetError::Link(LinkError::HandlerPanicked))),
        "{err:?}"
    );
    let peer = loop {
        match base_a.recv_timeout(StdDuration::from_secs(5)) {
            Ok(_) => {}
            Err(e) => break e,
        }
    };
    assert!(
        matches!(
            peer,
            NetError::Link(LinkError::PeerClosed {
                reason: ndr::core::wire::CloseReason::Application
            })
        ),
        "{peer:?}"
    );
    // The other link on the same hub keeps being released.
    let before = count.load(std::sync::atomic::Ordering::Relaxed);
    std::thread::sleep(StdDuration::from_millis(500));
    let after = count.load(std::sync::atomic::Ordering::Relaxed);
    assert!(after >= before + 30, "{before} → {after}");
}

#[test]
fn a_blocking_listener_serves_bases_one_after_another_without_a_runtime() {
    let _serial = common::serial();
    let listener = Listener::listen_blocking("127.0.0.1:0".parse().unwrap(), config()).unwrap();
    let addr = listener.local_addr().unwrap();
    // The robot: echoes each command until its base closes, for two bases.
    let robot = std::thread::spawn(move || {
        let mut served = Vec::new();
        for _ in 0..2 {
            let mut link = listener.accept_blocking().expect("a base");
            let mut releases = Vec::new();
            let end = loop {
                match link.recv() {
                    Ok(command) => {
                        releases.push((command.seq, command.status));
                        link.send(command.values()).expect("send");
                    }
                    Err(e) => break e,
                }
            };
            served.push((releases, end, link.stats().expect("the robot's stats")));
        }
        served
    });
    let mut bases = Vec::new();
    for _ in 0..2 {
        let mut base = Link::connect_blocking(addr, config()).expect("connect");
        let mut states = 0;
        while states < 30 {
            base.send(&[1.0, 2.0]).unwrap();
            let state = base.recv().expect("a state");
            if state.status == Status::Fresh && state.values() == [1.0, 2.0] {
                states += 1;
            }
        }
        bases.push(base.close().expect("the base's stats"));
    }
    let served = robot.join().expect("the robot's thread");
    for ((releases, end, robot), base) in served.into_iter().zip(bases) {
        // Every command once, in order, and the base's close as the end.
        // A host that holds the robot's hub past the queue's slack makes
        // an underflow: the last command is released again, marked held
        // (by design); a fresh release never repeats a seq, and skips one
        // only where a side counted it dropped or lost.
        let fresh: Vec<u64> = releases
            .iter()
            .filter(|r| r.1 == Status::Fresh)
            .map(|r| r.0)
            .collect();
        // The base's 30 fresh states went out at 30 of the robot's ticks,
        // each of which released a command, fresh or held.
        assert!(
            releases.len() as u64 + robot.app_dropped >= 30,
            "{} commands released, {} dropped",
            releases.len(),
            robot.app_dropped
        );
        let missing: u64 = fresh
            .windows(2)
            .map(|w| w[1].saturating_sub(w[0] + 1))
            .sum();
        let counted = base.endpoint.tx_dropped + robot.endpoint.samples_lost + robot.app_dropped;
        assert!(
            fresh.windows(2).all(|w| w[1] > w[0]) && missing <= counted,
            "{missing} missing, {counted} counted: {releases:?}"
        );
        // A held release repeats the last fresh one (a newer seq only where
        // a fresh release was dropped before the application saw it).
        let mut last_fresh = None;
        for &(seq, status) in &releases {
            if status == Status::Fresh {
                last_fresh = Some(seq);
            } else {
                let repeat = Some(seq) == last_fresh
                    || (robot.app_dropped > 0 && last_fresh.is_none_or(|f| seq > f));
                assert!(repeat, "{status:?} {seq}: {releases:?}");
            }
        }
        assert!(
            matches!(
                end,
                NetError::Link(LinkError::PeerClosed {
                    reason: CloseReason::Normal
                })
            ),
            "{end}"
        );
    }
}

#[test]
fn blocking_calls_on_a_runtime_or_an_async_listener_say_what_to_await() {
    let rt = common::runtime();
    let listener = rt
        .block_on(Listener::listen("127.0.0.1:0".parse().unwrap(), config()))
        .unwrap();
    let err = listener.accept_blocking().unwrap_err();
    assert!(err.to_string().contains("accept().await"), "{err}");
    // A blocking listener dropped inside async code does not panic, and the
    // blocking calls made there are refused, not a panic of tokio's.
    let blocking = Listener::listen_blocking("127.0.0.1:0".parse().unwrap(), config()).unwrap();
    let addr = listener.local_addr().unwrap();
    rt.block_on(async move {
        let err = blocking.accept_blocking().unwrap_err();
        assert!(err.to_string().contains("accept().await"), "{err}");
        drop(blocking);
        let err = Listener::listen_blocking("127.0.0.1:0".parse().unwrap(), config()).unwrap_err();
        assert!(
            err.to_string().contains("Listener::listen(..).await"),
            "{err}"
        );
        let err = Link::connect_blocking(addr, config()).unwrap_err();
        assert!(err.to_string().contains("Link::connect(..).await"), "{err}");
    });
}

/// The drive contract, across drivers: a remote whose application answers
/// on its hub's thread (a release handler) answers in the frame of the
/// tick that released the command, as the simulator's plant does, so a
/// loopback link and the simulator with the same grids' phase and a
/// loopback's delay see the same GRTT.
///
/// One run, judged with margins a host's pauses cannot break: answers in
/// their tick's frame but for a few, and two per tick a hub missed; the
/// link's GRTT constant at its level (`common::judge_grtts`); and its
/// whole ticks the simulator's, taken to the link's queue size by the
/// FIFO's relation (2·ns·T: a host that held a hub through the
/// initialization pattern sizes the queue larger), or whole periods from
/// it, one per underflow or tick missed counted (the FIFO's delay steps a
/// period when a held hub runs its queue dry, by design) and one either
/// way when the grids' phase is within 1.5 ms of their meeting (a frame
/// then counts for one tick or the next by the loopback's jitter). What a
/// GRTT holds past its whole ticks is its release's lateness, the host's:
/// that the FIFO makes the round trip exactly constant, to the
/// nanosecond, is judged in simulated time (the simulator's own std
/// below, crates/ndr-sim/tests/paper.rs).
#[test]
fn the_simulator_and_a_loopback_link_with_a_release_handler_agree_on_the_grtt() {
    use ndr::sim::delay::DelayModel;
    use ndr::sim::{SimConfig, run};

    let _serial = common::serial();
    let rt = common::runtime();
    let period = 0.010;
    // Half a period apart, the two hubs' grids are clear of each other.
    let (mut base, mut remote) = pair_apart(&rt, StdDuration::from_millis(5));
    // The remote answers each command with the sequence number of the
    // frame that brought it, and notes when it released it.
    let released = std::sync::Arc::new(std::sync::Mutex::new(BTreeMap::new()));
    let (tx, log) = (remote.sender(), std::sync::Arc::clone(&released));
    remote
        .on_release(move |s| {
            if s.status == Status::Fresh {
                log.lock().unwrap().insert(s.seq, s.released_at);
                tx.send(&[s.seq as f64, 0.0]).unwrap();
            }
        })
        .unwrap();
    let (mut grtts, mut answers, mut grtt_ns) = (Vec::new(), Vec::new(), Vec::new());
    for k in 1..=300u32 {
        base.send(&[f64::from(k), 0.0]).unwrap();
        let s = base.recv_timeout(StdDuration::from_secs(5)).unwrap();
        if s.status == Status::Fresh {
            grtts.extend(s.grtt.map(|g| (s.released_at.as_nanos(), g.as_secs_f64())));
            grtt_ns.extend(s.grtt.map(Duration::as_nanos));
            // The answer's frame left at its tick (`sent_at`, the remote's
            // clock) after the command's release.
            answers.push((s.values()[0] as u64, s.sent_at));
        }
    }
    let stats = base.close().unwrap();
    let remote_stats = remote.stats().expect("the remote's stats");
    let released = released.lock().unwrap();
    let lags: Vec<f64> = answers
        .iter()
        .filter_map(|&(seq, sent)| {
            let at = released.get(&seq)?;
            Some(sent.signed_nanos_since(*at) as f64 * 1e-9 / period)
        })
        .collect();
    let missed = (stats.lateness.missed + remote_stats.lateness.missed) as usize;
    // Each answer left in the frame of the tick that released its command
    // (its stamp that tick's, the release a little after it), but where
    // the host held the hub half a period: 2 %, and two per tick missed.
    let late = lags.iter().filter(|&&l| l.abs() >= 0.5).count();
    assert!(
        lags.len() > 250usize.saturating_sub(2 * missed),
        "{} answers ({missed} ticks missed)",
        lags.len()
    );
    assert!(
        late <= lags.len() / 50 + 2 * missed,
        "{} answers, {late} left half a period or more after their command's release \
         ({missed} ticks missed): {lags:?}",
        lags.len()
    );
    // Its assertions: the round trip held at its level but for a few strays.
    common::judge_grtts(&grtts, &[&stats, &remote_stats]);
    // The remote's ticks, at k·T on its own clock, fall θ = local − peer
    // after the base's on the base's clock.
    let phase = stats.endpoint.clock_offset_s.rem_euclid(period);
    let clear = (1.5e-3..=period - 1.5e-3).contains(&phase);
    // The loopback's own delay: its least round trip (a host's stall only
    // lengthens one).
    let one_way = Duration::from_secs_f64(stats.endpoint.nrtt.min() / 2.0);
    let mut cfg = SimConfig::paper(DelayModel::Constant {
        fwd: one_way,
        bwd: one_way,
    });
    cfg.period = Duration::from_secs_f64(period);
    cfg.remote_phase = Duration::from_secs_f64(phase);
    cfg.axes = 2;
    cfg.duration = Duration::from_secs(10);
    let sim = run(&cfg).unwrap().report;
    assert!(
        sim.grtt_std_s < 1e-6,
        "the simulator's GRTT std {}",
        sim.grtt_std_s
    );
    // A GRTT runs from the command's scheduled tick to the moment its
    // answer was released: whole ticks of the base's grid, plus that
    // release's lateness, which the host decides (a loaded host makes
    // every release late by about the same, which no median phase
    // removes). The simulator releases on its ticks: its GRTT is whole
    // ticks. So the link's is compared in whole ticks: each GRTT's floor,
    // exact for a release less than a period late (a later one is a tick
    // missed, counted), and their median (`judge_grtts` bounds the strays).
    // The tolerance is whole steps the run counted, and one when the
    // grids' phase is inside the clearance asked of it above.
    let period_ns = stats.period.as_nanos();
    let mut ticks: Vec<u64> = grtt_ns.iter().map(|g| g / period_ns).collect();
    ticks.sort_unstable();
    let link_ticks = ticks[ticks.len() / 2] as f64;
    let sim_ticks = sim.grtt_mean_s / period;
    assert!(
        (sim_ticks - sim_ticks.round()).abs() < 1e-6,
        "the simulator's GRTT {} s, not whole ticks",
        sim.grtt_mean_s
    );
    let at_ns = sim_ticks.round() + 2.0 * (stats.ns as f64 - sim.ns as f64);
    let underflows = stats.endpoint.underflows + remote_stats.endpoint.underflows;
    let steps = (underflows as usize + missed + usize::from(!clear)) as f64;
    assert!(
        (link_ticks - at_ns).abs() <= steps,
        "the simulator's GRTT {} s (ns {}), {at_ns} ticks at the link's ns {}; the link's \
         {link_ticks} ticks, at phase {phase} s; {underflows} underflows, {missed} ticks missed",
        sim.grtt_mean_s,
        sim.ns,
        stats.ns
    );
}
