"""Batch functions agree with the step-by-step API."""

import numpy as np
import pytest

import ndr

rng = np.random.default_rng(1234)
Z = np.cumsum(rng.normal(scale=0.01, size=500)) + 0.6


def test_kalman3_filter_is_a_loop_of_steps():
    x, ahead = ndr.kalman3_filter(Z, period=0.2, sigma_q=0.3, horizon=20)
    assert x.shape == (len(Z), 3) and ahead.shape == (len(Z),)
    assert x.dtype == ahead.dtype == np.float64
    k = ndr.Kalman3(0.2, sigma_q=0.3, horizon=20)
    for i, z in enumerate(Z):
        k.step(z)
        np.testing.assert_array_equal(x[i], k.x)
        assert ahead[i] == k.predict_ahead()


def test_kalman3_run_continues_from_the_state_and_x0():
    k = ndr.Kalman3(0.2)
    k.run(Z[:100])
    x_tail, _ = k.run(Z[100:])
    x_all, _ = ndr.kalman3_filter(Z, period=0.2)
    np.testing.assert_array_equal(x_tail, x_all[100:])
    x0 = [Z[0], 0.0, 0.0]
    x, _ = ndr.kalman3_filter(Z, period=0.2, x0=x0)
    k = ndr.Kalman3(0.2)
    k.x = x0
    np.testing.assert_array_equal(x, k.run(Z)[0])


def test_kalman3_filter_takes_lists_and_empty_input():
    x, ahead = ndr.kalman3_filter([1.0, 2, 3], period=0.1)
    assert x.shape == (3, 3)
    x, ahead = ndr.kalman3_filter(np.array([]), period=0.1)
    assert x.shape == (0, 3) and ahead.shape == (0,)


def test_kalman3_filter_reads_strided_and_integer_arrays():
    a = ndr.kalman3_filter(Z[::2], period=0.2)[0]
    b = ndr.kalman3_filter(np.ascontiguousarray(Z[::2]), period=0.2)[0]
    np.testing.assert_array_equal(a, b)
    ints = np.arange(10)
    np.testing.assert_array_equal(
        ndr.kalman3_filter(ints, period=0.2)[0],
        ndr.kalman3_filter(ints.astype(float), period=0.2)[0],
    )


def test_rls_filter_is_a_loop_of_adapts():
    X = rng.normal(size=(200, 4))
    d = X @ np.array([1.0, 2.0, -1.0, 0.5]) + rng.normal(scale=0.1, size=200)
    y, e, w = ndr.rls_filter(d, X, lam=0.97, delta=50.0)
    rls = ndr.Rls(4, lam=0.97, delta=50.0)
    for k in range(len(d)):
        np.testing.assert_array_equal(w[k], rls.w)
        assert y[k] == rls.predict(X[k])
        assert e[k] == rls.adapt(d[k], X[k])


def test_lowpass_and_envelope_are_loops_of_updates():
    y = ndr.lowpass(Z, 5.0, 0.2)
    lp = ndr.LowPass(5.0, 0.2)
    assert lp.value is None
    np.testing.assert_array_equal(y, [lp.update(v) for v in Z])
    assert lp.alpha == pytest.approx(1 - np.exp(-0.2 / 5.0))
    e = ndr.envelope(Z, decay=1.001)
    env = ndr.Envelope(1.001)
    np.testing.assert_array_equal(e, [env.update(v) for v in Z])
    assert e[0] == Z[0]


def test_lowpass_step_response():
    y = ndr.lowpass(np.r_[0.0, np.ones(25)], 25 * 0.2, 0.2)
    assert y[0] == 0.0
    assert y[-1] == pytest.approx(1 - np.exp(-1.0), abs=1e-12)


def test_arx2_fit_is_a_loop_of_updates():
    u = rng.normal(size=100)
    y = ndr.Tf2([0.1, 0.05, 0.0], [1.0, -0.9, 0.2], 0.1).simulate(u)
    a = ndr.Arx2(0.1)
    e = a.fit(u, y)
    b = ndr.Arx2(0.1)
    steps = [b.update(uk, yk) for uk, yk in zip(u, y)]
    assert np.isnan(e[:2]).all() and steps[:2] == [None, None]
    np.testing.assert_array_equal(e[2:], steps[2:])
    np.testing.assert_array_equal(a.to_tf()[0], b.to_tf()[0])


def test_tf2_state_run_continues():
    tf = ndr.Tf2.low_pass(2.0, 0.7, 1.0, 0.1)
    u = rng.normal(size=60)
    s = ndr.Tf2State(tf)
    y = np.r_[s.run(u[:30]), s.run(u[30:])]
    np.testing.assert_allclose(y, tf.simulate(u), rtol=0, atol=0)
    s.reset()
    assert s.output == 0.0


def test_estimator_run_is_a_loop_of_steps_with_missing_samples():
    tf = ndr.Tf2.low_pass(2.0, 0.5, 3.0, 0.5)
    u = np.repeat(rng.normal(size=40), 5)
    y = tf.simulate(np.r_[0.0, u[:-1]])
    received = rng.random(len(u)) > 0.1
    y_sent = np.where(received, y, np.nan)
    a = ndr.Estimator(1, 2, dt=0.5)
    x3e, x3p, from_model = a.run(u, y_sent, received)
    b = ndr.Estimator(1, 2, dt=0.5)
    for k in range(len(u)):
        got = b.step(u[k], y[k] if received[k] else None)
        assert got == (x3e[k], x3p[k], bool(from_model[k]))
    assert from_model.dtype == np.bool_ and from_model[-1]


def test_batch_functions_run_in_parallel_threads():
    from concurrent.futures import ThreadPoolExecutor

    series = [Z * (1 + i) for i in range(8)]
    expected = [ndr.kalman3_filter(z, period=0.2)[0] for z in series]
    with ThreadPoolExecutor(max_workers=4) as pool:
        got = list(pool.map(lambda z: ndr.kalman3_filter(z, period=0.2)[0], series))
    for a, b in zip(got, expected):
        np.testing.assert_array_equal(a, b)
