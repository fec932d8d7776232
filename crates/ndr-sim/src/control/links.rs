//! The links a loop is closed across: none (the delay-free loop), a plain
//! socket (each sample applied the moment it arrives), and the regulated
//! link (the real endpoints in simulated time).

use std::boxed::Box;
use std::collections::VecDeque;
use std::vec::Vec;

use ndr_core::control::round_trip_ticks;
use ndr_core::endpoint::{Event, Phase, Status, Transport};
use ndr_core::pair::{Pair, World};
use ndr_core::storage::Heap;
use ndr_core::time::{Duration, Instant};
use ndr_core::wire::Role;

use super::apps::{App, Rx, WIDTH};
use crate::engine::{Network, SimEndpoint, endpoints, link_error, network_world};
use crate::{SimConfig, SimError};

/// What a run of a link saw besides the applications' records.
#[derive(Clone, Debug, Default)]
pub(crate) struct LinkLog {
    /// The base ticks at which either side announced a delay change.
    pub announced: Vec<u64>,
    /// The base ticks at which the base announced a new round trip.
    pub round_trips_announced: Vec<u64>,
    /// The times the link changed its period (paper-dynamic).
    pub period_changes: u64,
    /// The period when the loop started (the base's first release).
    pub start_period: Option<Duration>,
}

/// The loop over a plain socket: both sides tick on one grid; at each
/// tick a side applies the newest sample that has arrived (none new: the
/// last again). With `delay_free`, nothing is delayed: the remote applies
/// the command of the same tick, the base sees the state one tick later.
pub(crate) fn plain<A: App>(
    cfg: &SimConfig,
    app: &mut A,
    delay_free: bool,
) -> Result<LinkLog, SimError> {
    let mut net = Network::new(cfg);
    let datagram = matches!(cfg.transport, Transport::Datagram { .. });
    let period = cfg.period;
    let ticks = cfg.duration.as_nanos() / period.as_nanos().max(1);
    let mut to: [VecDeque<(Instant, [f64; WIDTH])>; 2] = [VecDeque::new(), VecDeque::new()];
    let mut last: [Option<[f64; WIDTH]>; 2] = [None, None];
    let control = |e| SimError::Control(e);
    for k in 0..ticks {
        let now = Instant::ZERO + period * k;
        for side in [Role::Base, Role::Remote] {
            let (inbox, from) = match side {
                Role::Base => (1, 0),
                Role::Remote => (0, 1),
            };
            let mut fresh = false;
            while to[inbox].front().is_some_and(|(at, _)| *at <= now) {
                last[inbox] = to[inbox].pop_front().map(|(_, v)| v);
                fresh = true;
            }
            let rx = Rx {
                values: last[inbox],
                fresh,
                round_trip: None,
            };
            let out = match side {
                Role::Base => app.base(rx).map_err(control)?,
                Role::Remote => app.remote(rx).map_err(control)?,
            };
            let arrival = if delay_free {
                Some(now)
            } else {
                net.deliver(side, now, datagram)
            };
            if let Some(at) = arrival {
                to[from].push_back((at.max(now), out));
            }
        }
    }
    Ok(LinkLog::default())
}

/// The loop across two endpoints regulated as `cfg` says.
pub(crate) fn regulated<A: App>(cfg: &SimConfig, app: &mut A) -> Result<LinkLog, SimError> {
    let (base, remote) = endpoints(cfg, WIDTH as u16)?;
    let world = LoopWorld {
        net: Network::new(cfg),
        app,
        period: cfg.period,
        periods: [cfg.period; 2],
        base_ticks: 0,
        pending: None,
        next_base_tick: None,
        log: LinkLog::default(),
    };
    let mut pair = Pair::new(base, remote, world);
    pair.run_until(Instant::ZERO + cfg.duration)?;
    let (_, _, world) = pair.into_parts();
    Ok(world.log)
}

/// The regulated link's world. The remote's application runs at each
/// release, as the simulator's plant does (an adaptive remote ticks with
/// its releases). The base's runs once a tick, on the base's grid, with
/// the newest state released since its last run: the adaptive playout
/// releases on a schedule of its own, and an application that answered
/// each release would leave some ticks' frames repeating its previous
/// command (a duplicate the remote takes as fresh) and overwrite others
/// before they are sent.
struct LoopWorld<'a, A> {
    net: Network,
    app: &'a mut A,
    /// The base's period: its grid, its round trips in ticks.
    period: Duration,
    /// Each side's period as its application knows it (base, remote).
    periods: [Duration; 2],
    base_ticks: u64,
    /// What the base released since its application last ran.
    pending: Option<Rx>,
    /// The base tick its application runs at next, once the loop started.
    next_base_tick: Option<Instant>,
    log: LinkLog,
}

impl<A: App> LoopWorld<'_, A> {
    /// The first tick of the base's grid (origin zero) at or after `t`.
    fn grid_at_or_after(&self, t: Instant) -> Instant {
        let p = self.period.as_nanos().max(1);
        Instant::from_nanos(t.as_nanos().div_ceil(p).saturating_mul(p))
    }
}

impl<A: App> World<Heap> for LoopWorld<'_, A> {
    type Error = SimError;

    network_world!();

    fn event(
        &mut self,
        side: Role,
        ep: &mut SimEndpoint,
        now: Instant,
        event: Event<Box<[f64]>>,
    ) -> Result<(), SimError> {
        match event {
            Event::Released(r) => {
                let mut values = [0.0; WIDTH];
                for (v, x) in values.iter_mut().zip(r.values()) {
                    *v = *x;
                }
                let fresh = r.status == Status::Fresh;
                let round_trip = r.grtt.and_then(|g| round_trip_ticks(g, self.period));
                match side {
                    Role::Base => {
                        let before = self.pending.take();
                        self.pending = Some(Rx {
                            values: Some(values),
                            fresh: fresh || before.is_some_and(|b| b.fresh),
                            round_trip: round_trip.or(before.and_then(|b| b.round_trip)),
                        });
                        if self.base_ticks == 0 && self.next_base_tick.is_none() {
                            self.next_base_tick = Some(self.grid_at_or_after(now));
                        }
                    }
                    Role::Remote => {
                        let rx = Rx {
                            values: Some(values),
                            fresh,
                            round_trip,
                        };
                        let out = self.app.remote(rx).map_err(SimError::Control)?;
                        ep.set_sample(&out)
                            .map_err(|e| link_error(side, self.net.global(side, now), e))?;
                    }
                }
            }
            Event::Paused { .. } if side == Role::Base => {
                // The loop stops with the samples; it runs again when they
                // flow again.
                self.next_base_tick = None;
                self.pending = None;
            }
            Event::Started { period, .. } => {
                // Each side's application changes its period when its
                // endpoint does (the two may start a tick apart).
                let known = &mut self.periods[usize::from(side == Role::Remote)];
                if period != *known {
                    *known = period;
                    self.app
                        .period(side, period.as_secs_f64())
                        .map_err(SimError::Control)?;
                    if side == Role::Base {
                        self.log.period_changes += 1;
                    }
                }
                if let (Role::Remote, Some(v)) = (side, self.app.resume_remote()) {
                    ep.set_sample(&v)
                        .map_err(|e| link_error(side, self.net.global(side, now), e))?;
                }
                if side == Role::Base {
                    self.period = period;
                    // After a pause samples flow from now: the application
                    // sets one every tick, or the endpoint would send its
                    // last one again, a command of before the pause. (At
                    // the start the loop waits for its first state; the
                    // endpoint sends zeros meanwhile.)
                    if self.base_ticks > 0 {
                        self.next_base_tick = Some(self.grid_at_or_after(now));
                    }
                }
                self.net.period = period;
            }
            Event::DelayChanged { .. } => self.log.announced.push(self.base_ticks),
            Event::RoundTripChanged { .. } if side == Role::Base => {
                self.log.round_trips_announced.push(self.base_ticks);
            }
            Event::Closed { error: Some(e) } => {
                return Err(link_error(side, self.net.global(side, now), e));
            }
            _ => {}
        }
        Ok(())
    }

    fn sample(&mut self, side: Role, ep: &mut SimEndpoint, now: Instant) -> Result<(), SimError> {
        // The base's application, at each of its ticks once the loop
        // started: after the tick itself (nothing due any more at `now`),
        // before the tick's frame is written.
        let Some(tick) = self.next_base_tick else {
            return Ok(());
        };
        if side != Role::Base
            || now < tick
            || ep.poll_timeout().is_some_and(|t| t <= now)
            || ep.phase() != Phase::Running
        {
            return Ok(());
        }
        let rx = self.pending.take().unwrap_or(Rx {
            values: None,
            fresh: false,
            round_trip: None,
        });
        self.base_ticks += 1;
        self.log.start_period.get_or_insert(self.period);
        let out = self.app.base(rx).map_err(SimError::Control)?;
        ep.set_sample(&out)
            .map_err(|e| link_error(side, self.net.global(side, now), e))?;
        self.next_base_tick = Some(self.grid_at_or_after(now + Duration::from_nanos(1)));
        Ok(())
    }
}
