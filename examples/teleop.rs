//! A robot and its operator over a regulated link, in one process on
//! loopback: `cargo run --release --example teleop [SECONDS]`.
//!
//! The robot (the remote) listens, applies each released command to a
//! first-order plant and sends its state back; the operator (the base)
//! follows a sine and reads the states. Each side holds the default
//! playout, a delay chosen from the measured one-way delays (`Config::new`;
//! `Config::paper` for the paper's FIFO). Neither needs a tokio runtime of its
//! own: `Listener::listen_blocking` and `Link::connect_blocking` bring one for
//! the connection, and each link is then driven by its hub thread. Across
//! two hosts, the same code with an address that is not loopback takes
//! `TlsConfig` (`LinkConfig::with_tls`).

use std::error::Error;
use std::net::SocketAddr;
use std::thread;

use ndr::core::endpoint::{Config, Status};
use ndr::core::time::Duration;
use ndr::core::wire::Role;
use ndr::net::{Link, LinkConfig, Listener};

const AXES: u16 = 2;
const PERIOD_MS: u64 = 10;

/// Both sides must agree on the widths and the period (the handshake checks).
fn config(role: Role) -> LinkConfig {
    let mut endpoint = Config::new(role).with_width(AXES);
    endpoint.period = Duration::from_millis(PERIOD_MS);
    LinkConfig::new(endpoint)
}

/// The robot: serves one operator, then returns.
fn robot(listener: Listener) -> Result<(), Box<dyn Error + Send + Sync>> {
    let mut link = listener.accept_blocking()?;
    let mut state = [0.0; AXES as usize];
    // `recv` returns each command at its release tick, and an error once
    // the operator has closed the link (or the network failed).
    while let Ok(command) = link.recv() {
        for (x, u) in state.iter_mut().zip(command.values()) {
            *x += 0.2 * (u - *x); // a first-order lag, one step per tick
        }
        link.send(&state)?; // goes out at the next tick
    }
    Ok(())
}

fn main() -> Result<(), Box<dyn Error>> {
    let seconds: f64 = match std::env::args().nth(1) {
        Some(s) => s
            .parse()
            .map_err(|_| format!("SECONDS: not a number: {s:?}"))?,
        None => 3.0,
    };
    let listener = Listener::listen_blocking("127.0.0.1:0".parse()?, config(Role::Remote))?;
    let addr: SocketAddr = listener.local_addr()?;
    let robot = thread::spawn(move || robot(listener).map_err(|e| e.to_string()));

    let mut link = Link::connect_blocking(addr, config(Role::Base))?;
    let ticks = (seconds * 1000.0 / PERIOD_MS as f64) as u64;
    let (mut grtts, mut held) = (Vec::new(), 0);
    for k in 0..ticks {
        let t = (k * PERIOD_MS) as f64 / 1000.0;
        let phase = 2.0 * std::f64::consts::PI * 0.5 * t;
        link.send(&[phase.sin(), phase.cos()])?;
        let state = link.recv()?; // the robot's state, at this side's release tick
        if state.status == Status::Held {
            held += 1; // an underflow: the last state is repeated
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
    println!(
        "{ticks} ticks at T = {PERIOD_MS} ms: round trip as the operator sees it \
         {:.2} ms, std {:.3} ms ({} measured); {held} held states",
        mean * 1e3,
        std * 1e3,
        grtts.len(),
    );
    if let Some(s) = stats {
        let nrtt = s.last_nrtt.map_or(f64::NAN, |d| d.as_secs_f64() * 1e3);
        println!(
            "playout delay {:.1} ms ({} changes), last network round trip {nrtt:.3} ms, release lateness p99 {}",
            s.endpoint.playout_delay_s * 1e3,
            s.endpoint.delay_changes,
            s.release_lateness.p99
        );
    }
    Ok(())
}
