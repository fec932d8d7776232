//! # ndr-core
//!
//! The building blocks of a regulated teleoperation link, after Lelevé,
//! Fraisse and Dauchez, *Telerobotics over IP networks: towards a low-level
//! real-time architecture* (IROS 2001): plain, deterministic Rust that runs
//! without `std` and without an allocator, so the same code can run on the
//! robot's control board, in a simulator, and behind a tokio driver.
//!
//! ## What each peer does
//!
//! Each peer runs the same loop, with `now` taken from its own clock:
//!
//! 1. on bytes from the network: deframe, [`wire::Frame::new_checked`], push
//!    the samples into the [`Regulator`](regulator::Regulator), feed NRTT (from the echo) and the
//!    reception gap to the [`NetworkPredictor`];
//! 2. on each tick `t0 + k·T`: [`Regulator::tick`](regulator::RegulatorIn::tick) releases one sample to the
//!    application (or reports pre-fill or underflow), the predictor steps, the
//!    estimator steps with the command sent and the state released;
//! 3. on each send tick: [`wire::encode`] the latest sample with the echo of
//!    the newest frame received.
//!
//! [`endpoint::Endpoint`] packages this loop, with the handshake, the
//! initialization pattern and the paper's dynamic pause-and-resize, as a
//! sans-IO state machine, so the same code runs in the simulator
//! (`ndr-sim`, deterministic, seeded), behind sockets (`ndr-net`'s hub), in
//! the fuzz harness and from Python.
//!
//! ## The drive contract
//!
//! Every driver moves an endpoint the same way, `now` from its own clock:
//!
//! 1. each frame that arrived, in order: [`handle_frame`](endpoint::Endpoint::handle_frame)
//!    (an error ends the link and queues a Close for the peer);
//! 2. once [`poll_timeout`](endpoint::Endpoint::poll_timeout) is due:
//!    [`handle_timeout`](endpoint::Endpoint::handle_timeout) runs every tick
//!    and release due by `now` (after a stall, until the event queue is
//!    full: then [`catching_up`](endpoint::Endpoint::catching_up) says so,
//!    and step 3 comes before calling it again);
//! 3. [`poll_event`](endpoint::Endpoint::poll_event) until `None`: the
//!    application takes its releases and sets the next sample with
//!    [`set_sample`](endpoint::Endpoint::set_sample);
//! 4. [`poll_transmit`](endpoint::Endpoint::poll_transmit) until `None`, each
//!    frame to the peer;
//! 5. sleep until `poll_timeout`, or the next frame.
//!
//! Steps 3 and 4 are [`drive::turn`]; a whole link in simulated time (two
//! endpoints, a wire, time that jumps) is a [`pair::Pair`] (feature
//! `alloc`), which the simulator, the endpoint tests and the fuzz harness
//! share. The example below spells the loop out.
//!
//! **A frame carries the sample set last, and names what it answers.** A
//! Data frame is written by `poll_transmit` with the sample as the
//! application last set it, and its `released` field names the newest peer
//! sample released when that sample was set. An application that answers a
//! release in step 3 (in the driver's loop, or as a release handler on the
//! hub's thread) answers in the frame of the tick that released it; one on
//! a thread of its own answers at the next tick. Either way the GRTT the
//! peer measures is the loop from a command to its answer.
//!
//! ```
//! use std::collections::VecDeque;
//!
//! use ndr_core::endpoint::{Config, Endpoint, Event, Status};
//! use ndr_core::storage::Inline;
//! use ndr_core::time::{Duration, Instant};
//! use ndr_core::wire::{MAX_FRAME_LEN, Role};
//!
//! let config = |role| {
//!     let mut c = Config::paper(role);
//!     c.period = Duration::from_millis(10);
//!     c
//! };
//! let mut base = Endpoint::<Inline<1, 16>>::new(config(Role::Base), Instant::ZERO)?;
//! let mut remote = Endpoint::<Inline<1, 16>>::new(config(Role::Remote), Instant::ZERO)?;
//! // An in-order wire each way that takes 3 ms; a remote that echoes each
//! // command it is given; a base that sends its tick count.
//! let wire = Duration::from_millis(3);
//! let mut to = [VecDeque::new(), VecDeque::new()];
//! let (mut buf, mut now, mut k, mut grtts) = ([0; MAX_FRAME_LEN], Instant::ZERO, 0.0, vec![]);
//! while now < Instant::from_millis(3000) {
//!     for (side, ep) in [&mut base, &mut remote].into_iter().enumerate() {
//!         while to[side].front().is_some_and(|(at, _)| *at <= now) {
//!             let (_, frame): (Instant, Vec<u8>) = to[side].pop_front().unwrap();
//!             ep.handle_frame(now, &frame)?;
//!         }
//!         if ep.poll_timeout().is_some_and(|t| t <= now) {
//!             ep.handle_timeout(now);
//!         }
//!         while let Some(event) = ep.poll_event() {
//!             if let Event::Released(r) = event {
//!                 if side == 0 && r.status == Status::Fresh {
//!                     grtts.extend(r.grtt);
//!                 }
//!                 let answer = if side == 0 { k += 1.0; k } else { r.values()[0] };
//!                 ep.set_sample(&[answer])?;
//!             }
//!         }
//!         while let Some(n) = ep.poll_transmit(now, &mut buf)? {
//!             to[1 - side].push_back((now + wire, buf[..n].to_vec()));
//!         }
//!     }
//!     let arrivals = to.iter().filter_map(|q| q.front().map(|(at, _)| *at));
//!     let deadlines = [base.poll_timeout(), remote.poll_timeout()].into_iter().flatten();
//!     now = arrivals.chain(deadlines).min().unwrap();
//! }
//! // A constant round trip: each way, the wire and the wait to the next
//! // tick, then the regulator's stock (ns = 2); the answer leaves at once.
//! assert!(grtts.len() > 250);
//! assert!(grtts.iter().all(|&g| g == grtts[0]), "{grtts:?}");
//! assert_eq!(grtts[0], Duration::from_millis(60));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! ## The main types
//!
//! A base (operator) and a remote (robot) exchange one frame per period `T`
//! each way. At each input a **Network Delay Regulator** turns the network's
//! jittery arrivals into releases at a constant period.
//!
//! - The link: [`Endpoint`] and its [`Config`] (in [`endpoint`], with the
//!   [`Event`]s it reports and its [`Stats`](endpoint::Stats)); [`drive`]
//!   and [`pair::Pair`] move it; [`storage`] says where its buffers live
//!   ([`storage::Inline`] arrays, or [`storage::Heap`] with `alloc`).
//! - [`time`]: integer-nanosecond [`Instant`](time::Instant) and
//!   [`Duration`](time::Duration); nothing here
//!   reads a clock, time is always an argument.
//! - [`regulator::Regulator`]: the NDR queue, capacity `N` fixed
//!   at compile time (or any [`storage::Queue`]), nominal size `ns` at run
//!   time, pre-fill, release per tick, underflow and overflow counted, never
//!   a silent drop.
//! - [`Regulation`]: how the delay is regulated, by the one name users give
//!   (`adaptive`, `paper-static`, `paper-dynamic`, …): the [`Mode`] both
//!   peers agree on and this side's [`Playout`].
//! - [`playout`]: when a regulator releases each sample, behind one
//!   interface ([`playout::Policy`]): the paper's FIFO or a target delay
//!   (Ramjee et al.'s algorithms 1 and 4, a NetEQ-like quantile, a fixed
//!   latency, a constant, and the adaptive timestamp-based policy), named by
//!   [`Playout`]; a policy of the application's own plugs in through a
//!   [`playout::Factory`].
//! - [`ClockSync`]: the peers' clock offset and skew from the timestamps the
//!   link already exchanges (Moon et al.'s hull of the delay floors, NTP's
//!   formula on them), which the adaptive playout and the one-way delays use.
//! - [`InitPattern`] (10 round trips) gives `mt`, and [`Sizing`] applies
//!   `ns = 2 + floor(η·mt/T)` and `T = max(T_min, NRTT/3)`.
//! - The paper's dynamic adaptation: [`NetworkPredictor`] low-passes
//!   ([`LowPass`]) the NRTT samples and the [`Envelope`] of the reception
//!   gaps, tracks both with a triple-integrator [`Kalman3`], forecasts them
//!   50 periods ahead, and says which `(T, ns)` the laws would choose.
//! - The remote system's model: an [`Arx2`] identifies each axis's
//!   second-order transfer function ([`Tf2`]) with recursive least squares
//!   ([`Rls`]); because the regulated delays are constant and known in
//!   samples, an [`Estimator`] can replay the commands in flight through that
//!   model to give `x3e` (the remote's state now) and `x3p` (its state when
//!   the command sent now takes effect).
//! - [`control`]: classical teleoperation control closed across the link:
//!   a [`SmithPredictor`](control::SmithPredictor), Niemeyer and Slotine's
//!   wave variables with the channel's energy account, a PID with
//!   anti-windup.
//! - [`wire`]: the frame codec (spec and test vectors in `docs/wire.md`):
//!   checked views over `&[u8]`, encoding into `&mut [u8]`; decoding is total.
//!   A datagram's samples travel in a [`wire::Bundle`]: the newest and
//!   copies of those before it ([`endpoint::Transport::Datagram`]).
//! - [`fingerprint`]: the fingerprint of the application's channel names,
//!   which both peers' Hellos carry so that a robot refuses an operator built
//!   for another layout.
//!
//! The simulator and the delay models it shares with `ndr-net`'s relay
//! (`ndr-netem`) are crates of their own, built on this one: nothing here
//! draws a random number or needs an allocator.
//!
//! ## Features
//!
//! - `std` (default): conversions between [`time::Instant`]/[`time::Duration`] and
//!   `std::time`; implies `alloc`.
//! - `alloc`: [`storage::Heap`], endpoints whose buffers are sized when they
//!   are made. Without `std` and `alloc` the crate is `#![no_std]` and uses no
//!   allocator: endpoints keep their buffers in [`storage::Inline`] arrays.
//! - `serde`: `serde::Serialize` for the endpoint's [`Stats`](endpoint::Stats)
//!   and what they hold, with the names and units the bindings show: a
//!   [`Duration`](time::Duration) is seconds (`f64`), a [`Phase`](endpoint::Phase) its
//!   lowercase name, a [`Running`](endpoint::Running) its count, mean, std,
//!   min and max. No `std` needed.
#![no_std]
#![forbid(unsafe_code)]
#![warn(unreachable_pub, unnameable_types)]

#[cfg(any(feature = "std", test))]
extern crate std;

#[cfg(feature = "alloc")]
extern crate alloc;

mod arx;
pub mod control;
pub mod drive;
pub mod endpoint;
mod estimator;
mod filters;
pub mod floor;
mod kalman;
mod layout;
#[cfg(feature = "alloc")]
pub mod pair;
pub mod playout;
mod predictor;
pub mod reconnect;
mod regulation;
pub mod regulator;
mod rls;
mod sizing;
pub mod storage;
mod sync;
pub mod time;
pub mod wire;

#[cfg(all(test, feature = "std"))]
mod tests;

pub use arx::{Arx2, ArxError, Tf2, Tf2State};
pub use endpoint::{Config, Endpoint, Event, LinkError, Mode, Underflow};
pub use estimator::{Estimate, Estimator, EstimatorError};
pub use filters::{Envelope, FilterError, LowPass};
pub use kalman::{Kalman3, KalmanError, KalmanModel};
pub use layout::fingerprint;
pub use playout::Playout;
pub use predictor::{NetworkPredictor, Prediction, PredictorConfig, PredictorError};
pub use regulation::{Regulation, UnknownRegulation};
pub use rls::{Rls, RlsError};
pub use sizing::{INIT_EXCHANGES, InitPattern, InitStats, Sizing, SizingError};
pub use sync::ClockSync;
