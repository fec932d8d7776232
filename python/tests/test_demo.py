"""`python -m ndr demo`: the main job, from Python."""

import json
import math
import subprocess
import sys

import pytest

import ndr
import ndr.sim
from ndr import demo


def test_python_m_ndr_demo_runs_and_reports(tmp_path):
    # One run checked for the report and for the adaptive playout it runs
    # by default (dropping late samples: the playout's own losses).
    out = tmp_path / "demo.csv"
    proc = subprocess.run(
        [sys.executable, "-m", "ndr", "demo", "--duration-s", "3", "--period-ms", "20",
         "--underflow", "drop-late", "--json", "--out", str(out)],
        capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["profile"] == "lan-75km"
    assert report["grtt_count"] > 20
    # The default: the adaptive playout, each side's delay announced.
    assert report["regulation"] == report["playout"] == "adaptive"
    # `regulation` names it alone, as in the Rust CLI's report.
    assert "mode" not in report
    assert report["samples_released"] > 100
    assert report["csv"] == str(out)
    # The deadlines the host made the hubs miss, as `ndr demo --json` has them.
    assert isinstance(report["wakes_late"], int) and report["wakes_late"] >= 0
    # Each hub's spin margin, learned from its timer, within its bounds.
    for side in ("base", "remote"):
        assert 20e-6 <= report[f"spin_margin_{side}_s"] <= 200e-6
    header = out.read_text().splitlines()[0]
    assert header == "t_s,seq,status,grtt_s,nrtt_s,command,state,x3e"
    # The delay each side holds: at least a tick, above the one-way delays
    # measured. Whole ticks and how far above are the playout's accuracy,
    # judged in simulated time (below): it holds whole ticks over its
    # estimate of the clocks' floor, which a real run only estimates, and
    # while its window warms up it covers the largest delay seen, which a
    # loaded host makes as long as it likes.
    for way in ("fwd", "bwd"):
        d = report[f"playout_delay_{way}_s"]
        assert d >= 0.02, report
        assert 0.005 < report[f"one_way_{way}_mean_s"] < d, report
        # Its first delay and every change after it, each an event.
        assert report[f"delay_changes_{way}"] >= 1, report


def test_the_demos_adaptive_playout_holds_whole_ticks_over_the_relays_delay_in_simulated_time():
    # The demo's network and playout (lan-75km, 20 ms, dropping late
    # samples, 3 s) in simulated time: whole 20 ms ticks over the relay's
    # 12 ms or so each way, or more while the window warms up.
    r = ndr.sim.run("lan-75km", regulation="adaptive", underflow="drop-late", period=0.02,
                    duration=3, series=False).summary
    d = r["playout_delay_fwd_s"]
    assert 0.02 <= d <= 0.2 and abs(d / 0.02 - round(d / 0.02)) < 1e-6, r
    assert 0.005 < r["one_way_fwd_mean_s"] < d, r
    assert r["delay_changes_fwd"] >= 1, r
    # The way back, as the end-to-end delay of its samples.
    assert 0.005 < r["one_way_bwd_mean_s"] < r["e2e_bwd_mean_s"] <= 0.2 + 0.02, r


def test_the_demo_table_shows_what_the_adaptive_playout_holds(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "ndr", "demo", "--duration-s", "2", "--period-ms", "20",
         "--regulation", "adaptive", "--out", str(tmp_path / "d.csv")],
        capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 0, proc.stderr
    # Where the series goes, said before the run; the header's labels as the
    # Rust CLI's (`ndr demo · lan-75km · adaptive · hold · udp:4:3 · T = …`),
    # over datagrams by default.
    assert proc.stderr.startswith(
        f"ndr python demo: the base's series goes to {tmp_path / 'd.csv'} (--out to change it)\n"
    ), proc.stderr
    assert proc.stdout.startswith("ndr python demo · lan-75km · adaptive · hold · udp · T = 20.00 ms"), proc.stdout
    line = next(l for l in proc.stdout.splitlines() if l.strip().startswith("playout"))
    assert "forward" in line and "back" in line and "ppm" in line, line
    assert "delays announced" in line, line


def test_the_reports_late_wakes_are_both_hubs_counts():
    # Not a number the binding makes up: each side's hub counts the
    # deadlines it woke for late (its `lateness.missed`); the report adds them.
    result = demo.run(duration=1.0, period=0.02, out=None)
    sides = (result.operator.stats, result.robot.stats)
    assert all(s is not None for s in sides)
    counted = sum(s["lateness"]["missed"] for s in sides if s is not None)
    assert result.report["wakes_late"] == counted, result.report


def test_bad_options_exit_with_a_message():
    proc = subprocess.run(
        [sys.executable, "-m", "ndr", "demo", "--duration-s", "-1"],
        capture_output=True, text=True, timeout=30,
    )
    assert proc.returncode == 2
    assert "duration" in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "ndr", "fly"], capture_output=True, text=True)
    assert proc.returncode == 2 and "unknown command" in proc.stderr


def test_regulation_is_the_only_flag_and_a_wrong_name_says_the_valid_ones():
    # The old spellings are gone: refused before anything runs.
    for flag, value in (("--mode", "paper-static"), ("--playout", "fifo")):
        proc = subprocess.run(
            [sys.executable, "-m", "ndr", "demo", "--regulation", "adaptive", flag, value],
            capture_output=True, text=True, timeout=30,
        )
        assert proc.returncode == 2
        assert f"unrecognized arguments: {flag}" in proc.stderr
    # An unknown name: the valid ones.
    proc = subprocess.run(
        [sys.executable, "-m", "ndr", "demo", "--regulation", "lifo"],
        capture_output=True, text=True, timeout=30,
    )
    assert proc.returncode == 2
    assert "unknown regulation; valid: adaptive" in proc.stderr


@pytest.mark.parametrize("transport", ["stream", "datagram"])
def test_the_demos_estimator_follows_the_plant_behind_a_constant_delay_in_simulated_time(
    transport,
):
    # The demo's loop as `test_link.py` runs it over real links (100 Hz, a
    # relay adding 5 ms each way, the paper's FIFO, a 0.5 Hz sine), judged
    # here in simulated time: the link's delays come from the simulator, the
    # split of the round trip, the plant and the error measure are the demo's.
    period = 0.01
    sim = ndr.sim.run("constant:5", regulation="paper-static", period=period,
                      duration=4.0, transport=transport, series=False)
    assert sim["grtt_std_s"] < 1e-9 and sim["e2e_fwd_std_s"] < 1e-9
    # The demo's robot answers from its own thread: at the tick after the
    # release that gave it the command, a tick the simulated remote does not wait.
    round_trip = round(sim["grtt_mean_s"] / period) + 1
    fwd = round(sim["e2e_fwd_mean_s"] / period)
    bwd = round_trip - fwd
    est_fwd, est_bwd = demo._delays(round_trip * period, period)

    signal = ndr.Signal("sine:freq=0.5")
    plant = ndr.Tf2State(demo.plant_model(period))
    ticks = 400
    u = [signal(n * period, 0) for n in range(ticks)]
    # The remote's state after its tick n, whose release was the command the
    # base sent `fwd` ticks before.
    truth = [plant.step(u[n - fwd]) if n >= fwd else 0.0 for n in range(ticks)]
    estimator = ndr.Estimator(est_fwd, est_bwd, dt=period, lam=0.999)
    op, rb = demo.OperatorLog(), demo.RobotLog()
    for n in range(ticks):
        # What the base's release gives at tick n: the state `bwd` ticks old.
        y = truth[n - bwd] if n >= bwd else 0.0
        x3e, _x3p, from_model = estimator.step(u[n], y)
        op.mono.append(n * period)
        op.state.append(y)
        op.x3e.append(x3e if from_model else math.nan)
        # The remote's tick comes a little before the base's in each period.
        rb.t.append(n * period - period / 2)
        rb.state.append(truth[n])
    r = demo.tracking_errors(op, rb)
    assert r["compared"] > 100
    # x3e is far closer to the true state now than the delayed state is.
    assert r["x3e_rms_error"] < 0.5 * r["delayed_rms_error"], r
    assert r["x3e_rms_error"] < 0.05, r
