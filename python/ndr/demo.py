"""``python -m ndr demo``: the whole link for real, in one process.

The same main job as ``ndr demo``, written with the Python API: a remote
whose controller runs the simulated plant, a delaying relay, and a base
whose operator follows a signal while an :class:`~ndr.Estimator` identifies
the plant and estimates its current state (``x3e``) from the delayed
feedback. It ends with a table (or one JSON object) of what it measured.

It is also a worked example: :func:`robot` and :func:`operator` are the two
controllers a user writes.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from typing import (
    Any,
    Callable,
    Dict,
    List,
    Mapping,
    Optional,
    Sequence,
    TextIO,
    Tuple,
    TypedDict,
)

import numpy as np

from . import _native
from ._native import Estimator, LinkError, Relay, Signal, Tf2, Tf2State, TlsConfig
from .link import Link, LinkStats, RelayStats, _is_normal_end

__all__ = ["DemoResult", "operator", "robot", "run", "main"]

#: The simulated plant: a slow arm axis (natural frequency, damping, gain).
PLANT = (0.5, 0.7, 1.0)


def plant_model(period: float) -> Tf2:
    """The plant discretized at ``period`` (Tustin), as ``ndr sim`` uses it."""
    hz, zeta, gain = PLANT
    return Tf2.low_pass(2 * math.pi * hz, zeta, gain, period)


@dataclass
class RobotLog:
    """What the remote did: the true state after each tick (monotonic time)."""

    t: List[float] = field(default_factory=list)
    state: List[float] = field(default_factory=list)
    stats: Optional[LinkStats] = None
    error: Optional[str] = None


def robot(link: Link, stop: threading.Event, log: RobotLog) -> None:
    """The remote's controller: each released command drives the plant (one
    second-order system per axis), and the new state is sent back."""
    plants = [Tf2State(plant_model(link.period)) for _ in range(link.axes)]
    state = np.zeros(link.axes)
    try:
        while not stop.is_set():
            try:
                tick = link.recv(timeout=0.2)
            except TimeoutError:
                continue
            command = tick.sample
            for i, p in enumerate(plants):
                state[i] = p.step(command[i])
            log.t.append(time.monotonic())
            log.state.append(float(state[0]))
            link.send(state)
            for e in link.events():
                # At the start, and again after a pause of the dynamic mode.
                if e.kind == "started" and e.period:
                    model = plant_model(e.period)
                    for p in plants:
                        p.model = model
    except LinkError as e:
        if not _is_normal_end(e):
            log.error = str(e)
    finally:
        log.stats = link.stats
        link.close()


@dataclass
class OperatorLog:
    """What the base saw, one row per released state."""

    t: List[float] = field(default_factory=list)
    mono: List[float] = field(default_factory=list)
    #: When the hub released each state (its clock, seconds).
    released_at: List[float] = field(default_factory=list)
    seq: List[int] = field(default_factory=list)
    held: List[bool] = field(default_factory=list)
    grtt: List[float] = field(default_factory=list)
    #: The network's round trip last measured by the base (seconds; NaN before the first).
    nrtt: List[float] = field(default_factory=list)
    command: List[float] = field(default_factory=list)
    state: List[float] = field(default_factory=list)
    x3e: List[float] = field(default_factory=list)
    stats: Optional[LinkStats] = None


def _delays(grtt: float, period: float) -> Tuple[int, int]:
    """The estimator's one-way delays in ticks, from the GRTT: the link's
    round trip is a whole number of ticks, split evenly (the paper's
    assumption). The GRTT counts the tick a remote that answers from its own
    thread waits before its answer leaves (the frame names the command its
    state answers), so nothing is added to it."""
    k = max(int(round(grtt / period)), 0)
    fwd = k // 2
    return fwd, k - fwd


def operator(
    link: Link,
    duration: float,
    signal: Signal,
    *,
    status: Optional[Callable[[float, Link, OperatorLog], object]] = None,
) -> OperatorLog:
    """The base's controller: sends the operator's command each tick, and
    estimates the remote's current state from the delayed feedback."""
    log = OperatorLog()
    start = time.monotonic()
    command = np.zeros(link.axes)
    estimator: Optional[Estimator] = None
    next_status = start
    while True:
        now = time.monotonic()
        t = now - start
        if t >= duration:
            break
        for axis in range(link.axes):
            command[axis] = signal(t, axis)
        link.send(command)
        try:
            tick = link.recv(timeout=0.5)
        except TimeoutError:
            continue
        for e in link.events():
            if e.kind == "started":
                estimator = None  # after a pause, a new period: new delays in ticks
        held = tick.status == "held"
        if estimator is None and tick.grtt is not None:
            stats = link.stats
            period = link.period if stats is None else stats["period"]
            fwd, bwd = _delays(tick.grtt, period)
            estimator = Estimator(fwd, bwd, dt=period, lam=0.999)
        y = float(tick.sample[0])
        x3e = math.nan
        if estimator is not None:
            x3e, _x3p, from_model = estimator.step(float(command[0]), None if held else y)
            if not from_model:
                x3e = math.nan
        log.t.append(t)
        log.mono.append(time.monotonic())
        log.released_at.append(tick.released_at)
        log.seq.append(tick.seq)
        log.held.append(held)
        log.grtt.append(math.nan if tick.grtt is None else tick.grtt)
        stats_now = link.stats
        nrtt = None if stats_now is None else stats_now["last_nrtt"]
        log.nrtt.append(math.nan if nrtt is None else nrtt)
        log.command.append(float(command[0]))
        log.state.append(y)
        log.x3e.append(x3e)
        if status is not None and now >= next_status:
            next_status += 0.25
            status(t, link, log)
    log.stats = link.stats
    link.close()
    return log


def tracking_errors(op: OperatorLog, rb: RobotLog, *, after: float = 0.5) -> Dict[str, Any]:
    """How well the base knows the remote's current state, over the last
    ``1 - after`` of the run: the RMS error of ``x3e`` and of the delayed
    state it receives, against the true state at the same instant."""
    if not rb.t or not op.mono:
        return {"x3e_rms_error": math.nan, "delayed_rms_error": math.nan, "compared": 0}
    rt = np.asarray(rb.t)
    truth_at = np.asarray(rb.state)
    mono = np.asarray(op.mono)
    keep = mono >= mono[0] + after * (mono[-1] - mono[0])
    idx = np.searchsorted(rt, mono[keep], side="right") - 1
    ok = idx >= 0
    truth = truth_at[idx[ok]]
    x3e = np.asarray(op.x3e)[keep][ok]
    y = np.asarray(op.state)[keep][ok]
    valid = np.isfinite(x3e)
    if not valid.any():
        return {"x3e_rms_error": math.nan, "delayed_rms_error": math.nan, "compared": 0}

    def rms(e: "np.ndarray[Any, Any]") -> float:
        return float(np.sqrt(np.mean(np.square(e))))

    return {
        "x3e_rms_error": rms(x3e[valid] - truth[valid]),
        "delayed_rms_error": rms(y[valid] - truth[valid]),
        "compared": int(valid.sum()),
    }


@dataclass
class DemoResult:
    """The demo's report (``report``, what ``--json`` prints, its keys
    those of ``ndr demo --json``: ``wakes_late``, for one, the wakes of
    both hubs for a deadline 1 ms late or more) and both logs."""

    report: Dict[str, Any]
    operator: OperatorLog
    robot: RobotLog


def _status_line(t: float, link: Link, log: OperatorLog) -> None:
    s: Mapping[str, Any] = link.stats or {}
    nrtt = s.get("last_nrtt")
    grtt = next((g for g in reversed(log.grtt[-50:]) if not math.isnan(g)), math.nan)

    def ms(x: Optional[float]) -> str:
        return "–" if x is None or math.isnan(x) else f"{x * 1e3:.1f} ms"

    sys.stderr.write(
        f"\r\x1b[2K  t {t:5.1f} s · {s.get('phase', 'starting'):<9} · NRTT {ms(nrtt):>9} · "
        f"GRTT {ms(grtt):>9} · queue {s.get('queue_len', 0):>3} · "
        f"underflows {s.get('underflows', 0)} "
    )
    sys.stderr.flush()


class _Settings(TypedDict):
    """The link settings both sides of the demo share."""

    axes: int
    period: float
    regulation: str
    underflow: str
    transport: str


def run(
    *,
    profile: str = "lan-75km",
    period: float = 0.05,
    duration: float = 20.0,
    regulation: Optional[str] = None,
    underflow: str = "hold",
    axes: int = 1,
    seed: int = 1,
    signal: str = "sine",
    out: Optional[str] = "ndr-demo.csv",
    live: bool = False,
    transport: str = "udp",
) -> DemoResult:
    """Runs the demo and returns what it measured (nothing is printed but
    the live status line when ``live``). ``regulation`` and ``transport``
    are those of :meth:`ndr.Link.connect`, on both sides: ``"adaptive"``
    by default, and ``"udp"`` (both ends are on loopback; a link's own
    default is ``"tcp"``)."""
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"duration must be a positive number of seconds, got {duration}")
    name, _, playout = _native._regulation(regulation=regulation, default="adaptive")
    sig = Signal(signal)
    settings = _Settings(
        axes=axes,
        period=period,
        regulation=name,
        underflow=underflow,
        transport=transport,
    )
    loopback = ("127.0.0.1", 0)
    rb = RobotLog()
    stop = threading.Event()
    # Over QUIC, each side gets a throwaway identity pinned by the other.
    base_tls, remote_tls = _throwaway_pair() if transport.startswith("quic") else (None, None)
    with Link.listen(
        loopback, tls=remote_tls, **settings
    ) as listener, Relay(
        loopback, listener.address, profile=profile, seed=seed
    ) as relay:
        accepted: List[Link] = []

        def serve() -> None:
            try:
                link = listener.accept(timeout=10.0)
            except (TimeoutError, LinkError) as e:
                rb.error = str(e)
                return
            accepted.append(link)
            robot(link, stop, rb)

        remote = threading.Thread(target=serve, name="ndr-demo-robot", daemon=True)
        remote.start()
        try:
            base = Link.connect(relay.address, tls=base_tls, **settings)
            with base:
                op = operator(base, duration, sig, status=_status_line if live else None)
        finally:
            stop.set()
            remote.join(timeout=5.0)
        if live:
            sys.stderr.write("\n")
        relay_stats = relay.stats
    if out:
        _write_csv(out, op)
    report = _report(
        profile=relay.model,
        regulation=name,
        playout=playout,
        underflow=underflow,
        transport=transport,
        duration=duration,
        axes=axes,
        op=op,
        rb=rb,
        relay=relay_stats,
        out=out,
    )
    return DemoResult(report=report, operator=op, robot=rb)


def _throwaway_pair() -> Tuple[TlsConfig, TlsConfig]:
    """TLS for a base and a remote that trust each other's certificate
    only, made for this run (the files are gone once loaded)."""
    with tempfile.TemporaryDirectory(prefix="ndr-demo-quic-") as d:
        base_cert, base_key, _ = _native.keygen(d, "base")
        remote_cert, remote_key, _ = _native.keygen(d, "remote")
        return (
            TlsConfig(base_cert, base_key, peer_cert=remote_cert),
            TlsConfig(remote_cert, remote_key, peer_cert=base_cert),
        )


def _write_csv(path: str, op: OperatorLog) -> None:
    with open(path, "w", encoding="utf-8") as f:
        f.write("t_s,seq,status,grtt_s,nrtt_s,command,state,x3e\n")
        for row in zip(op.t, op.seq, op.held, op.grtt, op.nrtt, op.command, op.state, op.x3e):
            t, seq, held, grtt, nrtt, u, y, x = row
            g, n, xe = ("" if math.isnan(v) else f"{v:.6f}" for v in (grtt, nrtt, x))
            f.write(f"{t:.6f},{seq},{'held' if held else 'fresh'},{g},{n},{u:.6f},{y:.6f},{xe}\n")


def _report(
    *,
    profile: str,
    regulation: str,
    playout: str,
    underflow: str,
    transport: str,
    duration: float,
    axes: int,
    op: OperatorLog,
    rb: RobotLog,
    relay: RelayStats,
    out: Optional[str],
) -> Dict[str, Any]:
    b: Mapping[str, Any] = op.stats or {}
    r: Mapping[str, Any] = rb.stats or {}
    grtts = np.asarray([g for g in op.grtt if not math.isnan(g)])
    qb = b.get("queue_range") or (0, 0)
    qr = r.get("queue_range") or (0, 0)

    def get(s: Mapping[str, Any], k: str) -> Any:
        return s.get(k, 0)

    report = {
        "command": "python demo",
        "profile": profile,
        "regulation": regulation,
        "playout": playout,
        "underflow": underflow,
        "transport": transport,
        "period_s": b.get("period", 0.0),
        "duration_s": duration,
        "axes": axes,
        "ns": b.get("ns", 0),
        "nrtt_mean_s": b.get("nrtt", {}).get("mean", math.nan),
        "nrtt_std_s": b.get("nrtt", {}).get("std", math.nan),
        "grtt_mean_s": float(grtts.mean()) if grtts.size else math.nan,
        "grtt_std_s": float(grtts.std()) if grtts.size else math.nan,
        "grtt_p99_s": float(np.percentile(grtts, 99)) if grtts.size else math.nan,
        "grtt_count": int(grtts.size),
        "queue_base_min": qb[0],
        "queue_base_max": qb[1],
        "queue_remote_min": qr[0],
        "queue_remote_max": qr[1],
        "samples_sent": get(b, "samples_sent") + get(r, "samples_sent"),
        "samples_released": get(b, "released_fresh") + get(r, "released_fresh"),
        "late_samples": get(b, "late") + get(r, "late"),
        "samples_lost": get(b, "samples_lost") + get(r, "samples_lost"),
        "samples_recovered": get(b, "samples_recovered") + get(r, "samples_recovered"),
        "samples_from_repeats": get(b, "samples_from_repeats") + get(r, "samples_from_repeats"),
        "datagrams_repeated": get(b, "datagrams_repeated") + get(r, "datagrams_repeated"),
        "underflows": get(b, "underflows") + get(r, "underflows"),
        "link_lost": get(b, "link_lost") + get(r, "link_lost"),
        "pauses": get(b, "pauses"),
        "clock_base_p50_s": b.get("lateness", {}).get("p50", math.nan),
        "clock_base_p99_s": b.get("lateness", {}).get("p99", math.nan),
        "clock_remote_p50_s": r.get("lateness", {}).get("p50", math.nan),
        "clock_remote_p99_s": r.get("lateness", {}).get("p99", math.nan),
        "clock_base_max_s": b.get("lateness", {}).get("max", math.nan),
        "clock_remote_max_s": r.get("lateness", {}).get("max", math.nan),
        "spin_margin_base_s": b.get("spin_margin", math.nan),
        "spin_margin_remote_s": r.get("spin_margin", math.nan),
        # The wakes of both hubs for a deadline 1 ms late or more (their
        # `lateness.missed`): the host's doing, as `ndr demo --json` has it.
        "wakes_late": b.get("lateness", {}).get("missed", 0)
        + r.get("lateness", {}).get("missed", 0),
        # What a target-delay playout holds, and the clock estimate under it
        # (the names of `ndr demo --json`).
        "playout_delay_fwd_s": r.get("playout_delay", math.nan),
        "playout_delay_bwd_s": b.get("playout_delay", math.nan),
        "delay_changes_fwd": get(r, "delay_changes"),
        "delay_changes_bwd": get(b, "delay_changes"),
        "one_way_fwd_mean_s": r.get("one_way_rx", {}).get("mean", math.nan),
        "one_way_bwd_mean_s": b.get("one_way_rx", {}).get("mean", math.nan),
        "remote_clock_offset_s": r.get("clock_offset", math.nan),
        "remote_clock_skew_ppm": r.get("clock_skew_ppm", math.nan),
        "relay_frames_fwd": relay["forward"]["frames_delivered"],
        "relay_frames_bwd": relay["backward"]["frames_delivered"],
        "robot_error": rb.error,
        "csv": out,
    }
    report.update(tracking_errors(op, rb))
    return report


def print_table(r: Dict[str, Any], file: Optional[TextIO] = None) -> None:
    """The report as the CLI prints it (to ``file``, standard output by default)."""
    out = sys.stdout if file is None else file

    def ms(s: float) -> str:
        return f"{s * 1e3:.2f} ms"

    def us(s: float) -> str:
        return f"{s * 1e6:.0f} µs"

    def p(*a: object) -> None:
        print(*a, file=out)

    # The same labels, in the same order, as the Rust CLI's header.
    p(
        f"ndr {r['command']} · {r['profile']} · {r['regulation']} · {r['underflow']} · "
        f"{r['transport']} · T = {ms(r['period_s'])} · {r['duration_s']:.0f} s · "
        f"{r['axes']} axis(es)"
    )
    p("                     mean          std")
    p(f"  NRTT       {ms(r['nrtt_mean_s']):>12} {ms(r['nrtt_std_s']):>12}   (the network, both ways)")
    p(
        f"  GRTT       {ms(r['grtt_mean_s']):>12} {ms(r['grtt_std_s']):>12}   (as the controller "
        f"sees it; p99 {ms(r['grtt_p99_s'])}, {r['grtt_count']} round trips)"
    )
    p(
        f"  queues     ns {r['ns']} · base {r['queue_base_min']}–{r['queue_base_max']} · remote "
        f"{r['queue_remote_min']}–{r['queue_remote_max']} (occupancy before a release)"
    )
    p(
        f"  samples    {r['samples_sent']} sent · {r['samples_released']} released · "
        f"{r['late_samples']} late · {r['underflows']} underflows · {r['link_lost']} link-lost alarms"
    )
    if r["playout"] != "fifo":
        p(
            f"  playout    delay {ms(r['playout_delay_fwd_s'])} forward · "
            f"{ms(r['playout_delay_bwd_s'])} back · delays announced {r['delay_changes_fwd']} / "
            f"{r['delay_changes_bwd']} (network one-way {ms(r['one_way_fwd_mean_s'])} / "
            f"{ms(r['one_way_bwd_mean_s'])}; remote clock {r['remote_clock_offset_s'] * 1e3:+.3f} ms, "
            f"{r['remote_clock_skew_ppm']:+.1f} ppm)"
        )
    p(
        f"  clock      release lateness p50 / p99: base {us(r['clock_base_p50_s'])} / "
        f"{us(r['clock_base_p99_s'])} · remote {us(r['clock_remote_p50_s'])} / {us(r['clock_remote_p99_s'])} "
        f"(spin margin learned {us(r['spin_margin_base_s'])} / {us(r['spin_margin_remote_s'])})"
    )
    p(f"  relay      {r['relay_frames_fwd']} frames forward, {r['relay_frames_bwd']} back")
    p(
        f"  estimator  x3e RMS error {r['x3e_rms_error']:.4f} against {r['delayed_rms_error']:.4f} "
        f"for the delayed state (second half, {r['compared']} ticks)"
    )
    if r.get("csv"):
        p(f"  series     {r['csv']}")


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m ndr demo [options]``: the options of ``ndr demo``."""
    parser = argparse.ArgumentParser(
        prog="python -m ndr demo",
        description="The whole link in one process: a remote with the simulated plant, "
        "a delaying relay, and a base whose operator follows a signal.",
    )
    parser.add_argument("--profile", default="lan-75km", help="delay profile of the relay "
                        "(paris-newyork, lan-75km, paper-fig6, constant:MS)")
    parser.add_argument("--period-ms", type=float, default=50.0, help="sampling period, ms")
    parser.add_argument("--duration-s", type=float, default=20.0, help="how long to run, s")
    parser.add_argument("--regulation", default=None,
                        help=f"how the delay is regulated: {_native.REGULATION_NAMES}")
    parser.add_argument("--underflow", default="hold", choices=("hold", "drop-late"))
    parser.add_argument("--transport", default="udp", help="how samples cross: tcp (the "
                        "paper's stream), udp[:K[:R]] (the default: datagrams of the newest "
                        "sample and K - 1 copies, 4 by default, sent R more times 1 ms apart, 3 "
                        "by default, while the peer reports losses) "
                        "or quic[:K[:R]] (the same over QUIC, under mutual TLS 1.3 with a "
                        "throwaway pair of certificates)")
    parser.add_argument("--axes", type=int, default=1, help="axes of the system (1 to 256)")
    parser.add_argument("--seed", type=int, default=1, help="seed of the relay's delays")
    parser.add_argument("--signal", default="sine", help="the operator's command: "
                        "sine[:amp=A,freq=F], steps[:low=L,high=H,period=P], constant:V")
    parser.add_argument("--out", default="ndr-demo.csv", help="where to write the base's series (CSV)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    # Checked here, in the unit given: the link would report seconds.
    if not (math.isfinite(args.period_ms) and args.period_ms > 0):
        parser.error(
            f"--period-ms must be a positive number of milliseconds, got {args.period_ms:g}"
        )
    if not (math.isfinite(args.duration_s) and args.duration_s > 0):
        parser.error(f"--duration-s must be a positive number of seconds, got {args.duration_s:g}")
    try:
        name, _, _ = _native._regulation(regulation=args.regulation, default="adaptive")
    except ValueError as e:
        parser.error(str(e))
    if not args.json:
        # Said up front, as the Rust CLI does: the file lands in the current
        # directory by default.
        print(
            f"ndr python demo: the base's series goes to {args.out} (--out to change it)",
            file=sys.stderr,
        )
    try:
        result = run(
            profile=args.profile,
            period=args.period_ms / 1e3,
            duration=args.duration_s,
            regulation=name,
            underflow=args.underflow,
            axes=args.axes,
            seed=args.seed,
            signal=args.signal,
            out=args.out,
            live=not args.json and sys.stderr.isatty(),
            transport=args.transport,
        )
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(_finite(result.report), allow_nan=False))
    else:
        print_table(result.report)
    return 0


def _finite(report: Dict[str, Any]) -> Dict[str, Any]:
    """NaN (nothing measured) becomes JSON's null."""
    return {k: None if isinstance(v, float) and math.isnan(v) else v for k, v in report.items()}
