"""The control blocks from Python: the Smith predictor's exactness against
a delay-free loop, the PID and the wave transform against their formulas
computed in numpy, and refusals of bad arguments."""

import math

import numpy as np
import pytest

import ndr

DT = 0.01
GAINS = dict(kp=4.0, ki=2.0, kd=0.3)


def plant():
    return ndr.Tf2.low_pass(2 * math.pi * 0.5, 0.7, 1.0, DT)


def reference(n):
    k = np.arange(n)
    return np.where(k < n // 2, 1.0, np.sin(2 * math.pi * 0.5 * k * DT))


def pid():
    return ndr.Pid(**GAINS, dt=DT, out_min=-10.0, out_max=10.0)


def delay_free(r):
    """The design: the PID on the plant's state one tick late (the state
    the command before produced), no link."""
    c, p = pid(), ndr.Tf2State(plant())
    x = np.zeros(len(r))
    for k, rk in enumerate(r):
        x[k] = p.step(c.step(rk, p.output))
    return x


def across(r, d, smith):
    """The same loop across a link of `d` ticks: the state produced by
    command `j` is measured at tick `j + d`. Returns the plant's state per
    command and what the PID was given."""
    c, p = pid(), ndr.Tf2State(plant())
    sp = ndr.SmithPredictor(plant(), round_trip=d) if smith else None
    x = np.zeros(len(r))
    seen = np.zeros(len(r))
    for k, rk in enumerate(r):
        y = x[k - d] if k >= d else None
        if sp is None:
            seen[k] = 0.0 if y is None else y
        else:
            seen[k] = sp.feedback(y)
        u = c.step(rk, seen[k])
        if sp is not None:
            sp.command(u)
        x[k] = p.step(u)
    return x, seen


def test_the_smith_predictor_with_the_true_model_is_the_delay_free_loop():
    r = reference(3000)
    design = delay_free(r)
    for d in (1, 5, 23):
        x, _ = across(r, d, smith=True)
        np.testing.assert_array_equal(x, design)
    # Without it, the same gains across 23 ticks are another loop.
    plain, _ = across(r, 23, smith=False)
    assert np.max(np.abs(plain - design)) > 0.1


def test_run_replays_the_ticks_as_feedback_and_command_do():
    r = reference(500)
    d = 7
    x, seen = across(r, d, smith=True)
    c = pid()
    sp = ndr.SmithPredictor(plant(), round_trip=d)
    measured = np.concatenate([np.full(d, np.nan), x[:-d]])
    # The commands the loop sent, recomputed from what it saw.
    u = c.run(r, seen)
    np.testing.assert_array_equal(sp.run(measured, u), seen)
    assert sp.ticks == len(r) and sp.round_trip == d and sp.correction == 0.0
    # A refused tick changes nothing.
    with pytest.raises(ValueError, match="measured"):
        sp.run([1.0, math.inf], [0.0, 0.0])
    assert sp.ticks == len(r)


def test_an_announced_round_trip_moves_the_correction_only():
    sp = ndr.SmithPredictor(plant(), round_trip=4)
    sp.set_round_trip(9)
    assert sp.round_trip == 9
    sp.set_delays(3, 2)
    assert sp.round_trip == 5
    sp.model = ndr.Tf2.low_pass(2 * math.pi * 0.5, 0.7, 1.0, 0.02)
    assert sp.dt == 0.02 and sp.model.dt == 0.02


def test_an_identified_model_converges_to_the_plant():
    d = 6
    sp = ndr.SmithPredictor(ndr.Arx2(DT), round_trip=d)
    assert sp.is_identifying and not sp.model_ready
    c, p = pid(), ndr.Tf2State(plant())
    rng = np.random.default_rng(1)
    r = reference(4000) + 0.05 * rng.standard_normal(4000)
    x = np.zeros(len(r))
    for k, rk in enumerate(r):
        seen = sp.feedback(x[k - d] if k >= d else None)
        u = c.step(rk, seen)
        sp.command(u)
        x[k] = p.step(u)
    assert sp.model_ready
    true = plant()
    np.testing.assert_allclose(sp.model.den, true.den, atol=1e-3)
    assert abs(sp.model.dc_gain - 1.0) < 0.05


def test_the_pid_is_its_formula():
    rng = np.random.default_rng(2)
    r, y = rng.standard_normal(200), rng.standard_normal(200)
    kp, ki, kd = 1.5, 0.7, 0.2
    c = ndr.Pid(kp, ki, kd, dt=DT)
    got = c.run(r, y)
    e = r - y
    integral = np.cumsum(e) * DT
    deriv = np.concatenate([[0.0], -(np.diff(y)) / DT])
    np.testing.assert_allclose(got, kp * e + ki * integral + kd * deriv, rtol=1e-12, atol=1e-12)
    # Limits hold, and the properties say what was given.
    lim = ndr.Pid(100.0, dt=DT, out_min=-1.0, out_max=2.0)
    u = lim.run(r, y)
    assert u.min() == -1.0 and u.max() == 2.0
    assert lim.limits == (-1.0, 2.0) and lim.kp == 100.0 and lim.ki == 0.0
    lim.dt = 0.02
    assert lim.dt == 0.02


def test_the_waves_carry_the_port_power_and_invert():
    w = ndr.WaveTransform(3.0)
    rng = np.random.default_rng(3)
    v, f = rng.standard_normal(50), rng.standard_normal(50)
    u, back = w.forward_wave(v, f), w.backward_wave(v, f)
    np.testing.assert_allclose(0.5 * (u**2 - back**2), v * f, atol=1e-12)
    np.testing.assert_allclose(u, (3.0 * v + f) / math.sqrt(6.0), atol=1e-12)
    assert isinstance(w.forward_wave(0.5, 2.0), float)
    force, wave = w.master(0.5, w.backward_wave(0.5, 2.0))
    assert force == pytest.approx(2.0) and wave == pytest.approx(w.forward_wave(0.5, 2.0))
    vel, wave = w.slave(w.forward_wave(0.5, 2.0), 2.0)
    assert vel == pytest.approx(0.5) and wave == pytest.approx(w.backward_wave(0.5, 2.0))


def test_a_delay_line_is_passive_and_repeats_are_not():
    waves = np.sin(np.arange(2000) * 0.05) + 0.3
    e = ndr.WaveEnergy()
    e.sent(waves, dt=DT)
    e.delivered(waves[:-7], dt=DT)
    assert e.generated == 0.0 and e.stored > 0.0
    assert e.entered == pytest.approx(0.5 * DT * np.sum(waves**2))
    # Each wave delivered twice: energy from nowhere.
    twice = ndr.WaveEnergy()
    twice.sent(waves, dt=DT)
    twice.delivered(np.repeat(waves, 2), dt=DT)
    assert twice.generated > 1.0 and twice.stored < 0.0


def test_round_trip_ticks_counts_to_the_tick_that_takes_the_release():
    assert ndr.round_trip_ticks(0.06, 0.02) == 3
    assert ndr.round_trip_ticks(0.041, 0.02) == 3
    assert ndr.round_trip_ticks(0.0, 0.02) == 0
    with pytest.raises(ValueError, match="period"):
        ndr.round_trip_ticks(0.06, 0.0)
    with pytest.raises(ValueError, match="grtt"):
        ndr.round_trip_ticks(-1.0, 0.02)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: ndr.SmithPredictor(plant(), round_trip=0), "round_trip"),
        (lambda: ndr.SmithPredictor(plant(), round_trip=ndr.SMITH_HISTORY + 1), "round_trip"),
        (lambda: ndr.SmithPredictor(plant(), round_trip=-3), "round_trip"),
        (lambda: ndr.SmithPredictor(plant(), round_trip=2).feedback(math.nan), "measured"),
        (lambda: ndr.SmithPredictor(plant(), round_trip=2).command(math.inf), "u"),
        (lambda: ndr.SmithPredictor(plant(), round_trip=2).set_round_trip(0), "round_trip"),
        (lambda: ndr.SmithPredictor(plant(), round_trip=2).set_delays(0, 0), "delay_fwd"),
        (lambda: ndr.Pid(math.nan, dt=DT), "kp"),
        (lambda: ndr.Pid(1.0, dt=0.0), "period"),
        (lambda: ndr.Pid(1.0, dt=DT, out_min=1.0, out_max=-1.0), "limits"),
        (lambda: ndr.Pid(1.0, dt=DT, derivative_filter=-1.0), "derivative"),
        (lambda: ndr.Pid(1.0, dt=DT).step(math.nan, 0.0), "r"),
        (lambda: ndr.WaveTransform(0.0), "impedance"),
        (lambda: ndr.WaveTransform(1.0).master(math.nan, 0.0), "velocity"),
        (lambda: ndr.WaveTransform(1.0).forward_wave([1.0, 2.0], [1.0]), "force"),
        (lambda: ndr.WaveEnergy().sent(1.0, dt=0.0), "dt"),
    ],
)
def test_bad_arguments_are_value_errors_that_say_what(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_a_model_of_the_wrong_kind_is_a_type_error():
    with pytest.raises(TypeError, match="Tf2"):
        ndr.SmithPredictor([1.0, 0.0, 0.0], round_trip=2)  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        ndr.SmithPredictor(plant(), round_trip="3")  # type: ignore[arg-type]
