//! One remote, several bases, in simulated time: each base's link is a
//! [`Pair`] of endpoints (the one drive contract), the remote's side of
//! every link shares one robot and one [`Floor`]. Control changes hands by
//! close, yield and liveness; terms fence the commands of the old holder;
//! observers see the states of both terms and send no commands.

#[allow(unused_imports)]
use std::{boxed::Box, format, string::String, vec, vec::Vec};

use std::cell::RefCell;
use std::rc::Rc;

use crate::endpoint::{Config, Endpoint, Event, LinkError, Status, Transport};
use crate::floor::{Action, Floor, LinkId};
use crate::pair::{Pair, World};
use crate::storage::Heap;
use crate::time::{Duration, Instant};
use crate::wire::{Kind, Role, Seat};

const T: Duration = Duration::from_millis(10);
const ONE_WAY: Duration = Duration::from_millis(5);
/// Far past any run: a stopped process serves nothing before.
const NEVER: Instant = Instant::from_millis(1_000_000_000);

/// A command the robot applied.
#[derive(Clone, Copy, Debug)]
struct Applied {
    link: LinkId,
    term: u16,
    seq: u64,
    value: f64,
    /// When its base sent it, harness time (by the remote's clock estimate).
    sent_at: Instant,
    /// Harness time.
    at: Instant,
}

/// The robot: what it applied, its state (the last command), the floor.
struct Robot {
    floor: Floor,
    applied: Vec<Applied>,
    state: f64,
    /// Links closed, and why, by harness time.
    closed: Vec<(LinkId, Instant, Option<LinkError>)>,
}

/// One base's link and what its base does and sees.
struct Site {
    link: LinkId,
    robot: Rc<RefCell<Robot>>,
    /// Harness time at which this link's clocks (and its pair's world) start.
    join: Duration,
    /// Datagrams lost when the xorshift state says so (per thousand).
    loss_per_mille: u64,
    rng: u64,
    reliable_last: [Instant; 2],
    /// The base's process stops from this pair-world time (a SIGSTOP).
    base_stops: Option<Instant>,
    /// The base yields control at this harness time.
    yield_at: Option<Instant>,
    /// The base closes its link at this harness time.
    close_at: Option<Instant>,
    /// The remote's offer was made.
    offered: bool,
    /// Commands the base sent: its count.
    k: f64,
    /// States the base released: (harness time, seq, term, status).
    states: Vec<(Instant, u64, u16, Status)>,
    granted: Vec<(Instant, u16)>,
    /// Applied commands an observer got: (term, seq, value, sent_at,
    /// applied_at), times harness times.
    seen_applied: Vec<(u16, u64, f64, Instant, Instant)>,
    lost: Vec<(Instant, u16)>,
    requested: Vec<Instant>,
    errors: Vec<(Role, LinkError)>,
}

impl Site {
    fn new(link: LinkId, robot: &Rc<RefCell<Robot>>, join_ms: u64) -> Self {
        Site {
            link,
            robot: Rc::clone(robot),
            join: Duration::from_millis(join_ms),
            loss_per_mille: 0,
            rng: 0x9e37_79b9_7f4a_7c15 ^ link,
            reliable_last: [Instant::ZERO; 2],
            base_stops: None,
            yield_at: None,
            close_at: None,
            offered: false,
            k: 0.0,
            states: vec![],
            granted: vec![],
            seen_applied: vec![],
            lost: vec![],
            requested: vec![],
            errors: vec![],
        }
    }

    fn harness(&self, t: Instant) -> Instant {
        t + self.join
    }

    fn lose(&mut self) -> bool {
        self.rng ^= self.rng << 13;
        self.rng ^= self.rng >> 7;
        self.rng ^= self.rng << 17;
        self.rng % 1000 < self.loss_per_mille
    }
}

impl World<Heap> for Site {
    type Error = LinkError;

    fn arrival(&mut self, from: Role, sent: Instant, frame: &[u8]) -> Option<Instant> {
        if from == Role::Base && self.base_stops.is_some_and(|s| sent >= s) {
            return None;
        }
        if frame.get(5) == Some(&(Kind::Bundle as u8)) {
            return (!self.lose()).then_some(sent + ONE_WAY);
        }
        // The reliable path: in order.
        let i = from as usize;
        let at = (sent + ONE_WAY).max(self.reliable_last[i]);
        self.reliable_last[i] = at;
        Some(at)
    }

    fn wake(&mut self, side: Role, deadline: Instant) -> Instant {
        match self.base_stops {
            Some(s) if side == Role::Base && deadline >= s => NEVER,
            _ => deadline,
        }
    }

    fn read(&self, side: Role, arrived: Instant) -> Instant {
        match self.base_stops {
            Some(s) if side == Role::Base && arrived >= s => NEVER,
            _ => arrived,
        }
    }

    fn event(
        &mut self,
        side: Role,
        ep: &mut Endpoint<Heap>,
        now: Instant,
        event: Event<Box<[f64]>>,
    ) -> Result<(), LinkError> {
        let at = self.harness(now);
        let link = self.link;
        match side {
            Role::Remote => {
                let mut robot = self.robot.borrow_mut();
                match event {
                    Event::Connected { peer } => {
                        let given = ep.seat().unwrap_or(Seat::Observe);
                        if let Err(e) = robot.floor.admit(link, peer.seat, given, true) {
                            ep.abort(e);
                        }
                    }
                    Event::Started { .. } => robot.floor.started(link),
                    Event::ControlYielded { .. } => robot.floor.yielded(link, at),
                    Event::Closed { error } => {
                        robot.floor.left(link, at);
                        robot.closed.push((link, at, error));
                    }
                    Event::Released(r)
                        if r.status == Status::Fresh && robot.floor.may_apply(link, r.term) =>
                    {
                        let value = r.values()[0];
                        let sent_at = self.harness(ep.peer_to_local(r.sent_at, now));
                        robot.applied.push(Applied {
                            link,
                            term: r.term,
                            seq: r.seq,
                            value,
                            sent_at,
                            at,
                        });
                        robot.state = value;
                    }
                    _ => {}
                }
            }
            Role::Base => match event {
                Event::Released(r) => self.states.push((at, r.seq, r.term, r.status)),
                Event::ControlGranted { term } => self.granted.push((at, term)),
                Event::ControlLost { term } => self.lost.push((at, term)),
                Event::ControlRequested => self.requested.push(at),
                Event::Applied(a) => self.seen_applied.push((
                    a.term,
                    a.seq,
                    a.values()[0],
                    // The remote's clock of this link is this pair's world.
                    self.harness(a.sent_at),
                    self.harness(a.applied_at),
                )),
                _ => {}
            },
        }
        Ok(())
    }

    fn sample(
        &mut self,
        side: Role,
        ep: &mut Endpoint<Heap>,
        now: Instant,
    ) -> Result<(), LinkError> {
        let at = self.harness(now);
        match side {
            Role::Remote => {
                let state = self.robot.borrow().state;
                ep.set_sample(&[state])
            }
            Role::Base => {
                if self.close_at.is_some_and(|c| at >= c) {
                    ep.close();
                    return Ok(());
                }
                if self.yield_at.is_some_and(|y| at >= y) && ep.term().is_some() {
                    self.yield_at = None;
                    return ep.yield_control();
                }
                // Each command names its base: link 1's are 1001, 1002, …
                self.k += 1.0;
                ep.set_sample(&[self.link as f64 * 1000.0 + self.k])
            }
        }
    }

    fn failed(&mut self, side: Role, _: Instant, error: LinkError) -> Result<(), LinkError> {
        self.errors.push((side, error));
        Ok(())
    }
}

fn config(role: Role, seat: Seat, transport: Transport, link: LinkId) -> Config {
    let mut c = Config::paper(role);
    c.period = T;
    c.seat = seat;
    c.transport = transport;
    c.liveness = Some(Duration::from_secs(2));
    if let Transport::Datagram { .. } = transport {
        c.session = 0x5151_0000 + 2 * link + role as u64;
    }
    c
}

/// A remote with its links, stepped together one millisecond at a time;
/// the floor's actions are carried out between steps.
struct Site0 {
    robot: Rc<RefCell<Robot>>,
    pairs: Vec<Pair<Heap, Site>>,
    now: Instant,
    /// Applied commands told to the observers so far.
    forwarded: usize,
    /// Whether the observers are told what the robot applied.
    forward: bool,
    transport: Transport,
    /// The links' regulation, if not the paper's.
    regulation: Option<crate::Regulation>,
}

impl Site0 {
    fn new(observers: usize, transport: Transport) -> Self {
        Site0 {
            robot: Rc::new(RefCell::new(Robot {
                floor: Floor::new(observers).unwrap(),
                applied: vec![],
                state: 0.0,
                closed: vec![],
            })),
            pairs: vec![],
            now: Instant::ZERO,
            forwarded: 0,
            forward: true,
            transport,
            regulation: None,
        }
    }

    /// A base that asks for `seat`, joining at `join_ms`; `tune` sets its
    /// behaviour. Its link is numbered by its order.
    fn base(&mut self, seat: Seat, join_ms: u64, tune: impl FnOnce(&mut Site)) -> LinkId {
        let link = self.pairs.len() as LinkId;
        let mut site = Site::new(link, &self.robot, join_ms);
        tune(&mut site);
        let regulated = |mut c: Config| {
            if let Some(r) = self.regulation {
                c.mode = r.mode();
                c.playout = r.playout();
            }
            c
        };
        let base = Endpoint::new(
            regulated(config(Role::Base, seat, self.transport, link)),
            Instant::ZERO,
        );
        let remote = Endpoint::new(
            regulated(config(Role::Remote, Seat::Control, self.transport, link)),
            Instant::ZERO,
        );
        self.pairs
            .push(Pair::new(base.unwrap(), remote.unwrap(), site));
        link
    }

    fn run_until(&mut self, end_ms: u64) {
        let end = Instant::from_millis(end_ms);
        while self.now < end {
            self.now += Duration::from_millis(1);
            for p in &mut self.pairs {
                let join = p.world.join;
                if let Some(local) = self.now.checked_duration_since(Instant::ZERO + join) {
                    // The driver offers what the floor would when the link
                    // starts (its Hello is a few milliseconds away).
                    if !p.world.offered {
                        p.world.offered = true;
                        let (offer, term) = self.robot.borrow().floor.offer();
                        p.remote.offer(offer, term).unwrap();
                    }
                    p.run_until(Instant::ZERO + local).unwrap();
                }
            }
            self.act();
        }
    }

    /// Carries out the floor's decisions on the links, and tells the
    /// observers what the robot applied.
    fn act(&mut self) {
        let applied = self.robot.borrow().applied[self.forwarded..].to_vec();
        self.forwarded += applied.len();
        for p in &mut self.pairs {
            if !self.forward || p.remote.seat() != Some(Seat::Observe) || p.remote.is_closed() {
                continue;
            }
            let local = |t: Instant| Instant::ZERO + (t - (Instant::ZERO + p.world.join));
            for a in &applied {
                let at = (a.term, a.seq);
                p.remote
                    .send_applied(at, local(a.sent_at), local(a.at), &[a.value])
                    .unwrap();
            }
            p.drain(Role::Remote).unwrap();
        }
        loop {
            let action = self.robot.borrow_mut().floor.poll_action();
            let Some(action) = action else { break };
            match action {
                Action::Grant { link, term } => {
                    let p = &mut self.pairs[link as usize];
                    p.remote.grant(term).unwrap();
                    p.drain(Role::Remote).unwrap();
                }
                Action::Request { link } => {
                    let p = &mut self.pairs[link as usize];
                    if p.remote.request_control().is_ok() {
                        p.drain(Role::Remote).unwrap();
                    }
                }
                Action::Term { term } => {
                    for p in &mut self.pairs {
                        p.remote.set_term(term);
                    }
                }
            }
        }
    }

    fn site(&self, link: LinkId) -> &Site {
        &self.pairs[link as usize].world
    }

    fn applied(&self) -> Vec<Applied> {
        self.robot.borrow().applied.clone()
    }
}

/// Checks the applied commands: each term's from one base, in order, none
/// of a term after the next began; returns them by term.
fn terms_of(applied: &[Applied]) -> Vec<(u16, LinkId, Instant, Instant)> {
    let mut terms: Vec<(u16, LinkId, Instant, Instant)> = vec![];
    let mut last = 0.0;
    for a in applied {
        match terms.last_mut() {
            Some(t) if t.0 == a.term => {
                assert_eq!(t.1, a.link, "one base per term");
                assert!(a.value > last, "in order: {} after {last}", a.value);
                t.3 = a.at;
            }
            _ => {
                assert!(
                    terms.iter().all(|t| t.0 < a.term),
                    "a term came back: {a:?}"
                );
                terms.push((a.term, a.link, a.at, a.at));
            }
        }
        last = a.value;
    }
    terms
}

#[test]
fn control_passes_to_the_waiting_base_when_the_controller_closes() {
    let mut site = Site0::new(2, Transport::Stream);
    let a = site.base(Seat::Control, 0, |s| {
        s.close_at = Some(Instant::from_millis(6000))
    });
    let o = site.base(Seat::Observe, 100, |_| {});
    let b = site.base(Seat::WaitForControl, 1000, |_| {});
    site.run_until(10_000);

    let terms = terms_of(&site.applied());
    assert_eq!(terms.len(), 2, "{terms:?}");
    assert_eq!((terms[0].0, terms[0].1), (1, a));
    assert_eq!((terms[1].0, terms[1].1), (2, b));
    // A's last command applied before A closed; B's first after. Between
    // them the robot applied nothing (it held) for at most the round trip
    // of the grant and B's queue (ns ticks) and a few ticks.
    assert!(terms[0].3 <= Instant::from_millis(6000) + ONE_WAY);
    let gap = terms[1].2 - terms[0].3;
    assert!(
        gap < Duration::from_millis(150),
        "hold between terms {gap:?}"
    );
    let robot = site.robot.borrow();
    assert_eq!(robot.floor.stats().handovers, 1);
    assert_eq!(robot.floor.stats().observers_max, 2);
    assert_eq!(robot.floor.controller(), Some((b, 2)));
    drop(robot);

    // B was told it observes, then granted term 2 after A left.
    let sb = site.site(b);
    assert_eq!(site.pairs[b as usize].base.seat(), Some(Seat::Control));
    assert_eq!(sb.granted.len(), 1);
    assert_eq!(sb.granted[0].1, 2);
    assert!(sb.granted[0].0 > Instant::from_millis(6000));
    assert!(sb.granted[0].0 < Instant::from_millis(6100));
    // A was told B waited.
    assert!(!site.site(a).requested.is_empty());
    assert_eq!(site.site(a).granted, [(site.site(a).granted[0].0, 1)]);

    // The observer: states in order, no gap longer than a few ticks, both
    // terms seen, no grant, no command sent.
    let so = site.site(o);
    assert!(so.granted.is_empty());
    let fresh: Vec<_> = so.states.iter().filter(|s| s.3 == Status::Fresh).collect();
    assert!(fresh.len() > 900, "{}", fresh.len());
    // From its start: its link's first states answer no command, so they
    // wait for no grid to settle.
    assert!(
        fresh[0].0 < Instant::from_millis(100 + 300),
        "the observer's first state at {:?}",
        fresh[0].0
    );
    assert!(
        fresh
            .windows(2)
            .all(|w| w[1].1 > w[0].1 && w[1].0 - w[0].0 <= T * 3)
    );
    assert!(fresh.iter().any(|s| s.2 == 1) && fresh.iter().any(|s| s.2 == 2));
    // It was told every command the robot applied since it joined, in
    // order, with its times.
    let robot_applied: Vec<_> = site
        .applied()
        .iter()
        .filter(|a| a.at >= Instant::from_millis(200) && a.at <= Instant::from_millis(9900))
        .map(|a| (a.term, a.seq, a.value, a.sent_at, a.at))
        .collect();
    let seen: Vec<_> = so
        .seen_applied
        .iter()
        .copied()
        .filter(|s| s.4 >= Instant::from_millis(200) && s.4 <= Instant::from_millis(9900))
        .collect();
    assert_eq!(seen.len(), robot_applied.len());
    if let Some(i) = (0..seen.len()).find(|&i| seen[i] != robot_applied[i]) {
        panic!(
            "applied {i}: seen {:?}, robot {:?}",
            seen[i], robot_applied[i]
        );
    }
    assert!(
        seen.iter()
            .all(|s| s.3 < s.4 && s.4 - s.3 < Duration::from_millis(100))
    );
    let ep = &site.pairs[o as usize];
    assert_eq!(ep.remote.stats().applied_dropped, 0);
    assert_eq!(ep.base.stats().samples_sent, 0);
    assert_eq!(ep.remote.stats().commands_refused_observer, 0);
}

/// Under the adaptive playout a remote's link waits for its ticks to fall
/// on its releases before it sends states; an observer's link releases
/// nothing, so its states must not wait for that.
#[test]
fn an_observer_sees_states_from_its_start_under_the_adaptive_playout() {
    let mut site = Site0::new(2, Transport::Stream);
    site.regulation = Some(crate::Regulation::ADAPTIVE);
    let a = site.base(Seat::Control, 0, |_| {});
    let o = site.base(Seat::Observe, 100, |_| {});
    let b = site.base(Seat::WaitForControl, 200, |_| {});
    site.run_until(3_000);
    assert_eq!(site.robot.borrow().floor.controller(), Some((a, 1)));
    for watcher in [o, b] {
        let fresh: Vec<_> = site
            .site(watcher)
            .states
            .iter()
            .filter(|s| s.3 == Status::Fresh)
            .collect();
        let first = fresh.first().map(|s| s.0);
        assert!(
            first.is_some_and(|t| t < Instant::from_millis(200 + 300)),
            "link {watcher}: first state at {first:?}"
        );
        assert!(
            fresh
                .windows(2)
                .all(|w| w[1].1 > w[0].1 && w[1].0 - w[0].0 <= T * 3)
        );
    }
}

#[test]
fn control_passes_when_the_controller_yields_and_it_observes_on() {
    let mut site = Site0::new(4, Transport::Stream);
    let a = site.base(Seat::Control, 0, |s| {
        s.yield_at = Some(Instant::from_millis(3000))
    });
    let b = site.base(Seat::WaitForControl, 500, |_| {});
    site.run_until(6000);

    let terms = terms_of(&site.applied());
    assert_eq!(
        terms.iter().map(|t| (t.0, t.1)).collect::<Vec<_>>(),
        [(1, a), (2, b)]
    );
    let sa = site.site(a);
    assert_eq!(sa.lost.len(), 1);
    assert_eq!(sa.lost[0].1, 1);
    // A stays, as an observer: it sees term 2's states.
    assert!(sa.states.iter().any(|s| s.2 == 2 && s.3 == Status::Fresh));
    let pa = &site.pairs[a as usize];
    assert!(!pa.base.is_closed() && pa.base.term().is_none());
    assert_eq!(pa.base.seat(), Some(Seat::Observe));
    // Whatever A had queued at the remote when it yielded was refused, not
    // applied (the FIFO keeps ns commands in stock).
    assert!(pa.remote.stats().commands_refused_stale_term >= 1);
    assert!(terms[0].3 <= Instant::from_millis(3000 + 20));
    assert_eq!(site.robot.borrow().floor.stats().handovers, 1);
}

#[test]
fn hand_over_under_datagram_loss_applies_no_command_of_the_old_term() {
    let mut site = Site0::new(2, Transport::DATAGRAM);
    let a = site.base(Seat::Control, 0, |s| {
        s.close_at = Some(Instant::from_millis(4000));
        s.loss_per_mille = 100;
    });
    let b = site.base(Seat::WaitForControl, 700, |s| s.loss_per_mille = 100);
    site.run_until(8000);

    let terms = terms_of(&site.applied());
    assert_eq!(
        terms.iter().map(|t| (t.0, t.1)).collect::<Vec<_>>(),
        [(1, a), (2, b)]
    );
    assert!(terms[0].3 <= Instant::from_millis(4000));
    // B's commands flow: most of its ticks applied despite the loss.
    let b_applied = site.applied().iter().filter(|x| x.link == b).count();
    assert!(b_applied > 300, "{b_applied}");
    assert_eq!(site.site(b).granted[0].1, 2);
    let rb = site.pairs[b as usize].remote.stats();
    assert!(rb.samples_recovered + rb.samples_from_repeats > 0, "{rb:?}");
}

#[test]
fn a_hung_controller_is_replaced_within_the_liveness_time() {
    let mut site = Site0::new(2, Transport::Stream);
    // A's process stops at 3 s: it sends and reads nothing from then.
    let a = site.base(Seat::Control, 0, |s| {
        s.base_stops = Some(Instant::from_millis(3000))
    });
    let b = site.base(Seat::WaitForControl, 500, |_| {});
    site.run_until(8000);

    let terms = terms_of(&site.applied());
    assert_eq!(
        terms.iter().map(|t| (t.0, t.1)).collect::<Vec<_>>(),
        [(1, a), (2, b)]
    );
    // The liveness rule (2 s) dropped A; B took over at once.
    let robot = site.robot.borrow();
    let (_, dropped, why) = robot.closed.iter().find(|c| c.0 == a).copied().unwrap();
    assert!(matches!(why, Some(LinkError::PeerSilent { .. })), "{why:?}");
    assert!(
        dropped >= Instant::from_millis(4990) && dropped < Instant::from_millis(5100),
        "{dropped:?}"
    );
    let granted = site.site(b).granted[0].0;
    assert!(granted >= dropped && granted - dropped < Duration::from_millis(50));
    // Between A's stop and B's term the robot applied nothing.
    assert!(terms[0].3 <= Instant::from_millis(3000 + 100));
}

#[test]
fn stale_term_commands_and_an_observers_commands_are_refused_and_counted() {
    let mut site = Site0::new(4, Transport::Stream);
    // A rogue base would drop the applied commands; these ones, holding a
    // term, take them for a protocol error.
    site.forward = false;
    let a = site.base(Seat::Control, 0, |s| {
        s.yield_at = Some(Instant::from_millis(2000))
    });
    let b = site.base(Seat::WaitForControl, 300, |_| {});
    let o = site.base(Seat::Observe, 300, |_| {});
    site.run_until(3000);
    let before = site.applied().len();
    // A rogue A goes on commanding in its old term after it yielded; a
    // rogue observer sends commands though it holds none.
    site.pairs[a as usize].base.force_term(1);
    site.pairs[o as usize].base.force_term(0);
    site.run_until(5000);

    let applied = site.applied();
    assert!(applied[before..].iter().all(|x| x.link == b && x.term == 2));
    let ra = site.pairs[a as usize].remote.stats();
    let ro = site.pairs[o as usize].remote.stats();
    // Two seconds of A's ticks, each refused on arrival.
    assert!(ra.commands_refused_stale_term > 190, "{ra:?}");
    assert!(ro.commands_refused_observer > 190, "{ro:?}");
    assert_eq!(ro.released_fresh, 0);
    // Neither link was ended for it: a refusal is counted, not fatal.
    assert!(!site.pairs[a as usize].remote.is_closed());
    assert!(!site.pairs[o as usize].remote.is_closed());
}

#[test]
fn a_base_that_asks_for_control_while_it_is_held_is_refused_busy() {
    let mut site = Site0::new(1, Transport::Stream);
    let _a = site.base(Seat::Control, 0, |_| {});
    let c = site.base(Seat::Control, 500, |_| {});
    let o = site.base(Seat::Observe, 600, |_| {});
    let full = site.base(Seat::Observe, 700, |_| {});
    site.run_until(1500);
    let err = |link: LinkId| {
        site.site(link)
            .errors
            .iter()
            .map(|e| e.1)
            .collect::<Vec<_>>()
    };
    assert!(
        err(c).contains(&LinkError::PeerClosed {
            reason: crate::wire::CloseReason::Busy
        }),
        "{:?}",
        err(c)
    );
    assert!(err(o).is_empty(), "{:?}", err(o));
    assert!(err(full).contains(&LinkError::PeerClosed {
        reason: crate::wire::CloseReason::ObserversFull
    }));
    let stats = site.robot.borrow().floor.stats();
    assert_eq!((stats.refused_busy, stats.refused_full), (0, 1));
}

#[test]
fn grant_needs_a_running_link_that_asked_for_control() {
    let mut c = Config::paper(Role::Remote);
    c.period = T;
    let mut remote: Endpoint<Heap> = Endpoint::new(c, Instant::ZERO).unwrap();
    assert_eq!(remote.grant(1), Err(LinkError::NotController));
    let mut base: Endpoint<Heap> = Endpoint::new(Config::paper(Role::Base), Instant::ZERO).unwrap();
    assert_eq!(base.yield_control(), Err(LinkError::NotController));
    assert_eq!(remote.request_control(), Err(LinkError::NotController));
}
