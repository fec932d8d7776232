"""A 1 kHz Python control loop over a loopback link: how late does the
controller see each tick?

    python python/bench/bench_link.py [--seconds 10] [--period-ms 1] [--loop-priority 40]

The remote runs in a second Python process (an echo controller), so the
base's loop has its interpreter to itself, as it would on a real robot
setup. For each tick the base records

    lateness = (link clock when ``recv`` returned) - (the tick's deadline)

where the deadline is the grid instant ``k·T`` the regulator released the
sample at: this is the delay from the ideal tick to the Python controller
holding the sample (release clock + hand-over + thread wake-up + GIL).

Baseline, in the same run: the same loop paced by ``time.sleep`` to the
next ``k·T`` (what a Python controller without ndr would do), lateness
measured the same way against its own grid.

Each loop runs twice, side by side: without real-time scheduling (the
link's ``realtime="off"``, every thread ``SCHED_OTHER``) and with it (the
link's default ``realtime="try"``: its hub thread ``SCHED_FIFO`` 49 with
locked memory; and the Python loop thread itself, in both processes,
``SCHED_FIFO`` at ``--loop-priority``, under the hub's). Where the host
refuses ``SCHED_FIFO`` (not root, no ``CAP_SYS_NICE``) the second run says
so and runs as the first.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

import ndr

REMOTE = r"""
import os, sys, ndr
period, seconds = float(sys.argv[1]), float(sys.argv[2])
realtime, priority = sys.argv[3], int(sys.argv[4])
if priority > 0:
    os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
with ndr.Link.listen(("127.0.0.1", 0), period=period, axes=2, watchdog=None,
                     realtime=realtime) as lst:
    print(lst.address[1], flush=True)
    with lst.accept(timeout=10) as link:
        for tick in link.ticks(timeout=5):
            link.send(tick.sample)
"""


def percentiles(x: np.ndarray) -> dict:
    return {
        "p50_us": float(np.percentile(x, 50) * 1e6),
        "p99_us": float(np.percentile(x, 99) * 1e6),
        "p999_us": float(np.percentile(x, 99.9) * 1e6),
        "max_us": float(x.max() * 1e6),
        "mean_us": float(x.mean() * 1e6),
        "ticks": int(x.size),
    }


def loop_priority(priority: int) -> None:
    """This thread ``SCHED_FIFO`` at ``priority``, or back to ``SCHED_OTHER``
    for 0; threads it starts (a link's hub) inherit it."""
    if priority > 0:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    else:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def ndr_loop(period: float, seconds: float, realtime: str, priority: int) -> dict:
    remote = subprocess.Popen(
        [sys.executable, "-c", REMOTE, str(period), str(seconds), realtime, str(priority)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        port = int(remote.stdout.readline())
        with ndr.Link.connect(
            ("127.0.0.1", port), period=period, axes=2, realtime=realtime
        ) as link:
            n = int(seconds / period)
            late = np.empty(n)
            grtt = []
            held = 0
            u = np.zeros(2)
            link.recv(timeout=5)  # the first tick after the initialization pattern
            for i in range(n):
                tick = link.recv(timeout=1)
                now = link.now()
                deadline = math.floor(tick.released_at / period + 1e-6) * period
                late[i] = now - deadline
                # The "controller": a little numpy work, then the command.
                u[0] = math.sin(i * period)
                u[1] = float(tick.sample[0])
                link.send(u)
                held += tick.status == "held"
                if tick.grtt is not None:
                    grtt.append(tick.grtt)
            stats = link.stats
    finally:
        remote.wait(timeout=10)
    out = percentiles(late)
    out.update(
        held=held,
        grtt_mean_ms=float(np.mean(grtt) * 1e3),
        grtt_std_ms=float(np.std(grtt) * 1e3),
        hub_lateness_p99_us=stats["lateness"]["p99"] * 1e6,
    )
    return out


def granted(priority: int) -> bool:
    """Whether this process may ask for ``SCHED_FIFO`` at ``priority``."""
    try:
        loop_priority(priority)
    except PermissionError:
        return False
    loop_priority(0)
    return True


def sleep_loop(period: float, seconds: float) -> dict:
    n = int(seconds / period)
    late = np.empty(n)
    t0 = time.monotonic()
    for i in range(n):
        deadline = t0 + (i + 1) * period
        left = deadline - time.monotonic()
        if left > 0:
            time.sleep(left)
        late[i] = time.monotonic() - deadline
    return percentiles(late)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--period-ms", type=float, default=1.0)
    ap.add_argument("--json", action="store_true")
    ap.add_argument(
        "--loop-priority",
        type=int,
        default=40,
        help="the Python loop thread's SCHED_FIFO priority in the real-time runs "
        "(under the hub's 49)",
    )
    args = ap.parse_args()
    period = args.period_ms / 1e3
    rt = granted(args.loop_priority)
    if not rt:
        print(
            "bench_link: SCHED_FIFO refused (run as root or grant CAP_SYS_NICE): "
            "the real-time runs run without it",
            file=sys.stderr,
        )
    prio = args.loop_priority if rt else 0
    results = {
        "period_ms": args.period_ms,
        "seconds": args.seconds,
        "cpus": os.cpu_count(),
        "realtime_granted": rt,
        "ndr": ndr_loop(period, args.seconds, "off", 0),
        "time.sleep": sleep_loop(period, args.seconds),
    }
    loop_priority(prio)
    try:
        results["ndr, real-time"] = ndr_loop(period, args.seconds, "try", prio)
        results["time.sleep, real-time"] = sleep_loop(period, args.seconds)
    finally:
        loop_priority(0)
    if args.json:
        print(json.dumps(results))
        return
    print(f"1/T = {1 / period:.0f} Hz for {args.seconds:.0f} s, lateness of the Python loop:")
    print(f"{'loop':<24}{'p50':>9}{'p99':>9}{'p99.9':>9}{'max':>10}{'mean':>9}  ticks")
    names = ("ndr", "ndr, real-time", "time.sleep", "time.sleep, real-time")
    for name in names:
        r = results[name]
        print(
            f"{name:<24}{r['p50_us']:>7.0f}µs{r['p99_us']:>7.0f}µs{r['p999_us']:>7.0f}µs"
            f"{r['max_us']:>8.0f}µs{r['mean_us']:>7.0f}µs  {r['ticks']}"
        )
    for name in names[:2]:
        r = results[name]
        print(
            f"{name}: GRTT {r['grtt_mean_ms']:.3f} ms ± {r['grtt_std_ms']:.3f} ms, "
            f"{r['held']} held ticks, hub release lateness p99 "
            f"{r['hub_lateness_p99_us']:.0f} µs"
        )


if __name__ == "__main__":
    main()
