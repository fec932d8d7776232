//! `ndr base` and `ndr remote`: the two peers as separate processes or hosts.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::net::metrics::LinkLabels;
use ndr::net::{Link, LinkStats, Listener, NetError, tls};

use ndr::core::endpoint::Event;
use ndr::core::wire::{Role, Seat};

use crate::args::{
    LinkArgs, MetricsArgs, ObserverTrustArgs, PlantArgs, RecordArgs, RunArgs, SecurityArgs,
    ZenohArgs, record, resolve,
};
use crate::metrics::Served;
use crate::operator::{Kept, operator};
use crate::report::{End, Outcome, Seating, Series, finish, with_series_error};
use crate::robot::{DriveSpec, robot};
use crate::runtime::runtime;
use crate::signals::{self, Stop, counters};

#[derive(clap::Args)]
pub struct BaseArgs {
    /// The remote (or a relay in front of it) to connect to: HOST:PORT, a
    /// name or an address (the first address the name resolves to).
    #[arg(long, value_name = "HOST:PORT", required_unless_present = "robot")]
    pub connect: Option<String>,
    /// With --transport zenoh: the name of the robot to connect to (its
    /// remote's --name), found through zenoh instead of --connect.
    #[arg(long, value_name = "NAME", conflicts_with = "connect")]
    pub robot: Option<String>,
    #[command(flatten)]
    pub zenoh: ZenohArgs,
    #[command(flatten)]
    pub link: LinkArgs,
    #[command(flatten)]
    pub security: SecurityArgs,
    #[command(flatten)]
    pub run: RunArgs,
    #[command(flatten)]
    pub metrics: MetricsArgs,
    #[command(flatten)]
    pub record: RecordArgs,
    /// Watch the robot without commanding it: the remote (started with
    /// --observers) sends its state and the commands it applied; this
    /// base sends none. The report's role is `observer`.
    #[arg(long, conflicts_with = "wait_for_control")]
    pub observe: bool,
    /// If another base holds control, watch as an observer until it is
    /// handed over (that base leaves, yields or goes silent), for at most
    /// SECS; --duration-s then counts from the grant. Fails if control was
    /// not granted in time. The report gives `waited_for_control_s`.
    #[arg(long, value_name = "SECS")]
    pub wait_for_control: Option<f64>,
    /// Wait up to SECS for a remote that is not there yet (the connection
    /// refused, the host unreachable, no answer), trying again after
    /// 0.1 s, 0.2 s, … up to 1 s apart; --duration-s then counts from the
    /// connection. The report gives `waited_for_remote_s`.
    #[arg(long, value_name = "SECS")]
    pub wait_for_remote: Option<f64>,
    /// When the link loses the remote (it stopped, restarted, or went
    /// silent past --liveness-s), connect again by itself, until the run's
    /// duration is over: the robot holds while the link is down, the new
    /// link runs its initialization pattern, no state of the old link is
    /// released after the new one's. The report counts the reconnects and
    /// the time the link was down.
    #[arg(long)]
    pub reconnect: bool,
}

#[derive(clap::Args)]
pub struct RemoteArgs {
    /// Where to wait for bases.
    #[arg(long, value_name = "ADDR", required_unless_present = "name")]
    pub listen: Option<SocketAddr>,
    /// With --transport zenoh: the robot's name, by which bases find it
    /// through zenoh (`ndr base --robot NAME`), instead of --listen.
    #[arg(long, value_name = "NAME", conflicts_with = "listen")]
    pub name: Option<String>,
    #[command(flatten)]
    pub zenoh: ZenohArgs,
    #[command(flatten)]
    pub link: LinkArgs,
    #[command(flatten)]
    pub security: SecurityArgs,
    #[command(flatten)]
    pub plant: PlantArgs,
    #[command(flatten)]
    pub record: RecordArgs,
    /// Serve one base, then exit: with status 0 if the base closed the link
    /// in order (by default it serves one after another, until SIGINT or
    /// SIGTERM, and exits 0 then; SIGUSR1 prints the listener's counters).
    #[arg(long)]
    pub once: bool,
    #[command(flatten)]
    pub metrics: MetricsArgs,
    /// Share the robot: serve one controlling base and up to N observers
    /// at once (4 if N is not given, at most 64); a base that asks for
    /// control while another holds it is refused, or waits as an observer
    /// (`ndr base --wait-for-control`) and is handed control when it
    /// frees. Without it, one base at a time, the next told "busy". With
    /// --once, it stops when the last base has left.
    #[arg(long, value_name = "N", num_args = 0..=1, default_missing_value = "4")]
    pub observers: Option<usize>,
    #[command(flatten)]
    pub observer_trust: ObserverTrustArgs,
    /// When it stops, print one JSON object on stdout: the listener's
    /// counters, the hand-overs of control, the commands refused, and each
    /// base's session.
    #[arg(long)]
    pub json: bool,
}

/// The operator's side: runs `--duration-s` over the link, then reports how
/// it ended; fails (after the report) when no link came up or it failed.
pub fn base(args: &BaseArgs) -> Result<(), String> {
    let mut config = args.link.config()?;
    let tls = args.security.apply(&mut config)?;
    crate::transport::check_security(args.link.transport(), tls.is_some())?;
    args.run.check_duration()?;
    crate::tracking::check_layout(args.run.controller, &args.link.state)?;
    let zenoh = by_name(
        args.link.transport(),
        args.robot.as_deref(),
        &args.zenoh,
        "--robot",
    )?;
    let connect_to = match &args.connect {
        Some(connect) => resolve("--connect", connect)?,
        // A zenoh link has no address.
        None => SocketAddr::from((std::net::Ipv4Addr::UNSPECIFIED, 0)),
    };
    // Refused as the link would refuse it, before the series is created.
    if !zenoh && tls.is_none() && !tls::plain_allowed(connect_to.ip(), config.insecure) {
        return Err(NetError::Insecure(connect_to).to_string());
    }
    let seat = seat(args)?;
    config.endpoint.seat = seat;
    let wait_for_remote = match args.wait_for_remote {
        Some(secs) if !(secs.is_finite() && secs > 0.0) => {
            return Err(format!(
                "--wait-for-remote must be a positive number of seconds, got {secs}"
            ));
        }
        Some(secs) => StdDuration::from_secs_f64(secs),
        None => StdDuration::ZERO,
    };
    config.wait_for_remote = wait_for_remote.into();
    config.reconnect = args.reconnect;
    let mut series = Series::create(&args.run.out)?;
    let served = Served::start(&args.metrics, "base")?;
    let recorder = args.record.start(args.link.axes, &args.link.state)?;
    let rt = runtime()?;
    let started = StdInstant::now();
    let run_for = StdDuration::from_secs_f64(args.run.duration_s);
    let wait_for = StdDuration::from_secs_f64(args.wait_for_control.unwrap_or(0.0));
    config.tls.clone_from(&tls);
    let connect = dial(args, connect_to, config.clone());
    // The connection counts in the run's duration (and the waits for
    // control and for the remote): a peer that never answers the SYN must
    // not hold the base beyond it.
    let connected = rt.block_on(async {
        tokio::time::timeout(run_for + wait_for + wait_for_remote, connect).await
    });
    let connected_at = StdInstant::now();
    let mut seating = Seating {
        role: if seat == Seat::Control {
            "controller"
        } else {
            "observer"
        },
        waited_for_control_s: None,
        terms_seen: Vec::new(),
    };
    let (stats, end, tracking) = match connected {
        Ok(Ok(mut link)) => {
            record::attach(recorder.as_ref(), &mut link);
            served.watch_link(
                connect_to,
                Role::Base,
                args.link.transport(),
                &link.sender(),
            );
            let granted = match args.wait_for_control {
                Some(secs) => wait_for_control(&mut link, started + wait_for, secs),
                None => Ok(()),
            };
            match granted {
                Ok(()) => {
                    if seat == Seat::WaitForControl {
                        seating.role = "controller";
                        seating.waited_for_control_s = Some(started.elapsed().as_secs_f64());
                    }
                    // A waiting base runs its duration from the grant, or
                    // from the connection.
                    let until = if seat == Seat::WaitForControl {
                        StdInstant::now() + run_for
                    } else if args.wait_for_remote.is_some() {
                        connected_at + run_for
                    } else {
                        started + run_for
                    };
                    operator(
                        link,
                        &args.run,
                        args.link.axes,
                        until,
                        None,
                        &mut series,
                        Kept {
                            late: None,
                            seating: Some(&mut seating),
                        },
                    )
                }
                Err(end) => (link.close(), end, None),
            }
        }
        Ok(Err(e)) => (
            None,
            match crate::report::refusal(&e) {
                Some(reason) => End::Refused {
                    reason,
                    why: format!("cannot connect to {connect_to}: {e}"),
                },
                None => End::NeverConnected(crate::explain::cannot_connect(
                    &e,
                    connect_to,
                    args.link.transport(),
                )),
            },
            None,
        ),
        Err(_) => (
            None,
            End::NeverConnected(format!(
                "no connection to {connect_to} within the {} s run",
                args.run.duration_s
            )),
            None,
        ),
    };
    let end = crate::explain::udp_silence(end, args.link.transport(), connect_to, stats.as_ref());
    let (series, error) = series.close();
    let outcome = Outcome {
        profile: crate::report::base_profile(args.link.transport(), connect_to, tls.is_some()),
        base: stats,
        remote: None,
        relay: None,
        series,
        end,
        tracking,
        host: None,
        recording: record::finish(recorder),
        seating: Some(seating),
        observers: Vec::new(),
    };
    finish(&args.link, &args.run, &with_series_error(outcome, error))
}

/// Whether the link runs over zenoh, found by `name` (`flag`); refuses
/// the name or zenoh's options without `--transport zenoh`, and zenoh
/// without a name.
fn by_name(
    transport: ndr::net::Transport,
    name: Option<&str>,
    zenoh: &ZenohArgs,
    flag: &str,
) -> Result<bool, String> {
    match (transport.is_zenoh(), name) {
        (true, Some(_)) => Ok(true),
        (true, None) => Err(format!(
            "--transport zenoh finds the robot by its name: give {flag} NAME (and \
             --zenoh-connect tcp/HOST:7447 for a router)"
        )),
        (false, Some(_)) => Err(format!(
            "{flag} names a robot over zenoh: give --transport zenoh too"
        )),
        (false, None) if zenoh.given() => {
            Err("--zenoh-connect and --zenoh-config apply to --transport zenoh: give it too".into())
        }
        (false, None) => Ok(false),
    }
}

/// Connects as `ndr base` says: to `addr`, or over zenoh by the robot's name.
async fn dial(
    args: &BaseArgs,
    addr: SocketAddr,
    config: ndr::net::LinkConfig,
) -> Result<Link, NetError> {
    #[cfg(feature = "zenoh")]
    if let (true, Some(robot)) = (args.link.transport().is_zenoh(), &args.robot) {
        return Link::connect_zenoh(robot, &args.zenoh.options(&[]), config).await;
    }
    #[cfg(not(feature = "zenoh"))]
    let _ = args;
    Link::connect(addr, config).await
}

/// Listens as `ndr remote` says: on its address, or over zenoh by its name.
async fn listen(args: &RemoteArgs, config: ndr::net::LinkConfig) -> Result<Listener, NetError> {
    #[cfg(feature = "zenoh")]
    if let (true, Some(name)) = (args.link.transport().is_zenoh(), &args.name) {
        return Listener::listen_zenoh(name, &args.zenoh.options(&[]), config).await;
    }
    let addr = args
        .listen
        .unwrap_or_else(|| SocketAddr::from((std::net::Ipv4Addr::UNSPECIFIED, 0)));
    Listener::listen(addr, config).await
}

/// The seat `ndr base` asks for.
fn seat(args: &BaseArgs) -> Result<Seat, String> {
    match args.wait_for_control {
        Some(secs) if !(secs.is_finite() && secs > 0.0) => Err(format!(
            "--wait-for-control must be a positive number of seconds, got {secs}"
        )),
        Some(_) => Ok(Seat::WaitForControl),
        None if args.observe => Ok(Seat::Observe),
        None => Ok(Seat::Control),
    }
}

/// A base waiting for control: watches (states released, events) until
/// the remote grants control, or fails at `deadline`.
fn wait_for_control(link: &mut Link, deadline: StdInstant, secs: f64) -> Result<(), End> {
    let mut released = 0_u64;
    loop {
        for event in link.drain_events() {
            crate::logging::event("base", &event);
            if let Event::ControlGranted { term } = event {
                tracing::info!("base: control granted (term {term})");
                return Ok(());
            }
        }
        let left = deadline.saturating_duration_since(StdInstant::now());
        if left.is_zero() {
            return Err(End::NotGranted(format!(
                "control was not granted within --wait-for-control {secs} s: another base \
                 held it throughout; wait longer, or ask its operator to yield"
            )));
        }
        match link.recv_timeout(left.min(StdDuration::from_millis(50))) {
            Ok(_) => released += 1,
            Err(NetError::Timeout) => {}
            Err(e) => return Err(crate::report::link_ended(&e, released)),
        }
    }
}

/// The robot's side: serves bases one after another (or one with
/// `--once`), or several at once with `--observers`; a line for each
/// base's end, the listener's counters at exit (and, with `--json`, the
/// report on stdout).
pub fn remote(args: &RemoteArgs) -> Result<(), String> {
    let mut config = args.link.config()?;
    let tls = args.security.apply(&mut config)?;
    let tls = args.observer_trust.apply(tls)?;
    crate::transport::check_security(args.link.transport(), tls.is_some())?;
    let zenoh = by_name(
        args.link.transport(),
        args.name.as_deref(),
        &args.zenoh,
        "--name",
    )?;
    let max_command = args.plant.max_command()?;
    if let Some(n) = args.observers
        && n > ndr::core::floor::MAX_OBSERVERS
    {
        return Err(format!(
            "--observers {n}: a remote serves at most {} observers",
            ndr::core::floor::MAX_OBSERVERS
        ));
    }
    config.admission.observers = args.observers;
    let recorder = args.record.start(args.link.axes, &args.link.state)?;
    let rt = runtime()?;
    config.tls = tls;
    let place = match (&args.name, args.listen) {
        (Some(name), _) if zenoh => format!("zenoh as {name:?}"),
        (_, Some(addr)) => addr.to_string(),
        _ => String::new(),
    };
    let listener = rt
        .block_on(listen(args, config.clone()))
        .map_err(|e| format!("cannot listen on {place}: {e}"))?;
    // Alone, one base at a time: the next one is told the robot is busy.
    // Shared, the floor admits one controller and the observers.
    let listener = if args.observers.is_some() {
        listener
    } else {
        listener.with_max_links(1)
    };
    let listener = Arc::new(listener);
    let addr = listener.local_addr().map_err(|e| e.to_string())?;
    let served = Served::start(&args.metrics, "remote")?;
    if let Some(m) = served.metrics() {
        let labels = LinkLabels::new(addr.to_string(), Role::Remote, args.link.transport());
        m.watch_listener(labels, &listener);
    }
    let stop = Arc::new(Stop::default());
    signals::watch(&rt, Arc::clone(&listener), Arc::clone(&stop))?;
    let spec = DriveSpec {
        axes: usize::from(args.link.axes),
        layout: args.link.state.clone(),
        period: config.endpoint.period,
        max_command,
    };
    let (sessions, failure) = match args.observers {
        Some(n) => {
            eprintln!(
                "ndr remote: waiting for bases on {addr} (a controller and up to {n} observers; \
                 SIGUSR1: print the counters; SIGINT or SIGTERM: stop)"
            );
            serve_shared(
                args,
                (&served, recorder.as_ref()),
                &rt,
                &listener,
                &stop,
                spec,
            )
        }
        None => {
            eprintln!(
                "ndr remote: waiting for a base on {addr} (SIGUSR1: print the counters; \
                 SIGINT or SIGTERM: stop)"
            );
            serve(
                args,
                &served,
                &rt,
                &listener,
                &stop,
                spec,
                recorder.as_ref(),
            )
        }
    };
    let stats = listener.stats();
    eprintln!("ndr remote: {}", counters(&stats));
    if let Some(r) = record::finish(recorder) {
        match r.error {
            Some(e) => eprintln!("ndr remote: {e}"),
            None => eprintln!(
                "ndr remote: recorded {} messages to {} ({} dropped)",
                r.messages, r.path, r.dropped
            ),
        }
    }
    if args.json {
        let report = crate::shared::RemoteReport::new(
            addr,
            &stats,
            listener.sharing(),
            sessions,
            failure.as_deref(),
        );
        println!(
            "{}",
            serde_json::to_string(&report).map_err(|e| e.to_string())?
        );
    }
    failure.map_or(Ok(()), Err)
}

/// Serves bases at once, sharing the robot, until stopped (or, with
/// `--once`, until the last has left): the sessions, and the failure that
/// makes the exit status non-zero, if any.
fn serve_shared(
    args: &RemoteArgs,
    (served, recorder): (&Served, Option<&ndr::net::Recorder>),
    rt: &tokio::runtime::Runtime,
    listener: &Arc<Listener>,
    stop: &Arc<Stop>,
    spec: DriveSpec,
) -> (crate::shared::Served, Option<String>) {
    let (tx, rx) = std::sync::mpsc::channel();
    let (l, st) = (Arc::clone(listener), Arc::clone(stop));
    let accepting = rt.spawn(async move {
        loop {
            tokio::select! {
                biased;
                () = st.wait() => return None,
                accepted = l.accept() => match accepted {
                    Ok(link) => {
                        if tx.send(link).is_err() {
                            return None;
                        }
                    }
                    // Refused peers are logged and counted by the
                    // listener, which fails only when its socket does.
                    Err(e) => return Some(format!("the listener stopped: {e}")),
                },
            }
        }
    });
    let figures = crate::shared::Figures {
        served,
        transport: args.link.transport(),
        recorder,
        controller_stats: None,
    };
    let served = crate::shared::robot(&rx, spec, stop, args.once, &figures);
    let stopped = if accepting.is_finished() {
        rt.block_on(accepting).ok().flatten()
    } else {
        accepting.abort();
        None
    };
    match served {
        Ok(served) => {
            let failed = served
                .sessions
                .iter()
                .find(|s| !s.ok)
                .map(|s| format!("base {}: {}", s.peer, s.end));
            let failure = stopped.or(if args.once { failed } else { None });
            (served, failure)
        }
        Err(why) => (
            crate::shared::Served::default(),
            Some(stopped.unwrap_or(why)),
        ),
    }
}

/// Serves bases until stopped (or after one with `--once`); the failure
/// that makes the exit status non-zero, if any.
fn serve(
    args: &RemoteArgs,
    served: &Served,
    rt: &tokio::runtime::Runtime,
    listener: &Listener,
    stop: &Stop,
    spec: DriveSpec,
    recorder: Option<&ndr::net::Recorder>,
) -> (crate::shared::Served, Option<String>) {
    let mut sessions = crate::shared::Served::default();
    let failure = serve_each(
        args,
        served,
        rt,
        listener,
        stop,
        (&spec, recorder),
        &mut sessions,
    );
    (sessions, failure)
}

/// [`serve`]'s loop: each base's session goes to `sessions`.
fn serve_each(
    args: &RemoteArgs,
    served: &Served,
    rt: &tokio::runtime::Runtime,
    listener: &Listener,
    stop: &Stop,
    (spec, recorder): (&DriveSpec, Option<&ndr::net::Recorder>),
    sessions: &mut crate::shared::Served,
) -> Option<String> {
    // The last base's figures stay on the page until the next one comes.
    let mut watched = None;
    loop {
        let accepted = rt.block_on(async {
            tokio::select! {
                biased;
                () = stop.wait() => None,
                accepted = listener.accept() => Some(accepted),
            }
        });
        let link = match accepted {
            None => return None,
            Some(Ok(mut link)) => {
                record::attach(recorder, &mut link);
                link
            }
            // Refused peers are logged and counted by the listener, which
            // fails only when its socket does.
            Some(Err(e)) => return Some(format!("the listener stopped: {e}")),
        };
        let peer = link.peer_addr();
        eprintln!("ndr remote: base {peer}: handshake done, running the initialization pattern");
        served.unwatch(watched.take());
        watched = served.watch_link(peer, Role::Remote, args.link.transport(), &link.sender());
        let stats = Mutex::new(None::<LinkStats>);
        let end = robot(link, spec.clone(), stop.flag(), &stats, None);
        let last = *stats
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let counted = last.map_or_else(String::new, |s| {
            let datagrams =
                crate::report::datagram_counts(&s).map_or_else(String::new, |d| format!("; {d}"));
            format!(
                " after {} samples released ({} underflows, {} late){datagrams}",
                s.endpoint.released_fresh, s.endpoint.underflows, s.endpoint.late
            )
        });
        let end_line = crate::robot::session_line(
            &end,
            last.as_ref(),
            args.link.transport(),
            listener.local_addr().map_or(0, |a| a.port()),
        );
        eprintln!("ndr remote: base {peer}: {end_line}{counted}");
        sessions.push(crate::shared::Session::alone(peer, &end, last));
        if args.once {
            return (!end.ok()).then(|| format!("base {peer}: {end}"));
        }
        if stop.is_set() {
            return None;
        }
    }
}
