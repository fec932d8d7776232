//! `ndr demo`: the whole link for real, in one process — a remote with the
//! simulated plant, a delaying relay, and a base whose operator follows a
//! signal — over loopback TCP.

use std::fs::File;
use std::io::{BufWriter, IsTerminal, Write};
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::arx::{Tf2, Tf2State};
use ndr::core::endpoint::{Config, Event, Mode, Status, Underflow};
use ndr::core::playout::Playout;
use ndr::core::sim::signal::Signal;
use ndr::core::sim::{PlantConfig, percentile};
use ndr::core::time::Duration;
use ndr::core::wire::Role;
use ndr::net::clock::LatenessStats;
use ndr::net::{Link, LinkConfig, LinkStats, Listener, NetError, Relay, RelayStats};
use serde::Serialize;

use crate::sim::NetArgs;
use crate::size::millis;

/// The link's settings, shared by `demo`, `base` and `remote`.
#[derive(clap::Args, Clone, Debug)]
pub struct LinkArgs {
    /// Regulation mode: adaptive (the default: the static handshake with
    /// `--playout adaptive`, lower delay than the paper's modes at the same
    /// late rate), paper-static or paper-dynamic (the paper's FIFO).
    #[arg(long, default_value = "adaptive", value_parser = link_mode)]
    pub mode: LinkMode,
    /// When this side releases each sample: fifo (the paper's queue, sized
    /// by the mode), ramjee-1, ramjee-4, neteq, fixed[:MS], constant:MS,
    /// adaptive[:PERCENT[:QUANTUM_MS]] (default: adaptive with `--mode
    /// adaptive`, else fifo).
    #[arg(long)]
    pub playout: Option<Playout>,
    /// The regulator's policy when a sample is missing at its tick.
    #[arg(long, default_value = "hold")]
    pub underflow: Underflow,
    /// Sampling period, in ms (50: the paper's choice for its LAN).
    #[arg(long, default_value_t = 50.0)]
    pub period_ms: f64,
    /// Axes of the teleoperated system (1 to 8).
    #[arg(long, default_value_t = 1)]
    pub axes: u16,
}

impl LinkArgs {
    pub fn config(&self) -> Result<LinkConfig, String> {
        let period = millis("--period-ms", self.period_ms)?;
        if period.is_zero() {
            return Err("--period-ms must be positive".into());
        }
        let mut endpoint = Config::new(Role::Base);
        endpoint.axes = self.axes;
        endpoint.period = period;
        endpoint.mode = self.mode.mode;
        endpoint.playout = self.playout.unwrap_or(if self.mode.adaptive {
            Playout::ADAPTIVE
        } else {
            Playout::Fifo
        });
        endpoint.underflow = self.underflow;
        endpoint.validate().map_err(|e| e.to_string())?;
        Ok(LinkConfig::new(endpoint))
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
        return Ok(LinkMode {
            mode: Mode::PaperStatic,
            adaptive: true,
        });
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
    /// Where to write the base's per-tick series (CSV).
    #[arg(long, value_name = "FILE.csv", default_value = "ndr-demo.csv")]
    pub out: PathBuf,
    /// Print one JSON object instead of the live line and the table.
    #[arg(long)]
    pub json: bool,
}

#[derive(clap::Args)]
pub struct DemoArgs {
    #[command(flatten)]
    pub net: NetArgs,
    #[command(flatten)]
    pub link: LinkArgs,
    #[command(flatten)]
    pub run: RunArgs,
    /// Seed of the relay's delays.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

/// What `ndr demo --json` prints. Times in seconds.
#[derive(Serialize)]
struct DemoReport {
    command: &'static str,
    profile: String,
    mode: &'static str,
    playout: String,
    underflow: &'static str,
    period_s: f64,
    duration_s: f64,
    axes: u16,
    ns: usize,
    nrtt_mean_s: f64,
    nrtt_std_s: f64,
    grtt_mean_s: f64,
    grtt_std_s: f64,
    grtt_p99_s: f64,
    grtt_count: u64,
    queue_base_min: usize,
    queue_base_max: usize,
    queue_remote_min: Option<usize>,
    queue_remote_max: Option<usize>,
    samples_sent: u64,
    samples_released: u64,
    late_samples: u64,
    underflows: u64,
    link_lost: u64,
    pauses: u64,
    /// The remote's estimates: one-way delay base → remote, clock offset
    /// (remote − base), skew (ppm); the base's: one-way delay back.
    one_way_fwd_mean_s: f64,
    one_way_bwd_mean_s: f64,
    remote_clock_offset_s: f64,
    remote_clock_skew_ppm: f64,
    /// Target-delay playouts: each side's delay at the end (0 for the FIFO).
    playout_delay_fwd_s: f64,
    playout_delay_bwd_s: f64,
    /// Target-delay playouts: how many delays each side announced (its
    /// first, then each change, made without a pause).
    delay_changes_fwd: u64,
    delay_changes_bwd: u64,
    clock_base_p50_s: f64,
    clock_base_p99_s: f64,
    clock_remote_p50_s: f64,
    clock_remote_p99_s: f64,
    /// How long before a deadline each side's hub spins, as learned from
    /// its timer at the end.
    spin_margin_base_s: f64,
    spin_margin_remote_s: f64,
    relay_frames_fwd: Option<u64>,
    relay_frames_bwd: Option<u64>,
    csv: String,
}

pub struct Row {
    t_s: f64,
    seq: u64,
    held: bool,
    grtt_s: Option<f64>,
    command: f64,
    state: f64,
}

pub fn run(args: &DemoArgs) -> Result<(), String> {
    let config = args.link.config()?;
    check_duration(&args.run)?;
    let model = args.net.model("lan-75km")?;
    let profile = model.name();
    let rt = runtime()?;
    let loopback: SocketAddr = ([127, 0, 0, 1], 0).into();
    let (base, remote, relay) = rt
        .block_on(async {
            let listener = Listener::bind(loopback, config).await?;
            let relay = Relay::bind(loopback, listener.local_addr()?, model, args.seed)
                .await?
                .spawn()?;
            let (remote, base) =
                tokio::join!(listener.accept(), Link::connect(relay.local_addr(), config));
            Ok::<_, NetError>((base?, remote?, relay))
        })
        .map_err(|e| format!("cannot set the demo up: {e}"))?;

    let stop = Arc::new(AtomicBool::new(false));
    let remote_stats = Arc::new(Mutex::new(None::<LinkStats>));
    let robot = {
        let (stop, remote_stats) = (Arc::clone(&stop), Arc::clone(&remote_stats));
        let axes = usize::from(args.link.axes);
        let period = config.endpoint.period;
        std::thread::Builder::new()
            .name("ndr-demo-robot".into())
            .spawn(move || robot(remote, axes, period, &stop, &remote_stats))
            .map_err(|e| e.to_string())?
    };

    let (base_stats, rows) = operator(base, &args.run, args.link.axes, Some(&remote_stats))?;
    stop.store(true, Ordering::Relaxed);
    let _ = robot.join();
    let relay_stats = rt.block_on(relay.shutdown());
    let remote_final = *remote_stats
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let outcome = Outcome {
        profile,
        base: base_stats,
        remote: remote_final,
        relay: Some(&relay_stats),
        rows,
    };
    finish(&args.link, &args.run, &outcome)
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

pub fn runtime() -> Result<tokio::runtime::Runtime, String> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("ndr-io")
        .enable_all()
        .build()
        .map_err(|e| format!("cannot start the I/O runtime: {e}"))
}

/// What a run of the operator ended with.
pub struct Outcome<'a> {
    /// Where the delays came from (a profile) or whom the base talked to.
    pub profile: String,
    /// The base's final counters.
    pub base: Option<LinkStats>,
    /// The remote's, when it ran in this process.
    pub remote: Option<LinkStats>,
    /// The relay's, when it ran in this process.
    pub relay: Option<&'a RelayStats>,
    /// One row per released state.
    pub rows: Vec<Row>,
}

/// Writes the series and prints the report (table or JSON).
pub fn finish(link: &LinkArgs, run: &RunArgs, outcome: &Outcome<'_>) -> Result<(), String> {
    write_csv(&run.out, &outcome.rows)?;
    let report = report(link, run, outcome);
    if run.json {
        println!(
            "{}",
            serde_json::to_string(&report).map_err(|e| e.to_string())?
        );
    } else {
        print_table(&report);
    }
    Ok(())
}

/// The remote: a second-order plant per axis driven by the released commands.
pub fn robot(
    mut link: Link,
    axes: usize,
    period: Duration,
    stop: &AtomicBool,
    stats: &Mutex<Option<LinkStats>>,
) {
    let discretize = |p: Duration| {
        let c = PlantConfig::default();
        Tf2::low_pass(
            std::f64::consts::TAU * c.natural_hz,
            c.damping,
            c.gain,
            p.as_secs_f64(),
        )
    };
    let Ok(model) = discretize(period) else {
        return;
    };
    let mut plants: Vec<Tf2State> = (0..axes).map(|_| Tf2State::new(model)).collect();
    let mut state = vec![0.0; axes];
    while !stop.load(Ordering::Relaxed) {
        match link.recv_timeout(StdDuration::from_millis(200)) {
            Ok(cmd) => {
                for ((p, y), &u) in plants.iter_mut().zip(&mut state).zip(cmd.values()) {
                    *y = p.step(u);
                }
                let _ = link.send(&state);
            }
            Err(NetError::Timeout) => {}
            Err(_) => break,
        }
        for event in link.drain_events() {
            match event {
                Event::Started { period, .. } => {
                    if let Ok(m) = discretize(period) {
                        plants.iter_mut().for_each(|p| p.set_model(m));
                    }
                }
                // A real robot would brake here; the plant simply holds its
                // last command until fresh ones come back.
                Event::LinkLost { .. } | Event::LinkRestored => {}
                _ => {}
            }
        }
        *stats
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = link.stats();
    }
    *stats
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner) = link.close();
}

pub type OperatorOutput = (Option<LinkStats>, Vec<Row>);

/// The base: the operator follows the signal; one row per released state.
pub fn operator(
    mut link: Link,
    run: &RunArgs,
    axes: u16,
    remote_stats: Option<&Mutex<Option<LinkStats>>>,
) -> Result<OperatorOutput, String> {
    let start = StdInstant::now();
    let end = start + StdDuration::from_secs_f64(run.duration_s);
    let live = !run.json && std::io::stderr().is_terminal();
    let mut next_status = start;
    let mut rows = Vec::new();
    let mut command = vec![0.0; usize::from(axes)];
    let mut last_grtt = f64::NAN;
    while StdInstant::now() < end {
        let t = start.elapsed().as_secs_f64();
        for (axis, c) in command.iter_mut().enumerate() {
            *c = run.signal.value(t, axis);
        }
        link.send(&command).map_err(|e| e.to_string())?;
        match link.recv_timeout(StdDuration::from_millis(500)) {
            Ok(s) => {
                if let Some(g) = s.grtt {
                    last_grtt = g.as_secs_f64();
                }
                rows.push(Row {
                    t_s: t,
                    seq: s.seq,
                    held: s.status == Status::Held,
                    grtt_s: s.grtt.map(Duration::as_secs_f64),
                    command: command[0],
                    state: s.values().first().copied().unwrap_or(f64::NAN),
                });
            }
            Err(NetError::Timeout) => {}
            Err(e) => return Err(format!("the link failed: {e}")),
        }
        let _ = link.drain_events().count();
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
    Ok((link.close(), rows))
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

fn write_csv(path: &PathBuf, rows: &[Row]) -> Result<(), String> {
    let err = |e: std::io::Error| format!("cannot write {}: {e}", path.display());
    let mut w = BufWriter::new(File::create(path).map_err(err)?);
    writeln!(w, "t_s,seq,status,grtt_s,command,state").map_err(err)?;
    for r in rows {
        let grtt = r.grtt_s.map_or(String::new(), |g| format!("{g:.6}"));
        let status = if r.held { "held" } else { "fresh" };
        writeln!(
            w,
            "{:.6},{},{status},{grtt},{:.6},{:.6}",
            r.t_s, r.seq, r.command, r.state
        )
        .map_err(err)?;
    }
    w.flush().map_err(err)
}

fn report(link: &LinkArgs, run: &RunArgs, o: &Outcome<'_>) -> DemoReport {
    let (b, remote, relay, rows) = (o.base.as_ref(), o.remote.as_ref(), o.relay, &o.rows);
    let eb = b.map(|s| s.endpoint).unwrap_or_default();
    let er = remote.map(|s| s.endpoint).unwrap_or_default();
    let range = |s: Option<&LinkStats>| s.and_then(|s| s.queue_range).unwrap_or((0, 0));
    let clock = |s: Option<&LinkStats>, p: fn(&LatenessStats) -> Duration| {
        s.map_or(0.0, |s| p(&s.lateness).as_secs_f64())
    };
    let grtts: Vec<f64> = rows.iter().filter_map(|r| r.grtt_s).collect();
    DemoReport {
        command: if relay.is_some() { "demo" } else { "base" },
        profile: o.profile.clone(),
        mode: link.mode.name(),
        playout: link
            .config()
            .map_or_else(|_| String::new(), |c| c.endpoint.playout.to_string()),
        underflow: link.underflow.name(),
        period_s: b.map_or(0.0, |s| s.period.as_secs_f64()),
        duration_s: run.duration_s,
        axes: link.axes,
        ns: b.map_or(0, |s| s.ns),
        nrtt_mean_s: eb.nrtt.mean(),
        nrtt_std_s: eb.nrtt.std(),
        grtt_mean_s: eb.grtt.mean(),
        grtt_std_s: eb.grtt.std(),
        grtt_p99_s: percentile(&grtts, 0.99),
        grtt_count: eb.grtt.count(),
        queue_base_min: range(b).0,
        queue_base_max: range(b).1,
        queue_remote_min: remote.map(|_| range(remote).0),
        queue_remote_max: remote.map(|_| range(remote).1),
        samples_sent: eb.samples_sent + er.samples_sent,
        samples_released: eb.released_fresh + er.released_fresh,
        late_samples: eb.late + er.late,
        underflows: eb.underflows + er.underflows,
        link_lost: eb.link_lost + er.link_lost,
        pauses: eb.pauses,
        one_way_fwd_mean_s: er.one_way_rx.mean(),
        one_way_bwd_mean_s: eb.one_way_rx.mean(),
        remote_clock_offset_s: er.clock_offset_s,
        remote_clock_skew_ppm: er.clock_skew_ppm,
        playout_delay_fwd_s: er.playout_delay_s,
        playout_delay_bwd_s: eb.playout_delay_s,
        delay_changes_fwd: er.delay_changes,
        delay_changes_bwd: eb.delay_changes,
        clock_base_p50_s: clock(b, |l| l.p50),
        clock_base_p99_s: clock(b, |l| l.p99),
        clock_remote_p50_s: clock(remote, |l| l.p50),
        clock_remote_p99_s: clock(remote, |l| l.p99),
        spin_margin_base_s: b.map_or(0.0, |s| s.spin_margin.as_secs_f64()),
        spin_margin_remote_s: remote.map_or(0.0, |s| s.spin_margin.as_secs_f64()),
        relay_frames_fwd: relay.map(|r| r.forward.frames_delivered),
        relay_frames_bwd: relay.map(|r| r.backward.frames_delivered),
        csv: run.out.display().to_string(),
    }
}

fn print_table(r: &DemoReport) {
    let ms = |s: f64| format!("{:.2} ms", s * 1e3);
    println!(
        "ndr {} · {} · {} · {} · {} · T = {} · {:.0} s · {} axis(es)",
        r.command,
        r.profile,
        r.mode,
        r.playout,
        r.underflow,
        ms(r.period_s),
        r.duration_s,
        r.axes
    );
    println!("                     mean          std");
    println!(
        "  NRTT       {:>12} {:>12}   (the network, both ways)",
        ms(r.nrtt_mean_s),
        ms(r.nrtt_std_s)
    );
    println!(
        "  GRTT       {:>12} {:>12}   (as the controller sees it; p99 {}, {} round trips)",
        ms(r.grtt_mean_s),
        ms(r.grtt_std_s),
        ms(r.grtt_p99_s),
        r.grtt_count
    );
    let remote_queue = match (r.queue_remote_min, r.queue_remote_max) {
        (Some(lo), Some(hi)) => format!(" · remote {lo}–{hi}"),
        _ => String::new(),
    };
    println!(
        "  queues     ns {} · base {}–{}{remote_queue} (occupancy before a release)",
        r.ns, r.queue_base_min, r.queue_base_max
    );
    println!(
        "  samples    {} sent · {} released · {} late · {} underflows · {} link-lost alarms",
        r.samples_sent, r.samples_released, r.late_samples, r.underflows, r.link_lost
    );
    if r.playout != "fifo" {
        // A target-delay playout: the constant delay each side holds now,
        // beside the one-way network delays its clock estimate measures.
        println!(
            "  playout    delay {} forward · {} back · delays announced {} / {} (network one-way {} / {}; remote clock {:+.3} ms, {:+.1} ppm)",
            ms(r.playout_delay_fwd_s),
            ms(r.playout_delay_bwd_s),
            r.delay_changes_fwd,
            r.delay_changes_bwd,
            ms(r.one_way_fwd_mean_s),
            ms(r.one_way_bwd_mean_s),
            r.remote_clock_offset_s * 1e3,
            r.remote_clock_skew_ppm
        );
    }
    let us = |s: f64| format!("{:.0} µs", s * 1e6);
    let (remote_clock, remote_spin) = if r.queue_remote_max.is_some() {
        (
            format!(
                " · remote {} / {}",
                us(r.clock_remote_p50_s),
                us(r.clock_remote_p99_s)
            ),
            format!(" / {}", us(r.spin_margin_remote_s)),
        )
    } else {
        (String::new(), String::new())
    };
    println!(
        "  clock      release lateness p50 / p99: base {} / {}{remote_clock} (spin margin learned {}{remote_spin})",
        us(r.clock_base_p50_s),
        us(r.clock_base_p99_s),
        us(r.spin_margin_base_s),
    );
    if let (Some(f), Some(b)) = (r.relay_frames_fwd, r.relay_frames_bwd) {
        println!("  relay      {f} frames forward, {b} back");
    }
    println!("  series     {}", r.csv);
}
