//! # ndr-sim
//!
//! A deterministic discrete-event simulator of the whole link.
//!
//! Two [`Endpoint`](ndr_core::endpoint::Endpoint)s — the base with an operator
//! following a [`Signal`](signal::Signal), the remote with a second-order
//! plant per axis — talk through two in-order network paths whose delays
//! come from a [`DelayModel`](delay::DelayModel). Nothing sleeps: time jumps
//! to the next arrival or deadline, so twenty simulated minutes take
//! milliseconds, and every draw comes from the seed, so a run is
//! reproducible bit for bit.
//!
//! ```
//! use ndr_sim::{SimConfig, delay::DelayModel, run};
//!
//! let mut cfg = SimConfig::paper(DelayModel::Lan75km);
//! cfg.duration = ndr_core::time::Duration::from_secs(60);
//! let report = run(&cfg)?.report;
//! assert_eq!(report.ns, 2);
//! # Ok::<(), ndr_sim::SimError>(())
//! ```
//!
//! ## What it holds
//!
//! - [`run`] and [`SimConfig`]: the engine, with the remote's plant
//!   ([`PlantConfig`]) and the operator's [`signal`]s; [`Report`] and
//!   [`Row`] are what a run measured (`ndr sim --json`, `--out`).
//! - [`delay`]: the delay models and in-order delivery, which are the
//!   `ndr-netem` crate re-exported here, so that a [`SimConfig`] and its
//!   delay model come from one place. `ndr-net`'s relay uses that crate
//!   directly and does not depend on the simulator.
//! - [`oracle`]: the best constant delay on a known trace, and
//!   [`compare`]: playout policies side by side against it (`ndr compare`).
//! - [`control`]: classical control closed across the link — a Smith
//!   predictor, wave variables — over each kind of link (`ndr control`).
//!
//! Its users: the `ndr` command line (`ndr sim`, `ndr sim --paper`, `ndr
//! compare`; `ndr demo`, `base` and `remote` borrow its plant and signals),
//! Python's `ndr.sim.run`, and the benches.
#![forbid(unsafe_code)]

pub mod compare;
pub mod control;
/// The delay models and in-order delivery: the `ndr-netem` crate.
pub use ndr_netem as delay;
mod engine;
pub mod oracle;
mod report;
pub mod signal;

pub use engine::{
    Answer, CommandTiming, ForwardLog, MAX_SIM_AXES, PlantConfig, SIM_QUEUE, SimConfig, SimError,
    SimOutput, run,
};
pub use report::{Report, Row, percentile};
