//! Regimes: the initialization pattern, the start of a running regime, and the paper's dynamic pause-and-resize.

use super::{Endpoint, Event, LinkError, MIN_PERIOD, Mode, PATTERN_SLACK, Phase, Tx};
use crate::playout::Policy;
use crate::predictor::Prediction;
use crate::sizing::{INIT_EXCHANGES, InitPattern};
use crate::storage::Storage;
use crate::time::{Duration, Instant};
use crate::wire::{ControlOp, Role};

impl<S: Storage> Endpoint<S> {
    pub(super) fn checked_ns(&self, ns: u16, period: Duration) -> Result<usize, LinkError> {
        let fits = usize::from(ns) < self.capacity() && period >= MIN_PERIOD;
        fits.then_some(usize::from(ns))
            .ok_or(LinkError::BadParameters { ns, period })
    }

    pub(super) fn change_period(&mut self, period: Duration) -> Result<(), LinkError> {
        self.period = period;
        self.policy.set_period(period);
        self.heard.check.period_changed(period);
        self.predictor
            .set_period(period)
            .map_err(|_| LinkError::BadParameters { ns: 0, period })
    }

    pub(super) fn enter_init(&mut self, now: Instant) {
        self.discard_queue();
        self.phase = Phase::Init;
        self.regime.pattern.clear();
        self.regime.init_started = now;
        self.deadline = Some(self.pattern_deadline(now));
        // Half a period after the last frame sent at least, whatever the
        // new grid: the peer refuses a stamp closer than that.
        let from = match self
            .out
            .next_seq
            .checked_sub(1)
            .and_then(|s| self.tick_of(s))
        {
            Some(last) => now.max(last + self.period / 2),
            None => now,
        };
        self.next_tick = Some(self.next_grid_tick(from));
    }

    /// The deadline of a pause or of an initialization pattern that starts
    /// at `now`: the handshake timeout, or longer when the pattern itself
    /// needs more — [`INIT_EXCHANGES`] probes at the current period and the
    /// slowest round trip seen so far, with a margin of [`PATTERN_SLACK`].
    /// The dynamic mode's period law (`NRTT/3`) makes a slow network's
    /// pattern long, longer than a fixed limit would allow.
    pub(super) fn pattern_deadline(&self, now: Instant) -> Instant {
        let probes = self.period * (INIT_EXCHANGES as u64 + 1);
        let slowest = Duration::from_secs_f64(self.stats.nrtt.max());
        let need = (probes + slowest).saturating_mul(PATTERN_SLACK);
        now + self.config.handshake_timeout.max(need)
    }

    pub(super) fn discard_queue(&mut self) {
        self.stats.discarded += self.regulator.clear() as u64;
    }

    /// Base: the initialization pattern is complete.
    pub(super) fn finish_init(&mut self, _now: Instant) -> Result<(), LinkError> {
        let ns = match self.regime.pending.take() {
            Some((_, ns)) => ns,
            None => match self.regime.pattern.stats() {
                Some(s) => self.config.sizing.nominal_size_for(&s, self.period),
                None => return Err(LinkError::Timeout),
            },
        };
        let ns = self.clamp_ns(ns);
        self.queue_tx(Tx::Control {
            op: ControlOp::Resume,
            ns: u16::try_from(ns).unwrap_or(u16::MAX),
            period: self.period,
        });
        self.start_running(ns);
        Ok(())
    }

    pub(super) fn clamp_ns(&mut self, ns: usize) -> usize {
        let limit = self.capacity().saturating_sub(1).min(usize::from(u16::MAX));
        if ns > limit {
            self.stats.clamped += 1;
            limit
        } else {
            ns
        }
    }

    pub(super) fn start_running(&mut self, ns: usize) {
        self.discard_queue();
        // `ns < N` was checked by the caller. The policy says what stock the
        // queue keeps (a target delay none: each sample waits for its slot).
        let stock = self.policy.start(ns);
        let _ = self.regulator.set_nominal(stock);
        self.regulator.restart_prefill();
        // Occupancy statistics describe the current parameters.
        self.regulator.reset_occupancy();
        self.ns = ns;
        // Round trips count from this regime's first sample: an echo of a
        // sample sent before a pause would measure the pause.
        self.rel.grtt_acked = self.out.next_seq.checked_sub(1);
        self.rel.armed = false;
        self.regime.ticks_running = 0;
        self.regime.grid_settled = false;
        self.deadline = None;
        self.phase = Phase::Running;
        if self.regime.started_once {
            self.stats.resizes += 1;
        }
        let first = !self.regime.started_once;
        self.regime.started_once = true;
        self.emit(Event::Started {
            period: self.period,
            ns,
        });
        if first {
            self.grant_at_start();
        }
    }

    /// Dynamic mode, base side: pause and resize when the forecast says so.
    pub(super) fn maybe_adapt(&mut self, t: Instant, p: Prediction) {
        let settle = u64::from(self.config.adaptation.settle_periods);
        if self.config.mode != Mode::PaperDynamic
            || self.config.role != Role::Base
            || self.phase != Phase::Running
            || self.regime.ticks_running < settle
        {
            return;
        }
        let band = self.config.adaptation.band;
        // Whole microseconds: a period both peers can state exactly.
        let period = Duration::from_micros(p.period.as_micros()).max(MIN_PERIOD);
        let current = self.period.as_secs_f64();
        let off = |forecast: f64, now: f64| libm::fabs(forecast - now) > band * now;
        let drift = off(period.as_secs_f64(), current) || off(p.ns as f64, self.ns as f64);
        // The forecast lag would use up the whole stock: the queue would empty.
        let drain = p.mt_ahead >= self.ns as f64 * current;
        if !(drift || drain) {
            return;
        }
        let ns = self.clamp_ns(p.ns);
        self.discard_queue();
        self.regime.pending = Some((period, ns));
        self.phase = Phase::Pausing;
        self.deadline = Some(self.pattern_deadline(t));
        self.stats.pauses += 1;
        self.queue_tx(Tx::Control {
            op: ControlOp::PauseRequest,
            ns: u16::try_from(ns).unwrap_or(u16::MAX),
            period,
        });
        self.emit(Event::Paused { period, ns });
    }
}

/// Where the protocol's regimes stand: the initialization pattern, the
/// pause under way, the running regime's ticks.
#[derive(Clone, Debug)]
pub(super) struct Regime {
    pub(super) pattern: InitPattern,
    /// When the current pattern started: echoes of frames sent before it
    /// are not its round trips.
    pub(super) init_started: Instant,
    /// Dynamic mode: the parameters the current pause will resume with.
    pub(super) pending: Option<(Duration, usize)>,
    pub(super) started_once: bool,
    pub(super) ticks_running: u64,
    /// Running: the ticks send samples (an adaptive remote's only once its
    /// grid has moved to its releases).
    pub(super) grid_settled: bool,
}

impl Regime {
    pub(super) fn new(now: Instant) -> Self {
        Regime {
            pattern: InitPattern::new(),
            init_started: now,
            pending: None,
            started_once: false,
            ticks_running: 0,
            grid_settled: false,
        }
    }
}
