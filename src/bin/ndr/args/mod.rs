//! Argument groups and flag readers shared by several subcommands.

mod address;
pub mod delay;
mod link;
mod metrics;
mod observers;
mod plant;
mod realtime;
pub mod record;
mod run;
mod security;
mod time;
mod zenoh;

pub use address::resolve;
pub use delay::DelayArgs;
pub use link::LinkArgs;
pub use metrics::MetricsArgs;
pub use observers::ObserverTrustArgs;
pub use plant::PlantArgs;
pub use realtime::RealtimeArgs;
pub use record::RecordArgs;
pub use run::RunArgs;
pub use security::SecurityArgs;
pub use time::millis;
pub use zenoh::ZenohArgs;
