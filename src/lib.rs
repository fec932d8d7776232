//! ndr: regulated teleoperation link (facade over `ndr-core` and `ndr-net`).
pub use ndr_core as core;
pub use ndr_net as net;
pub mod keygen;
