//! What the hub hands to a link's application, and the bounded queue it
//! goes through.
//!
//! std's `sync_channel(n)` allocates and writes its `n` slots up front: with
//! the default 1 024 that is 136 KiB of every link's memory before anything
//! waits. This queue is std's unbounded channel (its memory follows what
//! waits, in blocks of 31) with a counter that bounds it.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{self, RecvError, RecvTimeoutError, TryRecvError};

use ndr_core::endpoint::Event;

use crate::link::{MAX_AXES, Sample};

/// What the hub hands to a link's application.
pub(crate) enum Delivery {
    Sample(Sample),
    Event(Event<MAX_AXES>),
}

/// A queue that holds at most `capacity` deliveries (at least one).
pub(crate) fn queue(capacity: usize) -> (Outbox, Inbox) {
    let (tx, rx) = mpsc::channel();
    let waiting = Arc::new(AtomicUsize::new(0));
    (
        Outbox {
            tx,
            waiting: Arc::clone(&waiting),
            capacity: capacity.max(1),
        },
        Inbox { rx, waiting },
    )
}

/// Why a delivery was not queued (it is dropped).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Refused {
    /// The application has not read the `capacity` waiting.
    Full,
    /// The application's end is gone.
    Gone,
}

/// The hub's end (one sender: the count cannot overshoot).
pub(crate) struct Outbox {
    tx: mpsc::Sender<Delivery>,
    waiting: Arc<AtomicUsize>,
    capacity: usize,
}

impl Outbox {
    /// Queues `d`, or drops it and says why.
    pub(crate) fn try_send(&self, d: Delivery) -> Result<(), Refused> {
        if self.waiting.load(Ordering::Acquire) >= self.capacity {
            return Err(Refused::Full);
        }
        self.waiting.fetch_add(1, Ordering::AcqRel);
        self.tx.send(d).map_err(|_| {
            self.waiting.fetch_sub(1, Ordering::AcqRel);
            Refused::Gone
        })
    }
}

/// The application's end.
pub(crate) struct Inbox {
    rx: mpsc::Receiver<Delivery>,
    waiting: Arc<AtomicUsize>,
}

impl Inbox {
    fn took<E>(&self, r: Result<Delivery, E>) -> Result<Delivery, E> {
        if r.is_ok() {
            self.waiting.fetch_sub(1, Ordering::AcqRel);
        }
        r
    }

    pub(crate) fn recv(&self) -> Result<Delivery, RecvError> {
        self.took(self.rx.recv())
    }

    pub(crate) fn try_recv(&self) -> Result<Delivery, TryRecvError> {
        self.took(self.rx.try_recv())
    }

    pub(crate) fn recv_timeout(
        &self,
        timeout: std::time::Duration,
    ) -> Result<Delivery, RecvTimeoutError> {
        self.took(self.rx.recv_timeout(timeout))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ndr_core::endpoint::LinkError;

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
}
