//! A deterministic discrete-event simulator of the whole link.
//!
//! Two [`Endpoint`](crate::endpoint::Endpoint)s — the base with an operator
//! following a [`Signal`](signal::Signal), the remote with a second-order
//! plant per axis — talk through two in-order network paths whose delays
//! come from a [`DelayModel`](delay::DelayModel). Nothing sleeps: time jumps
//! to the next arrival or deadline, so twenty simulated minutes take
//! milliseconds, and every draw comes from the seed, so a run is
//! reproducible bit for bit.
//!
//! ```
//! use ndr_core::sim::{SimConfig, delay::DelayModel, run};
//!
//! let mut cfg = SimConfig::paper(DelayModel::Lan75km);
//! cfg.duration = ndr_core::time::Duration::from_secs(60);
//! let report = run(&cfg)?.report;
//! assert_eq!(report.ns, 2);
//! # Ok::<(), ndr_core::sim::SimError>(())
//! ```

pub mod compare;
pub mod delay;
mod engine;
pub mod oracle;
mod report;
pub mod signal;

pub use engine::{
    CommandTiming, ForwardLog, MAX_SIM_AXES, PlantConfig, SIM_QUEUE, SimConfig, SimError,
    SimOutput, run,
};
pub use report::{Report, Row, percentile};
