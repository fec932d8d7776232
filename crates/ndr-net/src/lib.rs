//! ndr-net: the network side of the ndr link.
//!
//! `ndr-core` holds the link as a sans-IO state machine; this crate will own
//! the sockets (tokio), the release-clock thread and the delay relay. Bytes
//! from a TCP stream become frames through a [`Deframer`], which bounds its
//! memory by the protocol's largest frame and refuses an absurd length prefix
//! before buffering anything.
#![forbid(unsafe_code)]

mod capacity;
pub mod clock;
pub mod framing;
pub mod hub;
pub mod link;
pub mod pool;
pub mod relay;

pub use capacity::QUEUE_CAPACITIES;
pub use clock::{ClockThread, LatenessStats, ReleaseClock};
pub use framing::{Deframer, FramingError};
pub use hub::Hub;
pub use link::{Link, LinkConfig, LinkStats, Listener, NetError, Sample};
pub use pool::HubPool;
pub use relay::{Relay, RelayConfig, RelayEvent, RelayHandle, RelayStats};
