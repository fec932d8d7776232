"""Rls, Arx2, Tf2 and Estimator: identifying and predicting a 2nd-order system."""

import numpy as np
import pytest

import ndr

# A stable second-order system (poles 0.7 ± 0.1j), scipy.signal's convention.
NUM = np.array([0.05, 0.1, 0.05])
DEN = np.array([1.0, -1.4, 0.5])
DT = 0.2


def simulate(u, num=NUM, den=DEN):
    """y[k] = b0 u[k] + b1 u[k-1] + b2 u[k-2] - a1 y[k-1] - a2 y[k-2], from rest."""
    y = np.zeros(len(u))
    for k in range(len(u)):
        acc = sum(num[i] * u[k - i] for i in range(3) if k - i >= 0)
        acc -= sum(den[i] * y[k - i] for i in (1, 2) if k - i >= 0)
        y[k] = acc
    return y


@pytest.fixture(scope="module")
def data():
    rng = np.random.default_rng(2001)
    u = rng.normal(size=400)
    return u, simulate(u)


def test_rls_recovers_a_known_second_order_system(data):
    u, y = data
    rls = ndr.Rls(5, lam=1.0, delta=1e6)
    assert rls.n == 5 and rls.lam == 1.0 and rls.delta == 1e6
    for k in range(2, len(u)):
        x = np.array([u[k], u[k - 1], u[k - 2], -y[k - 1], -y[k - 2]])
        e = rls.adapt(y[k], x)
        assert isinstance(e, float)
    np.testing.assert_allclose(rls.w, [*NUM, *DEN[1:]], atol=1e-6)
    x = np.array([u[-1], u[-2], u[-3], -y[-2], -y[-3]])
    assert rls.predict(x) == pytest.approx(y[-1], abs=1e-6)
    assert rls.updates == len(u) - 2
    assert rls.P.shape == (5, 5)
    np.testing.assert_array_equal(rls.P, rls.P.T)


def test_rls_padasip_style_run_and_weights():
    rng = np.random.default_rng(3)
    X = rng.normal(size=(300, 3))
    d = X @ np.array([0.5, -1.0, 2.0])
    rls = ndr.Rls(3, lam=0.99, delta=100.0)
    y, e, w = rls.run(d, X)
    assert y.shape == e.shape == (300,) and w.shape == (300, 3)
    np.testing.assert_allclose(e, d - y, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(w[0], np.zeros(3))  # weights used for sample 0
    np.testing.assert_allclose(rls.w, [0.5, -1.0, 2.0], atol=1e-4)
    rls.w = [1.0, 2.0, 3.0]
    assert rls.predict([1.0, 1.0, 1.0]) == pytest.approx(6.0)
    rls.reset()
    np.testing.assert_array_equal(rls.w, np.zeros(3))
    one = ndr.Rls(1)
    one.adapt(2.0, 1.0)  # a plain number is a 1-entry regressor
    assert one.w.shape == (1,)


def test_rls_against_padasip_when_installed():
    pa = pytest.importorskip("padasip")
    rng = np.random.default_rng(5)
    X = rng.normal(size=(200, 4))
    d = X @ np.array([1.0, -0.5, 0.25, 2.0]) + 0.01 * rng.normal(size=200)
    f = pa.filters.FilterRLS(4, mu=0.98, w="zeros", eps=0.01)  # P0 = I / eps
    y_ref, e_ref, w_ref = f.run(d, X)
    y, e, w = ndr.rls_filter(d, X, lam=0.98, delta=100.0)
    np.testing.assert_allclose(y, y_ref, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(e, e_ref, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(w, w_ref, rtol=1e-8, atol=1e-10)


def test_arx2_identifies_and_to_tf_gives_scipys_convention(data):
    u, y = data
    arx = ndr.Arx2(DT)
    assert arx.update(u[0], y[0]) is None and arx.predict(u[1]) is None
    assert arx.update(u[1], y[1]) is None
    assert isinstance(arx.update(u[2], y[2]), float)
    for k in range(3, len(u)):
        arx.update(u[k], y[k])
    num, den, dt = arx.to_tf()
    np.testing.assert_allclose(num, NUM, atol=1e-6)
    np.testing.assert_allclose(den, DEN, atol=1e-6)
    assert den[0] == 1.0 and dt == DT
    assert arx.updates == len(u) - 2
    np.testing.assert_allclose(arx.rls.w, [*num, *den[1:]])
    assert arx.model == ndr.Tf2(num, den, dt)


def test_to_tf_round_trip():
    tf = ndr.Tf2.low_pass(2.0, 0.5, 3.0, 0.5)
    np.testing.assert_allclose(tf.num, [3 / 7, 6 / 7, 3 / 7], rtol=1e-12)
    np.testing.assert_allclose(tf.den, [1.0, -6 / 7, 3 / 7], rtol=1e-12)
    num, den, dt = tf.to_tf()
    assert dt == 0.5
    assert ndr.Tf2(num, den, dt) == tf
    assert ndr.Tf2(2 * num, 2 * den, dt) == tf  # den[0] is normalized away
    assert tf.dc_gain == pytest.approx(3.0)
    assert tf.is_stable()
    assert ndr.Tf2(*ndr.Tf2(NUM, DEN, DT).to_tf()) == ndr.Tf2(NUM, DEN, DT)


def test_tf2_simulation_matches_the_difference_equation(data):
    u, y = data
    tf = ndr.Tf2(NUM, DEN, DT)
    np.testing.assert_allclose(tf.simulate(u), y, rtol=1e-12, atol=1e-12)
    state = ndr.Tf2State(tf)
    np.testing.assert_allclose([state.step(v) for v in u[:50]], y[:50], atol=1e-12)
    assert state.output == pytest.approx(y[49])


def test_tf2_agrees_with_scipy_when_installed(data):
    signal = pytest.importorskip("scipy.signal")
    u, _ = data
    tf = ndr.Tf2.low_pass(3.0, 0.7, 1.5, 0.1)
    num, den, dt = tf.to_tf()
    np.testing.assert_allclose(tf.simulate(u), signal.lfilter(num, den, u), atol=1e-12)
    _, y_step = signal.dstep((num, den, dt), n=5)
    np.testing.assert_allclose(tf.simulate(np.ones(5)), y_step[0].ravel(), atol=1e-12)


def delayed_loop(df, db, n=300, seed=11):
    rng = np.random.default_rng(seed)
    u = np.repeat(rng.normal(size=n // 5), 5)
    p = np.concatenate([np.zeros(df), u])  # the plant's input p[m] = u[m - df]
    y = simulate(p)  # y[m], m up to n + df - 1
    return u, y


def test_estimator_with_the_true_model_predicts_exactly():
    df, db = 2, 3
    u, y = delayed_loop(df, db)
    est = ndr.Estimator(df, db, model=ndr.Tf2(NUM, DEN, DT))
    assert est.dt == DT and not est.is_identifying and est.delays == (df, db)
    for n in range(len(u)):
        x3e, x3p, from_model = est.step(u[n], y[n - db] if n >= db else None)
        if n > df + db + 3:
            assert from_model
            assert x3e == pytest.approx(y[n], abs=1e-12)
            assert x3p == pytest.approx(y[n + df], abs=1e-12)
    assert est.ticks == len(u)


def test_estimator_identifies_then_predicts():
    df, db = 1, 2
    u, y = delayed_loop(df, db, n=600)
    est = ndr.Estimator(df, db, dt=DT)
    assert est.is_identifying
    for n in range(len(u)):
        x3e, x3p, from_model = est.step(u[n], y[n - db] if n >= db else None)
    assert from_model
    assert x3e == pytest.approx(y[len(u) - 1], abs=1e-6)
    assert x3p == pytest.approx(y[len(u) - 1 + df], abs=1e-6)
    num, den, dt = est.to_tf()
    np.testing.assert_allclose(num, NUM, atol=1e-6)
    np.testing.assert_allclose(den, DEN, atol=1e-6)
    assert est.arx.updates > 0


def test_tf2_takes_the_numerators_scipy_and_python_control_give():
    signal = pytest.importorskip("scipy.signal")
    # cont2discrete returns the numerator as a (1, 3) array.
    num, den, dt = signal.cont2discrete(([4.0], [1.0, 1.2, 4.0]), DT, method="bilinear")
    assert np.shape(num) == (1, 3)
    tf = ndr.Tf2(num, den, dt)
    np.testing.assert_allclose(tf.num, num[0] / den[0], rtol=1e-12)
    # A shorter numerator is a polynomial in z, padded on the left:
    # (z + 0.5) / (z² − 1.4 z + 0.5) is [0, 1, 0.5], as scipy.signal.dlti reads it.
    short = ndr.Tf2([1.0, 0.5], DEN, DT)
    np.testing.assert_array_equal(short.num, [0.0, 1.0, 0.5])
    _, y_ref = signal.dlti([1.0, 0.5], DEN, dt=DT).output(np.ones(30), t=np.arange(30) * DT)
    np.testing.assert_allclose(short.simulate(np.ones(30)), np.ravel(y_ref), rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(ndr.Tf2([2.0], DEN, DT).num, [0.0, 0.0, 2.0])
    with pytest.raises(ValueError, match=r"num: expected a 1-D array of 1 to 3 coefficients, or one row of them, got shape \(4,\)"):
        ndr.Tf2([1.0, 2.0, 3.0, 4.0], DEN, DT)


def test_to_tf_as_the_docstring_says_gives_scipy_the_same_system():
    signal = pytest.importorskip("scipy.signal")
    tf = ndr.Tf2(NUM, DEN, DT)
    for doc in (ndr.Tf2.to_tf.__doc__, ndr.Tf2.__doc__, ndr.Arx2.to_tf.__doc__):
        assert "dlti(*" not in (doc or "")
    num, den, dt = tf.to_tf()
    _, y = signal.dlti(num, den, dt=dt).step(n=40)
    np.testing.assert_allclose(np.ravel(y[0]), tf.simulate(np.ones(40)), rtol=1e-12, atol=1e-14)


def test_arx2_warns_when_the_input_does_not_excite_the_model():
    u = np.ones(200)
    arx = ndr.Arx2(DT)
    with pytest.warns(RuntimeWarning, match="2 of its 5 directions are not determined"):
        arx.fit(u, simulate(u))
    assert arx.unexcited == 2
    with pytest.warns(RuntimeWarning, match="did not excite the model"):
        arx.to_tf()
    with pytest.warns(RuntimeWarning, match="did not excite the model"):
        arx.model
    # A rich input: no warning, every direction determined.
    rng = np.random.default_rng(7)
    u = rng.normal(size=200)
    rich = ndr.Arx2(DT)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rich.fit(u, simulate(u))
        rich.to_tf()
    assert rich.unexcited == 0
