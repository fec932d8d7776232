"""The examples in python/examples run as a user runs them, and say what
they claim."""

import json
import math
import pathlib
import subprocess
import sys

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"


def test_the_smith_tracking_example_closes_the_loop_over_a_real_link():
    proc = subprocess.run(
        [
            sys.executable,
            str(EXAMPLES / "smith_tracking.py"),
            "--duration",
            "5",
            "--step",
            "1.5",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    r = json.loads(proc.stdout)
    assert r["remote_error"] is None, r
    assert r["ticks"] > 300, r
    # lan-75km through the relay: a round trip of a few 10 ms ticks.
    assert 2 <= r["round_trip_ticks"] <= 30, r
    # The loop tracks (steps of 1 then a sine: an error well below the
    # amplitude), and it is the design, delayed, to a fraction of that error:
    # only the link's delay changes and a loaded host's held ticks move it.
    assert 0.0 < r["rms_vs_reference"] < 0.6, r
    assert math.isfinite(r["rms_vs_delayed_design"])
    assert r["rms_vs_delayed_design"] < 0.25 * r["rms_vs_reference"], r
