//! What the hub hands to a link's application, and the bounded queue it
//! goes through.
//!
//! std's `sync_channel(n)` allocates and writes its `n` slots up front (136
//! KiB a link at the default 1 024), and its unbounded channel allocates in
//! blocks of 31 slots (4 KiB a link even when one delivery waits). This
//! queue is a `VecDeque` behind a mutex, so its memory follows what waits,
//! with a counter that bounds it. The hub wakes a blocked reader only when
//! there is one: a condition variable's notify is a syscall even when
//! nobody waits, and the hub delivers to every link at every tick.
//!
//! Releases come at deadlines the hub knows. A reader blocked when its
//! hub wakes for one (a spin margin early) is woken then
//! ([`Outbox::wake_ahead`]) and spins on a counter until the release is
//! queued, so the release reaches it without a kernel wake-up at that
//! instant; the spin ends a bounded while past the deadline, and the
//! reader then blocks again as before.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{RecvError, RecvTimeoutError, TryRecvError};
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use ndr_core::endpoint::{Event, Release};

/// A released sample, as the application receives it: its values are as
/// many as the link's axes.
pub type Sample = Release<Box<[f64]>>;

/// What a link's endpoint tells its application.
pub type LinkEvent = Event<Box<[f64]>>;

/// What the hub hands to a link's application.
pub(crate) enum Delivery {
    Sample(Sample),
    Event(LinkEvent),
}

struct State {
    waiting: VecDeque<Delivery>,
    /// The hub's end is gone: nothing more will come.
    sender_gone: bool,
    /// The application's end is gone: nothing will be read.
    receiver_gone: bool,
    /// Readers blocked on the condition variable.
    blocked: usize,
    /// Set by [`Outbox::wake_ahead`]: the reader it woke spins until a
    /// delivery or this instant, whichever comes first.
    spin_until: Option<Instant>,
}

struct Queue {
    state: Mutex<State>,
    ready: Condvar,
    capacity: usize,
    /// Bumped after each delivery queued and when the hub's end goes: a
    /// spinning reader watches it without taking the lock the hub needs.
    changes: AtomicU64,
    /// A reader spins now: a delivery reaches it without a syscall.
    spinning: AtomicBool,
}

impl Queue {
    fn lock(&self) -> MutexGuard<'_, State> {
        // Neither end panics while holding the lock; a poisoned state is whole.
        self.state.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// A queue that holds at most `capacity` deliveries (at least one).
pub(crate) fn queue(capacity: usize) -> (Outbox, Inbox) {
    let q = Arc::new(Queue {
        state: Mutex::new(State {
            waiting: VecDeque::new(),
            sender_gone: false,
            receiver_gone: false,
            blocked: 0,
            spin_until: None,
        }),
        ready: Condvar::new(),
        capacity: capacity.max(1),
        changes: AtomicU64::new(0),
        spinning: AtomicBool::new(false),
    });
    (Outbox { q: Arc::clone(&q) }, Inbox { q })
}

/// Why a delivery was not queued (it is dropped).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Refused {
    /// The application has not read the `capacity` waiting.
    Full,
    /// The application's end is gone.
    Gone,
}

/// The hub's end.
pub(crate) struct Outbox {
    q: Arc<Queue>,
}

impl Outbox {
    /// Queues `d`, or drops it and says why.
    pub(crate) fn try_send(&self, d: Delivery) -> Result<(), Refused> {
        let mut s = self.q.lock();
        if s.receiver_gone {
            return Err(Refused::Gone);
        }
        if s.waiting.len() >= self.q.capacity {
            return Err(Refused::Full);
        }
        s.waiting.push_back(d);
        let wake = s.blocked > 0;
        drop(s);
        self.q.changes.fetch_add(1, Ordering::Release);
        if wake {
            self.q.ready.notify_one();
        }
        Ok(())
    }

    /// Whether the reader spins now, so that queueing a delivery costs no
    /// wake-up.
    pub(crate) fn reader_spinning(&self) -> bool {
        self.q.spinning.load(Ordering::Acquire)
    }

    /// A delivery is due at `deadline`: wakes a reader blocked now, which
    /// then spins until something is queued or `spin` past the deadline.
    /// `true` if a reader was woken (a syscall).
    pub(crate) fn wake_ahead(&self, deadline: Instant, spin: Duration) -> bool {
        let mut s = self.q.lock();
        if s.blocked == 0 || s.spin_until.is_some() {
            return false;
        }
        s.spin_until = Some(deadline + spin);
        drop(s);
        self.q.ready.notify_one();
        true
    }
}

impl Drop for Outbox {
    fn drop(&mut self) {
        let mut s = self.q.lock();
        s.sender_gone = true;
        let wake = s.blocked > 0;
        drop(s);
        self.q.changes.fetch_add(1, Ordering::Release);
        if wake {
            self.q.ready.notify_all();
        }
    }
}

/// The application's end.
pub(crate) struct Inbox {
    q: Arc<Queue>,
}

impl Inbox {
    pub(crate) fn recv(&self) -> Result<Delivery, RecvError> {
        self.wait(None).map_err(|_| RecvError)
    }

    pub(crate) fn try_recv(&self) -> Result<Delivery, TryRecvError> {
        let mut s = self.q.lock();
        match s.waiting.pop_front() {
            Some(d) => Ok(d),
            None if s.sender_gone => Err(TryRecvError::Disconnected),
            None => Err(TryRecvError::Empty),
        }
    }

    pub(crate) fn recv_timeout(
        &self,
        timeout: std::time::Duration,
    ) -> Result<Delivery, RecvTimeoutError> {
        // A timeout too long for the clock waits as long as it takes.
        self.wait(Instant::now().checked_add(timeout))
    }

    /// The next delivery, waiting until `end` (`None`: as long as it takes).
    fn wait(&self, end: Option<Instant>) -> Result<Delivery, RecvTimeoutError> {
        let mut s = self.q.lock();
        loop {
            if let Some(d) = s.waiting.pop_front() {
                return Ok(d);
            }
            if s.sender_gone {
                return Err(RecvTimeoutError::Disconnected);
            }
            let left = end.map(|end| end.saturating_duration_since(Instant::now()));
            if left.is_some_and(|l| l.is_zero()) {
                return Err(RecvTimeoutError::Timeout);
            }
            s.blocked += 1;
            s = match left {
                None => self.q.ready.wait(s).unwrap_or_else(PoisonError::into_inner),
                Some(left) => {
                    self.q
                        .ready
                        .wait_timeout(s, left)
                        .unwrap_or_else(PoisonError::into_inner)
                        .0
                }
            };
            s.blocked -= 1;
            if let Some(until) = s.spin_until.take()
                && s.waiting.is_empty()
            {
                let until = end.map_or(until, |end| end.min(until));
                let seen = self.q.changes.load(Ordering::Acquire);
                drop(s);
                self.q.spinning.store(true, Ordering::Release);
                spin(&self.q.changes, seen, until);
                self.q.spinning.store(false, Ordering::Release);
                s = self.q.lock();
            }
        }
    }
}

/// Spins until `changes` moves past `seen` or `until` has passed.
fn spin(changes: &AtomicU64, seen: u64, until: Instant) {
    let mut n = 0u32;
    while changes.load(Ordering::Acquire) == seen {
        n = n.wrapping_add(1);
        // A clock read costs tens of nanoseconds: one every few dozen turns.
        if n.is_multiple_of(32) && Instant::now() >= until {
            return;
        }
        std::hint::spin_loop();
    }
}

impl Drop for Inbox {
    fn drop(&mut self) {
        let mut s = self.q.lock();
        s.receiver_gone = true;
        // What waits is dropped with the application's end, not kept by the hub.
        s.waiting = VecDeque::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndr_core::endpoint::{Event, LinkError};

    fn event() -> Delivery {
        Delivery::Event(Event::Closed {
            error: Some(LinkError::Closed),
        })
    }

    #[test]
    fn the_queue_holds_its_capacity_then_refuses_until_the_application_reads() {
        let (out, inbox) = queue(2);
        assert!(out.try_send(event()).is_ok());
        assert!(out.try_send(event()).is_ok());
        assert!(out.try_send(event()) == Err(Refused::Full));
        assert!(inbox.try_recv().is_ok());
        assert!(out.try_send(event()).is_ok());
        assert!(inbox.recv().is_ok());
        assert!(inbox.recv_timeout(std::time::Duration::ZERO).is_ok());
        assert!(matches!(inbox.try_recv(), Err(TryRecvError::Empty)));
        drop(inbox);
        assert_eq!(out.try_send(event()), Err(Refused::Gone));
    }

    #[test]
    fn a_zero_capacity_holds_one() {
        let (out, inbox) = queue(0);
        assert!(out.try_send(event()).is_ok());
        assert!(out.try_send(event()) == Err(Refused::Full));
        drop(out);
        assert!(inbox.recv().is_ok());
        assert!(matches!(inbox.recv(), Err(RecvError)));
    }

    #[test]
    fn a_blocked_reader_wakes_for_a_delivery_and_for_the_hub_going_away() {
        let (out, inbox) = queue(4);
        let reader = std::thread::spawn(move || {
            let first = inbox.recv().is_ok();
            let second = inbox.recv_timeout(std::time::Duration::from_secs(60));
            (first, matches!(second, Err(RecvTimeoutError::Disconnected)))
        });
        // Give the reader time to block (the test holds either way).
        std::thread::sleep(std::time::Duration::from_millis(20));
        assert!(out.try_send(event()).is_ok());
        std::thread::sleep(std::time::Duration::from_millis(20));
        drop(out);
        assert_eq!(reader.join().unwrap(), (true, true));
    }

    /// Waits (at most 10 s) until the queue's state is as `wanted` says.
    fn until(q: &Arc<Queue>, wanted: impl Fn(&State) -> bool) {
        let end = Instant::now() + Duration::from_secs(10);
        while !wanted(&q.lock()) {
            assert!(Instant::now() < end, "the reader never got there");
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// Waits until the reader is blocked on the condition variable (`true`)
    /// or not (`false`).
    fn until_blocked(q: &Arc<Queue>, blocked: bool) {
        until(q, |s| (s.blocked > 0) == blocked);
    }

    #[test]
    fn a_reader_woken_ahead_takes_the_delivery_without_a_wake_up() {
        let (out, inbox) = queue(4);
        let q = Arc::clone(&out.q);
        let reader = std::thread::spawn(move || inbox.recv_timeout(Duration::from_secs(60)));
        until_blocked(&q, true);
        // Nobody is woken for nothing: only a reader blocked now.
        let (empty_out, _empty_inbox) = queue(4);
        assert!(!empty_out.wake_ahead(Instant::now(), Duration::from_secs(1)));
        assert!(out.wake_ahead(Instant::now() + Duration::from_secs(30), Duration::ZERO));
        // Woken, it spins instead of blocking again: the delivery finds
        // no reader to notify, and reaches it anyway.
        until_blocked(&q, false);
        until(&q, |_| out.reader_spinning());
        assert!(out.try_send(event()).is_ok());
        assert!(reader.join().unwrap().is_ok());
        assert!(!out.reader_spinning());
    }

    #[test]
    fn a_reader_woken_ahead_for_nothing_blocks_again_after_its_spin() {
        let (out, inbox) = queue(4);
        let q = Arc::clone(&out.q);
        let reader = std::thread::spawn(move || inbox.recv_timeout(Duration::from_secs(60)));
        until_blocked(&q, true);
        assert!(out.wake_ahead(Instant::now(), Duration::from_millis(1)));
        // The spin is bounded: the reader took its wake-up and blocks
        // again (and a delivery then wakes it as before).
        until(&q, |s| s.spin_until.is_none() && s.blocked > 0);
        assert!(out.try_send(event()).is_ok());
        assert!(reader.join().unwrap().is_ok());
    }

    #[test]
    fn a_wait_with_nothing_coming_times_out() {
        let (_out, inbox) = queue(4);
        let start = std::time::Instant::now();
        let r = inbox.recv_timeout(std::time::Duration::from_millis(10));
        assert!(matches!(r, Err(RecvTimeoutError::Timeout)));
        assert!(start.elapsed() >= std::time::Duration::from_millis(10));
    }

    #[test]
    fn the_queue_holds_memory_for_what_waits_not_for_its_bound() {
        let (out, inbox) = queue(1024);
        assert_eq!(out.q.lock().waiting.capacity(), 0);
        for _ in 0..10_000 {
            assert!(out.try_send(event()).is_ok());
            assert!(inbox.try_recv().is_ok());
        }
        assert!(out.q.lock().waiting.capacity() <= 4);
        drop(inbox);
        assert_eq!(out.q.lock().waiting.capacity(), 0);
    }
}
