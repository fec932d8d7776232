//! `ndr soak`: a long run of a fast link through the relay under a schedule
//! of faults, checking that within each connection no sample is lost,
//! duplicated or reordered without a counter saying so, that nothing
//! panics, and that memory stays flat.
//!
//! Three parties: the remote runs as a child process (`ndr soak --serve`,
//! an echo controller that checks the commands it receives), the relay and
//! the base run here. The faults take turns, one every `--fault-every-s`:
//! the relay is restarted (every connection through it is cut), garbage is
//! sent to the remote (a random stream, a wrong version, an absurd length),
//! the remote process is killed (SIGKILL) and started again, a crowd of idle
//! connections is held open on the remote, a base completes its handshake
//! and then hangs (the remote must drop it within its liveness time), and a
//! base sends a stale frame (a repeated sequence number: refused, never
//! released). Throughout, the relay's delay trace adds a 150 ms spike every
//! 0.7 fault periods. After a cut the base connects again; each connection
//! is checked on its own.
//!
//! Over datagrams (`--transport udp`, or `quic`: the same datagrams as QUIC
//! DATAGRAM frames), the relay also loses datagrams by `--loss`: a sample
//! the network lost for good must be counted (`samples_lost`) by the side
//! that missed it, and a repeat or a reordering is never accepted. The
//! garbage fault then also sends stray and spoofed datagrams to the
//! remote's UDP port, which its listener must count as strays while the
//! link goes on.
//!
//! Over QUIC (mutual TLS 1.3), the soak makes throwaway identities for the
//! base and the remote in a fresh temporary directory (removed when it
//! ends), gives the remote its certificate, key and the base's fingerprint
//! on its command line, and each side pins the other. A QUIC remote has no
//! TCP port, so the faults aimed at one take their QUIC form. The garbage
//! connection is a stranger's handshake (a certificate the remote does not
//! pin), which must be refused. The hung base is a base on a UDP path of
//! its own that stops passing what it sends once its handshakes are done:
//! the remote must end it, with Close "timeout", within its liveness time
//! and 3 s. The stale frame is a replayed packet: a base on a path that
//! sends each of its packets again 20 ms later must run for a second with
//! no command repeated or reordered at the remote and no state at the
//! base. There is no idle crowd: its QUIC form, strangers that stop
//! halfway through their handshake, needs a QUIC client the link does not
//! offer. A relay restart need not end a QUIC connection: the remote takes
//! the new relay's address as the base's new path.

use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpListener as StdListener, TcpStream as StdStream, UdpSocket};
use std::path::PathBuf;
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::endpoint::{Config, LinkError, Phase, Status, Transport, Underflow};
use ndr::core::time::{Duration, Instant};
use ndr::core::wire::Role;
use ndr::core::wire::{self, Header, Hello, Message, close_reason};
use ndr::net::{
    Deframer, Fingerprint, HandshakeError, Hub, Link, LinkConfig, LinkStats, Listener, NetError,
    Relay, RelayConfig, RelayHandle, RelayStats,
};
use ndr::sim::delay::{DelayModel, LossModel, Trace, TraceRow};
use serde::Serialize;

use crate::args::millis;
use crate::runtime::runtime;
use crate::throwaway::{Throwaway, pinned};
use crate::transport::LinkTransport;

#[derive(clap::Args)]
pub struct SoakArgs {
    /// How long to run, in seconds.
    #[arg(long, default_value_t = 60.0)]
    pub duration_s: f64,
    /// The link's period, in ms (1: a 1 kHz link).
    #[arg(long, default_value_t = 1.0)]
    pub period_ms: f64,
    /// Seconds between two faults (relay restart, garbage, remote killed,
    /// idle connections, a hung base, a stale frame, in turn; over QUIC,
    /// their QUIC forms, and no idle connections).
    #[arg(long, default_value_t = 10.0)]
    pub fault_every_s: f64,
    /// How samples cross: tcp (the default), udp[:K[:R]] (datagrams,
    /// each with the newest sample and copies of the K − 1 before it, sent
    /// R more times; see `ndr demo --help`) or quic[:K[:R]] (the same
    /// datagrams over QUIC, mutual TLS 1.3: the soak makes throwaway
    /// identities for both sides, each pinning the other's). The remote
    /// runs the same.
    #[arg(long, default_value = "tcp")]
    pub transport: LinkTransport,
    /// Datagrams the relay loses, each way: none, PERCENT (each
    /// independently, e.g. 2) or ge:PERCENT:BURST (in bursts of BURST on
    /// average, e.g. ge:2:4). Needs --transport udp or quic: the relay
    /// never drops TCP bytes.
    #[arg(long, default_value = "none")]
    pub loss: LossModel,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Internal: be the remote, listening on ADDR (the soak starts itself so).
    #[arg(long, hide = true, value_name = "ADDR")]
    pub serve: Option<SocketAddr>,
    /// Internal, the remote over QUIC: its certificate, its key, and the
    /// fingerprint of the base's certificate it pins (the soak makes them).
    #[arg(long, hide = true, value_name = "FILE", requires = "serve")]
    pub cert: Option<PathBuf>,
    #[arg(long, hide = true, value_name = "FILE", requires = "serve")]
    pub key: Option<PathBuf>,
    #[arg(long, hide = true, value_name = "SHA256", requires = "serve")]
    pub pin: Option<Fingerprint>,
}

/// A delay spike in the relay's trace, `SPIKE_LEN_S` long, every 0.7 fault
/// periods (so each relay, restarted every third fault, sees a few).
const SPIKE_EVERY_FAULTS: f64 = 0.7;
const SPIKE_LEN_S: f64 = 0.2;
const SPIKE_DELAY_MS: u64 = 150;
const BASE_DELAY_US: u64 = 500;
/// The links' liveness time: a hung base is dropped after it.
const LIVENESS: Duration = Duration::from_secs(2);
/// Idle connections held open on the remote during that fault.
const IDLE_CONNECTIONS: usize = 200;
/// Values in a command: the command itself, the rest zeros.
const COMMAND_WIDTH: u16 = 4;
/// Values in a state: the echoed command, then the remote's report on its
/// connection (its gaps, the drops its counters explain, and its datagram
/// counters `samples_lost`, `samples_recovered`, `datagrams_stale`).
const STATE_WIDTH: u16 = 6;
/// The token a hung or stale-frame base gives in its Hello over datagrams
/// (any but 0: it sends no datagram).
const FAKE_SESSION: u64 = 0x50a4_50a4_50a4_50a4;
/// Over QUIC, how long after its first copy the stale-frame fault's path
/// sends each packet again.
const REPLAY_AFTER: StdDuration = StdDuration::from_millis(20);
/// Over QUIC, how long the stale-frame fault's base runs on its replaying
/// path, and the states it must release in that time at least.
const REPLAY_RUN: StdDuration = StdDuration::from_secs(1);
const REPLAY_MIN_STATES: u64 = 100;

/// What `ndr soak --json` prints.
#[derive(Serialize, Default)]
struct SoakReport {
    command: &'static str,
    duration_s: f64,
    period_s: f64,
    connections: u64,
    reconnections: u64,
    connect_failures: u64,
    samples_sent: u64,
    samples_released: u64,
    held: u64,
    underflows: u64,
    late: u64,
    /// Fresh samples missing in a connection's sequence that no counter
    /// (late, rejected, discarded, never sent) accounts for.
    lost: u64,
    /// Fresh samples missing in a connection's sequence, each counted by the
    /// link as late (dropped under `drop-late`), rejected, discarded, not
    /// read in time by the application, or never sent by the peer.
    dropped_with_counter: u64,
    /// Samples refused by a full regulator.
    rejected: u64,
    /// Releases dropped because the application's queue was full.
    app_dropped: u64,
    /// Fresh samples released twice.
    duplicated: u64,
    /// Fresh samples released out of order.
    reordered: u64,
    /// States whose echoed command went backwards.
    corrupted: u64,
    /// Gaps, repeats or reorderings the remote saw in the commands that its
    /// counters do not account for.
    remote_anomalies: u64,
    /// `tcp`, `udp[:K[:R]]` or `quic[:K[:R]]`.
    transport: String,
    /// The relay's datagram loss model.
    loss: String,
    /// Datagram transport, the base's side (the states), summed over the
    /// connections: datagrams taken, samples taken from a later datagram's
    /// copies, samples lost for good (each a gap the check accepts),
    /// datagrams dropped as older than one taken, repeats sent, datagrams
    /// of another session or refused, datagrams not sent, path changes,
    /// strays on the base's socket.
    datagrams_received: u64,
    samples_recovered: u64,
    samples_lost: u64,
    datagrams_stale: u64,
    datagrams_repeated: u64,
    datagrams_foreign: u64,
    datagrams_refused: u64,
    datagrams_unsent: u64,
    datagram_path_changes: u64,
    datagrams_stray: u64,
    /// Frames the base's hub gave up (its transmit queue full while it
    /// stalled): the remote counts them in `frames_missing` over TCP, in
    /// `samples_lost` over datagrams.
    tx_dropped: u64,
    /// The same of the commands at the remote, from its last report in
    /// each connection.
    remote_samples_lost: u64,
    remote_samples_recovered: u64,
    remote_datagrams_stale: u64,
    /// The relay's datagrams, both ways: read, dropped by the loss model,
    /// dropped on a full queue.
    relay_datagrams: u64,
    relay_datagrams_lost: u64,
    relay_datagrams_queue_full: u64,
    /// Garbage, stray and spoofed datagrams sent to the remote's UDP port
    /// (over QUIC, its QUIC port).
    garbage_datagrams: u64,
    /// Of those, the ones its listener counted as strays (the check waits
    /// for all of them).
    garbage_datagrams_counted: u64,
    /// Garbage datagram faults after which the base's link had ended.
    garbage_datagrams_harmed: u64,
    faults_relay_restarts: u64,
    faults_garbage: u64,
    faults_remote_killed: u64,
    faults_spikes: u64,
    /// Garbage connections the remote cut off within a second; over QUIC,
    /// strangers' handshakes it refused for their certificate.
    garbage_cut_off: u64,
    /// Crowds of idle connections held open on the remote (none over QUIC).
    faults_idle_crowds: u64,
    /// Connections of those crowds that connected (the remote refuses most:
    /// one source may hold only a few pending handshakes).
    idle_connections_held: u64,
    faults_hung_bases: u64,
    /// Hung bases the remote closed within its liveness time and 3 s.
    hung_bases_dropped: u64,
    faults_stale_frames: u64,
    /// Stale frames the remote refused with Close "frame out of sequence";
    /// over QUIC, runs of replayed packets of which nothing reached the
    /// released sequences.
    stale_frames_refused: u64,
    panics: u64,
    remote_crashes: u64,
    rss_start_kib: u64,
    rss_peak_kib: u64,
    rss_end_kib: u64,
    rss_growth_kib: i64,
    remote_rss_peak_kib: u64,
    ended_by: Vec<String>,
    /// Stopped early by SIGINT or SIGTERM, after `ran_s` of the
    /// `duration_s` asked: the counters cover that time.
    interrupted: bool,
    ran_s: f64,
    ok: bool,
}

pub fn run(args: &SoakArgs) -> Result<(), String> {
    let period = millis("--period-ms", args.period_ms)?;
    if period.is_zero() {
        return Err("--period-ms must be positive".into());
    }
    crate::transport::check_loss(
        args.transport.transport,
        &args.loss,
        "add --transport udp or --transport quic",
    )?;
    let config = link_config(period, args.transport.transport)?;
    if let Some(addr) = args.serve {
        let config = if args.transport.quic {
            let (Some(cert), Some(key), Some(pin)) = (&args.cert, &args.key, args.pin) else {
                return Err(
                    "ndr soak --serve over QUIC needs --cert, --key and --pin (the \
                            base's fingerprint): run `ndr soak --transport quic`, which \
                            makes them and starts its remote with them"
                        .into(),
                );
            };
            config.with_tls(pinned(cert, key, pin)?)
        } else {
            config
        };
        return serve(addr, config);
    }
    for (flag, v) in [
        ("--duration-s", args.duration_s),
        ("--fault-every-s", args.fault_every_s),
    ] {
        if !(v.is_finite() && v > 0.0 && v < 1e7) {
            return Err(format!(
                "{flag} must be a positive number of seconds, got {v}"
            ));
        }
    }
    let report = soak(args, config)?;
    if args.json {
        println!(
            "{}",
            serde_json::to_string(&report).map_err(|e| e.to_string())?
        );
    } else {
        print_table(&report);
    }
    if !report.ok {
        Err("the soak found a problem (see the counters above)".into())
    } else if report.interrupted {
        Err(format!(
            "interrupted after {:.0} s of the {:.0} s asked: the counters above cover that \
             time and found no problem",
            report.ran_s, report.duration_s
        ))
    } else {
        Ok(())
    }
}

fn link_config(period: Duration, transport: Transport) -> Result<LinkConfig, String> {
    // The paper's FIFO: what docs/reliability.md's soak runs measured.
    let mut endpoint = Config::paper(Role::Base);
    endpoint = endpoint.with_widths(COMMAND_WIDTH, STATE_WIDTH);
    endpoint.transport = transport;
    endpoint.period = period;
    // A delay spike then costs late samples (dropped and counted) instead of
    // a delay that grows by the spike's length each time.
    endpoint.underflow = Underflow::DropLate;
    endpoint.watchdog = Some(Duration::from_millis(500));
    endpoint.liveness = Some(LIVENESS);
    // The link draws its datagram session token when it starts: any but 0
    // passes the check here.
    let mut checked = endpoint;
    checked.session = checked.session.max(1);
    checked.validate().map_err(|e| e.to_string())?;
    Ok(LinkConfig::new(endpoint))
}

// ----- the remote (child process) --------------------------------------------

/// Echoes each command back with the gaps, repeats and reorderings seen in
/// this connection's command sequence, and the samples its counters say
/// were dropped (late, rejected, discarded, lost on the network).
fn serve(addr: SocketAddr, config: LinkConfig) -> Result<(), String> {
    let rt = runtime()?;
    let deadline = StdInstant::now() + StdDuration::from_secs(5);
    // The previous remote may have just died: its port frees up shortly.
    let listener = loop {
        match rt.block_on(Listener::bind(addr, config.clone())) {
            Ok(l) => break l,
            Err(e) if StdInstant::now() < deadline => {
                let _ = e;
                std::thread::sleep(StdDuration::from_millis(20));
            }
            Err(e) => return Err(format!("cannot listen on {addr}: {e}")),
        }
    };
    println!("ready");
    let _ = std::io::stdout().flush();
    let listener = Arc::new(listener);
    {
        let listener = Arc::clone(&listener);
        std::thread::spawn(move || answer(&listener));
    }
    loop {
        match rt.block_on(listener.accept()) {
            Ok(link) => {
                std::thread::spawn(move || echo(link));
            }
            Err(NetError::Io(e)) => eprintln!("ndr soak --serve: accept failed: {e}"),
            Err(e) => return Err(e.to_string()),
        }
    }
}

/// Answers the soak's questions on stdin (`stray`: the datagrams its
/// listener counted as strays), and ends this process once the soak is gone
/// (stdin closed), so that a soak killed outright leaves no remote behind.
fn answer(listener: &Listener) {
    for line in std::io::stdin().lock().lines() {
        let Ok(line) = line else { break };
        if line.trim() == "stray" {
            let mut out = std::io::stdout().lock();
            let _ = writeln!(out, "stray {}", listener.stats().datagrams_stray);
            let _ = out.flush();
        }
    }
    std::process::exit(0);
}

fn echo(mut link: Link) {
    let mut prev: Option<u64> = None;
    let mut anomalies = 0u64;
    loop {
        match link.recv_timeout(StdDuration::from_millis(200)) {
            Ok(s) => {
                if s.status == Status::Fresh {
                    anomalies += prev.map_or(0, |p| if s.seq > p { s.seq - p - 1 } else { 1 });
                    prev = Some(s.seq);
                }
                // Counted before this sample could be released: the snapshot
                // explains every gap before it.
                let stats = link.stats();
                let explained = stats.as_ref().map_or(0, dropped);
                let e = stats.map(|s| s.endpoint).unwrap_or_default();
                let command = s.values().first().copied().unwrap_or(0.0);
                let _ = link.send(&[
                    command,
                    anomalies as f64,
                    explained as f64,
                    e.samples_lost as f64,
                    e.samples_recovered as f64,
                    e.datagrams_stale as f64,
                ]);
            }
            Err(NetError::Timeout) => {}
            Err(_) => return,
        }
    }
}

struct Remote {
    child: Child,
    addr: SocketAddr,
    period_ms: f64,
    transport: LinkTransport,
    /// Over QUIC, its identity and the base's pin: `--cert`, `--key`, `--pin`.
    tls: Vec<String>,
    /// Where it is asked, and answers (see [`answer`]).
    ask: ChildStdin,
    answers: BufReader<ChildStdout>,
}

impl Remote {
    fn start(
        addr: SocketAddr,
        period_ms: f64,
        transport: LinkTransport,
        tls: Vec<String>,
    ) -> Result<Remote, String> {
        // This very binary: on Linux through /proc, which still reaches it
        // when a build has replaced (unlinked) the file it started from.
        let proc_exe = std::path::Path::new("/proc/self/exe");
        let exe = if proc_exe.exists() {
            proc_exe.to_path_buf()
        } else {
            std::env::current_exe().map_err(|e| format!("cannot find ndr itself: {e}"))?
        };
        let mut command = Command::new(exe);
        command
            .args(["soak", "--serve", &addr.to_string()])
            .args(["--period-ms", &period_ms.to_string()])
            .args(["--transport", &transport.to_string()])
            .args(&tls)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null());
        // A group of its own: a Ctrl-C at the terminal is the soak's to
        // handle (it stops the remote in order), not a crash of the remote.
        #[cfg(unix)]
        std::os::unix::process::CommandExt::process_group(&mut command, 0);
        let mut child = command
            .spawn()
            .map_err(|e| format!("cannot start the remote: {e}"))?;
        let mut line = String::new();
        let (Some(ask), Some(stdout)) = (child.stdin.take(), child.stdout.take()) else {
            let _ = child.kill();
            return Err("no pipe to the remote".into());
        };
        let mut answers = BufReader::new(stdout);
        answers
            .read_line(&mut line)
            .map_err(|e| format!("the remote did not start: {e}"))?;
        if line.trim() != "ready" {
            let _ = child.kill();
            return Err(format!("the remote did not start (it said {line:?})"));
        }
        Ok(Remote {
            child,
            addr,
            period_ms,
            transport,
            tls,
            ask,
            answers,
        })
    }

    /// The datagrams its listener counted as strays so far; `None` if it
    /// does not answer (it died).
    fn datagrams_stray(&mut self) -> Option<u64> {
        writeln!(self.ask, "stray").ok()?;
        self.ask.flush().ok()?;
        let mut line = String::new();
        self.answers.read_line(&mut line).ok()?;
        line.trim().strip_prefix("stray ")?.parse().ok()
    }

    fn rss_kib(&self) -> u64 {
        rss_kib(&format!("/proc/{}/statm", self.child.id()))
    }

    /// Kills it (SIGKILL) and starts another on the same address; `true`
    /// if the old one had died by itself (a crash) before.
    fn restart(&mut self) -> Result<bool, String> {
        let crashed = matches!(self.child.try_wait(), Ok(Some(_)));
        let _ = self.child.kill();
        let _ = self.child.wait();
        *self = Remote::start(self.addr, self.period_ms, self.transport, self.tls.clone())?;
        Ok(crashed)
    }
}

impl Drop for Remote {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

// ----- the base and the faults ------------------------------------------------

/// One connection's checks.
#[derive(Default)]
struct Conn {
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
fn dropped(s: &LinkStats) -> u64 {
    s.endpoint.late
        + s.endpoint.rejected
        + s.endpoint.discarded
        + s.app_dropped
        + s.endpoint.frames_missing
        + s.endpoint.samples_lost
        + s.endpoint_events_dropped
}

/// What a soak over QUIC runs with: the throwaway identities (their
/// directory goes with this), the base's link configuration (`config`
/// with its TLS), the same for the faults' own bases, and a stranger's (a
/// certificate the remote does not pin; it pins the remote), and the
/// remote's options.
struct Quic {
    _ids: Throwaway,
    base: LinkConfig,
    side: LinkConfig,
    stranger: LinkConfig,
    remote: Vec<String>,
}

impl Quic {
    fn new(config: &LinkConfig) -> Result<Quic, String> {
        // The faults' own links share one hub for the whole soak: a hub
        // each (a thread each) would leave the process a little larger at
        // each fault (each new thread's malloc arena keeps what it freed),
        // which the memory check would take for the link's.
        let hub = Hub::new(config.spin_margin).map_err(|e| e.to_string())?;
        let made = (|| {
            let ids = Throwaway::new("soak-quic")?;
            let (base, _) = ids.pair()?;
            let base = config.clone().with_tls(base);
            let side = base.clone().on_hub(hub.clone());
            let stranger = Throwaway::tls(&ids.another("stranger")?, &ids.remote)?;
            let stranger = config.clone().with_tls(stranger).on_hub(hub);
            let path = |p: &std::path::Path| p.display().to_string();
            let remote = vec![
                "--cert".into(),
                path(&ids.remote.cert),
                "--key".into(),
                path(&ids.remote.key),
                "--pin".into(),
                ids.base.fingerprint.to_string(),
            ];
            Ok::<_, String>(Quic {
                _ids: ids,
                base,
                side,
                stranger,
                remote,
            })
        })();
        made.map_err(|e| format!("cannot make the soak's QUIC certificates: {e}"))
    }
}

fn soak(args: &SoakArgs, config: LinkConfig) -> Result<SoakReport, String> {
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

/// A check on a thread of its own (`true`: it passed), and what it adds to
/// the report once it passed.
type Check = (std::thread::JoinHandle<bool>, fn(&mut SoakReport));

/// Joins the checks that have finished (all of them, waiting, if `all`),
/// adding what each that passed adds to the report.
fn join_checks(r: &mut SoakReport, checks: &mut Vec<Check>, all: bool) {
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

fn check(r: &mut SoakReport, conn: &mut Conn, status: Status, seq: u64, values: &[f64]) {
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

fn finish_conn(r: &mut SoakReport, conn: &Conn, stats: Option<LinkStats>) {
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
fn add_relay(r: &mut SoakReport, s: &RelayStats) {
    for d in [&s.datagrams.forward, &s.datagrams.backward] {
        r.relay_datagrams += d.received;
        r.relay_datagrams_lost += d.lost;
        r.relay_datagrams_queue_full += d.queue_full;
    }
}

fn link_up(link: Option<&(Link, Conn)>) -> bool {
    link.and_then(|(l, _)| l.stats())
        .is_some_and(|s| s.phase != Phase::Closed)
}

fn summarize(reasons: &[String]) -> Vec<String> {
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

/// Sends one kind of garbage to the remote; `true` if it cut the connection
/// off within a second.
fn inject_garbage(addr: SocketAddr, kind: u64) -> bool {
    let Ok(mut s) = StdStream::connect_timeout(&addr, StdDuration::from_secs(1)) else {
        return false;
    };
    let mut bytes: Vec<u8> = match kind % 3 {
        // A random stream (a xorshift of the fault's index: reproducible).
        0 => {
            let mut x = 0x9E37_79B9_7F4A_7C15u64 ^ kind;
            (0..256)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 7;
                    x ^= x << 17;
                    x as u8
                })
                .collect()
        }
        // A Hello-sized frame from another wire version.
        1 => {
            let mut f = vec![0u8; 64];
            f[..4].copy_from_slice(&64u32.to_le_bytes());
            f[4] = 99;
            f[5] = 2;
            f
        }
        // A length prefix no frame can have.
        _ => u32::MAX.to_le_bytes().to_vec(),
    };
    bytes.extend_from_slice(&[0u8; 64]);
    let _ = s.set_read_timeout(Some(StdDuration::from_secs(1)));
    if s.write_all(&bytes).is_err() {
        return true; // already cut off
    }
    let mut buf = [0u8; 512];
    let deadline = StdInstant::now() + StdDuration::from_secs(1);
    while StdInstant::now() < deadline {
        match s.read(&mut buf) {
            Ok(0) | Err(_) => return true,
            Ok(_) => {} // a Close frame, then the end
        }
    }
    false
}

/// Sends garbage datagrams to the remote's UDP port (its TCP listener's;
/// over QUIC, its QUIC port) from a stranger's socket: random bytes, an
/// empty datagram, a Hello, a Bundle cut short, one longer than any
/// Bundle, Bundles of commands with guessed session tokens (spoofs), and
/// two first packets of a QUIC client that are not. Then waits, a second
/// at most, for its listener to count them all as strays (over QUIC,
/// packets that no connection took and that opened none): (sent,
/// counted).
fn garbage_datagrams(remote: &mut Remote, kind: u64) -> (u64, u64) {
    let Some(before) = remote.datagrams_stray() else {
        return (0, 0);
    };
    let mut x = 0x2545_F491_4F6C_DD1Du64 ^ kind;
    let mut next = move || {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        x
    };
    let spoof = |session: u64, seq: u64| {
        let header = Header::new(seq, Instant::ZERO + Duration::from_millis(seq));
        let command = [1.0; COMMAND_WIDTH as usize];
        let msg = Message::Bundle {
            session,
            repeat: 0,
            missed: 0,
            newest: &command,
            older: &[],
        };
        let mut buf = [0u8; wire::MAX_FRAME_LEN];
        let n = wire::encode(&header, &msg, &mut buf).unwrap_or(0);
        buf[..n].to_vec()
    };
    let mut all: Vec<Vec<u8>> = vec![
        (0..256).map(|_| next() as u8).collect(),
        Vec::new(),
        base_hello(Duration::from_millis(1), FAKE_SESSION),
        spoof(0, 1),
        spoof(1, 2),
        spoof(u64::MAX, 3),
        spoof(next(), 4),
        spoof(next(), 5),
    ];
    let bundle = spoof(next(), 6);
    all.push(bundle[..bundle.len().min(wire::HEADER_LEN + 4)].to_vec());
    let mut long = bundle;
    long.resize(5000, 0xA5);
    all.push(long);
    // Two that a QUIC remote reads as QUIC (to a UDP one, strays as the
    // rest): a long header of a version no one speaks, as long as a client's
    // first packet, which quinn answers with a version negotiation; and a
    // version 1 Initial (a random connection id) whose 1182 bytes of
    // payload do not decrypt.
    for version in [0x0a1a_2a3au32, 1] {
        let mut d = vec![0xc3];
        d.extend(version.to_be_bytes());
        d.push(8);
        d.extend(next().to_be_bytes());
        d.extend([0, 0, 0x44, 0x9e]);
        d.extend((d.len()..1200).map(|_| next() as u8));
        all.push(d);
    }
    let Ok(socket) = UdpSocket::bind("127.0.0.1:0") else {
        return (0, 0);
    };
    let sent = all
        .iter()
        .filter(|d| socket.send_to(d, remote.addr).is_ok())
        .count() as u64;
    let deadline = StdInstant::now() + StdDuration::from_secs(1);
    let mut counted = 0;
    while StdInstant::now() < deadline {
        // Other strays may come too (a late datagram of a link that just
        // ended): the rise counts up to what was sent.
        counted = remote
            .datagrams_stray()
            .map_or(0, |n| n.saturating_sub(before).min(sent));
        if counted == sent {
            break;
        }
        std::thread::sleep(StdDuration::from_millis(5));
    }
    (sent, counted)
}

/// Over QUIC, the garbage connection's form: a stranger (`config`), whose
/// certificate the remote does not pin (it pins the remote's), tries the
/// handshake; `true` if the remote refused it for its certificate.
fn stranger_refused(rt: &tokio::runtime::Runtime, addr: SocketAddr, config: LinkConfig) -> bool {
    let attempt = rt.block_on(async {
        tokio::time::timeout(StdDuration::from_secs(1), Link::connect(addr, config)).await
    });
    matches!(
        attempt,
        Ok(Err(NetError::Handshake(
            HandshakeError::UnknownCertificate(_)
        )))
    )
}

/// A UDP path of its own from one base to the remote's QUIC port (the hung
/// and stale-frame faults over QUIC, whose bases are whole links: they
/// cannot go silent or send a frame twice inside QUIC's encryption, as
/// those faults' bases do on a TCP stream). It passes the base's datagrams
/// until [`cut`](Self::cut) (the remote's always come back), and if
/// `replay`, sends each again [`REPLAY_AFTER`] later.
struct SidePath {
    addr: SocketAddr,
    cut: Arc<AtomicBool>,
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl SidePath {
    fn open(remote: SocketAddr, replay: bool) -> std::io::Result<SidePath> {
        let front = UdpSocket::bind("127.0.0.1:0")?;
        let up = UdpSocket::bind("127.0.0.1:0")?;
        up.connect(remote)?;
        front.set_read_timeout(Some(StdDuration::from_millis(2)))?;
        up.set_read_timeout(Some(StdDuration::from_millis(20)))?;
        let (back_front, back_up) = (front.try_clone()?, up.try_clone()?);
        let addr = front.local_addr()?;
        let cut = Arc::new(AtomicBool::new(false));
        let stop = Arc::new(AtomicBool::new(false));
        let base = Arc::new(Mutex::new(None::<SocketAddr>));
        let forward = {
            let (cut, stop, base) = (Arc::clone(&cut), Arc::clone(&stop), Arc::clone(&base));
            std::thread::spawn(move || {
                let mut buf = [0u8; 1 << 16];
                let mut stale: VecDeque<(StdInstant, Vec<u8>)> = VecDeque::new();
                while !stop.load(Ordering::Relaxed) {
                    let now = StdInstant::now();
                    while stale.front().is_some_and(|(at, _)| *at <= now) {
                        if let Some((_, d)) = stale.pop_front() {
                            let _ = up.send(&d);
                        }
                    }
                    let Ok((n, from)) = front.recv_from(&mut buf) else {
                        continue;
                    };
                    *base.lock().unwrap_or_else(PoisonError::into_inner) = Some(from);
                    if !cut.load(Ordering::Relaxed) {
                        let _ = up.send(&buf[..n]);
                        if replay {
                            stale.push_back((now + REPLAY_AFTER, buf[..n].to_vec()));
                        }
                    }
                }
            })
        };
        let backward = {
            let stop = Arc::clone(&stop);
            std::thread::spawn(move || {
                let mut buf = [0u8; 1 << 16];
                while !stop.load(Ordering::Relaxed) {
                    if let Ok(n) = back_up.recv(&mut buf)
                        && let Some(to) = *base.lock().unwrap_or_else(PoisonError::into_inner)
                    {
                        let _ = back_front.send_to(&buf[..n], to);
                    }
                }
            })
        };
        Ok(SidePath {
            addr,
            cut,
            stop,
            threads: vec![forward, backward],
        })
    }

    /// Passes nothing more from the base.
    fn cut(&self) {
        self.cut.store(true, Ordering::Relaxed);
    }
}

impl Drop for SidePath {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Over QUIC, a hung base: a base (`config`: the soak's, with its TLS) on
/// a [`SidePath`] completes its handshakes, then the path passes nothing
/// more of it. `true` if the remote ended it with Close "timeout" (its
/// liveness) within its liveness time and 3 s.
fn quic_hung_base(rt: &tokio::runtime::Handle, remote: SocketAddr, config: LinkConfig) -> bool {
    let Ok(path) = SidePath::open(remote, false) else {
        return false;
    };
    let Ok(mut link) = rt.block_on(Link::connect(path.addr, config)) else {
        return false;
    };
    path.cut();
    let deadline = StdInstant::now() + StdDuration::from(LIVENESS) + StdDuration::from_secs(3);
    while StdInstant::now() < deadline {
        match link.recv_timeout(StdDuration::from_millis(100)) {
            Ok(_) | Err(NetError::Timeout) => {}
            Err(e) => {
                return matches!(
                    e,
                    NetError::Link(LinkError::PeerClosed {
                        reason: close_reason::TIMEOUT
                    })
                );
            }
        }
    }
    false
}

/// Over QUIC, the stale-frame fault: a stale frame is a replayed packet. A
/// base (`config`: the soak's, with its TLS) on a [`SidePath`] that sends
/// each of its packets again [`REPLAY_AFTER`] later runs for
/// [`REPLAY_RUN`], checked as the soak's link is. QUIC drops a replayed
/// packet (its packet number was seen); one that got through would be a
/// stale datagram, dropped whole by the endpoint. `true` if no replay
/// harmed the link: it stayed up, released [`REPLAY_MIN_STATES`] states
/// at least, none repeated, reordered or lost without a counter, and the
/// remote saw no command repeated or reordered. (Not that the remote
/// counted no stale datagram: over QUIC a few come now and then without
/// any replay, as the soak's own link counts at the base.)
fn quic_replay(rt: &tokio::runtime::Handle, remote: SocketAddr, config: LinkConfig) -> bool {
    let Ok(path) = SidePath::open(remote, true) else {
        return false;
    };
    let Ok(mut link) = rt.block_on(Link::connect(path.addr, config)) else {
        return false;
    };
    let mut r = SoakReport::default();
    let mut conn = Conn::default();
    let mut command = 0.0;
    let until = StdInstant::now() + REPLAY_RUN;
    while StdInstant::now() < until {
        match link.recv_timeout(StdDuration::from_millis(100)) {
            Ok(s) => {
                check(&mut r, &mut conn, s.status, s.seq, s.values());
                command += 1.0;
                let _ = link.send(&[command, 0.0, 0.0, 0.0]);
            }
            Err(NetError::Timeout) => {}
            Err(_) => return false,
        }
    }
    finish_conn(&mut r, &conn, link.close());
    r.samples_released >= REPLAY_MIN_STATES
        && r.lost + r.duplicated + r.reordered + r.corrupted + r.remote_anomalies == 0
}

/// Opens [`IDLE_CONNECTIONS`] connections to the remote that send nothing,
/// from 25 addresses other than the base's (127.0.0.2 to .26: strangers
/// that fill the remote's pending handshakes); those that connected.
fn idle_crowd(rt: &tokio::runtime::Runtime, addr: SocketAddr) -> Vec<tokio::net::TcpStream> {
    rt.block_on(async {
        let mut held = Vec::new();
        for i in 0..IDLE_CONNECTIONS {
            let Ok(socket) = tokio::net::TcpSocket::new_v4() else {
                break;
            };
            let host = 2 + u8::try_from(i % 25).unwrap_or(0);
            if socket.bind(([127, 0, 0, host], 0).into()).is_err() {
                break;
            }
            let connect = tokio::time::timeout(StdDuration::from_millis(200), socket.connect(addr));
            if let Ok(Ok(stream)) = connect.await {
                held.push(stream);
            }
        }
        held
    })
}

/// A base's Hello for the soak's link (its widths at `period`, the paper's
/// static mode, on datagrams if `session` is not 0), framed.
fn base_hello(period: Duration, session: u64) -> Vec<u8> {
    let header = Header::new(0, Instant::ZERO);
    let hello = Hello {
        role: Role::Base,
        mode: wire::mode::PAPER_STATIC,
        underflow: wire::underflow::DROP_LATE,
        command_width: COMMAND_WIDTH,
        state_width: STATE_WIDTH,
        period,
        layout: 0,
        session,
    };
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let n = wire::encode(&header, &Message::Hello(hello), &mut buf).unwrap_or(0);
    buf[..n].to_vec()
}

/// Connects to the remote and completes the handshake as a base: the
/// stream, once the remote's Hello has come.
fn handshake(addr: SocketAddr, period: Duration, session: u64) -> Option<(StdStream, Deframer)> {
    let mut s = StdStream::connect_timeout(&addr, StdDuration::from_secs(1)).ok()?;
    s.write_all(&base_hello(period, session)).ok()?;
    let mut deframer = Deframer::new();
    let _ = s.set_read_timeout(Some(StdDuration::from_secs(2)));
    let mut buf = [0u8; 512];
    loop {
        match deframer.next_frame() {
            Ok(Some(f)) if matches!(f.payload(), wire::Payload::Hello(_)) => {
                return Some((s, deframer));
            }
            Ok(Some(_)) => {}
            Ok(None) => {
                let n = s.read(&mut buf).ok().filter(|&n| n > 0)?;
                if deframer.extend(&buf[..n]) < n {
                    return None;
                }
            }
            Err(_) => return None,
        }
    }
}

/// Reads until the remote ends the connection; the Close reason it sent,
/// if any, and `None` if it did not end it by `deadline`.
fn await_close(
    s: &mut StdStream,
    deframer: &mut Deframer,
    deadline: StdInstant,
) -> Option<Option<u16>> {
    let mut buf = [0u8; 512];
    let mut reason = None;
    while StdInstant::now() < deadline {
        while let Ok(Some(f)) = deframer.next_frame() {
            if let wire::Payload::Close(c) = f.payload() {
                reason = Some(c.reason);
            }
        }
        let left = deadline.saturating_duration_since(StdInstant::now());
        let _ = s.set_read_timeout(Some(left.max(StdDuration::from_millis(1))));
        match s.read(&mut buf) {
            Ok(0) => return Some(reason),
            Ok(n) => {
                // Frames past a full deframer do not matter here: only the end does.
                let _ = deframer.extend(&buf[..n]);
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(_) => return Some(reason),
        }
    }
    None
}

/// A base that completes its handshake and then sends nothing (a hung
/// operator): `true` if the remote ended the connection within its
/// liveness time and 3 s.
fn hung_base(addr: SocketAddr, period: Duration, session: u64, liveness: Duration) -> bool {
    let Some((mut s, mut deframer)) = handshake(addr, period, session) else {
        return false;
    };
    let deadline = StdInstant::now() + StdDuration::from(liveness) + StdDuration::from_secs(3);
    await_close(&mut s, &mut deframer, deadline).is_some()
}

/// A base that completes its handshake, sends a probe, then the same
/// probe again: `true` if the remote refused it with Close "frame out of
/// sequence" within a second.
fn stale_frame(addr: SocketAddr, period: Duration, session: u64) -> bool {
    let Some((mut s, mut deframer)) = handshake(addr, period, session) else {
        return false;
    };
    let header = Header::new(0, Instant::ZERO + period);
    let mut buf = [0u8; wire::MAX_FRAME_LEN];
    let Ok(n) = wire::encode(&header, &Message::Data(&[]), &mut buf) else {
        return false;
    };
    let probe = buf[..n].to_vec();
    if s.write_all(&probe)
        .and_then(|()| s.write_all(&probe))
        .is_err()
    {
        return false;
    }
    let deadline = StdInstant::now() + StdDuration::from_secs(1);
    await_close(&mut s, &mut deframer, deadline) == Some(Some(close_reason::SEQUENCE))
}

fn free_port() -> Result<SocketAddr, String> {
    let l = StdListener::bind("127.0.0.1:0").map_err(|e| e.to_string())?;
    l.local_addr().map_err(|e| e.to_string())
}

/// 0.5 ms each way, with a 150 ms spike for 200 ms every `every` seconds.
fn spike_trace(duration_s: f64, every: f64) -> Result<Trace, String> {
    let base = Duration::from_micros(BASE_DELAY_US);
    let spike = Duration::from_millis(SPIKE_DELAY_MS);
    let mut rows = vec![TraceRow {
        at: Instant::ZERO,
        fwd: base,
        bwd: base,
    }];
    let mut t = every;
    while t < duration_s + every {
        let at = Instant::ZERO + Duration::from_secs_f64(t);
        rows.push(TraceRow {
            at,
            fwd: spike,
            bwd: spike,
        });
        rows.push(TraceRow {
            at: at + Duration::from_secs_f64(SPIKE_LEN_S),
            fwd: base,
            bwd: base,
        });
        t += every;
    }
    Trace::from_rows(rows).map_err(|e| e.to_string())
}

fn spikes_within(lifetime: StdDuration, every: f64) -> u64 {
    (lifetime.as_secs_f64() / every) as u64
}

/// Resident memory from a `/proc/<pid>/statm` file, in KiB (0 if unreadable).
fn rss_kib(statm: &str) -> u64 {
    std::fs::read_to_string(statm)
        .ok()
        .and_then(|s| s.split_whitespace().nth(1)?.parse::<u64>().ok())
        .map_or(0, |pages| pages * 4)
}

fn print_table(r: &SoakReport) {
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
    // Over QUIC, the faults' QUIC forms (see the module's doc).
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
