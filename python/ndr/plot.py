"""The paper's figures from a simulation (matplotlib, an optional extra:
``pip install 'ndr[plot]'``).

::

    import ndr.sim, ndr.plot

    result = ndr.sim.run(profile="paper-fig6", regulation="paper-dynamic", duration=1200)
    fig = ndr.plot.predictions(result)
    fig.savefig("fig8-9.png")

- :func:`round_trips`: NRTT against GRTT over time (the paper's Fig. 5);
- :func:`predictions`: the network predictor's mean NRTT and ``mt``, measured
  and forecast (Figs. 8 and 9);
- :func:`queues`: the regulators' occupancy and nominal size;
- :func:`compare`: delay against late rate, one point per playout policy,
  from ``ndr compare --json``;
- :func:`demo`: a real run's series (the CSV ``ndr demo``, ``ndr base`` and
  ``python -m ndr demo`` write, or an MCAP recording: ``--record``,
  ``record=``): NRTT against GRTT, and the operator's command against the
  robot's state as the base saw it. From a shell:
  ``python -m ndr plot ndr-demo.csv`` (writes ``ndr-demo.png``), or
  ``python -m ndr plot x.mcap -o x.png``.

Each function takes a :class:`~ndr.sim.SimResult` (or its ``series`` dict),
draws on ``ax`` when given (else on a new figure) and returns the figure.
"""

from __future__ import annotations

import json
import math
from typing import Any, Dict, List, Mapping, Optional, Tuple, Union

import numpy as np

__all__ = [
    "compare",
    "demo",
    "predictions",
    "queues",
    "read_series",
    "round_trips",
    "series_from_recording",
]


def _pyplot() -> Any:
    try:
        import matplotlib.pyplot as plt  # type: ignore[import-not-found,unused-ignore]
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError(
            "ndr.plot needs matplotlib: pip install 'ndr[plot]' (or pip install matplotlib)"
        ) from e
    return plt


def _series(result: Any) -> Mapping[str, np.ndarray]:
    series = getattr(result, "series", result)
    if not isinstance(series, Mapping) or "t" not in series:
        raise ValueError(
            "expected a SimResult from ndr.sim.run(..., series=True) or its series dict"
        )
    if len(series["t"]) == 0:
        raise ValueError("the result has no series: run ndr.sim.run(..., series=True)")
    return series


def _axes(ax: Any, rows: int = 1) -> Tuple[Any, List[Any]]:
    plt = _pyplot()
    if ax is not None:
        axes = ax if rows > 1 else [ax]
        return axes[0].figure, list(axes)
    fig, axes = plt.subplots(
        rows, 1, sharex=True, figsize=(8, 3 * rows), squeeze=False, constrained_layout=True
    )
    return fig, list(axes[:, 0])


def round_trips(result: Any, ax: Any = None) -> Any:
    """NRTT (the network) against GRTT (as the controller sees it), in
    seconds against time: the paper's Fig. 5."""
    s = _series(result)
    fig, (a,) = _axes(ax)
    a.plot(s["t"], s["nrtt"], lw=0.6, color="0.6", label="NRTT")
    a.plot(s["t"], s["grtt"], lw=1.5, color="C0", label="GRTT")
    a.set_xlabel("time (s)")
    a.set_ylabel("round trip (s)")
    a.legend(loc="upper right")
    a.set_title("Network round trip against the regulated round trip")
    return fig


def predictions(result: Any, ax: Any = None) -> Any:
    """The network predictor: mean NRTT and ``mt``, measured and forecast
    ``horizon`` periods ahead (the paper's Figs. 8 and 9). ``ax``, when
    given, is a pair of axes."""
    s = _series(result)
    fig, (a, b) = _axes(ax, rows=2)
    if np.isfinite(s["truth_nrtt"]).any():
        a.plot(s["t"], s["truth_nrtt"], lw=1, color="0.3", ls="--", label="generating mean")
    a.plot(s["t"], s["nrtt_mean"], lw=1, color="C0", label="measured mean NRTT")
    a.plot(s["t"], s["nrtt_ahead"], lw=1, color="C1", label="forecast")
    a.set_ylabel("mean NRTT (s)")
    a.legend(loc="upper right")
    b.plot(s["t"], s["mt"], lw=1, color="C0", label="measured mt")
    b.plot(s["t"], s["mt_ahead"], lw=1, color="C1", label="forecast")
    b.set_ylabel("mt (s)")
    b.set_xlabel("time (s)")
    b.legend(loc="upper right")
    return fig


def queues(result: Any, ax: Any = None) -> Any:
    """The regulators' occupancy before each release, and the nominal size."""
    s = _series(result)
    fig, (a,) = _axes(ax)
    a.step(s["t"], s["queue_base"], where="post", lw=0.8, label="base")
    a.step(s["t"], s["queue_remote"], where="post", lw=0.8, label="remote")
    a.step(s["t"], s["ns"], where="post", lw=1.5, color="k", label="ns")
    a.set_xlabel("time (s)")
    a.set_ylabel("samples in the queue")
    a.legend(loc="upper right")
    return fig


def compare(report: Union[str, Mapping[str, Any]], ax: Any = None, *, family: Optional[str] = None) -> Any:
    """Mean end-to-end delay against late rate, one point per regulation
    (the oracles as crosses), from the JSON of ``ndr compare --json``
    (schema ``ndr-compare/2``, or ``/1`` whose ``policies`` it renamed: a
    dict, a JSON string or a file path).
    ``family`` picks one trace family by name; by default, the first. Late
    rates of zero are drawn at 1e-6 on the log axis."""
    data = _load(report)
    points = _regulation_points(data, family)
    fig, (a,) = _axes(ax)
    for name, delay, late in points:
        marker = "x" if name.startswith("oracle") else "o"
        a.scatter([max(late, 1e-6)], [delay * 1e3], label=name, marker=marker)
        a.annotate(name, (max(late, 1e-6), delay * 1e3), fontsize=7, xytext=(3, 3),
                   textcoords="offset points")
    a.set_xscale("log")
    a.set_xlabel("late rate")
    a.set_ylabel("mean end-to-end delay (ms)")
    a.set_title(f"Regulations: delay against late rate ({points.family})")
    return fig


#: The columns a run's series must have (``ndr demo``'s CSV; more are allowed).
SERIES_COLUMNS = ("t_s", "grtt_s", "nrtt_s", "command", "state")


def read_series(path: str) -> Dict[str, np.ndarray]:
    """A run's CSV series (``ndr demo --out``, ``ndr base --out``,
    ``python -m ndr demo --out``) as one float array per column, an empty
    field as NaN. Raises ``ValueError`` naming the file and what it lacks."""
    with open(path, encoding="utf-8") as f:
        header = f.readline().strip().split(",")
        missing = [c for c in SERIES_COLUMNS if c not in header]
        if missing:
            raise ValueError(
                f"{path} is not a run's series: no column {', '.join(missing)} in its "
                f"header {','.join(header)!r} (write one with ndr demo --out FILE.csv)"
            )
        columns: Dict[str, List[float]] = {c: [] for c in header}
        for line_no, line in enumerate(f, start=2):
            fields = line.rstrip("\n").split(",")
            if len(fields) != len(header):
                raise ValueError(
                    f"{path}, line {line_no}: {len(fields)} fields where the header has "
                    f"{len(header)}"
                )
            for name, value in zip(header, fields):
                if name == "status":
                    columns[name].append(1.0 if value == "held" else 0.0)
                    continue
                try:
                    columns[name].append(float(value) if value else math.nan)
                except ValueError:
                    raise ValueError(
                        f"{path}, line {line_no}: {name} is {value!r}, not a number"
                    ) from None
    return {name: np.asarray(values, dtype=float) for name, values in columns.items()}


def _is_mcap(path: str) -> bool:
    with open(path, "rb") as f:
        return f.read(8) == b"\x89MCAP0\r\n"


def series_from_recording(recording: Any) -> Dict[str, np.ndarray]:
    """The series of :func:`read_series` from a recording (a path, or
    :func:`ndr.read_recording`'s result): one row per state released to the
    base (``/ndr/state``), ``t_s`` from the first, ``command`` the command
    the remote had released last at that time (NaN without ``/ndr/command``),
    ``state`` the state's first value."""
    if isinstance(recording, str):
        from .recording import read_recording

        recording = read_recording(recording)
    states = recording.get("/ndr/state")
    if not states or len(states["log_time"]) == 0:
        raise ValueError("the recording has no state released to a base (/ndr/state)")
    t = states["log_time"]
    keep = states["status"] != "late"
    values = states.get("values", {})
    first = next(iter(values.values()), np.full(len(t), np.nan))
    commands = recording.get("/ndr/command")
    command = np.full(len(t), np.nan)
    if commands and len(commands["log_time"]) and commands.get("values"):
        ct = commands["log_time"]
        cv = next(iter(commands["values"].values()))
        ok = commands["status"] != "late"
        ct, cv = ct[ok], cv[ok]
        i = np.searchsorted(ct, t, side="right") - 1
        command = np.where(i >= 0, cv[np.clip(i, 0, None)], np.nan)
    return {
        "t_s": (t - t[0])[keep],
        "seq": states["seq"][keep],
        "status": (states["status"] == "repeated").astype(float)[keep],
        "grtt_s": states.get("grtt_s", np.full(len(t), np.nan))[keep],
        "nrtt_s": states.get("nrtt_s", np.full(len(t), np.nan))[keep],
        "command": command[keep],
        "state": first[keep],
    }


def demo(series: Union[str, Mapping[str, np.ndarray]], ax: Any = None) -> Any:
    """A real run, as the paper draws it (Figs. 4 and 5): above, the
    network's round trip (NRTT, jittery) against the round trip the
    controller sees (GRTT, constant), in milliseconds; below, the operator's
    command against the robot's state as the base saw it. ``series`` is a
    CSV path, an MCAP recording's path (:func:`series_from_recording`) or
    :func:`read_series`'s dict; ``ax``, two axes to draw on."""
    s: Mapping[str, np.ndarray]
    if isinstance(series, str):
        s = series_from_recording(series) if _is_mcap(series) else read_series(series)
    else:
        s = series
    if len(s["t_s"]) == 0:
        raise ValueError("the series has no rows: the run released no sample")
    fig, (top, bottom) = _axes(ax, rows=2)
    t = s["t_s"]
    top.plot(t, s["nrtt_s"] * 1e3, lw=0.6, color="0.6", label="NRTT (network)")
    top.plot(t, s["grtt_s"] * 1e3, lw=1.5, color="C0", label="GRTT (regulated)")
    top.set_ylabel("round trip (ms)")
    top.set_ylim(bottom=0)
    top.legend(loc="center right")
    top.set_title("The network's round trip against the one the controller sees")
    bottom.plot(t, s["command"], lw=1.0, color="C1", label="command (operator)")
    bottom.plot(t, s["state"], lw=1.0, color="C2", label="state (robot, as seen)")
    bottom.set_xlabel("time (s)")
    bottom.set_ylabel("axis 0")
    bottom.legend(loc="upper right")
    return fig


class _Points(List[Tuple[Any, ...]]):
    family: str = ""


def _load(report: Union[str, Mapping[str, Any]]) -> Mapping[str, Any]:
    if isinstance(report, Mapping):
        return report
    text = str(report)
    loaded: Mapping[str, Any]
    if text.lstrip().startswith("{"):
        loaded = json.loads(text)
    else:
        with open(text, encoding="utf-8") as f:
            loaded = json.load(f)
    return loaded


def _regulation_points(data: Mapping[str, Any], family: Optional[str]) -> _Points:
    families = data.get("families")
    if not families:
        raise ValueError("not an `ndr compare --json` report: it has no \"families\"")
    if isinstance(families, Mapping):
        names = list(families)
        chosen = family or names[0]
        if chosen not in families:
            raise ValueError(f"no family {chosen!r} in the report; it has {names}")
        fam = families[chosen]
    else:
        by_name = {f.get("name"): f for f in families}
        chosen = family or next(iter(by_name))
        if chosen not in by_name:
            raise ValueError(f"no family {chosen!r} in the report; it has {list(by_name)}")
        fam = by_name[chosen]
    # `policies` and `policy`: schema ndr-compare/1's names.
    rows = (fam.get("regulations") or fam.get("policies")) if isinstance(fam, Mapping) else None
    if not rows:
        raise ValueError(f"family {chosen!r} has no regulations")
    out = _Points()
    out.family = str(chosen)
    if isinstance(rows, Mapping):
        items = list(rows.items())
    else:
        items = [(p.get("regulation", p.get("policy", p.get("name"))), p) for p in rows]
    for name, p in items:
        point = p.get("point") or {}
        delay = point.get("mean_delay_s", _mean(p, "mean_delay_s"))
        late = point.get("late_rate", _mean(p, "late_rate"))
        if delay is None or late is None:
            continue  # every run of this regulation failed
        out.append((str(name), float(delay), float(late)))
    return out


def _mean(p: Mapping[str, Any], key: str) -> Optional[float]:
    if key not in p:
        raise ValueError(f"a regulation entry has no {key!r}: not an `ndr compare --json` report")
    v = p[key]
    if isinstance(v, Mapping):
        v = v.get("mean")
    return None if v is None else float(v)
