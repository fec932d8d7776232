"""The link in deterministic simulated time: ``ndr sim`` from Python.

::

    import ndr.sim

    result = ndr.sim.run(profile="lan-75km", regulation="paper-dynamic", duration=120)
    print(result.summary["grtt_mean_s"], result.summary["grtt_std_s"])
    t, grtt = result.series["t"], result.series["grtt"]

Two endpoints (handshake, initialization pattern, regulators, network
predictor) exchange samples over two in-order simulated network paths, the
base's operator follows a signal and the remote runs the plant. Nothing
sleeps: twenty minutes at 200 ms take a few milliseconds. The same seed
gives the same result.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Dict, Mapping, Optional, TypedDict

import numpy as np
import numpy.typing as npt

from . import _native

__all__ = [
    "SimResult",
    "SimSummary",
    "run",
    "PROFILES",
    "REGULATIONS",
    "UNDERFLOWS",
]

#: The built-in delay profiles (``constant:MS`` also works, e.g. ``"constant:20"``).
PROFILES = ("paris-newyork", "lan-75km", "paper-fig6")
#: How the delay is regulated, each accepted as it is written here (the
#: names of ``ndr sim --regulation``, ``ndr.Link.connect(regulation=…)`` and
#: the reports' ``"regulation"``, from the playout registry of the Rust
#: core, :data:`ndr._native.REGULATION_NAMES`): ``"paper-static"`` (the paper's FIFO,
#: sized once; the simulator's default), ``"paper-dynamic"`` (resized as the
#: network changes), ``"ramjee-1"``, ``"ramjee-4"``, ``"neteq"``,
#: ``"fixed"`` (200 ms above the smallest delay seen) and ``"adaptive"`` (a
#: 0.1 % late rate). Three take a parameter: ``"fixed:MS"``,
#: ``"constant:MS"`` (a constant target delay of MS ms above the send time;
#: no bare ``"constant"``) and ``"adaptive:PERCENT"`` (a target late rate,
#: 0 < PERCENT < 100), e.g. ``"fixed:150"``, ``"constant:120"``,
#: ``"adaptive:0.5"``; ``"adaptive:PERCENT:QUANTUM_MS"`` also sets the step
#: the delay is held in (1 to 10 000 ms; by default the period up to
#: 20 ms, 1 ms at longer periods within a 20 ms dead band), e.g. ``"adaptive:0.1:10"``: a finer step holds a lower
#: delay that changes more often.
REGULATIONS: tuple[str, ...] = _native.REGULATIONS
#: Underflow policies.
UNDERFLOWS = ("hold", "drop-late")


class SimSummary(TypedDict):
    """The summary of a run (:attr:`SimResult.summary`): the report of
    ``ndr sim --json``, times in seconds, ``fwd`` base → remote (commands),
    ``bwd`` remote → base (states). ``None`` where nothing was measured:
    ``grtt_*`` without a GRTT (``grtt_count == 0``), ``settled_*`` without
    one since the last parameter change, ``pred_*`` without a forecast
    compared (``pred_count == 0``), ``e2e_*`` without a sample released,
    a side's ``queue_*`` without a running tick since the last parameter
    change, the ``relation_*`` without those, ``initial_ns`` before the
    first initialization pattern ends, ``remote_clock_offset_s`` before the
    remote has a clock estimate.
    """

    profile: str
    """The delay model's name."""
    regulation: str
    """How the delay was regulated (:data:`REGULATIONS`)."""
    mode: str
    """``"paper-static"`` or ``"paper-dynamic"``: a part of ``regulation``."""
    underflow: str
    """``"hold"`` or ``"drop-late"``."""
    playout: str
    """The regulators' playout policy, a part of ``regulation``: ``"fifo"``
    (the paper's queue) or the target-delay policy's name."""
    seed: int
    duration_s: float
    """Simulated time."""
    axes: int
    nrtt_mean_s: float
    """Network round trip measured by the base: mean (0 before the first)."""
    nrtt_std_s: float
    """Network round trip: standard deviation."""
    grtt_mean_s: Optional[float]
    """Round trip as the application sees it (both regulators): mean."""
    grtt_std_s: Optional[float]
    """GRTT standard deviation: the residual jitter a controller sees."""
    grtt_p99_s: Optional[float]
    """GRTT 99th percentile."""
    grtt_count: int
    """GRTTs measured."""
    settled_grtt_mean_s: Optional[float]
    """GRTT mean since the last parameter change (``grtt_mean_s`` in static mode)."""
    settled_grtt_std_s: Optional[float]
    """GRTT standard deviation since the last parameter change."""
    e2e_fwd_mean_s: Optional[float]
    """End-to-end delay of commands (release at the remote − send at the base): mean."""
    e2e_fwd_std_s: Optional[float]
    """End-to-end delay of commands: standard deviation."""
    e2e_bwd_mean_s: Optional[float]
    """End-to-end delay of states: mean."""
    e2e_bwd_std_s: Optional[float]
    """End-to-end delay of states: standard deviation."""
    late_rate_fwd: float
    """Late commands / commands received."""
    late_rate_bwd: float
    """Late states / states received."""
    ns: int
    """Nominal queue size at the end."""
    period_s: float
    """Period at the end."""
    initial_ns: Optional[int]
    """Nominal size chosen by the first initialization pattern."""
    queue_base_min: Optional[int]
    """Base regulator occupancy before a release, in the final regime: min."""
    queue_base_max: Optional[int]
    """Base regulator occupancy: max."""
    queue_base_mean: Optional[float]
    """Base regulator occupancy: mean."""
    queue_remote_min: Optional[int]
    """Remote regulator occupancy, in the final regime: min."""
    queue_remote_max: Optional[int]
    """Remote regulator occupancy: max."""
    queue_remote_mean: Optional[float]
    """Remote regulator occupancy: mean."""
    samples_sent: int
    """Samples sent, both directions."""
    samples_released: int
    """Samples released fresh, both directions."""
    late_samples: int
    """Late samples, both directions."""
    underflows: int
    """Underflows (ticks that repeated a sample), both directions."""
    rejected: int
    """Samples refused by a full regulator, both directions."""
    discarded: int
    """Samples discarded by pauses, or (adaptive playout under hold) held past
    their slot by an outage, both directions."""
    skipped: int
    """Samples skipped when a target delay fell by a tick at once, both directions."""
    link_lost: int
    """Watchdog alarms (no fresh sample for a second), both sides."""
    outage_delays: int
    """Adaptive playout: frames of outages left out of the delay window, both directions."""
    resizes: int
    """Parameter changes."""
    pauses: int
    """Pauses."""
    relation_grtt_s: Optional[float]
    """``2·max(s)·T + NRTT``, the paper's relation (``max(s)`` the larger
    regulator maximum of the final regime)."""
    relation_error_s: Optional[float]
    """Settled GRTT minus the relation's value."""
    relation_mean_grtt_s: Optional[float]
    """The relation with the mean occupancies, ``(s̄_base + s̄_remote)·T + NRTT``."""
    relation_mean_error_s: Optional[float]
    """Settled GRTT minus the mean-occupancy relation's value."""
    pred_nrtt_mae_s: Optional[float]
    """Forecasts of the mean NRTT against the measured one when that time
    came: mean absolute error."""
    pred_nrtt_rmse_s: Optional[float]
    """Same, root mean square."""
    pred_mt_mae_s: Optional[float]
    """Forecasts of ``mt`` against the measured ``mt``: mean absolute error."""
    pred_mt_rmse_s: Optional[float]
    """Same, root mean square."""
    pred_count: int
    """Forecasts compared."""
    pred_horizon_s: float
    """How far ahead the forecasts look, at the final period."""
    remote_clock_skew_ppm: float
    """The remote's estimate of the skew ``d(remote − base)/dt``, ppm."""
    remote_clock_offset_s: Optional[float]
    """The remote's estimate of ``remote − base`` clocks at the end."""
    base_clock_skew_ppm: float
    """The base's estimate of the skew ``d(base − remote)/dt``, ppm."""
    one_way_fwd_mean_s: float
    """Mean one-way delay base → remote as the remote estimates it."""
    one_way_bwd_mean_s: float
    """Mean one-way delay remote → base as the base estimates it."""
    delay_changes_fwd: int
    """Changes of the remote's playout delay (target policies)."""
    delay_events_fwd: int
    """``delay_changed`` events the remote's application received."""
    playout_delay_fwd_s: float
    """The remote's playout delay at the end (target policies)."""


@dataclass(frozen=True)
class SimResult:
    """What a simulation gives.

    Attributes:
        summary: the report of ``ndr sim --json`` (times in seconds; see
            :class:`SimSummary`): ``nrtt_mean_s``, ``grtt_mean_s``,
            ``grtt_std_s``, end-to-end delays per direction, late rates, …;
            ``None`` where nothing was measured (e.g. every ``grtt_*`` when
            ``grtt_count`` is 0).
        series: one float64 array per base tick (empty unless ``series``
            was asked for): ``t``, ``period``, ``ns``, ``queue_base``,
            ``queue_remote``, ``nrtt``, ``nrtt_mean``, ``nrtt_ahead``,
            ``mt``, ``mt_ahead``, ``grtt``, ``e2e_fwd``, ``e2e_bwd``,
            ``truth_nrtt`` (``NaN`` where nothing was measured yet).
    """

    summary: SimSummary
    series: Dict[str, npt.NDArray[np.float64]]

    def __getitem__(self, key: str) -> object:
        """``result["grtt_std_s"]`` reads the summary."""
        summary: Mapping[str, object] = self.summary
        return summary[key]


def run(
    profile: Optional[str] = None,
    *,
    trace: Optional[str] = None,
    dist: Optional[str] = None,
    mean: Optional[float] = None,
    std: Optional[float] = None,
    regulation: Optional[str] = None,
    underflow: str = "hold",
    period: float = 0.2,
    duration: float = 600.0,
    seed: int = 1,
    axes: int = 1,
    signal: str = "sine",
    series: bool = True,
    loss: str = "none",
    transport: str = "stream",
) -> SimResult:
    """Runs one simulation, with the options of ``ndr sim``.

    Args:
        profile: a built-in delay profile (:data:`PROFILES`, or
            ``"constant:MS"``); the default is ``"paris-newyork"``.
        trace: instead, a delay trace CSV with header ``t_s,fwd_ms,bwd_ms``.
        dist: instead, an iproute2 netem table (``*.dist``), with ``mean``
            and ``std`` (seconds) of the one-way delay.
        regulation: how both sides regulate the delay
            (:data:`REGULATIONS`): ``"paper-static"`` (the default),
            ``"paper-dynamic"``, ``"ramjee-1"``, ``"ramjee-4"``, ``"neteq"``,
            ``"fixed[:MS]"``, ``"constant:MS"`` or
            ``"adaptive[:PERCENT[:QUANTUM_MS]]"``.
        underflow: ``"hold"`` or ``"drop-late"``.
        period: the sampling period, seconds (the paper's 0.2).
        duration: simulated time, seconds.
        seed: seed of every random draw, an integer from 0 to 2**64 - 1.
        axes: axes of the teleoperated system, 1 to 256.
        signal: the operator's command: ``"sine[:amp=A,freq=F]"``,
            ``"steps[:low=L,high=H,period=P]"`` or ``"constant:V"``.
        series: keep the per-tick series (for plots).
        loss: packets lost each way, as ``ndr sim --loss``: ``"none"``,
            ``"PERCENT"`` (each independently, e.g. ``"1"``) or
            ``"ge:PERCENT:BURST"`` (Gilbert–Elliott bursts of ``BURST``
            packets on average). Over TCP a loss holds the stream back
            until it is repaired (RACK: about a period and a round trip;
            a retransmission lost again waits Linux's 200 ms timeout,
            doubled at each repeat).
        transport: ``"stream"`` (TCP, the paper's) or ``"datagram[:K[:R]]"``:
            each datagram carries the newest sample and copies of the
            ``K - 1`` before it (default 4) and is sent ``R`` more times 1 ms
            apart (default 3, as many as fit before the next sample), so a
            lost one is made good by a repeat or the next one's copies; the
            handshake stays on TCP. The link's names read too: ``"tcp"``,
            ``"udp[:K[:R]]"``, and ``"quic[:K[:R]]"``, simulated as its
            datagrams.

    Returns:
        A :class:`SimResult`; its ``summary`` holds ``None`` where nothing
        was measured (a run too short for a GRTT, a forecast, …).

    Raises:
        ValueError: an invalid option, an unreadable trace or table, or a link that
            failed during the run (the message says when and why).
    """
    summary, columns = _native.sim_run(
        profile=profile,
        trace=None if trace is None else str(trace),
        dist=None if dist is None else str(dist),
        mean=mean,
        std=std,
        regulation=regulation,
        underflow=underflow,
        period=period,
        duration=duration,
        seed=seed,
        axes=axes,
        signal=signal,
        series=series,
        loss=loss,
        transport=transport,
    )
    parsed: SimSummary = json.loads(summary)
    return SimResult(summary=parsed, series=dict(columns))
