//! What a simulation measured: the summary [`Report`] (the JSON of
//! `ndr sim --json`) and the per-tick [`Row`]s (the CSV of `--out`).

use std::collections::VecDeque;
use std::string::String;
use std::vec::Vec;

use ndr_core::endpoint::{Endpoint, Release};
use ndr_core::storage::Heap;
use ndr_core::time::{Duration, Instant};
use ndr_core::wire::Role;
use serde::Serialize;

use super::delay::{DelayModel, fig6_truth};
use super::engine::{SimConfig, SimOutput};

/// Summary of one run. Times in seconds; `fwd` is base → remote (commands),
/// `bwd` remote → base (states).
#[derive(Clone, Debug, PartialEq, Serialize)]
#[non_exhaustive]
pub struct Report {
    /// The delay model's name.
    pub profile: String,
    /// How the delay was regulated: `paper-static`, `adaptive`, ...
    /// ([`Regulation`](ndr_core::Regulation)'s name), or `MODE with
    /// PLAYOUT` for the pairing no regulation names.
    pub regulation: String,
    /// `paper-static` or `paper-dynamic`: a part of `regulation`.
    pub mode: String,
    /// `hold` or `drop-late`.
    pub underflow: String,
    /// The regulators' playout policy, a part of `regulation`: `fifo` (the
    /// paper's), `ramjee-1`, ...
    pub playout: String,
    /// The seed.
    pub seed: u64,
    /// Simulated time.
    pub duration_s: f64,
    /// Axes.
    pub axes: u16,
    /// Network round trip measured by the base: mean.
    pub nrtt_mean_s: f64,
    /// Network round trip measured by the base: standard deviation.
    pub nrtt_std_s: f64,
    /// Round trip as the application sees it (both regulators): mean.
    pub grtt_mean_s: f64,
    /// GRTT standard deviation: the residual jitter a controller sees.
    pub grtt_std_s: f64,
    /// GRTT 99th percentile.
    pub grtt_p99_s: f64,
    /// GRTTs measured.
    pub grtt_count: u64,
    /// GRTT mean since the last parameter change (equals `grtt_mean_s` in static mode).
    pub settled_grtt_mean_s: f64,
    /// GRTT standard deviation since the last parameter change.
    pub settled_grtt_std_s: f64,
    /// End-to-end delay of commands (release at the remote − send at the base): mean.
    pub e2e_fwd_mean_s: f64,
    /// End-to-end delay of commands: standard deviation.
    pub e2e_fwd_std_s: f64,
    /// End-to-end delay of states: mean.
    pub e2e_bwd_mean_s: f64,
    /// End-to-end delay of states: standard deviation.
    pub e2e_bwd_std_s: f64,
    /// Late commands / commands received.
    pub late_rate_fwd: f64,
    /// Late states / states received.
    pub late_rate_bwd: f64,
    /// Nominal queue size at the end.
    pub ns: usize,
    /// Period at the end.
    pub period_s: f64,
    /// Nominal size chosen by the first initialization pattern.
    pub initial_ns: usize,
    /// Base regulator occupancy before a release, in the final regime: min.
    pub queue_base_min: usize,
    /// Base regulator occupancy: max.
    pub queue_base_max: usize,
    /// Base regulator occupancy: mean.
    pub queue_base_mean: f64,
    /// Remote regulator occupancy, in the final regime: min.
    pub queue_remote_min: usize,
    /// Remote regulator occupancy: max.
    pub queue_remote_max: usize,
    /// Remote regulator occupancy: mean.
    pub queue_remote_mean: f64,
    /// Samples sent, both directions.
    pub samples_sent: u64,
    /// Samples released fresh, both directions.
    pub samples_released: u64,
    /// Late samples, both directions.
    pub late_samples: u64,
    /// Underflows (ticks that repeated a sample), both directions.
    pub underflows: u64,
    /// Samples refused by a full regulator, both directions.
    pub rejected: u64,
    /// Samples discarded by pauses, or (adaptive playout under hold) held
    /// past their slot by an outage, both directions.
    pub discarded: u64,
    /// Samples skipped when a target delay fell by a tick at once, both
    /// directions (the adaptive policy slides instead: none).
    pub skipped: u64,
    /// Watchdog alarms (no fresh sample for a second), both sides.
    pub link_lost: u64,
    /// Adaptive playout: frames of outages (after a silence longer than
    /// the watchdog) left out of the delay window, both directions.
    pub outage_delays: u64,
    /// Parameter changes.
    pub resizes: u64,
    /// Pauses.
    pub pauses: u64,
    /// `2·max(s)·T + NRTT`, the paper's relation, with `max(s)` the larger
    /// regulator maximum of the final regime.
    pub relation_grtt_s: f64,
    /// Settled GRTT minus the relation's value.
    pub relation_error_s: f64,
    /// The relation with the mean occupancies instead, `(s̄_base +
    /// s̄_remote)·T + NRTT`. By Little's law (mean occupancy = time in queue
    /// ÷ T) it holds for any delay distribution; `max(s)` equals `s̄` only
    /// when the queue sits at its maximum, as the paper's did.
    pub relation_mean_grtt_s: f64,
    /// Settled GRTT minus the mean-occupancy relation's value.
    pub relation_mean_error_s: f64,
    /// Forecasts of the mean NRTT, `horizon` periods ahead, compared with
    /// the measured mean NRTT when that time came: mean absolute error.
    pub pred_nrtt_mae_s: f64,
    /// Same, root mean square.
    pub pred_nrtt_rmse_s: f64,
    /// Forecasts of `mt` compared with the measured `mt`: mean absolute error.
    pub pred_mt_mae_s: f64,
    /// Same, root mean square.
    pub pred_mt_rmse_s: f64,
    /// Forecasts compared.
    pub pred_count: u64,
    /// How far ahead the forecasts look, at the final period.
    pub pred_horizon_s: f64,
    /// The remote's estimate of the skew `d(remote − base)/dt`, ppm.
    pub remote_clock_skew_ppm: f64,
    /// The remote's estimate of `remote − base` clocks at the end, s.
    pub remote_clock_offset_s: f64,
    /// The base's estimate of the skew `d(base − remote)/dt`, ppm.
    pub base_clock_skew_ppm: f64,
    /// Mean one-way delay base → remote as the remote estimates it, s.
    pub one_way_fwd_mean_s: f64,
    /// Mean one-way delay remote → base as the base estimates it, s.
    pub one_way_bwd_mean_s: f64,
    /// Changes of the remote's playout delay (target policies).
    pub delay_changes_fwd: u64,
    /// `DelayChanged` events the remote's application received.
    pub delay_events_fwd: u64,
    /// The remote's playout delay at the end (target policies), s.
    pub playout_delay_fwd_s: f64,
}

/// One base tick of a run, for plots (`ndr sim --out`). Times in seconds;
/// `NaN` where nothing was measured yet.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Row {
    /// Simulation time.
    pub t_s: f64,
    /// Period.
    pub period_s: f64,
    /// Nominal queue size.
    pub ns: usize,
    /// Samples in the base's regulator.
    pub queue_base: usize,
    /// Samples in the remote's regulator.
    pub queue_remote: usize,
    /// Latest NRTT measured by the base.
    pub nrtt_s: f64,
    /// The predictor's measured mean NRTT.
    pub nrtt_mean_s: f64,
    /// The predictor's forecast of the mean NRTT, `horizon` periods ahead.
    pub nrtt_ahead_s: f64,
    /// The predictor's measured `mt`.
    pub mt_s: f64,
    /// The predictor's forecast of `mt`.
    pub mt_ahead_s: f64,
    /// Latest GRTT.
    pub grtt_s: f64,
    /// Latest end-to-end delay of a command.
    pub e2e_fwd_s: f64,
    /// Latest end-to-end delay of a state.
    pub e2e_bwd_s: f64,
    /// `paper-fig6` only: the generating mean NRTT (twice the one-way mean).
    pub truth_nrtt_s: f64,
}

impl Row {
    /// The CSV header matching [`Row::csv`].
    pub const CSV_HEADER: &'static str = "t_s,period_s,ns,queue_base,queue_remote,nrtt_s,nrtt_mean_s,nrtt_ahead_s,mt_s,mt_ahead_s,grtt_s,e2e_fwd_s,e2e_bwd_s,truth_nrtt_s";

    /// The row as one CSV line (no newline); empty fields for NaN.
    #[must_use]
    pub fn csv(&self) -> String {
        use std::fmt::Write;
        let mut s = String::new();
        let f = |x: f64| {
            if x.is_finite() {
                std::format!("{x:.6}")
            } else {
                String::new()
            }
        };
        let _ = write!(
            s,
            "{:.6},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            self.t_s,
            f(self.period_s),
            self.ns,
            self.queue_base,
            self.queue_remote,
            f(self.nrtt_s),
            f(self.nrtt_mean_s),
            f(self.nrtt_ahead_s),
            f(self.mt_s),
            f(self.mt_ahead_s),
            f(self.grtt_s),
            f(self.e2e_fwd_s),
            f(self.e2e_bwd_s),
            f(self.truth_nrtt_s),
        );
        s
    }
}

/// Gathers measurements while a simulation runs.
pub(crate) struct Collector {
    grtt: Vec<f64>,
    settled_from: usize,
    e2e: [Vec<f64>; 2],
    last_grtt: f64,
    last_e2e: [f64; 2],
    initial_ns: Option<usize>,
    forecasts: VecDeque<(Instant, f64, f64)>,
    nrtt_err: (f64, f64),
    mt_err: (f64, f64),
    pred_count: u64,
    rows: Option<Vec<Row>>,
    fig6: bool,
    /// `Event::DelayChanged` the remote's application received.
    pub(crate) delay_events_fwd: u64,
}

fn mean_std(xs: &[f64]) -> (f64, f64) {
    if xs.is_empty() {
        return (0.0, 0.0);
    }
    let n = xs.len() as f64;
    let mean = xs.iter().sum::<f64>() / n;
    let var = xs.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
    (mean, var.sqrt())
}

/// The `q` quantile of `xs` (0 < q ≤ 1) by nearest rank: the smallest value
/// with at least `q·n` values at or below it; 0 for no values.
#[must_use]
pub fn percentile(xs: &[f64], q: f64) -> f64 {
    let mut v = xs.to_vec();
    v.sort_by(f64::total_cmp);
    let rank = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len().max(1));
    v.get(rank - 1).copied().unwrap_or(0.0)
}

impl Collector {
    pub(crate) fn new(cfg: &SimConfig) -> Self {
        Collector {
            delay_events_fwd: 0,
            grtt: Vec::new(),
            settled_from: 0,
            e2e: [Vec::new(), Vec::new()],
            last_grtt: f64::NAN,
            last_e2e: [f64::NAN; 2],
            initial_ns: None,
            forecasts: VecDeque::new(),
            nrtt_err: (0.0, 0.0),
            mt_err: (0.0, 0.0),
            pred_count: 0,
            rows: cfg.record_series.then(Vec::new),
            fig6: matches!(cfg.model, DelayModel::PaperFig6),
        }
    }

    /// A fresh release on `side`.
    pub(crate) fn fresh(&mut self, side: Role, r: &Release<Box<[f64]>>) {
        // One clock in the simulator: send and release times compare directly.
        let e2e = (r.released_at - r.sent_at).as_secs_f64();
        let dir = if side == Role::Remote { 0 } else { 1 };
        self.e2e[dir].push(e2e);
        self.last_e2e[dir] = e2e;
        if side == Role::Base
            && let Some(g) = r.grtt
        {
            self.last_grtt = g.as_secs_f64();
            self.grtt.push(self.last_grtt);
        }
    }

    pub(crate) fn started(&mut self, side: Role, _now: Instant, _period: Duration, ns: usize) {
        if side == Role::Base {
            self.initial_ns.get_or_insert(ns);
            self.settled_from = self.grtt.len();
        }
    }

    pub(crate) fn base_tick(
        &mut self,
        now: Instant,
        base: &Endpoint<Heap>,
        remote: &Endpoint<Heap>,
    ) {
        let prediction = base.prediction();
        if let Some(p) = prediction {
            while let Some(&(target, nrtt, mt)) = self.forecasts.front() {
                if target > now {
                    break;
                }
                self.forecasts.pop_front();
                let (en, em) = (nrtt - p.nrtt_mean, mt - p.mt);
                self.nrtt_err.0 += en.abs();
                self.nrtt_err.1 += en * en;
                self.mt_err.0 += em.abs();
                self.mt_err.1 += em * em;
                self.pred_count += 1;
            }
            let horizon = base.period() * u64::from(base.predictor().config().horizon);
            self.forecasts
                .push_back((now + horizon, p.nrtt_ahead, p.mt_ahead));
        }
        if let Some(rows) = &mut self.rows {
            let t = now.as_secs_f64();
            let (nm, na, m, ma) = prediction
                .map_or((f64::NAN, f64::NAN, f64::NAN, f64::NAN), |p| {
                    (p.nrtt_mean, p.nrtt_ahead, p.mt, p.mt_ahead)
                });
            rows.push(Row {
                t_s: t,
                period_s: base.period().as_secs_f64(),
                ns: base.ns(),
                queue_base: base.queue_len(),
                queue_remote: remote.queue_len(),
                nrtt_s: base.last_nrtt().map_or(f64::NAN, Duration::as_secs_f64),
                nrtt_mean_s: nm,
                nrtt_ahead_s: na,
                mt_s: m,
                mt_ahead_s: ma,
                grtt_s: self.last_grtt,
                e2e_fwd_s: self.last_e2e[0],
                e2e_bwd_s: self.last_e2e[1],
                truth_nrtt_s: if self.fig6 {
                    2.0 * fig6_truth(t).0
                } else {
                    f64::NAN
                },
            });
        }
    }

    pub(crate) fn finish(
        self,
        cfg: &SimConfig,
        base: &Endpoint<Heap>,
        remote: &Endpoint<Heap>,
    ) -> SimOutput {
        let (bs, rs) = (base.stats(), remote.stats());
        let (grtt_mean, grtt_std) = mean_std(&self.grtt);
        let settled = self.grtt.get(self.settled_from..).unwrap_or(&[]);
        let (settled_mean, settled_std) = mean_std(settled);
        let (fwd_mean, fwd_std) = mean_std(&self.e2e[0]);
        let (bwd_mean, bwd_std) = mean_std(&self.e2e[1]);
        let late_rate = |late: u64, received: u64, discarded: u64| {
            let n = received.saturating_sub(discarded);
            if n == 0 { 0.0 } else { late as f64 / n as f64 }
        };
        let occ_b = base.occupancy();
        let occ_r = remote.occupancy();
        let max_s = occ_b.map_or(0, |o| o.max).max(occ_r.map_or(0, |o| o.max));
        let period = base.period();
        let relation = 2.0 * max_s as f64 * period.as_secs_f64() + bs.nrtt.mean();
        let mean_s = occ_b.map_or(0.0, |o| o.mean) + occ_r.map_or(0.0, |o| o.mean);
        let relation_mean = mean_s * period.as_secs_f64() + bs.nrtt.mean();
        let n = self.pred_count.max(1) as f64;
        // The end of the run on the remote's clock.
        let skew = 1.0 + cfg.remote_skew_ppm * 1e-6;
        let remote_end = Instant::ZERO + Duration::from_secs_f64(cfg.duration.as_secs_f64() * skew);
        let report = Report {
            remote_clock_skew_ppm: remote.clock_sync().skew() * 1e6,
            remote_clock_offset_s: remote
                .clock_sync()
                .offset_at(remote_end)
                .unwrap_or(f64::NAN),
            base_clock_skew_ppm: base.clock_sync().skew() * 1e6,
            one_way_fwd_mean_s: rs.one_way_rx.mean(),
            one_way_bwd_mean_s: bs.one_way_rx.mean(),
            delay_changes_fwd: rs.delay_changes,
            delay_events_fwd: self.delay_events_fwd,
            playout_delay_fwd_s: rs.playout_delay_s,
            profile: cfg.model.name(),
            regulation: std::format!("{}", ndr_core::Regulation::name_of(cfg.mode, cfg.playout)),
            mode: String::from(cfg.mode.name()),
            underflow: String::from(cfg.underflow.name()),
            playout: std::format!("{}", cfg.playout),
            seed: cfg.seed,
            duration_s: cfg.duration.as_secs_f64(),
            axes: cfg.axes,
            nrtt_mean_s: bs.nrtt.mean(),
            nrtt_std_s: bs.nrtt.std(),
            grtt_mean_s: grtt_mean,
            grtt_std_s: grtt_std,
            grtt_p99_s: percentile(&self.grtt, 0.99),
            grtt_count: self.grtt.len() as u64,
            settled_grtt_mean_s: settled_mean,
            settled_grtt_std_s: settled_std,
            e2e_fwd_mean_s: fwd_mean,
            e2e_fwd_std_s: fwd_std,
            e2e_bwd_mean_s: bwd_mean,
            e2e_bwd_std_s: bwd_std,
            late_rate_fwd: late_rate(rs.late, rs.samples_received, rs.discarded),
            late_rate_bwd: late_rate(bs.late, bs.samples_received, bs.discarded),
            ns: base.ns(),
            period_s: period.as_secs_f64(),
            initial_ns: self.initial_ns.unwrap_or(0),
            queue_base_min: occ_b.map_or(0, |o| o.min),
            queue_base_max: occ_b.map_or(0, |o| o.max),
            queue_base_mean: occ_b.map_or(0.0, |o| o.mean),
            queue_remote_min: occ_r.map_or(0, |o| o.min),
            queue_remote_max: occ_r.map_or(0, |o| o.max),
            queue_remote_mean: occ_r.map_or(0.0, |o| o.mean),
            samples_sent: bs.samples_sent + rs.samples_sent,
            samples_released: bs.released_fresh + rs.released_fresh,
            late_samples: bs.late + rs.late,
            underflows: bs.underflows + rs.underflows,
            rejected: bs.rejected + rs.rejected,
            discarded: bs.discarded + rs.discarded,
            skipped: bs.skipped + rs.skipped,
            link_lost: bs.link_lost + rs.link_lost,
            outage_delays: bs.outage_delays + rs.outage_delays,
            resizes: bs.resizes,
            pauses: bs.pauses,
            relation_grtt_s: relation,
            relation_error_s: settled_mean - relation,
            relation_mean_grtt_s: relation_mean,
            relation_mean_error_s: settled_mean - relation_mean,
            pred_nrtt_mae_s: self.nrtt_err.0 / n,
            pred_nrtt_rmse_s: (self.nrtt_err.1 / n).sqrt(),
            pred_mt_mae_s: self.mt_err.0 / n,
            pred_mt_rmse_s: (self.mt_err.1 / n).sqrt(),
            pred_count: self.pred_count,
            pred_horizon_s: (period * u64::from(base.predictor().config().horizon)).as_secs_f64(),
        };
        SimOutput {
            report,
            series: self.rows.unwrap_or_default(),
            forward: super::engine::ForwardLog::default(),
        }
    }
}
