"""ndr.sim.run: the simulator of `ndr sim`, from Python."""

import math

import numpy as np
import pytest

import ndr
import ndr.sim


def test_lan_static_reproduces_the_paper():
    r = ndr.sim.run("lan-75km", period=0.2, duration=120, series=False)
    assert r["grtt_mean_s"] == pytest.approx(1.2, rel=0.15)
    assert r.summary["grtt_std_s"] < 1e-6
    assert r.summary["profile"] == "lan-75km"
    assert r.series["t"].size == 0


def test_dynamic_mode_lowers_the_lan_delay():
    r = ndr.sim.run("lan-75km", regulation="paper-dynamic", period=0.2, duration=120)
    assert r["settled_grtt_mean_s"] == pytest.approx(0.3, rel=0.15)
    assert np.nanmin(r.series["period"]) == pytest.approx(0.05)


def test_packet_loss_on_tcp_raises_the_adaptive_delay():
    runs = {
        loss: ndr.sim.run("lan-75km", regulation="adaptive", period=0.02, duration=30, loss=loss)
        for loss in ("none", "3", "ge:2:4")
    }
    clean = runs["none"]["grtt_mean_s"]
    assert runs["3"]["grtt_mean_s"] > 2 * clean
    assert runs["ge:2:4"]["grtt_mean_s"] > 2 * clean
    # Datagrams with copies of the samples before: no stall to cover.
    udp = ndr.sim.run(
        "lan-75km", regulation="adaptive", period=0.001, duration=10, loss="3", transport="datagram"
    )
    tcp = ndr.sim.run("lan-75km", regulation="adaptive", period=0.001, duration=10, loss="3")
    assert udp["grtt_mean_s"] < 0.3 * tcp["grtt_mean_s"]
    assert udp["late_rate_fwd"] < 0.001


def test_series_are_float64_arrays_of_one_length():
    r = ndr.sim.run("paper-fig6", period=0.2, duration=60)
    n = r.series["t"].size
    assert n > 250
    for name, column in r.series.items():
        assert isinstance(column, np.ndarray) and column.dtype == np.float64, name
        assert column.shape == (n,), name
    assert np.isfinite(r.series["truth_nrtt"]).all()
    assert (np.diff(r.series["t"]) > 0).all()


def test_the_same_seed_gives_the_same_run():
    a = ndr.sim.run("paris-newyork", duration=60, seed=7)
    b = ndr.sim.run("paris-newyork", duration=60, seed=7)
    c = ndr.sim.run("paris-newyork", duration=60, seed=8)
    assert a.summary == b.summary
    np.testing.assert_array_equal(a.series["grtt"], b.series["grtt"])
    assert a.summary != c.summary


def test_playout_policies_run_and_a_bad_name_is_refused():
    fifo = ndr.sim.run("lan-75km", period=0.05, duration=60, series=False, underflow="drop-late")
    neteq = ndr.sim.run(
        "lan-75km", period=0.05, duration=60, series=False, underflow="drop-late", regulation="neteq"
    )
    assert neteq["regulation"] == "neteq" and fifo["regulation"] == "paper-static"
    assert neteq["playout"] == "neteq" and fifo["playout"] == "fifo"
    # A target from the measured delays beats the paper's queue on a LAN.
    assert neteq["e2e_fwd_mean_s"] < fifo["e2e_fwd_mean_s"]
    with pytest.raises(ValueError, match="regulation"):
        ndr.sim.run(duration=10, regulation="lifo")


def test_the_adaptive_playout_takes_the_step_of_its_delay():
    def run(regulation):
        return ndr.sim.run("lan-75km", period=0.02, duration=120, series=False,
                           underflow="drop-late", regulation=regulation)
    default, fine = run("adaptive"), run("adaptive:0.1:10")
    assert fine["regulation"] == fine["playout"] == "adaptive:0.1:10"
    # The LAN needs about 25 ms each way: 40 in steps of 20 ms, 30 in 10.
    assert default["playout_delay_fwd_s"] == pytest.approx(0.04)
    assert fine["playout_delay_fwd_s"] == pytest.approx(0.03)
    assert fine["late_samples"] == 0
    for bad in ("adaptive:0.1:0.5", "adaptive:0.1:20000", "adaptive::10", "adaptive:0.1:x"):
        with pytest.raises(ValueError, match="QUANTUM_MS"):
            ndr.sim.run(duration=10, regulation=bad)


def test_a_trace_file_drives_the_network(tmp_path):
    trace = tmp_path / "trace.csv"
    trace.write_text("t_s,fwd_ms,bwd_ms\n0,10,20\n30,40,40\n")
    r = ndr.sim.run(trace=trace, period=0.05, duration=60)
    assert r["nrtt_mean_s"] == pytest.approx(0.065, abs=0.02)
    assert math.isfinite(r["grtt_mean_s"])


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(profile="mars"), "mars"),
        (dict(profile="lan-75km", trace="x.csv"), "one of"),
        (dict(dist="normal.dist"), "mean and std"),
        (dict(profile="lan-75km", mean=0.1), "dist"),
        (dict(regulation="warp"), "regulation"),
        (dict(underflow="skip"), "underflow"),
        (dict(period=0), "period"),
        (dict(duration=-1), "duration"),
        (dict(axes=257), "axes"),
        (dict(loss="lots"), "loss: unknown loss model"),
        (dict(loss="100"), "loss: a loss rate of 100 %"),
        (dict(transport="carrier-pigeon"), "transport: unknown transport"),
        (dict(signal="sawtooth"), "signal"),
    ],
)
def test_bad_options_raise_value_error(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ndr.sim.run(**{"duration": 10, **kwargs})


def test_a_garbage_trace_file_is_refused_with_its_name(tmp_path):
    bad = tmp_path / "garbage.csv"
    bad.write_bytes(b"\x00\xff not a trace\n1,2\n")
    with pytest.raises(ValueError, match="garbage.csv"):
        ndr.sim.run(trace=bad, duration=10)
    with pytest.raises(ValueError, match="missing.csv"):
        ndr.sim.run(trace=tmp_path / "missing.csv", duration=10)


def test_signal_values():
    s = ndr.Signal("sine:amp=2,freq=1")
    assert s(0.25) == pytest.approx(2.0)
    assert ndr.Signal("constant:0.5")(123.0) == 0.5
    assert s.kind == "sine"
    with pytest.raises(ValueError, match="signal"):
        ndr.Signal("noise")
