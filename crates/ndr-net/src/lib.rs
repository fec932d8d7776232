//! ndr-net: the network side of the ndr link.
//!
//! `ndr-core` holds the link as a sans-IO state machine; this crate drives it
//! over TCP (plain or mutual TLS 1.3), UDP datagrams, or QUIC (the datagram
//! transport with TLS: [`quic`]) and keeps its release clock. Two optional
//! features hold tooling a robot does not run: `relay`, the delay relay
//! (whose delay models are `ndr-netem`'s, the simulator's, without the
//! simulator), `keygen`, self-signed identities for a lab pair, and
//! `record`, MCAP recordings of links ([`record`]). Feature `zenoh` adds
//! links through a zenoh router or zenoh peers (`Transport::Zenoh`,
//! `Link::connect_zenoh`, `Listener::listen_zenoh`).
//!
//! # The drive loop
//!
//! A [`Hub`] is one OS thread (`ndr-hub`) that owns the endpoints and the
//! sockets of its links; tokio only connects and accepts, then hands the
//! socket over. The hub waits in a mio poll (epoll) over the links' sockets,
//! a waker (links added or closed) and a timerfd armed a spin margin
//! before the next deadline (learned from how late the timer wakes, 20 µs
//! to 200 µs: [`spin`]); the links of one hub share one tick grid, so one
//! wake-up serves all the links due at an instant. Then:
//!
//! - a frame is read as soon as its socket is ready, with the kernel's
//!   receive timestamp (`SO_TIMESTAMPNS`) as its arrival time, and handed to
//!   its endpoint at once;
//! - from the timer to the deadline the hub spins, still serving sockets one
//!   at a time while one more service fits before the deadline (it measures
//!   what a service costs), so the deadline keeps its microseconds;
//! - at the deadline it reads what is still waiting, runs every due endpoint
//!   (releases to the applications first when several are due), then writes
//!   their frames itself, non-blocking; bytes a full socket will not take
//!   wait in the link, bounded.
//!
//! Without a timerfd (not Linux), epoll's millisecond timeout is topped up
//! with a native sleep. A [`HubPool`] spreads links over several hubs on one
//! grid, one per core. The application holds a [`Link`] (send the next
//! sample, receive released ones, read [`LinkStats`]), or gives it a
//! handler that the hub runs at each release on its own thread
//! ([`Link::on_release`]), so that no thread is woken per tick. Bytes from
//! a TCP stream become frames through a [`Deframer`], which bounds its
//! memory by a few of the largest frames the link carries and refuses an
//! absurd or too long length prefix before buffering anything. [`clock`]
//! holds what the hub's release clock is measured with.
#![forbid(unsafe_code)]

mod arrival;
pub mod clock;
mod config;
mod connect;
mod delivery;
mod error;
mod framing;
mod hub;
mod keepalive;
#[cfg(feature = "keygen")]
pub mod keygen;
mod link;
mod listener;
#[cfg(feature = "metrics")]
pub mod metrics;
mod pool;
mod ports;
pub mod quic;
pub mod realtime;
mod reconnect;
#[cfg(feature = "record")]
pub mod record;
#[cfg(feature = "relay")]
pub mod relay;
mod runtime;
mod seats;
mod sharing;
pub mod spin;
mod stats;
pub mod tls;
mod transport;
#[cfg(feature = "zenoh")]
mod zenoh_link;

pub use clock::LatenessStats;
pub use config::{Admission, LinkConfig, QUEUE};
pub use delivery::{LinkEvent, Sample};
pub use error::NetError;
pub use framing::{Deframer, FramingError};
pub use hub::Hub;
pub use link::{EVENT_BACKLOG, Link, LinkSender};
pub use listener::{Listener, ListenerStats};
pub use pool::{HubChoice, HubPool};
pub use realtime::{Realtime, RealtimeError, RealtimeMode};
#[cfg(feature = "record")]
pub use record::{RecordConfig, RecordError, RecordStats, Recorder};
#[cfg(feature = "relay")]
pub use relay::{Relay, RelayConfig, RelayEvent, RelayHandle, RelayStats};
pub use sharing::SharingStats;
pub use stats::LinkStats;
pub use tls::{Fingerprint, HandshakeError, TlsConfig, TlsError, Trust};
pub use transport::{Transport, TransportError};
#[cfg(feature = "zenoh")]
pub use zenoh_link::{ZenohOptions, ZenohRouter};
