//! `ndr demo`: the whole link for real, in one process — a remote with the
//! simulated plant, a delaying relay, and a base whose operator follows a
//! signal — over loopback, on UDP datagrams unless told otherwise.

use std::io::{IsTerminal, Write};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::Regulation;
use ndr::core::endpoint::{Config, Event, Mode, Status, Underflow};
use ndr::core::playout::Playout;
use ndr::core::time::Duration;
use ndr::core::wire::Role;
use ndr::net::{Link, LinkConfig, LinkStats, Listener, NetError, Relay, RelayConfig, TlsConfig};
use ndr::netem::LossModel;
use ndr::sim::signal::Signal;

use crate::keygen::Throwaway;
use crate::transport::{LinkTransport, check_loss};

use crate::pauses::{self, LateTicks};
use crate::report::{End, Outcome, Row, Series, finish, link_ended};
use crate::robot::{DriveSpec, PlantArgs, StateLayout, robot};
use crate::sim::NetArgs;
use crate::size::millis;
use crate::tracking::{ControllerKind, Tracker, TrackingSummary, check_layout};

/// The link's settings, shared by `demo`, `base` and `remote`.
#[derive(clap::Args, Clone, Debug)]
pub struct LinkArgs {
    #[arg(
        long,
        value_name = "NAME",
        help = format!(
            "How the delay is regulated: {} (adaptive: a target delay above each sample's \
             send time, the lowest with a late rate of PERCENT, 0.1 by default; paper-static \
             or paper-dynamic: the paper's FIFO, sized once or resized as the network changes)",
            Regulation::names()
        )
    )]
    pub regulation: Option<Regulation>,
    /// Deprecated: --regulation (paper-static, paper-dynamic, adaptive).
    #[arg(long, hide = true, value_parser = link_mode)]
    pub mode: Option<LinkMode>,
    /// Deprecated: --regulation (the same names; fifo is paper-static).
    #[arg(long, hide = true)]
    pub playout: Option<Playout>,
    /// What a tick does when its sample has not arrived: hold (the default:
    /// repeat the last sample and keep every one; the paper's FIFO then
    /// releases the late one a tick later) or drop-late (keep the delay
    /// constant: a sample that missed its tick is dropped and counted).
    #[arg(long, default_value = "hold")]
    pub underflow: Underflow,
    /// Sampling period, in ms (50: the paper's choice for its LAN).
    #[arg(long, default_value_t = 50.0)]
    pub period_ms: f64,
    /// Axes of the teleoperated system (1 to 256): a command value each,
    /// and a state value per quantity of --state.
    #[arg(long, default_value_t = 1)]
    pub axes: u16,
    /// What the robot's state holds for each axis: a comma-separated list
    /// of positions, velocities and efforts (the default: positions; e.g.
    /// positions,velocities,efforts is 21 values for 7 axes). Both sides
    /// must give the same: a peer with another layout is refused.
    #[arg(long, default_value = "positions")]
    pub state: StateLayout,
    /// How samples cross: tcp (the paper's stream: a lost packet holds
    /// back every sample behind it until it is resent; the default of base
    /// and remote) or udp[:K[:R]] (datagrams, each with the newest sample
    /// and copies of the K − 1 before it, 4 by default, sent R more times
    /// 1 ms apart, 3 by default, while the peer reports losses, so that a
    /// lost one is made good within a millisecond or two; the handshake
    /// stays on TCP, and the datagrams go to the same port over UDP; the
    /// default of the demo, which runs on loopback) or quic[:K[:R]] (the
    /// same datagrams as QUIC DATAGRAM frames, the handshake on a QUIC
    /// stream, all under mutual TLS 1.3: base and remote need the TLS
    /// options; the demo makes a throwaway pair). UDP is plain: loopback,
    /// or --insecure, and not with TLS.
    #[arg(long)]
    pub transport: Option<LinkTransport>,
}

impl LinkArgs {
    /// `--transport`, or the paper's stream when it was not given.
    pub fn transport(&self) -> LinkTransport {
        self.transport.unwrap_or_default()
    }

    pub fn config(&self) -> Result<LinkConfig, String> {
        let period = millis("--period-ms", self.period_ms)?;
        if period.is_zero() {
            return Err("--period-ms must be positive".into());
        }
        let states = self.state.width(self.axes)?;
        let mut endpoint = Config::new(Role::Base).with_widths(self.axes, states);
        endpoint.layout = self.state.fingerprint(self.axes);
        endpoint.transport = self.transport().transport;
        endpoint.period = period;
        let (mode, playout, old) = self.asked()?;
        if old {
            crate::logging::deprecated_mode_playout(mode, playout);
        }
        endpoint.mode = mode;
        endpoint.playout = playout;
        endpoint.underflow = self.underflow;
        // The link draws its datagram session token when it starts.
        let mut checked = endpoint;
        checked.session = checked.session.max(1);
        checked.validate().map_err(|e| e.to_string())?;
        Ok(LinkConfig::new(endpoint))
    }

    /// The mode and playout asked for, and whether through the deprecated
    /// `--mode` or `--playout`.
    fn asked(&self) -> Result<(Mode, Playout, bool), String> {
        if let Some(r) = self.regulation {
            if self.mode.is_some() || self.playout.is_some() {
                return Err(
                    "--regulation replaces --mode and --playout: give --regulation alone".into(),
                );
            }
            return Ok((r.mode(), r.playout(), false));
        }
        let mode = self.mode.unwrap_or(LinkMode::ADAPTIVE);
        let playout = self.playout.unwrap_or(if mode.adaptive {
            Playout::ADAPTIVE
        } else {
            Playout::Fifo
        });
        let old = self.mode.is_some() || self.playout.is_some();
        Ok((mode.mode, playout, old))
    }

    /// The regulation's name for reports: its own, or `MODE with PLAYOUT`
    /// for the pairing no regulation names.
    pub fn regulation_name(&self) -> String {
        self.asked().map_or_else(
            |_| String::new(),
            |(mode, playout, _)| Regulation::name_of(mode, playout).to_string(),
        )
    }

    /// This side's playout's name, for reports.
    pub fn playout_name(&self) -> String {
        self.asked()
            .map_or_else(|_| String::new(), |(_, playout, _)| playout.to_string())
    }

    /// The report's deprecated `mode`: what `--mode` said, `adaptive` for
    /// the adaptive playout over the static handshake.
    pub fn legacy_mode_name(&self) -> &'static str {
        match (self.mode, self.asked()) {
            (Some(m), _) => m.name(),
            (None, Ok((Mode::PaperStatic, Playout::Adaptive { .. }, _))) => "adaptive",
            (None, Ok((mode, _, _))) => mode.name(),
            (None, Err(_)) => "",
        }
    }
}

/// `--mode`: a paper mode, or `adaptive`.
#[derive(Clone, Copy, Debug)]
pub struct LinkMode {
    /// The mode stated in the Hello.
    pub mode: Mode,
    /// `--mode adaptive`: the static mode with the adaptive playout.
    pub adaptive: bool,
}

impl LinkMode {
    /// `--mode adaptive`, the default when neither `--regulation` nor
    /// `--mode` is given.
    const ADAPTIVE: LinkMode = LinkMode {
        mode: Mode::PaperStatic,
        adaptive: true,
    };

    /// The name given on the command line.
    pub fn name(self) -> &'static str {
        if self.adaptive {
            "adaptive"
        } else {
            self.mode.name()
        }
    }
}

fn link_mode(s: &str) -> Result<LinkMode, String> {
    if s.trim() == "adaptive" {
        return Ok(LinkMode::ADAPTIVE);
    }
    s.parse::<Mode>()
        .map(|mode| LinkMode {
            mode,
            adaptive: false,
        })
        .map_err(|e| format!("{e}; or adaptive"))
}

/// The operator's run, shared by `demo` and `base`.
#[derive(clap::Args, Clone, Debug)]
pub struct RunArgs {
    /// How long to run, in seconds.
    #[arg(long, default_value_t = 20.0)]
    pub duration_s: f64,
    /// The operator's command: sine[:amp=A,freq=F], steps[:low=L,high=H,period=P], constant:V.
    #[arg(long, default_value = "sine")]
    pub signal: Signal,
    /// Where to write the base's per-tick series (CSV), row by row as the
    /// states are released; written however the run ends.
    #[arg(long, value_name = "FILE.csv", default_value = "ndr-demo.csv")]
    pub out: PathBuf,
    /// Print one JSON object instead of the live line and the table; it
    /// says how the run ended (`ok`, `end`) and is printed whatever the end.
    #[arg(long)]
    pub json: bool,
    /// Close a position loop at the base on the remote's state instead of
    /// following --signal: smith (a PID through a Smith predictor with the
    /// plant's model, following the round trip the link announces) or pid
    /// (the PID on the delayed state), with the gains, plant and
    /// reference of `ndr control --scenario tracking`, on the first axis;
    /// the report gains the tracking errors. none (the default): the
    /// open-loop operator.
    #[arg(long, default_value = "none")]
    pub controller: ControllerKind,
}

#[derive(clap::Args)]
pub struct DemoArgs {
    #[command(flatten)]
    pub net: NetArgs,
    #[command(flatten)]
    pub link: LinkArgs,
    #[command(flatten)]
    pub run: RunArgs,
    #[command(flatten)]
    pub plant: PlantArgs,
    /// Datagrams the relay loses each way: none, PERCENT (each
    /// independently, e.g. 1) or ge:PERCENT:BURST (in bursts of BURST
    /// datagrams on average, e.g. ge:2:4). Datagrams (udp, the default,
    /// or quic) only: the relay never drops TCP bytes.
    #[arg(long, default_value = "none")]
    pub loss: LossModel,
    /// Seed of the relay's delays and losses.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

pub fn run(args: &DemoArgs) -> Result<(), String> {
    // Both ends and the relay on loopback: datagrams unless told otherwise,
    // since they hold a lower delay than the stream at every loss rate
    // (docs/benchmarks.md, "Real kernel loss").
    let link = &LinkArgs {
        transport: Some(args.link.transport.unwrap_or(LinkTransport::DEMO)),
        ..args.link.clone()
    };
    let config = link.config()?;
    check_loss(
        link.transport().transport,
        &args.loss,
        "leave --transport out (datagrams)",
    )?;
    // Over QUIC, each side gets a throwaway identity pinned by the other.
    let (base_config, config) = if link.transport().quic {
        let (base, remote) = throwaway_pair()?;
        (config.clone().with_tls(base), config.with_tls(remote))
    } else {
        (config.clone(), config)
    };
    check_duration(&args.run)?;
    check_layout(args.run.controller, &link.state)?;
    let max_command = args.plant.max_command()?;
    let model = args.net.model("lan-75km")?;
    let profile = model.name();
    let mut series = Series::create(&args.run.out)?;
    if !args.run.json {
        // Said up front: the file lands in the current directory by default.
        eprintln!(
            "ndr demo: the base's series goes to {} (--out to change it)",
            args.run.out.display()
        );
    }
    let rt = runtime()?;
    let loopback: SocketAddr = ([127, 0, 0, 1], 0).into();
    let set_up = rt.block_on(async {
        let listener = Listener::bind(loopback, config.clone()).await?;
        let relay = Relay::bind(loopback, listener.local_addr()?, model, args.seed)
            .await?
            .with_config(RelayConfig {
                loss: args.loss,
                ..RelayConfig::default()
            })
            .spawn()?;
        let (remote, base) = tokio::join!(
            listener.accept(),
            Link::connect(relay.local_addr(), base_config.clone())
        );
        Ok::<_, NetError>((base?, remote?, relay))
    });
    let (base, remote, relay) = match set_up {
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
                host: None,
            };
            return finish(link, &args.run, &with_series_error(outcome, error));
        }
    };
    // The run starts with the link: the set-up waited for its handshake.
    let until = StdInstant::now() + StdDuration::from_secs_f64(args.run.duration_s);

    let stop = Arc::new(AtomicBool::new(false));
    let remote_stats = Arc::new(Mutex::new(None::<LinkStats>));
    let (base_late, remote_late) = (Mutex::default(), Arc::new(Mutex::default()));
    let watch = pauses::Watch::start();
    let robot = {
        let (stop, remote_stats) = (Arc::clone(&stop), Arc::clone(&remote_stats));
        let late = Arc::clone(&remote_late);
        let spec = DriveSpec {
            axes: usize::from(link.axes),
            layout: link.state.clone(),
            period: config.endpoint.period,
            max_command,
        };
        std::thread::Builder::new()
            .name("ndr-demo-robot".into())
            .spawn(move || robot(remote, spec, &stop, &remote_stats, Some(&late)))
            .map_err(|e| e.to_string())?
    };

    let (base_stats, end, tracking) = operator(
        base,
        &args.run,
        link.axes,
        until,
        Some(&remote_stats),
        &mut series,
        Some(&base_late),
    );
    stop.store(true, Ordering::Relaxed);
    match robot.join() {
        Ok(session) if session.ok() => tracing::info!("remote: {session}"),
        Ok(session) => tracing::warn!("remote: {session}"),
        Err(_) => tracing::error!("remote: the robot's thread panicked"),
    }
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
    };
    finish(link, &args.run, &with_series_error(outcome, error))
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

/// A run that completed but whose series could not be written failed.
pub fn with_series_error(mut outcome: Outcome<'_>, error: Option<String>) -> Outcome<'_> {
    if let Some(e) = error {
        if outcome.end.ok() {
            outcome.end = End::AppFailure(e);
        } else {
            tracing::error!("{e}");
        }
    }
    outcome
}

pub fn check_duration(run: &RunArgs) -> Result<(), String> {
    if run.duration_s.is_finite() && run.duration_s > 0.0 {
        Ok(())
    } else {
        Err(format!(
            "--duration-s must be positive, got {}",
            run.duration_s
        ))
    }
}

/// TLS for a base and a remote that trust each other's certificate only,
/// made for this run and gone with it.
fn throwaway_pair() -> Result<(TlsConfig, TlsConfig), String> {
    Throwaway::new("demo-quic")
        .and_then(|ids| ids.pair())
        .map_err(|e| format!("cannot make the demo's QUIC certificates: {e}"))
}

pub fn runtime() -> Result<tokio::runtime::Runtime, String> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("ndr-io")
        .enable_all()
        .build()
        .map_err(|e| format!("cannot start the I/O runtime: {e}"))
}

/// The base: the operator follows the signal until `until`; one row per
/// released state goes to `series`. Returns the base's final counters and
/// how the run ended; the link is closed (or aborted) either way.
pub fn operator(
    mut link: Link,
    run: &RunArgs,
    axes: u16,
    until: StdInstant,
    remote_stats: Option<&Mutex<Option<LinkStats>>>,
    series: &mut Series,
    late: Option<&Mutex<LateTicks>>,
) -> (Option<LinkStats>, End, Option<TrackingSummary>) {
    let start = StdInstant::now();
    // Made at the first release, at the period the link runs at.
    let mut tracker: Option<Tracker> = None;
    let mut u = 0.0;
    let live = !run.json && std::io::stderr().is_terminal();
    let mut next_status = start;
    let mut command = vec![0.0; usize::from(axes)];
    let mut last_grtt = f64::NAN;
    let mut released = 0_u64;
    let mut end = None;
    loop {
        let now = StdInstant::now();
        if now >= until {
            break;
        }
        let t = start.elapsed().as_secs_f64();
        for (axis, c) in command.iter_mut().enumerate() {
            *c = match run.controller {
                ControllerKind::None => run.signal.value(t, axis),
                // The loop drives the first axis; the others stay at rest.
                _ if axis == 0 => u,
                _ => 0.0,
            };
        }
        match link.send(&command) {
            Ok(()) => {}
            Err(NetError::Link(e)) if e.is_fatal() => {
                end = Some(link_ended(&NetError::Link(e), released));
                break;
            }
            Err(e) => {
                end = Some(End::AppFailure(format!(
                    "the operator's command was refused: {e}"
                )));
                break;
            }
        }
        let wait = (until - now).min(StdDuration::from_millis(500));
        match link.recv_timeout(wait) {
            Ok(s) => {
                released += 1;
                if let Some(g) = s.grtt {
                    last_grtt = g.as_secs_f64();
                }
                let state = s.values().first().copied().unwrap_or(f64::NAN);
                if run.controller != ControllerKind::None {
                    let stepped = match &mut tracker {
                        Some(tr) => tr.tick(state, s.status != Status::Held, s.grtt),
                        None => link
                            .stats()
                            .map(|st| st.period)
                            .ok_or_else(|| "the link released a state before it started".into())
                            .and_then(|p| Tracker::new(run.controller, p))
                            .and_then(|made| {
                                let tr = tracker.insert(made.ok_or("no controller")?);
                                tr.tick(state, s.status != Status::Held, s.grtt)
                            }),
                    };
                    match stepped {
                        Ok(next) => u = next,
                        Err(e) => {
                            end = Some(End::AppFailure(e));
                            break;
                        }
                    }
                }
                pauses::note(late, &link, &s);
                let row = Row {
                    t_s: t,
                    seq: s.seq,
                    held: s.status == Status::Held,
                    grtt_s: s.grtt.map(Duration::as_secs_f64),
                    nrtt_s: link
                        .stats()
                        .and_then(|st| st.last_nrtt)
                        .map(Duration::as_secs_f64),
                    command: command[0],
                    state,
                };
                if let Err(e) = series.push(&row) {
                    end = Some(End::AppFailure(e));
                    break;
                }
            }
            Err(NetError::Timeout) => {}
            Err(e) => {
                end = Some(link_ended(&e, released));
                break;
            }
        }
        for event in link.drain_events() {
            crate::logging::event("base", &event);
            if let (Event::Started { period, .. }, Some(tr)) = (&event, &mut tracker)
                && let Err(e) = tr.set_period(*period)
            {
                end = Some(End::AppFailure(e));
            }
        }
        if end.is_some() {
            break;
        }
        if StdInstant::now() >= next_status {
            next_status += StdDuration::from_millis(250);
            if live {
                status_line(t, link.stats().as_ref(), remote_stats, last_grtt);
            }
        }
    }
    if live {
        eprintln!();
    }
    let end = end.unwrap_or_else(|| {
        if released > 0 {
            return End::Completed;
        }
        // `connect` returns before the handshake: a peer that accepts the
        // connection but never answers shows only here.
        let phase = link.stats().map_or("the handshake", |s| s.phase.name());
        End::NeverConnected(format!(
            "no sample was released in the {} s run (the link was still in {phase}); \
             check that the peer is an ndr remote (or a relay to one) with the same \
             settings, or run longer",
            run.duration_s
        ))
    });
    if matches!(end, End::AppFailure(_)) {
        tracing::error!("base: {end}; ending the link as an application failure");
        link.abort();
    }
    (link.close(), end, tracker.map(|t| t.summary()))
}

fn status_line(
    t: f64,
    base: Option<&LinkStats>,
    remote: Option<&Mutex<Option<LinkStats>>>,
    grtt: f64,
) {
    let remote = remote.and_then(|r| *r.lock().unwrap_or_else(std::sync::PoisonError::into_inner));
    let ms = |d: Option<Duration>| {
        d.map_or("–".to_string(), |d| {
            format!("{:.1} ms", d.as_secs_f64() * 1e3)
        })
    };
    let (nrtt, qb, uf_b, phase) = base.map_or((String::from("–"), 0, 0, "starting"), |s| {
        (
            ms(s.last_nrtt),
            s.queue_len,
            s.endpoint.underflows,
            s.phase.name(),
        )
    });
    let (qr, uf_r) = remote.map_or((0, 0), |s| (s.queue_len, s.endpoint.underflows));
    let grtt = if grtt.is_finite() {
        format!("{:.1} ms", grtt * 1e3)
    } else {
        "–".into()
    };
    eprint!(
        "\r\x1b[2K  t {t:5.1} s · {phase:<12} · NRTT {nrtt:>9} · GRTT {grtt:>9} · queue base {qb:>3} remote {qr:>3} · underflows {} ",
        uf_b + uf_r
    );
    let _ = std::io::stderr().flush();
}

#[cfg(test)]
mod tests {
    use clap::Parser;
    use ndr::core::endpoint::Mode;
    use ndr::core::playout::Playout;

    use super::LinkArgs;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        link: LinkArgs,
    }

    fn link(args: &[&str]) -> LinkArgs {
        Cli::try_parse_from([&["ndr"][..], args].concat())
            .expect("the flags parse")
            .link
    }

    #[test]
    fn the_regulation_sets_the_mode_and_the_playout() {
        let cases: [(&[&str], Mode, Playout, &str); 5] = [
            (&[], Mode::PaperStatic, Playout::ADAPTIVE, "adaptive"),
            (
                &["--regulation", "paper-dynamic"],
                Mode::PaperDynamic,
                Playout::Fifo,
                "paper-dynamic",
            ),
            (
                &["--regulation", "neteq"],
                Mode::PaperStatic,
                Playout::NetEq,
                "neteq",
            ),
            // The old spellings, as before.
            (
                &["--mode", "paper-static"],
                Mode::PaperStatic,
                Playout::Fifo,
                "paper-static",
            ),
            (
                &["--mode", "paper-dynamic", "--playout", "adaptive"],
                Mode::PaperDynamic,
                Playout::ADAPTIVE,
                "paper-dynamic with adaptive",
            ),
        ];
        for (args, mode, playout, name) in cases {
            let l = link(args);
            let c = l.config().expect("a valid configuration").endpoint;
            assert_eq!((c.mode, c.playout), (mode, playout), "{args:?}");
            assert_eq!(l.regulation_name(), name, "{args:?}");
        }
        // Base and remote run the paper's stream unless told otherwise.
        assert_eq!(link(&[]).transport().to_string(), "tcp");
        assert_eq!(link(&["--mode", "adaptive"]).legacy_mode_name(), "adaptive");
        assert_eq!(link(&[]).legacy_mode_name(), "adaptive");
        assert_eq!(
            link(&["--regulation", "paper-dynamic"]).legacy_mode_name(),
            "paper-dynamic"
        );
    }

    #[test]
    fn both_spellings_at_once_or_a_wrong_name_is_an_error() {
        let err = link(&["--regulation", "neteq", "--playout", "fifo"])
            .config()
            .unwrap_err();
        assert!(err.contains("give --regulation alone"), "{err}");
        let err = Cli::try_parse_from(["ndr", "--regulation", "fifo"])
            .err()
            .expect("fifo is no regulation")
            .to_string();
        assert!(
            err.contains("paper-static") && err.contains("paper-dynamic"),
            "{err}"
        );
    }
}
