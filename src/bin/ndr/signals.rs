//! Signals: `ndr remote`'s (SIGUSR1 prints the listener's counters,
//! SIGINT and SIGTERM stop it in order), and a long run's stop in order
//! (`ndr soak`).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use ndr::net::{Listener, ListenerStats};
use tokio::sync::Notify;

/// A request to stop, seen by the blocking robot loop (a flag) and by the
/// async accept (a notification).
#[derive(Default)]
pub struct Stop {
    flag: AtomicBool,
    notify: Notify,
}

impl Stop {
    pub fn set(&self) {
        self.flag.store(true, Ordering::Relaxed);
        self.notify.notify_waiters();
    }

    /// The flag, for a loop that checks it.
    pub fn flag(&self) -> &AtomicBool {
        &self.flag
    }

    pub fn is_set(&self) -> bool {
        self.flag.load(Ordering::Relaxed)
    }

    /// Returns once stop was asked.
    pub async fn wait(&self) {
        loop {
            // Made before the check, it sees a `set` that comes after it.
            let notified = self.notify.notified();
            if self.is_set() {
                return;
            }
            notified.await;
        }
    }
}

/// The listener's counters as a table: each counter (named as in
/// `ListenerStats`, the metrics and docs/guide/troubleshooting.md) on a line
/// of its own, with its value and what it counts.
pub fn counters(stats: &ListenerStats) -> String {
    let s = stats;
    let rows: [(&str, u64, &str); 21] = [
        ("accepted", s.accepted, "links handed to the robot"),
        (
            "refused_busy",
            s.refused_busy,
            "refused: another base was served",
        ),
        (
            "refused_certificate",
            s.refused_certificate,
            "TLS: a certificate refused (by either side)",
        ),
        (
            "refused_no_certificate",
            s.refused_no_certificate,
            "TLS: the peer gave no certificate",
        ),
        (
            "refused_version",
            s.refused_version,
            "TLS: the peer does not speak TLS 1.3 (or is plain)",
        ),
        ("timeouts", s.timeouts, "handshakes not finished in time"),
        (
            "failed_other",
            s.failed_other,
            "handshakes failed otherwise (closed, reset)",
        ),
        ("refused_role", s.refused_role, "the peer is a remote too"),
        (
            "refused_layout",
            s.refused_layout,
            "other --axes or --state",
        ),
        (
            "refused_settings",
            s.refused_settings,
            "another period or regulation mode",
        ),
        (
            "refused_wire_version",
            s.refused_wire_version,
            "another ndr wire version",
        ),
        ("refused_protocol", s.refused_protocol, "not ndr frames"),
        (
            "refused_transport",
            s.refused_transport,
            "another transport (stream or datagrams)",
        ),
        (
            "evicted",
            s.evicted,
            "handshakes cut short: every slot taken",
        ),
        (
            "refused_per_source",
            s.refused_per_source,
            "handshakes cut short: too many from one address",
        ),
        ("unclaimed", s.unclaimed, "linked, but not taken in time"),
        (
            "accept_errors",
            s.accept_errors,
            "the kernel could not hand a connection over",
        ),
        (
            "datagrams_stray",
            s.datagrams_stray,
            "datagrams of no link, dropped",
        ),
        ("retried", s.retried, "QUIC: asked to prove their address"),
        (
            "refused_observer_only",
            s.refused_observer_only,
            "an observer's identity asked for control",
        ),
        (
            "refused_observers_full",
            s.refused_observers_full,
            "observers refused: as many as allowed",
        ),
    ];
    let mut table = String::from("listener counters:");
    for (name, value, what) in rows {
        table.push_str(&format!("\n  {name:<24}{value:>8}   {what}"));
    }
    table
}

/// Starts serving the signals on `rt`; the handlers are in place when it
/// returns (a signal sent after it is never the default one, which kills).
#[cfg(unix)]
pub fn watch(
    rt: &tokio::runtime::Runtime,
    listener: Arc<Listener>,
    stop: Arc<Stop>,
) -> Result<(), String> {
    use tokio::signal::unix::SignalKind;

    let _runtime = rt.enter();
    let mut usr1 = handler(SignalKind::user_defined1(), "SIGUSR1")?;
    let mut int = handler(SignalKind::interrupt(), "SIGINT")?;
    let mut term = handler(SignalKind::terminate(), "SIGTERM")?;
    rt.spawn(async move {
        loop {
            let name = tokio::select! {
                Some(()) = usr1.recv() => {
                    eprintln!("ndr remote: {}", counters(&listener.stats()));
                    continue;
                }
                Some(()) = int.recv() => "SIGINT",
                Some(()) = term.recv() => "SIGTERM",
                else => return,
            };
            eprintln!(
                "ndr remote: {name}: stopping (the current link, if any, is closed in order)"
            );
            stop.set();
        }
    });
    Ok(())
}

/// Without Unix signals: Ctrl-C stops it.
#[cfg(not(unix))]
pub fn watch(
    rt: &tokio::runtime::Runtime,
    _listener: Arc<Listener>,
    stop: Arc<Stop>,
) -> Result<(), String> {
    rt.spawn(async move {
        if tokio::signal::ctrl_c().await.is_ok() {
            eprintln!(
                "ndr remote: Ctrl-C: stopping (the current link, if any, is closed in order)"
            );
            stop.set();
        }
    });
    Ok(())
}

/// SIGINT and SIGTERM set the flag returned (the handlers are in place
/// when it returns), for a loop that then stops in order; `who` says so on
/// stderr. A second one ends the process at once.
#[cfg(unix)]
pub fn interrupts(
    rt: &tokio::runtime::Runtime,
    who: &'static str,
) -> Result<Arc<AtomicBool>, String> {
    use tokio::signal::unix::SignalKind;

    let _runtime = rt.enter();
    let mut int = handler(SignalKind::interrupt(), "SIGINT")?;
    let mut term = handler(SignalKind::terminate(), "SIGTERM")?;
    let flag = Arc::new(AtomicBool::new(false));
    let set = Arc::clone(&flag);
    rt.spawn(async move {
        loop {
            let name = tokio::select! {
                Some(()) = int.recv() => "SIGINT",
                Some(()) = term.recv() => "SIGTERM",
                else => return,
            };
            if set.swap(true, Ordering::Relaxed) {
                eprintln!("{who}: {name} again: ending now");
                std::process::exit(130);
            }
            eprintln!("{who}: {name}: stopping in order (again to end at once)");
        }
    });
    Ok(flag)
}

/// Without Unix signals: Ctrl-C.
#[cfg(not(unix))]
pub fn interrupts(
    rt: &tokio::runtime::Runtime,
    who: &'static str,
) -> Result<Arc<AtomicBool>, String> {
    let flag = Arc::new(AtomicBool::new(false));
    let set = Arc::clone(&flag);
    rt.spawn(async move {
        while tokio::signal::ctrl_c().await.is_ok() {
            if set.swap(true, Ordering::Relaxed) {
                std::process::exit(130);
            }
            eprintln!("{who}: Ctrl-C: stopping in order (again to end at once)");
        }
    });
    Ok(flag)
}

/// A stream of `kind` signals; `name` for the error.
#[cfg(unix)]
fn handler(
    kind: tokio::signal::unix::SignalKind,
    name: &str,
) -> Result<tokio::signal::unix::Signal, String> {
    tokio::signal::unix::signal(kind).map_err(|e| format!("cannot handle {name}: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_counters_are_a_table_with_every_field() {
        let mut stats = ListenerStats::default();
        stats.accepted = 3;
        stats.refused_protocol = 1;
        let table = counters(&stats);
        assert!(!table.contains("ListenerStats"), "{table}");
        let rows: Vec<Vec<&str>> = table
            .lines()
            .skip(1)
            .map(|l| l.split_whitespace().collect())
            .collect();
        let value = |name: &str| rows.iter().find(|r| r[0] == name).map(|r| r[1]);
        assert_eq!(value("accepted"), Some("3"), "{table}");
        assert_eq!(value("refused_protocol"), Some("1"), "{table}");
        // Every counter `Debug` shows is a row: a new one cannot be left out.
        let debug = format!("{stats:?}");
        let fields = debug
            .split(['{', ',', '}'])
            .filter_map(|f| f.split_once(':'))
            .map(|(name, _)| name.trim());
        for field in fields {
            assert!(
                value(field).is_some(),
                "{field} is not in the table:\n{table}"
            );
        }
    }
}
