"""A 1 kHz Python control loop over a loopback link: how late does the
controller see each tick?

    python python/bench/bench_link.py [--seconds 10] [--period-ms 1]

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
import sys, ndr
period, seconds = float(sys.argv[1]), float(sys.argv[2])
with ndr.Link.listen(("127.0.0.1", 0), period=period, axes=2, watchdog=None) as lst:
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


def ndr_loop(period: float, seconds: float) -> dict:
    remote = subprocess.Popen(
        [sys.executable, "-c", REMOTE, str(period), str(seconds)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        port = int(remote.stdout.readline())
        with ndr.Link.connect(("127.0.0.1", port), period=period, axes=2) as link:
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
    args = ap.parse_args()
    period = args.period_ms / 1e3
    cpu = os.cpu_count()
    results = {
        "period_ms": args.period_ms,
        "seconds": args.seconds,
        "cpus": cpu,
        "ndr": ndr_loop(period, args.seconds),
        "time.sleep": sleep_loop(period, args.seconds),
    }
    if args.json:
        print(json.dumps(results))
        return
    print(f"1/T = {1 / period:.0f} Hz for {args.seconds:.0f} s, lateness of the Python loop:")
    print(f"{'loop':<12}{'p50':>9}{'p99':>9}{'p99.9':>9}{'max':>10}{'mean':>9}  ticks")
    for name in ("ndr", "time.sleep"):
        r = results[name]
        print(
            f"{name:<12}{r['p50_us']:>7.0f}µs{r['p99_us']:>7.0f}µs{r['p999_us']:>7.0f}µs"
            f"{r['max_us']:>8.0f}µs{r['mean_us']:>7.0f}µs  {r['ticks']}"
        )
    r = results["ndr"]
    print(
        f"ndr link: GRTT {r['grtt_mean_ms']:.3f} ms ± {r['grtt_std_ms']:.3f} ms, "
        f"{r['held']} held ticks, hub release lateness p99 {r['hub_lateness_p99_us']:.0f} µs"
    )


if __name__ == "__main__":
    main()
