"""The examples in python/examples run as a user runs them, and say what
they claim."""

import json
import math
import pathlib
import subprocess
import sys

import pytest

import ndr

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


def _serve(*args: str) -> "tuple[subprocess.Popen[str], str]":
    """examples/two_hosts_robot.py on a free loopback port: the process, its address."""
    robot = subprocess.Popen(
        [sys.executable, str(EXAMPLES / "two_hosts_robot.py"), "--listen", "127.0.0.1:0", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert robot.stdout is not None
    line = robot.stdout.readline()
    assert line.startswith("listening on "), (line, robot.stderr.read() if robot.poll() else "")
    return robot, line.split()[-1]


@pytest.mark.parametrize("transport", ["tcp", "tcp+tls", "quic"])
def test_the_robot_and_operator_examples_link_as_on_two_hosts(transport, tmp_path):
    # Plain with insecure=True, as off loopback; TCP under TLS with each
    # side pinning the other's fingerprint; QUIC with each other's
    # certificate pinned.
    if transport == "tcp":
        robot_args = operator_args = ["--insecure"]
    else:
        robot_crt, robot_key, robot_pin = ndr.keygen(tmp_path, "robot")
        op_crt, op_key, op_pin = ndr.keygen(tmp_path, "operator")
        if transport == "tcp+tls":
            robot_args = ["--cert", robot_crt, "--key", robot_key, "--pin", op_pin]
            operator_args = ["--cert", op_crt, "--key", op_key, "--pin", robot_pin]
        else:
            robot_args = ["--transport", "quic", "--cert", robot_crt, "--key", robot_key,
                          "--peer-cert", op_crt]
            operator_args = ["--transport", "quic", "--cert", op_crt, "--key", op_key,
                             "--peer-cert", robot_crt]
    robot, address = _serve(*robot_args)
    try:
        operator = subprocess.run(
            [sys.executable, str(EXAMPLES / "two_hosts_operator.py"), "--connect", address,
             "--duration", "1.5", *operator_args],
            capture_output=True, text=True, timeout=60,
        )
        assert operator.returncode == 0, operator.stderr
        out, err = robot.communicate(timeout=30)
    finally:
        robot.kill()
    assert robot.returncode == 0, err
    report = json.loads(operator.stdout)
    assert report["end"] == "completed", report
    # 20-ms periods for 1.5 s, the handshake and the initialization
    # pattern inside it: well over a few dozen states.
    assert report["released"] > 20, report
    assert report["grtt_mean_s"] is not None and report["grtt_mean_s"] > 0, report
    served = json.loads(out.strip().splitlines()[-1])
    assert served["released"] > 20, served
