"""A position loop closed over a real link with a Smith predictor.

The remote runs the plant (a slow arm axis, as ``ndr demo``'s robot); the
base runs a PID on the remote's delayed position, through a
:class:`ndr.SmithPredictor` whose round trip in ticks comes from the link
(each release's GRTT, whose changes the link also announces as
``"round_trip_changed"`` events). Both run in this process over loopback,
through a :class:`ndr.Relay` that delays every frame as a real network
would.

It prints the RMS tracking error against the reference, and against the
delayed design: the same PID on the same plant without a link (computed
alongside), delayed by the round trip. With the true model and a
constant round trip the loop is the design, delayed, so the second is
near zero.

    python python/examples/smith_tracking.py --profile lan-75km --duration 10
"""

from __future__ import annotations

import argparse
import json
import math
import threading
from typing import Any, Dict, List, Optional

import numpy as np

import ndr
from ndr.demo import RobotLog, plant_model, robot

# The simulator's tracking loop (`ndr control --scenario tracking`).
KP, KI, KD, U_MAX = 4.0, 2.0, 0.3, 10.0


def reference(t: float, step: float, steps: int, sine_hz: float) -> float:
    """Steps between 1 and 0, each held `step` seconds, then a sine."""
    end = step * steps
    if t < end:
        return 1.0 if int(t / step) % 2 == 0 else 0.0
    return math.sin(2 * math.pi * sine_hz * (t - end))


def loop_round_trip(grtt: float, period: float) -> int:
    """The round trip in this loop's ticks that a release's GRTT is: the
    loop answers each release at once and its command leaves at the link's
    next tick, one tick before the GRTT starts counting; a release the host
    served a little late (up to a tenth of a period) is still on its tick."""
    return ndr.round_trip_ticks(max(grtt - 0.1 * period, 0.0), period) + 1


def control(
    link: ndr.Link,
    duration: float,
    *,
    step: float,
    steps: int,
    sine_hz: float,
) -> Dict[str, Any]:
    """The base's controller: one PID step per released state."""
    period = link.period
    model = plant_model(period)
    pid = ndr.Pid(KP, KI, KD, dt=period, out_min=-U_MAX, out_max=U_MAX)
    smith: Optional[ndr.SmithPredictor] = None
    # The design: the same PID on a local plant, no link.
    design_pid = ndr.Pid(KP, KI, KD, dt=period, out_min=-U_MAX, out_max=U_MAX)
    design_plant = ndr.Tf2State(model)
    design: List[float] = []
    r_log: List[float] = []
    y_log: List[float] = []
    trip_log: List[int] = []
    changes = 0
    for k in range(int(round(duration / period))):
        tick = link.recv(timeout=2.0)
        # The round trip in ticks: the link's GRTT, on each release that
        # closes one; a delay change is announced before it takes effect.
        trip = None
        if tick.grtt is not None:
            trip = loop_round_trip(tick.grtt, period)
        for event in link.events():
            if event.kind == "delay_changed":
                changes += 1
        y = float(tick.sample[0])
        if smith is None and trip:
            smith = ndr.SmithPredictor(model, round_trip=min(trip, ndr.SMITH_HISTORY))
        elif smith is not None and trip and trip != smith.round_trip:
            smith.set_round_trip(min(trip, ndr.SMITH_HISTORY))
        t = k * period
        r = reference(t, step, steps, sine_hz)
        if smith is None:
            # No round trip known yet: the plant is at rest, hold it there.
            seen = y
            u = 0.0
        else:
            seen = smith.feedback(y if tick.status == "fresh" else None)
            u = pid.step(r, seen)
            smith.command(u)
        link.send([u])
        if smith is not None:
            design.append(design_plant.step(design_pid.step(r, design_plant.output)))
            r_log.append(r)
            y_log.append(y)
            trip_log.append(smith.round_trip)
    # The delayed design at tick k: the design's state on the command sent
    # one round trip before (zero before the loop started).
    d = np.asarray(design)
    idx = np.arange(len(d)) - np.asarray(trip_log, dtype=int)
    delayed = np.where(idx >= 0, d[np.clip(idx, 0, None)], 0.0)
    y_arr, r_arr = np.asarray(y_log), np.asarray(r_log)
    return {
        "ticks": len(y_arr),
        "rms_vs_reference": float(np.sqrt(np.mean((y_arr - r_arr) ** 2))),
        "rms_vs_delayed_design": float(np.sqrt(np.mean((y_arr - delayed) ** 2))),
        "round_trip_ticks": int(np.median(trip_log)) if trip_log else None,
        "delay_changes": changes,
    }


def main(argv: Optional[List[str]] = None) -> Dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--profile", default="lan-75km", help="the relay's delay profile")
    p.add_argument("--period", type=float, default=0.01, help="seconds")
    p.add_argument("--duration", type=float, default=10.0, help="seconds")
    p.add_argument("--step", type=float, default=2.0, help="seconds each step is held")
    p.add_argument("--steps", type=int, default=2, help="steps before the sine")
    p.add_argument("--sine-hz", type=float, default=0.25)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    args = p.parse_args(argv)

    loopback = ("127.0.0.1", 0)
    settings: Dict[str, Any] = dict(period=args.period, regulation="adaptive")
    with ndr.Link.listen(loopback, **settings) as listener:
        with ndr.Relay(loopback, listener.address, profile=args.profile, seed=args.seed) as relay:
            accepted: Dict[str, ndr.Link] = {}
            accepting = threading.Thread(
                target=lambda: accepted.setdefault("link", listener.accept(timeout=30.0))
            )
            accepting.start()
            base = ndr.Link.connect(relay.address, **settings)
            accepting.join()
            stop = threading.Event()
            log = RobotLog()
            remote = threading.Thread(target=robot, args=(accepted["link"], stop, log))
            remote.start()
            try:
                with base:
                    result = control(
                        base, args.duration, step=args.step, steps=args.steps, sine_hz=args.sine_hz
                    )
            finally:
                stop.set()
                remote.join()
    result.update(profile=args.profile, period=args.period, remote_error=log.error)
    if args.json:
        print(json.dumps(result))
    else:
        print(
            f"{args.profile}, T = {args.period * 1e3:g} ms, {result['ticks']} ticks, "
            f"round trip {result['round_trip_ticks']} ticks: RMS error "
            f"{result['rms_vs_reference']:.4f} against the reference, "
            f"{result['rms_vs_delayed_design']:.2e} against the delayed design"
        )
    return result


if __name__ == "__main__":
    main()
