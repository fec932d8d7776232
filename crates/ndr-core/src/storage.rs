//! Where a regulator and an endpoint keep what they queue.
//!
//! The core never allocates on its own: its owner chooses the storage.
//! [`Inline`] holds everything in arrays whose sizes are type parameters
//! (no heap, for `no_std` targets); [`Heap`] (feature `alloc`) sizes each
//! buffer once, when the endpoint is made, from the link's width and queue
//! capacity, so one endpoint type serves every link.
//!
//! ```
//! use ndr_core::endpoint::{Config, Endpoint};
//! use ndr_core::storage::{Heap, Inline};
//! use ndr_core::time::Instant;
//! use ndr_core::wire::Role;
//!
//! let config = Config::new(Role::Remote).with_width(2);
//! // Two channels and 16 queued samples, inline.
//! let small: Endpoint<Inline<2, 16>> = Endpoint::new(config, Instant::ZERO).unwrap();
//! // The link's own width, and room for 40 samples, on the heap.
//! let sized: Endpoint<Heap> = Endpoint::with_capacity(config, Instant::ZERO, 40).unwrap();
//! assert_eq!((small.capacity(), sized.capacity()), (16, 40));
//! ```

use core::fmt;
use core::marker::PhantomData;

use heapless::Deque;

use crate::playout::{Builtin, Room};
use crate::time::Instant;

/// The largest regulator a [`Heap`] storage holds: a nominal size is at
/// most `u16::MAX` on the wire.
pub const MAX_CAPACITY: usize = 1 << 16;

/// A first-in, first-out queue with a fixed capacity.
pub trait Queue<T> {
    /// Appends `item`; a full queue hands it back.
    fn push_back(&mut self, item: T) -> Result<(), T>;
    /// Removes the oldest item.
    fn pop_front(&mut self) -> Option<T>;
    /// The oldest item.
    fn front(&self) -> Option<&T>;
    /// The `index`-th oldest item.
    fn get(&self, index: usize) -> Option<&T>;
    /// Items queued now.
    fn len(&self) -> usize;
    /// Whether no item is queued.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// How many items fit.
    fn capacity(&self) -> usize;
    /// Removes every item.
    fn clear(&mut self);
    /// The items, oldest first.
    fn iter<'a>(&'a self) -> impl Iterator<Item = &'a T>
    where
        T: 'a;
}

impl<T, const N: usize> Queue<T> for Deque<T, N> {
    fn push_back(&mut self, item: T) -> Result<(), T> {
        Deque::push_back(self, item)
    }

    fn pop_front(&mut self) -> Option<T> {
        Deque::pop_front(self)
    }

    fn front(&self) -> Option<&T> {
        Deque::front(self)
    }

    fn get(&self, index: usize) -> Option<&T> {
        Deque::get(self, index)
    }

    fn len(&self) -> usize {
        Deque::len(self)
    }

    fn capacity(&self) -> usize {
        N
    }

    fn clear(&mut self) {
        Deque::clear(self);
    }

    fn iter<'a>(&'a self) -> impl Iterator<Item = &'a T>
    where
        T: 'a,
    {
        Deque::iter(self)
    }
}

/// How an [`Endpoint`](crate::endpoint::Endpoint) keeps its buffers: a
/// sample's values, its regulator's queue, the send times of its recent
/// ticks and its playout policy.
pub trait Storage {
    /// One sample's values.
    type Values: AsRef<[f64]> + AsMut<[f64]> + Clone + fmt::Debug + PartialEq;
    /// A queue of at most the capacity the endpoint was made with.
    type Queue<T: Clone + fmt::Debug>: Queue<T> + Clone + fmt::Debug;
    /// One entry per queued sample the endpoint can hold.
    type Ticks: AsRef<[(u64, Instant)]> + AsMut<[(u64, Instant)]> + Clone + fmt::Debug;
    /// Where the playout policy is kept.
    type Policy: Room;
    /// The capacity [`Endpoint::new`](crate::endpoint::Endpoint::new) asks for.
    const DEFAULT_CAPACITY: usize;

    /// Zeroed values for samples of `width` channels; `None` if they do not fit.
    fn values(width: usize) -> Option<Self::Values>;
    /// An empty queue for `capacity` items; `None` if it does not fit.
    fn queue<T: Clone + fmt::Debug>(capacity: usize) -> Option<Self::Queue<T>>;
    /// `len` entries of `fill`; `None` if they do not fit.
    fn ticks(len: usize, fill: (u64, Instant)) -> Option<Self::Ticks>;
}

/// Storage in arrays: samples of up to `C` channels, `N` of them queued,
/// and the playout policy in `P`: [`Builtin`], every built-in policy
/// inline (the adaptive playout's histogram is about 7 KiB: an endpoint
/// that never runs it can drop it with
/// `Builtin<`[`NoAdaptive`](crate::playout::NoAdaptive)`>`). An endpoint of
/// this storage holds about `N·(8·C + 64)` bytes inline: box it when `N`
/// is large.
#[derive(Clone, Debug)]
pub struct Inline<const C: usize, const N: usize, P = Builtin>(PhantomData<P>);

impl<const C: usize, const N: usize, P: Room> Storage for Inline<C, N, P> {
    type Values = [f64; C];
    type Queue<T: Clone + fmt::Debug> = Deque<T, N>;
    type Ticks = [(u64, Instant); N];
    type Policy = P;
    const DEFAULT_CAPACITY: usize = N;

    fn values(width: usize) -> Option<[f64; C]> {
        (width <= C).then_some([0.0; C])
    }

    fn queue<T: Clone + fmt::Debug>(capacity: usize) -> Option<Deque<T, N>> {
        (capacity == N).then(Deque::new)
    }

    fn ticks(len: usize, fill: (u64, Instant)) -> Option<[(u64, Instant); N]> {
        (len == N).then_some([fill; N])
    }
}

#[cfg(feature = "alloc")]
pub use heap::{Heap, HeapQueue};

#[cfg(feature = "alloc")]
mod heap {
    use alloc::boxed::Box;
    use alloc::collections::VecDeque;
    use alloc::vec;
    use core::fmt;

    use super::{MAX_CAPACITY, Queue, Storage};
    use crate::playout::HeapRoom;
    use crate::time::Instant;

    /// Storage on the heap, each buffer sized once when the endpoint is
    /// made: values as wide as the link, a queue as long as asked, and the
    /// playout policy ([`HeapRoom`]: a built-in one, the adaptive
    /// playout's state only when the link runs it, or the application's
    /// own, boxed). A received sample's values are one allocation, handed
    /// on in its release.
    #[derive(Clone, Copy, Debug)]
    pub struct Heap;

    impl Storage for Heap {
        type Values = Box<[f64]>;
        type Queue<T: Clone + fmt::Debug> = HeapQueue<T>;
        type Ticks = Box<[(u64, Instant)]>;
        type Policy = HeapRoom;
        const DEFAULT_CAPACITY: usize = 256;

        fn values(width: usize) -> Option<Box<[f64]>> {
            Some(vec![0.0; width].into_boxed_slice())
        }

        fn queue<T: Clone + fmt::Debug>(capacity: usize) -> Option<HeapQueue<T>> {
            fits(capacity).then(|| HeapQueue::with_capacity(capacity))
        }

        fn ticks(len: usize, fill: (u64, Instant)) -> Option<Box<[(u64, Instant)]>> {
            fits(len).then(|| vec![fill; len].into_boxed_slice())
        }
    }

    fn fits(capacity: usize) -> bool {
        (1..=MAX_CAPACITY).contains(&capacity)
    }

    /// A queue on the heap whose capacity is fixed when it is made: its
    /// memory is taken then, and a push beyond it is refused.
    #[derive(Clone, Debug)]
    pub struct HeapQueue<T> {
        items: VecDeque<T>,
        capacity: usize,
    }

    impl<T> HeapQueue<T> {
        /// An empty queue with room for `capacity` items.
        #[must_use]
        pub(crate) fn with_capacity(capacity: usize) -> Self {
            HeapQueue {
                items: VecDeque::with_capacity(capacity),
                capacity,
            }
        }
    }

    impl<T> Queue<T> for HeapQueue<T> {
        fn push_back(&mut self, item: T) -> Result<(), T> {
            if self.items.len() >= self.capacity {
                return Err(item);
            }
            self.items.push_back(item);
            Ok(())
        }

        fn pop_front(&mut self) -> Option<T> {
            self.items.pop_front()
        }

        fn front(&self) -> Option<&T> {
            self.items.front()
        }

        fn get(&self, index: usize) -> Option<&T> {
            self.items.get(index)
        }

        fn len(&self) -> usize {
            self.items.len()
        }

        fn capacity(&self) -> usize {
            self.capacity
        }

        fn clear(&mut self) {
            self.items.clear();
        }

        fn iter<'a>(&'a self) -> impl Iterator<Item = &'a T>
        where
            T: 'a,
        {
            self.items.iter()
        }
    }
}
