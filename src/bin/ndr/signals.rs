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

/// The listener's counters, every field, on one line.
pub fn counters(stats: &ListenerStats) -> String {
    format!("listener counters: {stats:?}")
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
