//! ndr: a regulated teleoperation link — a controller drives a robot over an
//! ordinary IP network as if the delay were constant and known.
//!
//! Periodic samples travel both ways over TCP, and a Network Delay Regulator
//! at each input (a FIFO released at a constant period, or a playout policy
//! that releases each sample at its send time plus a chosen delay) absorbs
//! the network's jitter. This crate gathers the layers under one name and
//! carries the `ndr` command line:
//!
//! - [`core`] (`ndr-core`, `no_std` and allocation-free): the building
//!   blocks of the paper (the regulator, queue sizing, the Kalman network
//!   predictor, RLS identification and state estimation), the wire codec,
//!   and the link [`Endpoint`](core::endpoint::Endpoint): a sans-IO state
//!   machine that takes time as an argument (its drive loop is documented in
//!   [`core::endpoint`]).
//! - [`netem`] (`ndr-netem`): the network's delays as seeded models (the
//!   paper's profiles, netem tables, trace replay, events) and TCP's
//!   in-order delivery; the relay and the simulator share them.
//! - [`sim`] (`ndr-sim`): two endpoints over a simulated network in
//!   deterministic time, the plant and the operator's signals, the oracle
//!   and the playout comparison (`ndr sim`, `ndr compare`); its
//!   [`sim::delay`] is [`netem`].
//! - [`net`] (`ndr-net`): the endpoint over real TCP (optionally mutual TLS
//!   1.3). A [`Hub`](net::Hub) thread owns the sockets and keeps every
//!   link's deadlines to the microsecond; the application holds a
//!   [`Link`](net::Link) (its drive loop is documented in [`net`]). Its
//!   [`Relay`](net::Relay) delays a real link's frames by a [`netem`] model.
//!
//! A robot and its operator, neither with a tokio runtime of its own
//! (`examples/teleop.rs` runs both on loopback):
//!
//! ```no_run
//! use ndr::core::{endpoint::Config, time::Duration, wire::Role};
//! use ndr::net::{Link, LinkConfig, Listener};
//!
//! fn config(role: Role) -> LinkConfig {
//!     // Both sides agree: 2 command values, 4 state values, 10 ms.
//!     let mut c = Config::new(role).with_widths(2, 4);
//!     c.period = Duration::from_millis(10);
//!     LinkConfig::new(c)
//! }
//!
//! // The robot's side.
//! let listener = Listener::listen_blocking("127.0.0.1:7300".parse()?, config(Role::Remote))?;
//! let mut link = listener.accept_blocking()?;
//! while let Ok(command) = link.recv() {
//!     // Each command at its release tick, the delay constant; the state
//!     // is two positions and two velocities.
//!     let mut state: Vec<f64> = command.values().iter().map(|u| 0.5 * u).collect();
//!     state.extend([0.0, 0.0]);
//!     link.send(&state)?; // goes out at the next tick
//! }
//!
//! // The operator's side, in another program.
//! let mut link = Link::connect_blocking("127.0.0.1:7300".parse()?, config(Role::Base))?;
//! link.send(&[0.1, 0.2])?;
//! let state = link.recv()?; // .values(), .seq, .status, .grtt
//! # let _ = state;
//! link.close();
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
#![forbid(unsafe_code)]

pub use ndr_core as core;
pub use ndr_net as net;
/// Certificate pairs for a lab setup (`ndr keygen`); lives in `ndr-net`.
pub use ndr_net::keygen;
pub use ndr_netem as netem;
pub use ndr_sim as sim;

/// The README's and the user guide's Rust examples, compiled (and run,
/// unless marked `no_run`) as doctests, so that they cannot rot. Every
/// page of `docs/guide/` is listed here (a test of the `ndr` binary checks).
#[cfg(doctest)]
mod docs {
    #[doc = include_str!("../README.md")]
    struct Readme;
    #[doc = include_str!("../docs/guide/README.md")]
    struct Guide;
    #[doc = include_str!("../docs/guide/concepts.md")]
    struct Concepts;
    #[doc = include_str!("../docs/guide/regulation-and-transport.md")]
    struct RegulationAndTransport;
    #[doc = include_str!("../docs/guide/safety.md")]
    struct Safety;
    #[doc = include_str!("../docs/guide/security.md")]
    struct Security;
    #[doc = include_str!("../docs/guide/two-hosts.md")]
    struct TwoHosts;
    #[doc = include_str!("../docs/guide/sharing.md")]
    struct Sharing;
    #[doc = include_str!("../docs/guide/tuning.md")]
    struct Tuning;
    #[doc = include_str!("../docs/guide/simulator.md")]
    struct Simulator;
    #[doc = include_str!("../docs/guide/python.md")]
    struct Python;
    #[doc = include_str!("../docs/guide/troubleshooting.md")]
    struct Troubleshooting;
    #[doc = include_str!("../docs/guide/control.md")]
    struct Control;
    #[doc = include_str!("../docs/guide/realtime.md")]
    struct Realtime;
    #[doc = include_str!("../docs/guide/metrics.md")]
    struct Metrics;
    #[doc = include_str!("../docs/guide/recording.md")]
    struct Recording;
    #[doc = include_str!("../docs/guide/reconnecting.md")]
    struct Reconnecting;
    #[doc = include_str!("../docs/guide/zenoh.md")]
    struct Zenoh;
}
