//! The remote, as the child process `ndr soak --serve`: an echo
//! controller that reports what it saw of the commands.

use std::io::{BufRead, Write};
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration as StdDuration, Instant as StdInstant};

use ndr::core::endpoint::Status;
use ndr::net::{Link, LinkConfig, Listener, NetError};

use super::check::dropped;
use crate::runtime::runtime;

/// Echoes each command back with the gaps, repeats and reorderings seen in
/// this connection's command sequence, and the samples its counters say
/// were dropped (late, rejected, discarded, lost on the network).
pub(super) fn serve(addr: SocketAddr, config: LinkConfig) -> Result<(), String> {
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
