//! `ndr demo`: the whole link for real, in one process — a remote with the
//! simulated plant, a delaying relay, and a base whose operator follows a
//! signal — over loopback, on UDP datagrams unless told otherwise.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::net::{
    Link, LinkStats, Listener, NetError, Realtime, RealtimeMode, Relay, RelayConfig, TlsConfig,
};
use ndr::netem::LossModel;

use ndr::core::wire::{Role, Seat};
use ndr::net::metrics::RelayLabels;

use crate::args::{DelayArgs, LinkArgs, MetricsArgs, PlantArgs, RecordArgs, RunArgs, record};
use crate::metrics::Served;
use crate::operator::{Kept, operator};
use crate::pauses;
use crate::report::{End, Outcome, Series, finish, with_series_error};
use crate::robot::{DriveSpec, robot};
use crate::runtime::runtime_under;
use crate::throwaway::Throwaway;
use crate::tracking::check_layout;
use crate::transport::{LinkTransport, check_loss};
use crate::watchers::Watcher;

#[derive(clap::Args)]
pub struct DemoArgs {
    #[command(flatten)]
    pub net: DelayArgs,
    #[command(flatten)]
    pub link: LinkArgs,
    #[command(flatten)]
    pub run: RunArgs,
    #[command(flatten)]
    pub plant: PlantArgs,
    #[command(flatten)]
    pub record: RecordArgs,
    /// Datagrams the relay loses each way: none, PERCENT (each
    /// independently, e.g. 1) or ge:PERCENT:BURST (in bursts of BURST
    /// datagrams on average, e.g. ge:2:4). Datagrams (udp, the default,
    /// or quic) only: the relay never drops TCP bytes.
    #[arg(long, default_value = "none")]
    pub loss: LossModel,
    /// Seed of the relay's delays and losses.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    #[command(flatten)]
    pub metrics: MetricsArgs,
    /// Observers watching beside the operator: N more bases, each on a
    /// link of its own through the relay, that receive the robot's state
    /// at their own constant delay and the commands it applied, and send
    /// none (at most 64). The report gives what each saw.
    #[arg(long, value_name = "N")]
    pub observers: Option<usize>,
}

pub fn run(args: &DemoArgs) -> Result<(), String> {
    // Both ends and the relay on loopback: datagrams unless told otherwise,
    // since they hold a lower delay than the stream at every loss rate
    // (docs/benchmarks.md, "Real kernel loss").
    let link = &LinkArgs {
        transport: Some(args.link.transport.unwrap_or(LinkTransport::UDP)),
        ..args.link.clone()
    };
    let mut config = link.config()?;
    let observers = observers(args.observers)?;
    if observers > 0 {
        config.admission.observers = Some(observers);
    }
    check_loss(
        link.transport().carriage(),
        &args.loss,
        "leave --transport out (datagrams)",
    )?;
    // Over QUIC, each side gets a throwaway identity pinned by the other.
    let (base_config, config) = if link.transport().is_quic() {
        let (base, remote) = throwaway_pair()?;
        (config.clone().with_tls(base), config.with_tls(remote))
    } else {
        (config.clone(), config)
    };
    args.run.check_duration()?;
    check_layout(args.run.controller, &link.state)?;
    let max_command = args.plant.max_command()?;
    let model = args.net.model("lan-75km")?;
    let profile = model.name();
    let mut series = Series::create(&args.run.out)?;
    let recorder = args.record.start(link.axes, &link.state)?;
    if !args.run.json {
        // Said up front: the file lands in the current directory by default.
        eprintln!(
            "ndr demo: the base's series goes to {} (--out to change it)",
            args.run.out.display()
        );
    }
    let served = Served::start(&args.metrics, "demo")?;
    // The relay stands for the network and the two applications for a
    // robot's control loops: under the hubs' real-time priority where the
    // hubs ask for one, so that what the demo measures at 1 kHz on a loaded
    // host is the link, not the scheduler's queue in front of them.
    let apps = demo_realtime(config.realtime);
    let _ = apps.enter_current_thread();
    let rt = runtime_under(apps)?;
    let loopback: SocketAddr = ([127, 0, 0, 1], 0).into();
    let set_up = rt.block_on(async {
        let listener = Listener::listen(loopback, config.clone()).await?;
        let relay = Relay::listen(loopback, listener.local_addr()?, model, args.seed)
            .await?
            .with_config(RelayConfig::default().with_loss(args.loss))
            .spawn()?;
        let (remote, base) = tokio::join!(
            listener.accept(),
            Link::connect(relay.local_addr(), base_config.clone())
        );
        let (remote, base) = (remote?, base?);
        // The observers come once the operator's base holds control.
        let mut watching = Vec::with_capacity(observers);
        let mut watched = base_config.clone();
        watched.endpoint.seat = Seat::Observe;
        for _ in 0..observers {
            let (r, o) = tokio::join!(
                listener.accept(),
                Link::connect(relay.local_addr(), watched.clone())
            );
            watching.push((r?, o?));
        }
        let upstream = listener.local_addr()?;
        Ok::<_, NetError>((base, remote, watching, relay, upstream, listener))
    });
    // (The listener lives as long as the links: a shared robot's floor,
    // which grants control, is its.)
    let (mut base, mut remote, watching, relay, upstream, _listener) = match set_up {
        Ok(parts) => parts,
        Err(e) => {
            let (series, error) = series.close();
            let outcome = Outcome {
                profile,
                base: None,
                remote: None,
                relay: None,
                series,
                end: End::NeverConnected(format!("cannot set the demo up: {e}")),
                tracking: None,
                seating: None,
                host: None,
                recording: record::finish(recorder),
                observers: Vec::new(),
            };
            return finish(link, &args.run, &with_series_error(outcome, error));
        }
    };
    let transport = link.transport();
    // A shared robot shows each of its links itself.
    if observers == 0 {
        served.watch_link(
            remote.peer_addr(),
            Role::Remote,
            transport,
            &remote.sender(),
        );
    }
    served.watch_link(base.peer_addr(), Role::Base, transport, &base.sender());
    if let Some(m) = served.metrics() {
        let labels = RelayLabels::new(relay.local_addr().to_string(), upstream.to_string());
        m.watch_relay(labels, &relay.stats_reader());
    }
    // Both sides into one file: the base's releases are the states, the
    // remote's the commands.
    record::attach(recorder.as_ref(), &mut base);
    // A shared robot records each of its links itself.
    if observers == 0 {
        record::attach(recorder.as_ref(), &mut remote);
    }
    // The run starts with the link: the set-up waited for its handshake.
    let until = StdInstant::now() + StdDuration::from_secs_f64(args.run.duration_s);

    let stop = Arc::new(AtomicBool::new(false));
    let remote_stats = Arc::new(Mutex::new(None::<LinkStats>));
    let (base_late, remote_late) = (Mutex::default(), Arc::new(Mutex::default()));
    let watch = pauses::Watch::start();
    let spec = DriveSpec {
        axes: usize::from(link.axes),
        layout: link.state.clone(),
        period: config.endpoint.period,
        max_command,
    };
    let shared_stop = crate::signals::Stop::default();
    let (base_stats, end, tracking, watched) = std::thread::scope(|scope| {
        let robot = if observers == 0 {
            let (stop, remote_stats) = (Arc::clone(&stop), Arc::clone(&remote_stats));
            let late = Arc::clone(&remote_late);
            std::thread::Builder::new()
                .name("ndr-demo-robot".into())
                .spawn_scoped(scope, move || {
                    let session = robot(remote, spec, &stop, &remote_stats, Some(&late));
                    if session.ok() {
                        tracing::info!("remote: {session}");
                    } else {
                        tracing::warn!("remote: {session}");
                    }
                    Vec::new()
                })
                .map_err(|e| e.to_string())?
        } else {
            let (tx, rx) = std::sync::mpsc::channel();
            let mut watchers = Vec::with_capacity(observers);
            let _ = tx.send(remote);
            for (n, (r, o)) in watching.into_iter().enumerate() {
                let _ = tx.send(r);
                watchers.push(Watcher::start(n + 1, o, until, Arc::clone(&stop))?);
            }
            drop(tx);
            let (served, remote_stats, shared_stop) = (&served, &remote_stats, &shared_stop);
            let recorder = recorder.as_ref();
            std::thread::Builder::new()
                .name("ndr-demo-robot".into())
                .spawn_scoped(scope, move || {
                    let figures = crate::shared::Figures {
                        served,
                        transport,
                        recorder,
                        controller_stats: Some(remote_stats),
                    };
                    if let Err(why) = crate::shared::robot(&rx, spec, shared_stop, false, &figures)
                    {
                        tracing::error!("remote: {why}");
                    }
                    // (The watchers go back with the robot's thread.)
                    watchers
                })
                .map_err(|e| e.to_string())?
        };
        let (base_stats, end, tracking) = operator(
            base,
            &args.run,
            link.axes,
            until,
            Some(&remote_stats),
            &mut series,
            Kept {
                late: Some(&base_late),
                seating: None,
            },
        );
        stop.store(true, Ordering::Relaxed);
        shared_stop.set();
        let watchers = robot.join().unwrap_or_else(|_| {
            tracing::error!("remote: the robot's thread panicked");
            Vec::new()
        });
        let mut watched = Vec::with_capacity(watchers.len());
        for w in watchers {
            watched.push(w.join()?);
        }
        Ok::<_, String>((base_stats, end, tracking, watched))
    })?;
    let relay_stats = rt.block_on(relay.shutdown());
    let remote_final = *remote_stats
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let host = pauses::summarize(
        watch,
        &[&base_late, &remote_late],
        pause_aftermath(base_stats.as_ref(), remote_final.as_ref()),
        [base_stats.as_ref(), remote_final.as_ref()]
            .iter()
            .flatten()
            .map(|s| s.endpoint.late)
            .sum(),
    );
    let (series, error) = series.close();
    let outcome = Outcome {
        profile,
        base: base_stats,
        remote: remote_final,
        relay: Some(&relay_stats),
        series,
        end,
        tracking,
        host,
        recording: record::finish(recorder),
        seating: None,
        observers: watched,
    };
    finish(link, &args.run, &with_series_error(outcome, error))
}

/// What the demo's own threads (its relay, base and robot) ask for: the
/// hubs' mode but never refusing to run, a priority under theirs.
fn demo_realtime(hubs: Realtime) -> Realtime {
    let mode = match hubs.mode {
        RealtimeMode::Off => RealtimeMode::Off,
        _ => RealtimeMode::Try,
    };
    let below = hubs.priority.saturating_sub(1).max(1);
    let rt = Realtime::default().with_mode(mode);
    rt.with_priority(below).unwrap_or(rt)
}

/// `--observers`: how many, checked.
fn observers(n: Option<usize>) -> Result<usize, String> {
    match n {
        Some(0) => Err("--observers 0: give at least one observer, or leave it out".into()),
        Some(n) if n > ndr::core::floor::MAX_OBSERVERS => Err(format!(
            "--observers {n}: a remote serves at most {} observers",
            ndr::core::floor::MAX_OBSERVERS
        )),
        n => Ok(n.unwrap_or(0)),
    }
}

/// How long after a host pause its late ticks may still come: the samples
/// it held back cross the network and wait out the playout, so twice the
/// longer of the delay either side holds and half the round trip, and at
/// least two periods.
fn pause_aftermath(base: Option<&LinkStats>, remote: Option<&LinkStats>) -> StdDuration {
    let held = |s: Option<&LinkStats>| {
        s.map_or(0.0, |s| {
            let e = &s.endpoint;
            e.playout_delay_s
                .max(e.grtt.mean() / 2.0)
                .max(2.0 * s.period.as_secs_f64())
        })
    };
    let d = held(base).max(held(remote));
    StdDuration::try_from_secs_f64(2.0 * d).unwrap_or(StdDuration::ZERO)
}

/// TLS for a base and a remote that trust each other's certificate only,
/// made for this run and gone with it.
fn throwaway_pair() -> Result<(TlsConfig, TlsConfig), String> {
    Throwaway::new("demo-quic")
        .and_then(|ids| ids.pair())
        .map_err(|e| format!("cannot make the demo's QUIC certificates: {e}"))
}
