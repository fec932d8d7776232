//! A playout policy of one's own, plugged into ndr without editing it:
//! `cargo run --release --example custom_playout [SECONDS]`.
//!
//! The policy holds each sample for the 95th percentile of the last 64
//! one-way delays. It sets only a target delay ([`TargetDelay`]: told each
//! delay, asked the target), so [`OnTicks`] runs it: each sample released
//! at the first tick at or after its send time plus the target. A policy
//! that decides more implements [`Policy`] itself. Either reaches an
//! endpoint through a [`Factory`], named in the configuration by
//! [`Playout::Custom`], which every driver takes as it is: here the
//! simulator, then a link on loopback. Each prints the GRTT, the round
//! trip the controller sees.

use std::collections::VecDeque;
use std::error::Error;
use std::net::SocketAddr;
use std::thread;

use ndr::core::Regulation;
use ndr::core::endpoint::{Config, Status};
use ndr::core::playout::{Custom, Factory, OnTicks, Playout, Policy, Setup, TargetDelay};
use ndr::core::time::{Duration, Instant};
use ndr::core::wire::Role;
use ndr::net::{Link, LinkConfig, Listener};
use ndr::sim::delay::DelayModel;
use ndr::sim::{SimConfig, run};

/// The `q` quantile of the last `n` one-way delays.
#[derive(Clone, Debug)]
struct Percentile {
    q: f64,
    n: usize,
    delays: VecDeque<Duration>,
}

impl TargetDelay for Percentile {
    fn observe(&mut self, _sent_at: Instant, delay: Duration) {
        if self.delays.len() == self.n {
            self.delays.pop_front();
        }
        self.delays.push_back(delay);
    }

    fn target(&self) -> Option<Duration> {
        let mut sorted: Vec<Duration> = self.delays.iter().copied().collect();
        sorted.sort_unstable();
        let rank = (self.q * sorted.len() as f64).ceil() as usize;
        sorted.get(rank.saturating_sub(1)).copied()
    }
}

/// Makes one [`Percentile`] policy for each endpoint.
struct PercentileOf {
    name: &'static str,
    q: f64,
    n: usize,
}

impl Factory for PercentileOf {
    fn name(&self) -> &str {
        self.name
    }

    fn build(&self, setup: &Setup) -> Box<dyn Policy> {
        let policy = Percentile {
            q: self.q,
            n: self.n,
            delays: VecDeque::with_capacity(self.n),
        };
        Box::new(OnTicks::new(policy, setup))
    }
}

/// A `static`, so that the configuration that names it stays `Copy`.
static P95: PercentileOf = PercentileOf {
    name: "p95-of-64",
    q: 0.95,
    n: 64,
};

const PERIOD: Duration = Duration::from_millis(10);

fn main() -> Result<(), Box<dyn Error>> {
    let seconds: f64 = match std::env::args().nth(1) {
        Some(s) => s
            .parse()
            .map_err(|_| format!("SECONDS: not a number: {s:?}"))?,
        None => 3.0,
    };
    let playout = Playout::Custom(Custom::new(&P95));

    // In the simulator: the paper's 75 km LAN, two minutes of simulated
    // time, beside the paper's static FIFO on the same delays.
    for regulation in [Regulation::Target(playout), Regulation::PaperStatic] {
        let mut cfg = SimConfig::paper(DelayModel::Lan75km).with_regulation(regulation);
        cfg.period = PERIOD;
        cfg.duration = Duration::from_secs(120);
        let r = run(&cfg)?.report;
        println!(
            "simulator, {:<13} GRTT {:6.1} ± {:4.1} ms over {} round trips, late rate {:.4} forward",
            r.regulation,
            r.grtt_mean_s * 1e3,
            r.grtt_std_s * 1e3,
            r.grtt_count,
            r.late_rate_fwd
        );
    }

    // On loopback: a robot that echoes its commands as its state.
    let config = |role| {
        let mut endpoint = Config::new(role);
        endpoint.period = PERIOD;
        endpoint.playout = playout;
        LinkConfig::new(endpoint)
    };
    let listener = Listener::listen_blocking("127.0.0.1:0".parse()?, config(Role::Remote))?;
    let addr: SocketAddr = listener.local_addr()?;
    let robot = thread::spawn(move || -> Result<(), String> {
        let mut link = listener.accept_blocking().map_err(|e| e.to_string())?;
        while let Ok(command) = link.recv() {
            link.send(command.values()).map_err(|e| e.to_string())?;
        }
        Ok(())
    });
    let mut link = Link::connect_blocking(addr, config(Role::Base))?;
    let ticks = (seconds / PERIOD.as_secs_f64()) as u64;
    let (mut grtts, mut held) = (Vec::new(), 0);
    for k in 0..ticks {
        link.send(&[k as f64])?;
        let state = link.recv()?;
        if state.status == Status::Held {
            held += 1;
        }
        if let Some(grtt) = state.grtt {
            grtts.push(grtt.as_secs_f64());
        }
    }
    let stats = link.close();
    robot.join().map_err(|_| "the robot's thread panicked")??;
    let n = grtts.len().max(1) as f64;
    let mean = grtts.iter().sum::<f64>() / n;
    let std = (grtts.iter().map(|g| (g - mean).powi(2)).sum::<f64>() / n).sqrt();
    let delay = stats.map_or(f64::NAN, |s| s.endpoint.playout_delay_s * 1e6);
    println!(
        "loopback,  {:<13} GRTT {:6.1} ± {:4.1} ms over {} round trips, {held} states held, \
         playout delay {delay:.0} µs",
        playout.to_string(),
        mean * 1e3,
        std * 1e3,
        grtts.len(),
    );
    Ok(())
}
