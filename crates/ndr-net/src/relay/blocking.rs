//! The relay for callers without an async runtime: it brings its own.

use std::io;
use std::net::SocketAddr;
use std::time::Duration as StdDuration;

use ndr_netem::DelayModel;
use tokio::runtime::Runtime;

use super::{Relay, RelayConfig, RelayEvent, RelayStats};

/// When [`BlockingRelay::serve`] stops. With neither set it serves until the
/// process ends.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct StopWhen {
    /// Stop on Ctrl-C (SIGINT). Once asked for, the process no longer ends
    /// on Ctrl-C by itself.
    pub ctrl_c: bool,
    /// Stop after this long.
    pub after: Option<StdDuration>,
}

impl StopWhen {
    /// Stop on Ctrl-C.
    #[must_use]
    pub fn ctrl_c() -> Self {
        StopWhen {
            ctrl_c: true,
            after: None,
        }
    }

    /// The same, and also after `after` if given.
    #[must_use]
    pub fn or_after(mut self, after: Option<StdDuration>) -> Self {
        self.after = after;
        self
    }
}

/// A [`Relay`] on its own multi-threaded tokio runtime, driven from
/// synchronous code (the `ndr relay` command).
///
/// ```no_run
/// use ndr_netem::DelayModel;
/// use ndr_net::relay::{BlockingRelay, StopWhen};
///
/// let relay = BlockingRelay::listen(
///     "127.0.0.1:7000".parse().unwrap(),
///     "127.0.0.1:7001".parse().unwrap(),
///     DelayModel::ParisNewYork,
///     1,
/// )?;
/// let stats = relay.serve(StopWhen::ctrl_c())?;
/// println!("{} connections", stats.connections);
/// # Ok::<(), std::io::Error>(())
/// ```
#[derive(Debug)]
pub struct BlockingRelay {
    runtime: Runtime,
    relay: Relay,
}

impl BlockingRelay {
    /// Starts a runtime and starts the relay on it (see [`Relay::listen`]); it
    /// serves from [`serve`](Self::serve) on.
    ///
    /// # Errors
    ///
    /// The runtime cannot start, or the listening socket cannot be bound.
    pub fn listen(
        listen: SocketAddr,
        upstream: SocketAddr,
        model: DelayModel,
        seed: u64,
    ) -> io::Result<Self> {
        BlockingRelay::listen_with(listen, upstream, model, seed, false)
    }

    /// [`listen`](Self::listen) on any address, loopback or not (see
    /// [`Relay::listen_insecure`]).
    ///
    /// # Errors
    ///
    /// The runtime cannot start, or the listening socket cannot be bound.
    pub fn listen_insecure(
        listen: SocketAddr,
        upstream: SocketAddr,
        model: DelayModel,
        seed: u64,
    ) -> io::Result<Self> {
        BlockingRelay::listen_with(listen, upstream, model, seed, true)
    }

    fn listen_with(
        listen: SocketAddr,
        upstream: SocketAddr,
        model: DelayModel,
        seed: u64,
        insecure: bool,
    ) -> io::Result<Self> {
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .thread_name("ndr-relay")
            .build()
            .map_err(|e| io::Error::new(e.kind(), format!("relay: cannot start tokio: {e}")))?;
        let relay = runtime.block_on(async {
            if insecure {
                Relay::listen_insecure(listen, upstream, model, seed).await
            } else {
                Relay::listen(listen, upstream, model, seed).await
            }
        })?;
        Ok(BlockingRelay { runtime, relay })
    }

    /// See [`Relay::with_config`].
    #[must_use]
    pub fn with_config(mut self, config: RelayConfig) -> Self {
        self.relay = self.relay.with_config(config);
        self
    }

    /// See [`Relay::on_event`].
    #[must_use]
    pub fn on_event(mut self, observer: impl Fn(&RelayEvent) + Send + Sync + 'static) -> Self {
        self.relay = self.relay.on_event(observer);
        self
    }

    /// The address the relay listens on.
    #[must_use]
    pub const fn local_addr(&self) -> SocketAddr {
        self.relay.local_addr()
    }

    /// Serves until `stop` says so, then shuts the relay down (closing every
    /// connection) and returns its final counters.
    ///
    /// # Errors
    ///
    /// The Ctrl-C handler cannot be installed (the relay is shut down first).
    pub fn serve(self, stop: StopWhen) -> io::Result<RelayStats> {
        self.serve_with(stop, |_| {})
    }

    /// [`serve`](Self::serve), telling `started` the running relay first
    /// (to take a [`RelayHandle::stats_reader`](super::RelayHandle::stats_reader), say).
    ///
    /// # Errors
    ///
    /// As [`serve`](Self::serve).
    pub fn serve_with(
        self,
        stop: StopWhen,
        started: impl FnOnce(&super::RelayHandle),
    ) -> io::Result<RelayStats> {
        let BlockingRelay { runtime, relay } = self;
        runtime.block_on(async move {
            let handle = relay.spawn()?;
            started(&handle);
            let waited = wait(stop).await;
            let stats = handle.shutdown().await;
            waited.map(|()| stats)
        })
    }
}

async fn wait(stop: StopWhen) -> io::Result<()> {
    let deadline = async {
        match stop.after {
            Some(after) => tokio::time::sleep(after).await,
            None => std::future::pending().await,
        }
    };
    let ctrl_c = async {
        if stop.ctrl_c {
            tokio::signal::ctrl_c().await
        } else {
            std::future::pending().await
        }
    };
    tokio::select! {
        () = deadline => Ok(()),
        signal = ctrl_c => signal.map_err(|e| {
            io::Error::new(e.kind(), format!("relay: cannot listen for Ctrl-C: {e}"))
        }),
    }
}
