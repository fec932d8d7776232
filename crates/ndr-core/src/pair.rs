//! Two endpoints, a wire between them and time that jumps from one event to
//! the next: the simulator, the endpoint tests and the fuzz harness run a
//! link this way, each with its own [`World`] (the network, the clocks, the
//! applications). Needs the `alloc` feature.
//!
//! A [`Pair`] follows the drive contract of the crate doc. At each instant
//! it hands over the frames due (arrivals before deadlines; at equal times,
//! base → remote first), each followed by its receiver's
//! [turn](crate::drive::turn); then each side whose deadline is due, base
//! first, runs [`handle_timeout`](Endpoint::handle_timeout) and its turn.
//!
//! ```
//! use ndr_core::endpoint::{Config, Endpoint, Event, LinkError, Status};
//! use ndr_core::pair::{Pair, World};
//! use ndr_core::storage::Heap;
//! use ndr_core::time::{Duration, Instant};
//! use ndr_core::wire::Role;
//!
//! /// 3 ms each way; the remote echoes its commands; the base counts.
//! struct Echo {
//!     k: f64,
//!     grtts: Vec<Duration>,
//! }
//!
//! impl World<Heap> for Echo {
//!     type Error = LinkError;
//!     fn arrival(&mut self, _: Role, sent: Instant, _: &[u8]) -> Option<Instant> {
//!         Some(sent + Duration::from_millis(3))
//!     }
//!     fn event(
//!         &mut self,
//!         side: Role,
//!         ep: &mut Endpoint<Heap>,
//!         _: Instant,
//!         event: Event<Box<[f64]>>,
//!     ) -> Result<(), LinkError> {
//!         if let Event::Released(r) = event {
//!             if side == Role::Base && r.status == Status::Fresh {
//!                 self.grtts.extend(r.grtt);
//!             }
//!             let answer = if side == Role::Base { self.k += 1.0; self.k } else { r.values()[0] };
//!             ep.set_sample(&[answer])?;
//!         }
//!         Ok(())
//!     }
//!     fn failed(&mut self, _: Role, _: Instant, error: LinkError) -> Result<(), LinkError> {
//!         Err(error)
//!     }
//! }
//!
//! let config = |role| {
//!     let mut c = Config::paper(role);
//!     c.period = Duration::from_millis(10);
//!     c
//! };
//! let base = Endpoint::new(config(Role::Base), Instant::ZERO)?;
//! let remote = Endpoint::new(config(Role::Remote), Instant::ZERO)?;
//! let mut pair = Pair::new(base, remote, Echo { k: 0.0, grtts: vec![] });
//! pair.run_until(Instant::from_millis(3000))?;
//! let grtts = &pair.world.grtts;
//! assert!(grtts.len() > 250 && grtts.iter().all(|&g| g == Duration::from_millis(60)));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

use alloc::collections::VecDeque;
use alloc::vec::Vec;

use crate::drive::{self, Turn};
use crate::endpoint::{DatagramError, Endpoint, Event, LinkError, Origin};
use crate::storage::Storage;
use crate::time::Instant;
use crate::wire::{self, MAX_DATAGRAM_LEN, Role};

/// Everything around a [`Pair`]'s two endpoints. Times are the world's
/// ("global") unless they say they are a side's own clock; by default both
/// clocks are the world's.
pub trait World<S: Storage> {
    /// What ends the run.
    type Error;

    /// When a frame `from` sends at `sent` reaches its peer, or `None` if
    /// the wire loses it. A time before `sent` counts as `sent`. Frames
    /// reach their peer in the order of these times (the order they were
    /// sent at equal times): an in-order wire returns times that never go
    /// back.
    fn arrival(&mut self, from: Role, sent: Instant, frame: &[u8]) -> Option<Instant>;

    /// `side`'s clock at world time `t`.
    fn local(&self, side: Role, t: Instant) -> Instant {
        let _ = side;
        t
    }

    /// When `side`'s driver serves its deadline `deadline` (on `side`'s
    /// clock), in world time: at the first world time that clock reads
    /// `deadline`, later for a driver that is late or stopped. Called more
    /// than once for the same deadline; it must answer the same each time.
    fn wake(&mut self, side: Role, deadline: Instant) -> Instant {
        let _ = side;
        deadline
    }

    /// When `side` reads a frame that reached it at `arrived`: then, or
    /// later if its process is stopped. Must not go back as `arrived`
    /// grows.
    fn read(&self, side: Role, arrived: Instant) -> Instant {
        let _ = side;
        arrived
    }

    /// The receive time `side` gives a frame that reached it at `arrived`
    /// and that it reads at `read` (world times), on its own clock: by
    /// default the time it reads it; a kernel stamp would be `arrived`.
    fn stamp(&self, side: Role, arrived: Instant, read: Instant) -> Instant {
        let _ = arrived;
        self.local(side, read)
    }

    /// `side` took a frame, stamped `at` on its clock (after
    /// [`World::failed`] if the endpoint refused it).
    fn received(&mut self, side: Role, at: Instant, frame: &[u8]) {
        let _ = (side, at, frame);
    }

    /// An event for `side`'s application, at `now` on its clock.
    fn event(
        &mut self,
        side: Role,
        endpoint: &mut Endpoint<S>,
        now: Instant,
        event: Event<S::Values>,
    ) -> Result<(), Self::Error>;

    /// `side`'s application after its events, before its frames
    /// ([`Turn::sample`]), at `now` on its clock.
    fn sample(
        &mut self,
        side: Role,
        endpoint: &mut Endpoint<S>,
        now: Instant,
    ) -> Result<(), Self::Error> {
        let _ = (side, endpoint, now);
        Ok(())
    }

    /// `side` ran a tick at world time `at` (its predictor stepped), after
    /// its turn.
    fn ticked(&mut self, side: Role, at: Instant, base: &Endpoint<S>, remote: &Endpoint<S>) {
        let _ = (side, at, base, remote);
    }

    /// `side`'s endpoint refused a frame or could not write one, at world
    /// time `at`: `Err` ends the run, `Ok` carries on.
    fn failed(&mut self, side: Role, at: Instant, error: LinkError) -> Result<(), Self::Error>;
}

/// A base and a remote endpoint, the frames in flight between them, and
/// their [`World`].
pub struct Pair<S: Storage, W> {
    /// The base (operator) side.
    pub base: Endpoint<S>,
    /// The remote (robot) side.
    pub remote: Endpoint<S>,
    /// The network, the clocks and the applications.
    pub world: W,
    now: Instant,
    started: bool,
    /// Per direction (index: the sender's role): frames by arrival, then
    /// by the order they were sent.
    wire: [VecDeque<(Instant, Vec<u8>)>; 2],
    /// Buffers of delivered frames, reused.
    spare: Vec<Vec<u8>>,
    buf: Vec<u8>,
}

impl<S: Storage, W: World<S>> Pair<S, W> {
    /// Two endpoints made at world time zero, nothing in flight. The first
    /// step starts with a turn of each side, base first,
    /// which sends what they have before any event.
    pub fn new(base: Endpoint<S>, remote: Endpoint<S>, world: W) -> Self {
        Pair {
            base,
            remote,
            world,
            now: Instant::ZERO,
            started: false,
            wire: [VecDeque::new(), VecDeque::new()],
            spare: Vec::new(),
            // A datagram's bundle may be longer than any frame of a stream.
            buf: alloc::vec![0; MAX_DATAGRAM_LEN],
        }
    }

    /// The world time of the last event handled.
    #[must_use]
    pub fn now(&self) -> Instant {
        self.now
    }

    /// The endpoint of `side`.
    pub fn endpoint(&mut self, side: Role) -> &mut Endpoint<S> {
        match side {
            Role::Base => &mut self.base,
            Role::Remote => &mut self.remote,
        }
    }

    #[cfg(test)]
    /// Frames `from` sent that its peer has not read yet.
    #[must_use]
    pub(crate) fn in_flight(&self, from: Role) -> usize {
        self.wire[from as usize].len()
    }

    #[cfg(test)]
    /// Loses every frame `from` sent that its peer has not read yet (a
    /// process that died with its socket); returns how many.
    pub(crate) fn drop_in_flight(&mut self, from: Role) -> usize {
        let lost = core::mem::take(&mut self.wire[from as usize]);
        let n = lost.len();
        self.spare.extend(lost.into_iter().map(|(_, bytes)| bytes));
        n
    }

    /// `side`'s turn now: its events to the world, then its frames onto
    /// the wire.
    pub fn drain(&mut self, side: Role) -> Result<(), W::Error> {
        let Pair {
            base,
            remote,
            world,
            now,
            started: _,
            wire,
            spare,
            buf,
        } = self;
        let endpoint = match side {
            Role::Base => base,
            Role::Remote => remote,
        };
        let local = world.local(side, *now);
        let mut turn = SideTurn {
            world,
            side,
            now: *now,
            local,
            wire: &mut wire[side as usize],
            spare,
        };
        drive::turn(endpoint, local, buf, &mut turn)
    }

    /// When the next frame is read or the next deadline served, if any.
    pub(crate) fn next_event(&mut self) -> Option<Instant> {
        let reads = [Role::Base, Role::Remote].map(|from| self.next_read(from));
        let wakes = [Role::Base, Role::Remote].map(|side| self.wake(side));
        reads.into_iter().chain(wakes).flatten().min()
    }

    /// Handles the next instant at which something happens, if it is no
    /// later than `until`; `false` if nothing did.
    pub(crate) fn step(&mut self, until: Instant) -> Result<bool, W::Error> {
        if !self.started {
            self.started = true;
            self.drain(Role::Base)?;
            self.drain(Role::Remote)?;
        }
        let Some(now) = self.next_event().filter(|&t| t <= until) else {
            return Ok(false);
        };
        self.now = now;
        loop {
            let due = [Role::Base, Role::Remote]
                .into_iter()
                .filter_map(|from| self.next_read(from).map(|t| (t, from)))
                .filter(|&(t, _)| t <= now)
                .min_by_key(|&(t, from)| (t, from as usize));
            let Some((_, from)) = due else { break };
            let Some((arrived, bytes)) = self.wire[from as usize].pop_front() else {
                break;
            };
            let side = from.peer();
            let at = self.world.stamp(side, arrived, now);
            // A datagram's samples (a Bundle) go to the datagram path: one
            // that is refused is counted there and harms nothing.
            let result = if wire::is_bundle(&bytes) {
                match self
                    .endpoint(side)
                    .handle_datagram(at, &bytes, Origin::Path)
                {
                    Err(DatagramError::Link(e)) => Err(e),
                    _ => Ok(()),
                }
            } else {
                self.endpoint(side).handle_frame(at, &bytes)
            };
            if let Err(e) = result {
                self.world.failed(side, now, e)?;
            }
            self.world.received(side, at, &bytes);
            self.spare.push(bytes);
            self.drain(side)?;
        }
        for side in [Role::Base, Role::Remote] {
            if self.wake(side).is_none_or(|t| t > now) {
                continue;
            }
            let at = self.world.local(side, now);
            let endpoint = self.endpoint(side);
            let steps = endpoint.predictor().steps();
            endpoint.handle_timeout(at);
            // A long catch-up stops at a full event queue: the application
            // takes the events, and the catch-up goes on.
            while self.endpoint(side).catching_up(at) {
                self.drain(side)?;
                self.endpoint(side).handle_timeout(at);
            }
            let ticked = self.endpoint(side).predictor().steps() != steps;
            self.drain(side)?;
            if ticked {
                self.world.ticked(side, now, &self.base, &self.remote);
            }
        }
        Ok(true)
    }

    /// Steps until the next event would come after `end` (or none is
    /// left).
    pub fn run_until(&mut self, end: Instant) -> Result<(), W::Error> {
        while self.step(end)? {}
        Ok(())
    }

    /// The endpoints and the world.
    pub fn into_parts(self) -> (Endpoint<S>, Endpoint<S>, W) {
        (self.base, self.remote, self.world)
    }

    /// When `from`'s peer reads the first frame in flight to it.
    fn next_read(&self, from: Role) -> Option<Instant> {
        let &(arrived, _) = self.wire[from as usize].front()?;
        Some(self.world.read(from.peer(), arrived))
    }

    fn wake(&mut self, side: Role) -> Option<Instant> {
        let deadline = self.endpoint(side).poll_timeout()?;
        Some(self.world.wake(side, deadline))
    }
}

/// One side's turn: the world's hooks for that side, and its wire.
struct SideTurn<'a, W> {
    world: &'a mut W,
    side: Role,
    /// World time.
    now: Instant,
    /// The side's clock.
    local: Instant,
    wire: &'a mut VecDeque<(Instant, Vec<u8>)>,
    spare: &'a mut Vec<Vec<u8>>,
}

impl<S: Storage, W: World<S>> Turn<S> for SideTurn<'_, W> {
    type Error = W::Error;

    fn event(
        &mut self,
        endpoint: &mut Endpoint<S>,
        event: Event<S::Values>,
    ) -> Result<(), W::Error> {
        self.world.event(self.side, endpoint, self.local, event)
    }

    fn sample(&mut self, endpoint: &mut Endpoint<S>) -> Result<(), W::Error> {
        self.world.sample(self.side, endpoint, self.local)
    }

    fn transmit(&mut self, frame: &[u8]) -> Result<(), W::Error> {
        if let Some(at) = self.world.arrival(self.side, self.now, frame) {
            let at = at.max(self.now);
            let mut bytes = self.spare.pop().unwrap_or_default();
            bytes.clear();
            bytes.extend_from_slice(frame);
            // After every frame due no later: at the back on an in-order wire.
            let i = self.wire.partition_point(|&(t, _)| t <= at);
            self.wire.insert(i, (at, bytes));
        }
        Ok(())
    }

    fn failed(&mut self, error: LinkError) -> Result<(), W::Error> {
        self.world.failed(self.side, self.now, error)
    }
}

#[cfg(test)]
mod tests {
    use alloc::vec;

    use super::*;
    use crate::endpoint::{Config, Phase};
    use crate::storage::Heap;
    use crate::time::Duration;

    /// Each way, the n-th frame takes `delays[n % len]`, or is lost when
    /// that is `None`; what each side was handed, by its stamp.
    struct Wire {
        delays: Vec<Option<Duration>>,
        sent: [usize; 2],
        stamps: [Vec<Instant>; 2],
        errors: Vec<LinkError>,
    }

    impl World<Heap> for Wire {
        type Error = LinkError;
        fn arrival(&mut self, from: Role, sent: Instant, _: &[u8]) -> Option<Instant> {
            let n = &mut self.sent[from as usize];
            *n += 1;
            Some(sent + self.delays[*n % self.delays.len()]?)
        }
        fn received(&mut self, side: Role, at: Instant, _: &[u8]) {
            self.stamps[side as usize].push(at);
        }
        fn event(
            &mut self,
            _: Role,
            _: &mut Endpoint<Heap>,
            _: Instant,
            _: Event<alloc::boxed::Box<[f64]>>,
        ) -> Result<(), LinkError> {
            Ok(())
        }
        fn failed(&mut self, _: Role, _: Instant, e: LinkError) -> Result<(), LinkError> {
            self.errors.push(e);
            Ok(())
        }
    }

    fn pair(delays: Vec<Option<Duration>>) -> Pair<Heap, Wire> {
        let ep = |role| {
            let mut c = Config::paper(role);
            c.period = Duration::from_millis(10);
            Endpoint::new(c, Instant::ZERO).unwrap()
        };
        let wire = Wire {
            delays,
            sent: [0; 2],
            stamps: [vec![], vec![]],
            errors: vec![],
        };
        Pair::new(ep(Role::Base), ep(Role::Remote), wire)
    }

    #[test]
    fn frames_are_read_in_the_order_they_arrive_even_when_sent_in_another() {
        let ms = |m| Some(Duration::from_millis(m));
        // Every third frame overtakes the one before it (which the
        // endpoint, made for an in-order stream, refuses).
        let mut p = pair(vec![ms(3), ms(25), ms(4)]);
        p.run_until(Instant::from_millis(2000)).unwrap();
        assert!(p.world.stamps.iter().any(|s| s.len() >= 2));
        for stamps in &p.world.stamps {
            assert!(stamps.windows(2).all(|w| w[0] < w[1]), "{stamps:?}");
        }
        assert!(!p.world.errors.is_empty());
        assert!(p.now() <= Instant::from_millis(2000));
    }

    #[test]
    fn a_wire_that_loses_everything_leaves_both_sides_unconnected() {
        let mut p = pair(vec![None]);
        p.run_until(Instant::from_millis(500)).unwrap();
        assert!(p.world.stamps.iter().all(Vec::is_empty));
        assert_eq!(p.in_flight(Role::Base) + p.in_flight(Role::Remote), 0);
        assert_ne!(p.base.phase(), Phase::Running);
        assert!(p.base.stats().frames_sent >= 1);
    }
}
