//! `ndr base` and `ndr remote`: the two peers as separate processes or hosts.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::net::metrics::LinkLabels;
use ndr::net::{Link, LinkStats, Listener, NetError, tls};

use ndr::core::wire::Role;

use crate::args::{
    LinkArgs, MetricsArgs, PlantArgs, RecordArgs, RunArgs, SecurityArgs, record, resolve,
};
use crate::metrics::Served;
use crate::operator::operator;
use crate::report::{End, Outcome, Series, finish, with_series_error};
use crate::robot::{DriveSpec, robot};
use crate::runtime::runtime;
use crate::signals::{self, Stop, counters};

#[derive(clap::Args)]
pub struct BaseArgs {
    /// The remote (or a relay in front of it) to connect to: HOST:PORT, a
    /// name or an address (the first address the name resolves to).
    #[arg(long, value_name = "HOST:PORT")]
    pub connect: String,
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
}

#[derive(clap::Args)]
pub struct RemoteArgs {
    /// Where to wait for bases.
    #[arg(long, value_name = "ADDR")]
    pub listen: SocketAddr,
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
}

/// The operator's side: runs `--duration-s` over the link, then reports how
/// it ended; fails (after the report) when no link came up or it failed.
pub fn base(args: &BaseArgs) -> Result<(), String> {
    let mut config = args.link.config()?;
    let tls = args.security.apply(&mut config)?;
    crate::transport::check_security(args.link.transport(), tls.is_some())?;
    args.run.check_duration()?;
    crate::tracking::check_layout(args.run.controller, &args.link.state)?;
    let connect_to = resolve("--connect", &args.connect)?;
    // Refused as the link would refuse it, before the series is created.
    if tls.is_none() && !tls::plain_allowed(connect_to.ip(), config.insecure) {
        return Err(NetError::Insecure(connect_to).to_string());
    }
    let mut series = Series::create(&args.run.out)?;
    let served = Served::start(&args.metrics, "base")?;
    let recorder = args.record.start(args.link.axes, &args.link.state)?;
    let rt = runtime()?;
    let run_for = StdDuration::from_secs_f64(args.run.duration_s);
    let until = StdInstant::now() + run_for;
    config.tls.clone_from(&tls);
    let connect = Link::connect(connect_to, config.clone());
    // The connection counts in the run's duration: a peer that never
    // answers the SYN must not hold the base beyond it.
    let connected = rt.block_on(async { tokio::time::timeout(run_for, connect).await });
    let (stats, end, tracking) = match connected {
        Ok(Ok(mut link)) => {
            record::attach(recorder.as_ref(), &mut link);
            served.watch_link(
                connect_to,
                Role::Base,
                args.link.transport(),
                &link.sender(),
            );
            operator(
                link,
                &args.run,
                args.link.axes,
                until,
                None,
                &mut series,
                None,
            )
        }
        Ok(Err(e)) => (
            None,
            match crate::report::refusal(&e) {
                Some(reason) => End::Refused {
                    reason,
                    why: format!("cannot connect to {connect_to}: {e}"),
                },
                None => End::NeverConnected(format!("cannot connect to {connect_to}: {e}")),
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
    let (series, error) = series.close();
    let outcome = Outcome {
        profile: format!("tcp {connect_to}"),
        base: stats,
        remote: None,
        relay: None,
        series,
        end,
        tracking,
        host: None,
        recording: record::finish(recorder),
    };
    finish(&args.link, &args.run, &with_series_error(outcome, error))
}

/// The robot's side: serves bases one after another (or one with
/// `--once`), a line for each base's end, the listener's counters at exit.
pub fn remote(args: &RemoteArgs) -> Result<(), String> {
    let mut config = args.link.config()?;
    let tls = args.security.apply(&mut config)?;
    crate::transport::check_security(args.link.transport(), tls.is_some())?;
    let max_command = args.plant.max_command()?;
    let recorder = args.record.start(args.link.axes, &args.link.state)?;
    let rt = runtime()?;
    config.tls = tls;
    let listener = rt
        .block_on(Listener::listen(args.listen, config.clone()))
        .map_err(|e| format!("cannot listen on {}: {e}", args.listen))?
        // One base at a time: the next one is told the robot is busy.
        .with_max_links(1);
    let listener = Arc::new(listener);
    let addr = listener.local_addr().map_err(|e| e.to_string())?;
    let served = Served::start(&args.metrics, "remote")?;
    if let Some(m) = served.metrics() {
        let labels = LinkLabels::new(addr.to_string(), Role::Remote, args.link.transport());
        m.watch_listener(labels, &listener);
    }
    let stop = Arc::new(Stop::default());
    signals::watch(&rt, Arc::clone(&listener), Arc::clone(&stop))?;
    eprintln!(
        "ndr remote: waiting for a base on {addr} (SIGUSR1: print the counters; \
         SIGINT or SIGTERM: stop)"
    );
    let failure = serve(
        args,
        &served,
        &rt,
        &listener,
        &stop,
        &DriveSpec {
            axes: usize::from(args.link.axes),
            layout: args.link.state.clone(),
            period: config.endpoint.period,
            max_command,
        },
        recorder.as_ref(),
    );
    eprintln!("ndr remote: {}", counters(&listener.stats()));
    if let Some(r) = record::finish(recorder) {
        match r.error {
            Some(e) => eprintln!("ndr remote: {e}"),
            None => eprintln!(
                "ndr remote: recorded {} messages to {} ({} dropped)",
                r.messages, r.path, r.dropped
            ),
        }
    }
    failure.map_or(Ok(()), Err)
}

/// Serves bases until stopped (or after one with `--once`); the failure
/// that makes the exit status non-zero, if any.
fn serve(
    args: &RemoteArgs,
    served: &Served,
    rt: &tokio::runtime::Runtime,
    listener: &Listener,
    stop: &Stop,
    spec: &DriveSpec,
    recorder: Option<&ndr::net::Recorder>,
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
        eprintln!("ndr remote: base {peer} connected");
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
        eprintln!("ndr remote: base {peer}: {end}{counted}");
        if args.once {
            return (!end.ok()).then(|| format!("base {peer}: {end}"));
        }
        if stop.is_set() {
            return None;
        }
    }
}
