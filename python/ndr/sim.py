"""The link in deterministic simulated time: ``ndr sim`` from Python.

::

    import ndr.sim

    result = ndr.sim.run(profile="lan-75km", mode="paper-dynamic", duration=120)
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
from typing import Dict, Optional

import numpy as np

from . import _native

__all__ = ["SimResult", "run", "PROFILES", "MODES", "PLAYOUTS", "UNDERFLOWS"]

#: The built-in delay profiles (``constant:MS`` also works, e.g. ``"constant:20"``).
PROFILES = ("paris-newyork", "lan-75km", "paper-fig6")
#: Regulation modes.
MODES = ("paper-static", "paper-dynamic")
#: Underflow policies.
UNDERFLOWS = ("hold", "drop-late")
#: Playout policies (``"fixed:MS"`` and ``"constant:MS"`` take a delay in ms).
PLAYOUTS = ("fifo", "ramjee-1", "ramjee-4", "neteq", "fixed", "constant:MS")


@dataclass(frozen=True)
class SimResult:
    """What a simulation gives.

    Attributes:
        summary: the report of ``ndr sim --json`` (times in seconds):
            ``nrtt_mean_s``, ``grtt_mean_s``, ``grtt_std_s``, end-to-end
            delays per direction, late rates, …
        series: one float64 array per base tick (empty unless ``series``
            was asked for): ``t``, ``period``, ``ns``, ``queue_base``,
            ``queue_remote``, ``nrtt``, ``nrtt_mean``, ``nrtt_ahead``,
            ``mt``, ``mt_ahead``, ``grtt``, ``e2e_fwd``, ``e2e_bwd``,
            ``truth_nrtt`` (``NaN`` where nothing was measured yet).
    """

    summary: Dict[str, object]
    series: Dict[str, np.ndarray]

    def __getitem__(self, key: str) -> object:
        """``result["grtt_std_s"]`` reads the summary."""
        return self.summary[key]


def run(
    profile: Optional[str] = None,
    *,
    trace: Optional[str] = None,
    dist: Optional[str] = None,
    mean: Optional[float] = None,
    std: Optional[float] = None,
    mode: str = "paper-static",
    playout: str = "fifo",
    underflow: str = "hold",
    period: float = 0.2,
    duration: float = 600.0,
    seed: int = 1,
    axes: int = 1,
    signal: str = "sine",
    series: bool = True,
) -> SimResult:
    """Runs one simulation, with the options of ``ndr sim``.

    Args:
        profile: a built-in delay profile (:data:`PROFILES`, or
            ``"constant:MS"``); the default is ``"paris-newyork"``.
        trace: instead, a delay trace CSV with header ``t_s,fwd_ms,bwd_ms``.
        dist: instead, an iproute2 netem table (``*.dist``), with ``mean``
            and ``std`` (seconds) of the one-way delay.
        mode: ``"paper-static"`` or ``"paper-dynamic"``.
        playout: both regulators' release policy: ``"fifo"`` (the paper's),
            ``"ramjee-1"``, ``"ramjee-4"``, ``"neteq"``, ``"fixed[:MS]"``,
            ``"constant:MS"``.
        underflow: ``"hold"`` or ``"drop-late"``.
        period: the sampling period, seconds (the paper's 0.2).
        duration: simulated time, seconds.
        seed: seed of every random draw.
        axes: axes of the teleoperated system, 1 to 8.
        signal: the operator's command: ``"sine[:amp=A,freq=F]"``,
            ``"steps[:low=L,high=H,period=P]"`` or ``"constant:V"``.
        series: keep the per-tick series (for plots).

    Raises:
        ValueError: an invalid option, an unreadable trace or table, or a
            link that failed during the run (the message says when and why).
    """
    summary, columns = _native.sim_run(
        profile=profile,
        trace=None if trace is None else str(trace),
        dist=None if dist is None else str(dist),
        mean=mean,
        std=std,
        mode=mode,
        playout=playout,
        underflow=underflow,
        period=period,
        duration=duration,
        seed=seed,
        axes=axes,
        signal=signal,
        series=series,
    )
    return SimResult(summary=json.loads(summary), series=dict(columns))
