//! ndr: regulated teleoperation link (facade over `ndr-core` and `ndr-net`).
pub use ndr_core as core;
pub use ndr_net as net;
/// Certificate pairs for a lab setup (`ndr keygen`); lives in `ndr-net`.
pub use ndr_net::keygen;
