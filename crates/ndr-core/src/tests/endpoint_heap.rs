//! The endpoint's cases on heap storage (buffers sized when the endpoint is
//! made), and what only heap storage does: links wider than any inline
//! width, capacities chosen at run time, and the same releases as inline.

#[allow(unused_imports)]
use std::{borrow::ToOwned, boxed::Box, string::String, string::ToString, vec::Vec};
#[allow(unused_imports)]
use std::{eprintln, format, println, vec};

use crate::endpoint::{Config, ConfigError, Endpoint, Event, LinkError, Status};
use crate::pair::{Pair, World};
use crate::playout::Playout;
use crate::storage::{Heap, Inline, MAX_CAPACITY, Storage};
use crate::time::{Duration, Instant};
use crate::wire::{MAX_CHANNELS, Role};

type Store = Heap;

// Each storage runs its own copy of the cases, `super::Store` apart.
#[allow(clippy::duplicate_mod)]
#[path = "common/endpoint_cases.rs"]
mod cases;

/// One release as the application sees it.
type Seen = (u64, Instant, Status, Option<Duration>, Vec<f64>);

/// A base and a remote of storage `S` (capacity `capacity`) over a wire
/// whose delay follows `delay(n)` for the n-th frame each way, in order,
/// for `secs` seconds. The base sends `axes` values that encode its tick;
/// the remote answers each command it releases with it, reversed. Returns
/// what each side released.
fn run<S: Storage>(
    config: impl Fn(Role) -> Config,
    capacity: usize,
    delay: impl Fn(u64) -> Duration,
    secs: u64,
) -> [Vec<Seen>; 2] {
    run_with::<S>(&config, [capacity; 2], delay, secs).0
}

/// [`run`], with each side's capacity, and the endpoints at the end.
fn run_with<S: Storage>(
    config: &impl Fn(Role) -> Config,
    capacity: [usize; 2],
    delay: impl Fn(u64) -> Duration,
    secs: u64,
) -> ([Vec<Seen>; 2], [Endpoint<S>; 2]) {
    let ep = |role, cap| Endpoint::<S>::with_capacity(config(role), Instant::ZERO, cap).unwrap();
    let world = Echo {
        widths: {
            let c = config(Role::Base);
            [c.command_width, c.state_width].map(usize::from)
        },
        delay,
        sent: 0,
        last: [Instant::ZERO; 2],
        k: 0,
        seen: [Vec::new(), Vec::new()],
    };
    let mut pair = Pair::new(
        ep(Role::Base, capacity[0]),
        ep(Role::Remote, capacity[1]),
        world,
    );
    pair.run_until(Instant::from_millis(secs * 1000)).unwrap();
    let (base, remote, world) = pair.into_parts();
    (world.seen, [base, remote])
}

/// An in-order wire whose n-th frame (both ways) takes `delay(n)`; a base
/// that sends its command width of values encoding its tick, a remote that
/// answers each command with it reversed (repeated to its state width);
/// what each side released.
struct Echo<D> {
    /// What each side sends: commands, states.
    widths: [usize; 2],
    delay: D,
    sent: u64,
    last: [Instant; 2],
    k: u32,
    seen: [Vec<Seen>; 2],
}

impl<S: Storage, D: Fn(u64) -> Duration> World<S> for Echo<D> {
    type Error = LinkError;

    fn arrival(&mut self, from: Role, sent: Instant, _: &[u8]) -> Option<Instant> {
        self.sent += 1;
        let at = (sent + (self.delay)(self.sent)).max(self.last[from as usize]);
        self.last[from as usize] = at;
        Some(at)
    }

    fn event(
        &mut self,
        side: Role,
        ep: &mut Endpoint<S>,
        _: Instant,
        event: Event<S::Values>,
    ) -> Result<(), LinkError> {
        if let Event::Released(r) = event {
            let values = r.values().to_vec();
            let answer: Vec<f64> = if side == Role::Base {
                self.k += 1;
                (0..self.widths[0])
                    .map(|i| f64::from(self.k) + i as f64 / 100.0)
                    .collect()
            } else {
                let reversed = values.iter().rev().copied();
                reversed.cycle().take(self.widths[1]).collect()
            };
            self.seen[side as usize].push((r.seq, r.released_at, r.status, r.grtt, values));
            ep.set_sample(&answer)?;
        }
        Ok(())
    }

    fn failed(&mut self, _: Role, _: Instant, error: LinkError) -> Result<(), LinkError> {
        Err(error)
    }
}

fn config(width: u16, playout: Playout) -> impl Fn(Role) -> Config {
    widths(width, width, playout)
}

fn widths(command: u16, state: u16, playout: Playout) -> impl Fn(Role) -> Config {
    move |role| {
        let mut c = Config::new(role).with_widths(command, state);
        c.period = Duration::from_millis(10);
        c.playout = playout;
        c
    }
}

/// A jittery wire: 20 ms, up to 37 ms more, a spike every 50 frames.
fn jitter(n: u64) -> Duration {
    let spike = if n.is_multiple_of(50) { 60 } else { 0 };
    Duration::from_micros(20_000 + (n * 7919 % 37) * 1000 + spike * 1000)
}

#[test]
fn heap_and_inline_storage_release_the_same_samples_at_the_same_times() {
    for playout in [Playout::Fifo, Playout::ADAPTIVE, Playout::NetEq] {
        let inline = run::<Inline<3, 64>>(config(3, playout), 64, jitter, 20);
        let heap = run::<Heap>(config(3, playout), 64, jitter, 20);
        assert!(
            inline[0].len() > 1500 && inline[1].len() > 1500,
            "{playout}"
        );
        assert_eq!(inline, heap, "{playout}");
    }
}

#[test]
fn a_heap_endpoint_carries_as_many_channels_as_a_frame_holds() {
    let axes = u16::try_from(MAX_CHANNELS).unwrap();
    let [base, remote] = run::<Heap>(config(axes, Playout::ADAPTIVE), 64, jitter, 5);
    let fresh = |s: &Vec<Seen>| s.iter().filter(|r| r.2 == Status::Fresh).count();
    assert!(fresh(&base) > 300 && fresh(&remote) > 300);
    let nonzero = |s: &Vec<Seen>| s.iter().filter(|r| r.4.iter().any(|&x| x != 0.0)).count();
    assert!(nonzero(&base) > 300 && nonzero(&remote) > 300);
    // The remote released every command whole; the base got each back reversed.
    for (_, _, _, _, v) in remote.iter().filter(|r| r.4.iter().any(|&x| x != 0.0)) {
        assert_eq!(v.len(), MAX_CHANNELS);
        assert!(
            v.windows(2).all(|w| (w[1] - w[0] - 0.01).abs() < 1e-9),
            "{v:?}"
        );
    }
    for (_, _, _, _, v) in base.iter().filter(|r| r.4.iter().any(|&x| x != 0.0)) {
        assert!(
            v.windows(2).all(|w| (w[0] - w[1] - 0.01).abs() < 1e-9),
            "{v:?}"
        );
    }
}

#[test]
fn each_direction_carries_its_own_width() {
    // A 7-joint arm whose state is positions, velocities and torques; and
    // 64 values each way.
    for (command, state) in [(7, 21), (64, 64), (21, 7)] {
        let c = widths(command, state, Playout::ADAPTIVE);
        let heap = run::<Heap>(&c, 64, jitter, 5);
        let inline = run::<Inline<64, 64>>(&c, 64, jitter, 5);
        assert_eq!(heap, inline, "{command} {state}");
        let [base, remote] = heap;
        let fresh = |s: &[Seen]| {
            s.iter()
                .filter(|r| r.2 == Status::Fresh && r.4.iter().any(|&x| x != 0.0))
                .count()
        };
        assert!(
            fresh(&base) > 300 && fresh(&remote) > 300,
            "{command} {state}"
        );
        assert!(remote.iter().all(|r| r.4.len() == usize::from(command)));
        assert!(base.iter().all(|r| r.4.len() == usize::from(state)));
    }
    // A sample of the other direction's width is refused.
    let c = widths(7, 21, Playout::Fifo);
    let mut base = Endpoint::<Heap>::new(c(Role::Base), Instant::ZERO).unwrap();
    assert_eq!(
        base.set_sample(&[0.0; 21]),
        Err(LinkError::SampleShape {
            expected: 7,
            got: 21
        })
    );
    assert!(base.set_sample(&[0.0; 7]).is_ok());
}

#[test]
fn an_inline_endpoint_refuses_more_channels_than_it_holds() {
    let c = config(9, Playout::Fifo)(Role::Base);
    let err = Endpoint::<Inline<8, 16>>::new(c, Instant::ZERO).unwrap_err();
    assert_eq!(
        err,
        ConfigError::Channels {
            width: 9,
            capacity: 8
        }
    );
    assert!(err.to_string().contains("or a Heap one"), "{err}");
    assert!(Endpoint::<Heap>::new(c, Instant::ZERO).is_ok());
}

#[test]
fn a_capacity_that_does_not_fit_is_refused_with_what_fits() {
    let c = config(2, Playout::Fifo)(Role::Remote);
    for asked in [0, MAX_CAPACITY + 1, usize::MAX] {
        let err = Endpoint::<Heap>::with_capacity(c, Instant::ZERO, asked).unwrap_err();
        assert_eq!(err, ConfigError::Capacity { asked });
        assert!(err.to_string().contains("a Heap one 1 to 65536"), "{err}");
    }
    let err = Endpoint::<Inline<2, 16>>::with_capacity(c, Instant::ZERO, 32).unwrap_err();
    assert_eq!(err, ConfigError::Capacity { asked: 32 });
    let ep = Endpoint::<Heap>::with_capacity(c, Instant::ZERO, 3).unwrap();
    assert_eq!(ep.capacity(), 3);
    assert_eq!(
        Endpoint::<Heap>::new(c, Instant::ZERO).unwrap().capacity(),
        256
    );
}

#[test]
fn a_heap_regulator_smaller_than_the_delay_needs_is_clamped_and_counted() {
    // ns = 2 + ⌊η·mt/T⌋ comes out far above 3 on a wire whose delay
    // varies by tens of periods.
    let fifo = config(1, Playout::Fifo);
    let (seen, eps) = run_with::<Heap>(&fifo, [4, 256], jitter, 10);
    assert_eq!(eps[0].ns(), 3);
    assert_eq!(eps[0].stats().clamped, 1);
    assert!(seen[1].len() > 500, "the link runs on: {}", seen[1].len());
}
