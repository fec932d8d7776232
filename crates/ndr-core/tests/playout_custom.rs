//! A playout policy written outside the crate plugs into `Endpoint<Heap>`
//! through the configuration alone, and the endpoint does only what the
//! policy answers: a policy built from the public interface runs exactly as
//! its built-in twin.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use ndr_core::Regulation;
use ndr_core::endpoint::{Config, ConfigError, Endpoint, Event, LinkError, Underflow};
use ndr_core::pair::{Pair, World};
use ndr_core::playout::{
    Admit, Announcement, Arrival, Builtin, Custom, Due, Factory, NoAdaptive, NoRoom, Observed,
    OnTicks, Outcome, Playout, Policy, Room, Setup, Stamps, TargetDelay, View,
};
use ndr_core::storage::{Heap, Inline};
use ndr_core::time::{Duration, Instant};
use ndr_core::wire::Role;

const T: Duration = Duration::from_millis(20);

/// What one side saw: each event, and its stats at the end.
type Seen = (Vec<String>, String);

/// A base and a remote with `playout`, 60 s over an in-order wire whose
/// delay wanders between 10 and 60 ms, with a stall of 0.5 s at 30 s.
fn run(playout: Playout, underflow: Underflow) -> [Seen; 2] {
    let config = |role| {
        let mut c = Config::new(role);
        c.period = T;
        c.playout = playout;
        c.underflow = underflow;
        c
    };
    let ep = |role| Endpoint::<Heap>::new(config(role), Instant::ZERO).unwrap();
    let world = Wire {
        n: 0,
        last: [Instant::ZERO; 2],
        seen: [Vec::new(), Vec::new()],
    };
    let mut pair = Pair::new(ep(Role::Base), ep(Role::Remote), world);
    pair.run_until(Instant::from_millis(60_000)).unwrap();
    let (base, remote, world) = pair.into_parts();
    let [b, r] = world.seen;
    [
        (b, format!("{:?}", base.stats())),
        (r, format!("{:?}", remote.stats())),
    ]
}

struct Wire {
    n: u64,
    last: [Instant; 2],
    seen: [Vec<String>; 2],
}

impl World<Heap> for Wire {
    type Error = LinkError;

    fn arrival(&mut self, from: Role, sent: Instant, _: &[u8]) -> Option<Instant> {
        self.n += 1;
        // A deterministic wander: 10 to 60 ms, and a stall at 30 s.
        let wander = (self.n * 7919 % 50) + 10;
        let mut at = sent + Duration::from_millis(wander);
        let stall = Instant::from_millis(30_000)..Instant::from_millis(30_500);
        if stall.contains(&at) {
            at = stall.end;
        }
        let at = at.max(self.last[from as usize]);
        self.last[from as usize] = at;
        Some(at)
    }

    fn event(
        &mut self,
        side: Role,
        ep: &mut Endpoint<Heap>,
        _: Instant,
        event: Event<Box<[f64]>>,
    ) -> Result<(), LinkError> {
        // The peer's Hello names its playout, which differs from the
        // twin's by name only.
        let seen = match &event {
            Event::Connected { peer } => format!(
                "{:?}",
                Event::<Box<[f64]>>::Connected {
                    peer: ndr_core::wire::Hello {
                        regulation: ndr_core::wire::RegulationName::NONE,
                        ..*peer
                    }
                }
            ),
            other => format!("{other:?}"),
        };
        self.seen[side as usize].push(seen);
        if let Event::Released(r) = event {
            let answer: Vec<f64> = r.values().iter().map(|v| v + 1.0).collect();
            ep.set_sample(&answer)?;
        }
        Ok(())
    }

    fn failed(&mut self, _: Role, _: Instant, error: LinkError) -> Result<(), LinkError> {
        Err(error)
    }
}

/// A constant target delay, written here.
#[derive(Clone, Debug)]
struct Hold(Duration);

impl TargetDelay for Hold {
    fn observe(&mut self, _: Instant, _: Duration) {}

    fn target(&self) -> Option<Duration> {
        Some(self.0)
    }
}

struct HoldFor(Duration);

impl Factory for HoldFor {
    fn name(&self) -> &str {
        "hold-for"
    }

    fn build(&self, setup: &Setup) -> Box<dyn Policy> {
        Box::new(OnTicks::new(Hold(self.0), setup))
    }
}

static HOLD_40: HoldFor = HoldFor(Duration::from_millis(40));

#[test]
fn a_target_delay_from_outside_runs_as_its_built_in_twin() {
    let custom = Playout::Custom(Custom::new(&HOLD_40));
    for underflow in [Underflow::Hold, Underflow::DropLate] {
        let ours = run(custom, underflow);
        let built_in = run(
            Playout::Constant {
                delay: Duration::from_millis(40),
            },
            underflow,
        );
        assert!(ours[0].0.len() > 2000, "{:?}", &ours[0].0[..5]);
        assert_eq!(ours, built_in, "{underflow:?}");
    }
}

/// Every call the endpoint makes, counted by name.
#[derive(Debug, Default)]
struct Calls {
    arrival: AtomicU64,
    admit: AtomicU64,
    tick: AtomicU64,
    due: AtomicU64,
    released: AtomicU64,
    later: AtomicU64,
}

/// A policy of its own that hands every call to the built-in adaptive
/// playout, and counts them.
#[derive(Clone, Debug)]
struct Counted {
    inner: Box<dyn Policy>,
    calls: Arc<Calls>,
}

fn count(c: &AtomicU64) {
    c.fetch_add(1, Ordering::Relaxed);
}

impl Policy for Counted {
    fn start(&mut self, ns: usize) -> usize {
        self.inner.start(ns)
    }
    fn set_period(&mut self, period: Duration) {
        self.inner.set_period(period);
    }
    fn stop(&mut self) {
        self.inner.stop();
    }
    fn arrival(&mut self, arrival: &Arrival, view: &View<'_>) -> Observed {
        count(&self.calls.arrival);
        self.inner.arrival(arrival, view)
    }
    fn floor_moved(&mut self, from: f64, to: f64) {
        self.inner.floor_moved(from, to);
    }
    fn admit(&self, sample: &Stamps, now: Instant, view: &View<'_>) -> Admit {
        count(&self.calls.admit);
        self.inner.admit(sample, now, view)
    }
    fn queued(&mut self, view: &View<'_>) {
        self.inner.queued(view);
    }
    fn lost(&mut self) {
        self.inner.lost();
    }
    fn tick(
        &mut self,
        at: Instant,
        t: Instant,
        next: Option<Instant>,
        view: &View<'_>,
    ) -> Option<Due> {
        count(&self.calls.tick);
        self.inner.tick(at, t, next, view)
    }
    fn due(&mut self, at: Instant, t: Instant, view: &View<'_>) -> Due {
        count(&self.calls.due);
        let due = self.inner.due(at, t, view);
        if let Due::Later(_) = due {
            count(&self.calls.later);
        }
        due
    }
    fn released(&mut self, at: Instant, t: Instant, outcome: Outcome, view: &View<'_>) {
        count(&self.calls.released);
        self.inner.released(at, t, outcome, view);
    }
    fn next_release(&self) -> Option<Instant> {
        self.inner.next_release()
    }
    fn delay(&self) -> Option<Duration> {
        self.inner.delay()
    }
    fn poll_announcement(&mut self) -> Option<Announcement> {
        self.inner.poll_announcement()
    }
    fn following_tick(&self, plain: Instant) -> Instant {
        self.inner.following_tick(plain)
    }
    fn grid_settled(&self, at: Instant) -> bool {
        self.inner.grid_settled(at)
    }
}

struct CountedAdaptive(Arc<Calls>);

impl Factory for CountedAdaptive {
    fn name(&self) -> &str {
        "counted-adaptive"
    }

    fn build(&self, setup: &Setup) -> Box<dyn Policy> {
        let inner = <Box<dyn Policy>>::make(Playout::ADAPTIVE, setup).unwrap();
        Box::new(Counted {
            inner,
            calls: Arc::clone(&self.0),
        })
    }
}

#[test]
fn a_policy_of_its_own_around_the_adaptive_playout_changes_nothing() {
    for underflow in [Underflow::Hold, Underflow::DropLate] {
        let calls = Arc::new(Calls::default());
        let factory: &'static CountedAdaptive =
            Box::leak(Box::new(CountedAdaptive(Arc::clone(&calls))));
        let ours = run(Playout::Custom(Custom::new(factory)), underflow);
        let built_in = run(Playout::ADAPTIVE, underflow);
        assert_eq!(ours, built_in, "{underflow:?}");
        // Its releases are its own: the ticks release nothing, every
        // release asks it what is due and tells it what was taken.
        let n = |c: &AtomicU64| c.load(Ordering::Relaxed);
        assert!(n(&calls.tick) > 5000, "{calls:?}");
        assert!(n(&calls.arrival) > 5000, "{calls:?}");
        assert!(n(&calls.admit) > 5000, "{calls:?}");
        assert!(n(&calls.due) > 5000, "{calls:?}");
        assert_eq!(
            n(&calls.released),
            n(&calls.due) - n(&calls.later),
            "{calls:?}"
        );
    }
}

#[test]
fn inline_storage_refuses_a_policy_of_its_own() {
    let mut c = Config::new(Role::Remote);
    c.playout = Playout::Custom(Custom::new(&HOLD_40));
    for refused in [
        Endpoint::<Inline<1, 16>>::new(c, Instant::ZERO).err(),
        Endpoint::<Inline<1, 16, Builtin<NoAdaptive>>>::new(c, Instant::ZERO).err(),
    ] {
        assert_eq!(refused, Some(ConfigError::NoRoom(NoRoom::Custom)));
        assert!(refused.unwrap().to_string().contains("Heap"));
    }
    assert!(Endpoint::<Heap>::new(c, Instant::ZERO).is_ok());
}

#[test]
fn a_policy_of_its_own_is_named_by_its_factory() {
    static OTHER: HoldFor = HoldFor(Duration::from_millis(40));
    let custom = Playout::Custom(Custom::new(&HOLD_40));
    assert_eq!(custom.to_string(), "hold-for");
    assert_eq!(Regulation::Target(custom).to_string(), "hold-for");
    assert_eq!(custom, Playout::Custom(Custom::new(&HOLD_40)));
    assert_ne!(custom, Playout::Custom(Custom::new(&OTHER)));
    assert_eq!(custom.validate(), Ok(()));
}
