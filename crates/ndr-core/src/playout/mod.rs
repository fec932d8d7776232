//! Playout policies: when a regulator releases each sample.
//!
//! Every policy implements one interface, [`Policy`]: the endpoint tells it
//! what happens (an arrival with its stamps, a tick, a release, a loss, a
//! new regime) and asks which queued samples a release takes, when it
//! releases apart from the ticks, the delay it holds and what it announces.
//! The endpoint calls nothing else, so a policy of the application's own
//! plugs in through a [`Factory`] ([`Playout::Custom`], feature `alloc`).
//!
//! The built-in ones, each named once in the [registry](Playout):
//!
//! - `Fifo`, the paper's NDR: a FIFO pre-filled to `ns` samples and
//!   released one per tick (its size set by the [`Mode`](crate::Mode)).
//! - Target delays released at the ticks ([`OnTicks`] over a
//!   [`TargetDelay`]): a sample sent at `sent_at` is released at the first
//!   tick at or after `sent_at + D`, `D` the policy's current target (Ramjee
//!   et al.'s algorithms 1 and 4, a NetEQ-like quantile, a fixed latency
//!   above the smallest delay, a constant). They assume synchronized clocks.
//! - `AdaptivePlayout`: the `1 − ε` quantile of the delays above the
//!   floor of the clock estimate ([`Adaptive`]), each sample released at its
//!   own slot on a `Schedule`.
//!
//! Under [`Underflow::DropLate`](crate::Underflow::DropLate) a sample that
//! arrives after its slot is late (counted, discarded, the tick repeats the
//! last sample).
//!
//! The constants and references of each policy are in `docs/algorithms.md`.

mod adaptive;
mod adaptive_playout;
mod classic;
mod fifo;
mod policy;
mod registry;
mod schedule;
mod target;

pub use adaptive::{Adaptive, AdaptiveSlot, NoAdaptive};
pub use policy::{
    Admit, Announcement, Arrival, Due, Lost, NoRoom, Observed, Outcome, Policy, PolicyClone,
    Queued, Room, Setup, Stamps, View,
};
#[cfg(feature = "alloc")]
pub use policy::{Custom, Factory, HeapRoom};
pub use registry::{Builtin, InvalidPlayout, Playout, UnknownPlayout};
pub use schedule::delay_quantum;
pub use target::{OnTicks, TargetDelay};

#[cfg(test)]
mod tests;
