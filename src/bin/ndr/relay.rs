//! `ndr relay`: a TCP and UDP relay that delays the link's frames and
//! datagrams like a real network, and loses datagrams by a loss model.

use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::net::relay::{
    BlockingRelay, DatagramDirectionStats, DatagramStats, DirectionStats, RelayConfig, RelayEvent,
    RelayStats, StopWhen,
};
use ndr::sim::delay::LossModel;

use ndr::net::metrics::RelayLabels;

use crate::args::{DelayArgs, MetricsArgs, resolve};
use crate::metrics::Served;

#[derive(clap::Args)]
pub struct RelayArgs {
    /// Address to listen on for clients (the base connects here), e.g.
    /// 0.0.0.0:7000: over TCP, and over UDP on the same port for the
    /// datagrams.
    #[arg(long, value_name = "ADDR")]
    pub listen: String,
    /// Address each client is relayed to (the remote), e.g. 10.0.0.2:7000:
    /// TCP connections to its TCP port, datagrams to the same port over UDP.
    #[arg(long, value_name = "ADDR")]
    pub upstream: String,
    /// Delays (default: the paper's relay, --profile paris-newyork).
    #[command(flatten)]
    pub net: DelayArgs,
    /// Datagrams lost each way, in each flow: none, PERCENT (each
    /// independently, e.g. 1) or ge:PERCENT:BURST (in bursts of BURST
    /// datagrams on average, e.g. ge:2:4). Applies to datagrams (UDP) only:
    /// the relay never drops TCP bytes, which would corrupt the stream.
    #[arg(long, default_value = "none")]
    pub loss: LossModel,
    /// Seed of the delays and losses: the same seed and send times give the
    /// same delays and losses.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Stop after this many seconds (default: run until Ctrl-C).
    #[arg(long, value_name = "S")]
    pub duration_s: Option<f64>,
    /// Print one JSON object of the counters instead of the table.
    #[arg(long)]
    pub json: bool,
    /// Allow --listen on a non-loopback address: the relay passes plain
    /// links through unencrypted, so it would expose a remote that only
    /// listens on loopback to the network.
    #[arg(long)]
    pub insecure: bool,
    #[command(flatten)]
    pub metrics: MetricsArgs,
}

pub fn run(args: &RelayArgs) -> Result<(), String> {
    let model = args.net.model("paris-newyork")?;
    let listen = resolve("--listen", &args.listen)?;
    let upstream = resolve("--upstream", &args.upstream)?;
    let after = match args.duration_s {
        None => None,
        Some(s) if s.is_finite() && s > 0.0 && s < 1e9 => Some(StdDuration::from_secs_f64(s)),
        Some(s) => {
            return Err(format!(
                "--duration-s must be a positive number of seconds, got {s}"
            ));
        }
    };
    let model_name = model.name();
    let start = if args.insecure {
        BlockingRelay::listen_insecure
    } else {
        BlockingRelay::listen
    };
    let config = RelayConfig::default().with_loss(args.loss);
    let relay = start(listen, upstream, model, args.seed)
        .map_err(|e| e.to_string())?
        .with_config(config)
        .on_event(print_event);
    let local = relay.local_addr();
    let served = Served::start(&args.metrics, "relay")?;
    eprintln!(
        "ndr relay: {local} -> {upstream} (TCP and UDP), delays {model_name}, datagram loss {}, \
         seed {}; {}",
        args.loss,
        args.seed,
        match after {
            Some(d) => format!("stopping after {:.1} s or on Ctrl-C", d.as_secs_f64()),
            None => "stop with Ctrl-C".to_string(),
        }
    );
    let started = StdInstant::now();
    let stats = relay
        .serve_with(StopWhen::ctrl_c().or_after(after), |handle| {
            if let Some(m) = served.metrics() {
                let labels = RelayLabels::new(local.to_string(), upstream.to_string());
                m.watch_relay(labels, &handle.stats_reader());
            }
        })
        .map_err(|e| e.to_string())?;
    let ran = started.elapsed().as_secs_f64();

    if args.json {
        let value = serde_json::json!({
            "listen": local.to_string(),
            "upstream": upstream.to_string(),
            "model": model_name,
            "loss": args.loss.to_string(),
            "seed": args.seed,
            "duration_s": ran,
            "connections": stats.connections,
            "finished": stats.finished,
            "upstream_failures": stats.upstream_failures,
            "framing_errors": stats.framing_errors,
            "queue_overflows": stats.queue_overflows,
            "io_errors": stats.io_errors,
            "closed_by_shutdown": stats.closed_by_shutdown,
            "forward": direction_json(&stats.forward),
            "backward": direction_json(&stats.backward),
            "datagrams": datagrams_json(&stats.datagrams),
        });
        println!("{value}");
    } else {
        print_table(&stats, ran);
    }
    Ok(())
}

fn print_event(event: &RelayEvent) {
    match event {
        RelayEvent::Opened { conn, peer } => eprintln!("ndr relay: [{conn}] {peer} opened"),
        RelayEvent::Closed(s) => eprintln!(
            "ndr relay: [{}] {} closed after {:.1} s: {}; forward {} frames ({} held back), \
             backward {} frames ({} held back)",
            s.conn,
            s.peer,
            s.duration.as_secs_f64(),
            s.end,
            s.forward.frames_delivered,
            s.forward.held_back,
            s.backward.frames_delivered,
            s.backward.held_back,
        ),
        // Events added later are not the log's yet.
        _ => {}
    }
}

fn direction_json(d: &DirectionStats) -> serde_json::Value {
    serde_json::json!({
        "frames_received": d.frames_received,
        "frames_delivered": d.frames_delivered,
        "bytes_delivered": d.bytes_delivered,
        "held_back": d.held_back,
    })
}

fn datagrams_json(d: &DatagramStats) -> serde_json::Value {
    let direction = |d: &DatagramDirectionStats| {
        serde_json::json!({
            "received": d.received,
            "lost": d.lost,
            "queue_full": d.queue_full,
            "delivered": d.delivered,
            "bytes_delivered": d.bytes_delivered,
            "send_failed": d.send_failed,
            "held_back": d.held_back,
            "evicted": d.evicted,
        })
    };
    serde_json::json!({
        "flows_opened": d.flows_opened,
        "flows_refused": d.flows_refused,
        "flows_evicted": d.flows_evicted,
        "flows_expired": d.flows_expired,
        "forward": direction(&d.forward),
        "backward": direction(&d.backward),
    })
}

fn print_table(stats: &RelayStats, ran: f64) {
    println!("ran {ran:.1} s, {} connections", stats.connections);
    let ends = [
        ("finished", stats.finished),
        ("upstream failures", stats.upstream_failures),
        ("bad framing", stats.framing_errors),
        ("queue overflows", stats.queue_overflows),
        ("i/o errors", stats.io_errors),
        ("closed at shutdown", stats.closed_by_shutdown),
    ];
    for (name, n) in ends {
        println!("  {name:<20} {n:>10}");
    }
    println!(
        "{:<10} {:>12} {:>12} {:>14} {:>10}",
        "direction", "frames in", "frames out", "bytes out", "held back"
    );
    for (name, d) in [("forward", &stats.forward), ("backward", &stats.backward)] {
        println!(
            "{name:<10} {:>12} {:>12} {:>14} {:>10}",
            d.frames_received, d.frames_delivered, d.bytes_delivered, d.held_back
        );
    }
    let d = &stats.datagrams;
    println!(
        "datagrams: {} flows opened, {} datagrams refused over the flow limit, {} unanswered \
         flows evicted for new clients, {} flows expired",
        d.flows_opened, d.flows_refused, d.flows_evicted, d.flows_expired
    );
    println!(
        "{:<10} {:>12} {:>10} {:>11} {:>12} {:>14} {:>12} {:>10} {:>8}",
        "direction",
        "dgrams in",
        "lost",
        "queue full",
        "dgrams out",
        "bytes out",
        "send failed",
        "held back",
        "evicted"
    );
    for (name, d) in [("forward", &d.forward), ("backward", &d.backward)] {
        println!(
            "{name:<10} {:>12} {:>10} {:>11} {:>12} {:>14} {:>12} {:>10} {:>8}",
            d.received,
            d.lost,
            d.queue_full,
            d.delivered,
            d.bytes_delivered,
            d.send_failed,
            d.held_back,
            d.evicted
        );
    }
}
