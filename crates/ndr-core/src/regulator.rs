//! The Network Delay Regulator: a fixed-capacity FIFO released at a constant period.
//!
//! Samples are [pushed](RegulatorIn::push) whenever the network delivers them;
//! one is [released](RegulatorIn::tick) per period on a clock common to both
//! peers. The nominal size `ns` is the stock the queue keeps between
//! releases: the queue is pre-filled to `ns`, and releases start at the first
//! tick that finds more than `ns` queued, so `ns` samples stay behind after
//! each release. A late frame then finds `ns` samples to live on; that stock
//! turns a jittery arrival process into a constant-delay one (paper §4.2.1).
//!
//! This reading of `ns` is the paper's: with `ns = 2` it reports "2 desired
//! samples in each queue which size varied between 1 and 3" and a time of
//! `3·T` spent in each regulator. Seen just before a release, the occupancy is
//! `ns + 1` in steady state.
//!
//! Nothing is ever dropped silently. A push into a full queue hands the sample
//! back; samples taken out other than by a release are counted as discarded; so
//! at every moment `arrived = released + len + rejected + discarded`.

use core::fmt;
use core::marker::PhantomData;

use heapless::Deque;

use crate::storage::Queue;

/// Error of [`RegulatorIn::push`]: the queue is full. It gives the sample back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Full<T>(pub T);

impl<T> Full<T> {
    #[cfg(test)]
    /// The sample that did not fit.
    #[must_use]
    pub(crate) fn into_inner(self) -> T {
        self.0
    }
}

impl<T> fmt::Display for Full<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(
            "regulator queue is full; the sample was handed back: \
             give the regulator a larger capacity N or a smaller nominal size",
        )
    }
}

impl<T: fmt::Debug> core::error::Error for Full<T> {}

/// Errors of configuring a [`Regulator`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum RegulatorError {
    /// The nominal size must leave room for one more sample: `ns < N`.
    NominalSize {
        /// The size asked for.
        ns: usize,
        /// The queue's capacity `N`.
        capacity: usize,
    },
}

impl fmt::Display for RegulatorError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            RegulatorError::NominalSize { ns, capacity } => write!(
                f,
                "nominal queue size {ns} does not fit a queue of capacity {capacity} \
                 (ns + 1 samples must fit); use a regulator with a larger capacity N \
                 or a larger period"
            ),
        }
    }
}

impl core::error::Error for RegulatorError {}

/// Whether the regulator is still building its stock or releasing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Building the stock: ticks release nothing until one finds more than `ns` queued.
    Prefilling,
    /// One release per tick.
    Running,
}

/// What one tick of the release clock gives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[must_use = "a released sample must be delivered or explicitly dropped"]
pub enum Tick<T> {
    /// The sample due at this tick.
    Released(T),
    /// Pre-fill is not complete: `have` samples are queued, releases start
    /// at a tick that finds `need = ns + 1`.
    Prefilling {
        /// Samples queued so far.
        have: usize,
        /// Samples a tick must find to start releasing: `ns + 1`.
        need: usize,
    },
    /// No sample was due and available at this tick (counted as an underflow).
    Underflow,
}

/// What went in and out of a regulator since it was created.
///
/// Invariant: `arrived = released + len + rejected + discarded`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[non_exhaustive]
pub struct Counters {
    /// Samples offered to [`RegulatorIn::push`].
    pub arrived: u64,
    /// Samples released by a tick.
    pub released: u64,
    /// Samples handed back because the queue was full.
    pub rejected: u64,
    /// Samples removed other than by a release ([`RegulatorIn::discard_front`], [`RegulatorIn::clear`]).
    pub discarded: u64,
    /// Running ticks that released nothing.
    pub underflows: u64,
    /// Running ticks (prefill ticks excluded).
    pub ticks: u64,
}

/// Queue occupancy seen at the running ticks, just before each release: the
/// paper's `s(t)`, of which `GRTT = 2·max(s)·T + NRTT`.
#[derive(Clone, Copy, Debug, PartialEq)]
#[non_exhaustive]
pub struct Occupancy {
    /// Smallest occupancy seen.
    pub min: usize,
    /// Largest occupancy seen.
    pub max: usize,
    /// Mean occupancy.
    pub mean: f64,
    /// Number of ticks it was measured over.
    pub ticks: u64,
}

#[derive(Clone, Copy, Debug, Default)]
struct OccupancyAcc {
    min: usize,
    max: usize,
    sum: u64,
    ticks: u64,
}

impl OccupancyAcc {
    fn record(&mut self, len: usize) {
        if self.ticks == 0 {
            self.min = len;
            self.max = len;
        } else {
            self.min = self.min.min(len);
            self.max = self.max.max(len);
        }
        self.sum = self.sum.saturating_add(len as u64);
        self.ticks += 1;
    }
}

/// The NDR queue: capacity `N` fixed at compile time, nominal size `ns < N`
/// chosen at run time. (A [`RegulatorIn`] over an array deque; a regulator
/// whose capacity is chosen at run time takes another
/// [`Queue`], such as [`HeapQueue`](crate::storage::HeapQueue).)
///
/// ```
/// use ndr_core::regulator::{Regulator, Tick};
///
/// let mut ndr: Regulator<u32, 16> = Regulator::new(2).unwrap();
/// ndr.push(1).unwrap();
/// ndr.push(2).unwrap();
/// assert_eq!(ndr.tick(), Tick::Prefilling { have: 2, need: 3 });
/// ndr.push(3).unwrap();
/// assert_eq!(ndr.tick(), Tick::Released(1)); // 2 and 3 stay as the stock
/// ndr.push(4).unwrap();
/// assert_eq!(ndr.tick(), Tick::Released(2));
/// assert_eq!(ndr.tick(), Tick::Released(3));
/// assert_eq!(ndr.tick(), Tick::Released(4));
/// assert_eq!(ndr.tick(), Tick::Underflow);
/// ```
pub type Regulator<T, const N: usize> = RegulatorIn<T, Deque<T, N>>;

/// The NDR queue over the queue `Q`, whose capacity bounds the nominal size.
#[derive(Clone, Debug)]
pub struct RegulatorIn<T, Q> {
    queue: Q,
    nominal: usize,
    phase: Phase,
    counters: Counters,
    occupancy: OccupancyAcc,
    item: PhantomData<T>,
}

impl<T, const N: usize> RegulatorIn<T, Deque<T, N>> {
    /// A regulator that keeps a stock of `ns` samples (`ns < N`).
    pub fn new(ns: usize) -> Result<Self, RegulatorError> {
        Self::with_queue(Deque::new(), ns)
    }
}

impl<T, Q: Queue<T>> RegulatorIn<T, Q> {
    /// A regulator over the empty `queue` that keeps a stock of `ns`
    /// samples (`ns` below the queue's capacity).
    pub(crate) fn with_queue(queue: Q, ns: usize) -> Result<Self, RegulatorError> {
        check_nominal(ns, queue.capacity())?;
        Ok(RegulatorIn {
            queue,
            nominal: ns,
            phase: Phase::Prefilling,
            counters: Counters::default(),
            occupancy: OccupancyAcc::default(),
            item: PhantomData,
        })
    }

    /// Queues a sample that has just arrived; a full queue hands it back.
    pub fn push(&mut self, sample: T) -> Result<(), Full<T>> {
        self.counters.arrived += 1;
        self.queue.push_back(sample).map_err(|s| {
            self.counters.rejected += 1;
            Full(s)
        })
    }

    /// One tick of the release clock: releases the oldest sample.
    pub fn tick(&mut self) -> Tick<T> {
        self.tick_if(|_| true)
    }

    /// One tick that releases the oldest sample only if `due` says it is due
    /// now, and otherwise counts an underflow and leaves it queued.
    ///
    /// Slot-based playout uses this: a sample whose slot is later than this
    /// tick must wait, and this tick's slot has nothing to give.
    pub(crate) fn tick_if(&mut self, due: impl FnOnce(&T) -> bool) -> Tick<T> {
        if self.phase == Phase::Prefilling {
            if self.queue.len() <= self.nominal {
                return Tick::Prefilling {
                    have: self.queue.len(),
                    need: self.nominal + 1,
                };
            }
            self.phase = Phase::Running;
        }
        self.counters.ticks += 1;
        self.occupancy.record(self.queue.len());
        match self.queue.front() {
            Some(head) if due(head) => match self.queue.pop_front() {
                Some(sample) => {
                    self.counters.released += 1;
                    Tick::Released(sample)
                }
                None => self.underflow(),
            },
            _ => self.underflow(),
        }
    }

    fn underflow(&mut self) -> Tick<T> {
        self.counters.underflows += 1;
        Tick::Underflow
    }

    /// Removes the oldest sample without releasing it (counted as discarded).
    pub fn discard_front(&mut self) -> Option<T> {
        let sample = self.queue.pop_front()?;
        self.counters.discarded += 1;
        Some(sample)
    }

    /// Empties the queue (counted as discarded) and returns how many were removed.
    pub fn clear(&mut self) -> usize {
        let n = self.queue.len();
        self.queue.clear();
        self.counters.discarded += n as u64;
        n
    }

    /// Changes the nominal size. Queued samples stay; the phase does not change.
    pub fn set_nominal(&mut self, ns: usize) -> Result<(), RegulatorError> {
        check_nominal(ns, self.queue.capacity())?;
        self.nominal = ns;
        Ok(())
    }

    /// Goes back to pre-filling (queued samples stay), as after the paper's pause:
    /// releases resume at a tick that finds more than `ns` queued.
    pub fn restart_prefill(&mut self) {
        self.phase = Phase::Prefilling;
    }

    /// Forgets the occupancy statistics (the counters stay).
    pub fn reset_occupancy(&mut self) {
        self.occupancy = OccupancyAcc::default();
    }

    /// Samples queued now.
    #[must_use]
    pub fn len(&self) -> usize {
        self.queue.len()
    }

    /// Whether no sample is queued.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.queue.is_empty()
    }

    /// The queue's capacity.
    #[must_use]
    pub(crate) fn capacity(&self) -> usize {
        self.queue.capacity()
    }

    /// The nominal size `ns`: the stock kept between releases.
    #[must_use]
    pub fn nominal(&self) -> usize {
        self.nominal
    }

    /// Pre-filling or running.
    #[must_use]
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// The oldest queued sample, the next to be released.
    #[must_use]
    pub fn front(&self) -> Option<&T> {
        self.queue.front()
    }

    /// The `index`-th oldest queued sample.
    #[must_use]
    pub(crate) fn get(&self, index: usize) -> Option<&T> {
        self.queue.get(index)
    }

    /// The queued samples, oldest first.
    pub fn iter(&self) -> impl Iterator<Item = &T> {
        self.queue.iter()
    }

    /// What went in and out so far.
    #[must_use]
    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Occupancy statistics over the running ticks, `None` before the first one.
    #[must_use]
    pub fn occupancy(&self) -> Option<Occupancy> {
        let acc = self.occupancy;
        (acc.ticks > 0).then(|| Occupancy {
            min: acc.min,
            max: acc.max,
            mean: acc.sum as f64 / acc.ticks as f64,
            ticks: acc.ticks,
        })
    }
}

fn check_nominal(ns: usize, capacity: usize) -> Result<(), RegulatorError> {
    if ns >= capacity {
        Err(RegulatorError::NominalSize { ns, capacity })
    } else {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nominal_size_is_checked() {
        assert!(Regulator::<u8, 4>::new(3).is_ok());
        assert!(Regulator::<u8, 4>::new(0).is_ok());
        assert_eq!(
            Regulator::<u8, 4>::new(4).unwrap_err(),
            RegulatorError::NominalSize { ns: 4, capacity: 4 }
        );
        let mut r = Regulator::<u8, 4>::new(2).unwrap();
        assert!(r.set_nominal(9).is_err());
        assert_eq!(r.nominal(), 2);
    }

    #[test]
    fn prefills_then_releases_one_per_tick() {
        let mut r = Regulator::<u32, 8>::new(2).unwrap();
        r.push(10).unwrap();
        r.push(11).unwrap();
        assert_eq!(r.tick(), Tick::Prefilling { have: 2, need: 3 });
        assert_eq!(r.phase(), Phase::Prefilling);
        r.push(12).unwrap();
        assert_eq!(r.tick(), Tick::Released(10));
        assert_eq!(r.len(), 2);
        assert_eq!(r.phase(), Phase::Running);
        r.push(13).unwrap();
        assert_eq!(r.tick(), Tick::Released(11));
        assert_eq!(r.tick(), Tick::Released(12));
        assert_eq!(r.tick(), Tick::Released(13));
        assert_eq!(r.tick(), Tick::Underflow);
        let occ = r.occupancy().unwrap();
        // Before each release: 3, 3, 2, 1, 0.
        assert_eq!((occ.min, occ.max, occ.ticks), (0, 3, 5));
        assert!((occ.mean - 9.0 / 5.0).abs() < 1e-12);
        let c = r.counters();
        assert_eq!((c.arrived, c.released, c.underflows, c.ticks), (4, 4, 1, 5));
    }

    #[test]
    fn full_queue_hands_the_sample_back_and_counts_it() {
        let mut r = Regulator::<u32, 2>::new(1).unwrap();
        r.push(1).unwrap();
        r.push(2).unwrap();
        assert_eq!(r.push(3), Err(Full(3)));
        assert_eq!(r.counters().rejected, 1);
        assert_eq!(r.len(), 2);
    }

    #[test]
    fn tick_if_keeps_a_sample_that_is_not_due() {
        let mut r = Regulator::<u64, 8>::new(0).unwrap();
        r.push(5).unwrap();
        assert_eq!(r.tick_if(|&seq| seq <= 4), Tick::Underflow);
        assert_eq!(r.len(), 1);
        assert_eq!(r.tick_if(|&seq| seq <= 5), Tick::Released(5));
    }

    #[test]
    fn restart_prefill_waits_for_the_new_stock() {
        let mut r = Regulator::<u32, 8>::new(0).unwrap();
        r.push(1).unwrap();
        assert_eq!(r.tick(), Tick::Released(1));
        r.set_nominal(1).unwrap();
        r.restart_prefill();
        r.push(2).unwrap();
        assert_eq!(r.tick(), Tick::Prefilling { have: 1, need: 2 });
        r.push(3).unwrap();
        assert_eq!(r.tick(), Tick::Released(2));
    }

    #[test]
    fn discarding_is_counted() {
        let mut r = Regulator::<u32, 8>::new(1).unwrap();
        for s in 0..5 {
            r.push(s).unwrap();
        }
        assert_eq!(r.discard_front(), Some(0));
        assert_eq!(r.clear(), 4);
        let c = r.counters();
        assert_eq!(c.discarded, 5);
        assert_eq!(
            c.arrived,
            c.released + r.len() as u64 + c.rejected + c.discarded
        );
        assert_eq!(r.discard_front(), None);
        assert_eq!(r.counters().discarded, 5);
    }
}
