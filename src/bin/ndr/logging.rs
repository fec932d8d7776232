//! The log on stderr: what ndr-net refuses and why links end, at `warn` by
//! default; `-v` for info, `-vv` for debug; `RUST_LOG` for any filter.

use std::io::IsTerminal;

use ndr::core::endpoint::Event;
use ndr::net::LinkEvent;
use tracing_subscriber::EnvFilter;
use tracing_subscriber::filter::LevelFilter;

/// Installs the subscriber: `verbose` (the count of `-v`) sets the level,
/// `RUST_LOG`'s directives come on top of it.
pub fn init(verbose: u8) {
    let level = match verbose {
        0 => LevelFilter::WARN,
        1 => LevelFilter::INFO,
        2 => LevelFilter::DEBUG,
        _ => LevelFilter::TRACE,
    };
    let filter = EnvFilter::builder()
        .with_default_directive(level.into())
        .from_env_lossy();
    // A second subscriber cannot be installed; there is only one here.
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        .try_init();
}

/// Logs what a link tells its application, at a level by how much it
/// matters to whoever watches the robot.
pub fn event(side: &str, event: &LinkEvent) {
    match event {
        Event::Connected { peer } => tracing::info!("{side}: handshake done, peer {peer:?}"),
        Event::Started { period, ns } => {
            tracing::info!("{side}: samples flow, period {period}, ns {ns}");
        }
        Event::Paused { period, ns } => {
            tracing::info!("{side}: pause, then period {period}, ns {ns}");
        }
        Event::LinkLost { silent_for } => tracing::warn!(
            "{side}: link lost: no fresh sample for {silent_for}{}",
            if side == "remote" {
                "; holding the robot where it is"
            } else {
                ""
            }
        ),
        Event::LinkRestored { outage } => {
            tracing::warn!("{side}: link restored after {outage}: fresh samples again");
        }
        Event::DelayChanged { delay, ticks } => {
            tracing::debug!("{side}: playout delay now {delay} ({ticks} ticks)");
        }
        Event::RoundTripChanged { grtt, ticks } => {
            tracing::debug!("{side}: round trip now {ticks} ticks (GRTT {grtt})");
        }
        Event::Closed { error: Some(e) } => tracing::info!("{side}: link closed: {e}"),
        Event::Closed { error: None } => tracing::info!("{side}: link closed by this side"),
        Event::Released(_) => {}
        other => tracing::debug!("{side}: {}", other.kind()),
    }
}
