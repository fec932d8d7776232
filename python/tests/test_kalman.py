"""Kalman3 against filterpy's equations, written out in numpy; the predictor."""

import numpy as np
import pytest

import ndr

T = 0.2
SIGMA_Q = 0.5


def filterpy_model(period, sigma_q):
    F = np.array([[1.0, period, period**2 / 2], [0.0, 1.0, period], [0.0, 0.0, 1.0]])
    H = np.array([[1.0, 0.0, 0.0]])
    Q = np.diag([0.0, 0.0, sigma_q**2])
    R = np.array([[sigma_q**2]])
    return F, H, Q, R


def reference_run(zs, x0, period=T, sigma_q=SIGMA_Q, model=None, P0=None):
    """filterpy's KalmanFilter.predict/update, written out (Joseph form)."""
    F, H, Q, R = model if model is not None else filterpy_model(period, sigma_q)
    x = np.array(x0, dtype=float).reshape(3, 1)
    P = np.eye(3) * sigma_q**2 if P0 is None else np.array(P0, dtype=float)
    out = []
    for z in zs:
        x = F @ x
        P = F @ P @ F.T + Q
        y = np.array([[z]]) - H @ x
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        x = x + K @ y
        I_KH = np.eye(3) - K @ H
        P = I_KH @ P @ I_KH.T + K @ R @ K.T
        out.append((x.ravel().copy(), P.copy(), float(y[0, 0])))
    return out


ZS = [1.0, 1.3, 0.9, 1.6, 1.75, 2.2, 2.1, 2.6]


def test_matrices_have_filterpys_names_and_shapes():
    k = ndr.Kalman3(T, sigma_q=SIGMA_Q, horizon=5)
    F, H, Q, R = filterpy_model(T, SIGMA_Q)
    np.testing.assert_allclose(k.F, F, rtol=0, atol=1e-15)
    np.testing.assert_allclose(k.A, F, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(k.H, H)
    np.testing.assert_allclose(k.Q, Q)
    np.testing.assert_allclose(k.R, R)
    np.testing.assert_allclose(k.P, np.eye(3) * SIGMA_Q**2)
    np.testing.assert_allclose(k.F_ahead, np.linalg.matrix_power(F, 5), atol=1e-12)
    assert k.x.shape == (3,) and k.x.dtype == np.float64
    assert (k.period, k.sigma_q, k.horizon) == (pytest.approx(T), pytest.approx(SIGMA_Q), 5)


def test_predict_update_match_the_equations():
    x0 = [0.8, 0.5, 0.0]
    k = ndr.Kalman3(T, sigma_q=SIGMA_Q, horizon=10)
    k.x = x0
    for z, (x_ref, P_ref, y_ref) in zip(ZS, reference_run(ZS, x0)):
        k.predict()
        innovation = k.update(z)
        assert innovation == pytest.approx(y_ref, rel=1e-12, abs=1e-12)
        assert k.y == innovation
        np.testing.assert_allclose(k.x, x_ref, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(k.P, P_ref, rtol=1e-10, atol=1e-12)
    F10 = np.linalg.matrix_power(filterpy_model(T, SIGMA_Q)[0], 10)
    np.testing.assert_allclose(k.predict_ahead_state(), F10 @ k.x, rtol=1e-12)
    assert k.predict_ahead() == pytest.approx((F10 @ k.x)[0], rel=1e-12)


def test_step_is_predict_then_update():
    a = ndr.Kalman3(T)
    b = ndr.Kalman3(T)
    for z in ZS:
        a.predict()
        a.update(z)
        assert b.step(z) == a.x[0] == a.value
    np.testing.assert_array_equal(a.P, b.P)


def test_against_filterpy_itself_when_installed():
    kalman = pytest.importorskip("filterpy.kalman")
    F, H, Q, R = filterpy_model(T, SIGMA_Q)
    kf = kalman.KalmanFilter(dim_x=3, dim_z=1)
    kf.F, kf.H, kf.Q, kf.R = F, H, Q, R
    kf.x = np.array([[0.8], [0.5], [0.0]])
    kf.P = np.eye(3) * SIGMA_Q**2
    k = ndr.Kalman3(T, sigma_q=SIGMA_Q)
    k.x = [0.8, 0.5, 0.0]
    for z in ZS:
        kf.predict()
        kf.update(z)
        k.predict()
        k.update(z)
        np.testing.assert_allclose(k.x, kf.x.ravel(), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(k.P, kf.P, rtol=1e-10, atol=1e-12)


def test_period_change_and_reset():
    k = ndr.Kalman3(T)
    for i in range(400):
        k.step(2.0 * i * T)
    x = k.x
    k.period = 0.05
    np.testing.assert_array_equal(k.x, x)
    assert k.predict_ahead() == pytest.approx(x[0] + 2.0 * 50 * 0.05, rel=1e-9)
    k.reset()
    np.testing.assert_array_equal(k.x, np.zeros(3))
    np.testing.assert_allclose(k.P, np.eye(3))


def test_a_rejected_measurement_changes_nothing():
    k = ndr.Kalman3(T)
    k.step(1.0)
    x, P = k.x, k.P
    for bad in (np.nan, np.inf):
        with pytest.raises(ValueError, match="not finite"):
            k.update(bad)
        with pytest.raises(ValueError, match="not finite"):
            k.step(bad)
    np.testing.assert_array_equal(k.x, x)
    np.testing.assert_array_equal(k.P, P)


def test_network_predictor_gives_the_papers_new_parameters_on_a_lan():
    p = ndr.NetworkPredictor(0.2)
    assert p.step() is None
    last = None
    for k in range(2000):
        last = p.update(nrtt=0.023, gap=0.012 if k % 10 == 0 else 0.001)
    assert isinstance(last, ndr.Prediction)
    assert last.nrtt_mean == pytest.approx(0.023, abs=1e-9)
    assert last.nrtt_ahead == pytest.approx(0.023, abs=1e-6)
    assert last.period == pytest.approx(0.05)
    assert last.ns == 2
    assert last.mt == pytest.approx(0.012, abs=1e-5)
    assert p.last == last and p.steps == 2000
    assert isinstance(p.nrtt_filter, ndr.Kalman3)
    assert p.nrtt_filter.value == pytest.approx(0.023, abs=1e-9)
    p.period = 0.05
    assert p.period == pytest.approx(0.05)


def test_network_predictor_observes_separately():
    p = ndr.NetworkPredictor(0.2, horizon=10, eta=1.0, min_period=0.01)
    p.observe_nrtt(0.3)
    assert p.step() is None
    p.observe_gap(0.05)
    pred = p.step()
    assert pred.period == pytest.approx(0.1)
    assert pred.ns == 2
    assert "Prediction(" in repr(pred)


def test_a_filterpy_user_tunes_the_filter_by_assignment():
    # A damped constant-velocity model measured through its rate and value.
    F = np.array([[1.0, T, 0.0], [0.0, 0.95, 0.0], [0.0, 0.0, 0.0]])
    H = np.array([[1.0, 0.5, 0.0]])
    Q = np.diag([1e-3, 1e-2, 0.0])
    R = np.array([[0.3]])
    P0 = np.diag([2.0, 1.0, 0.5])
    k = ndr.Kalman3(T, horizon=4)
    k.F, k.H, k.Q, k.R, k.P = F, H, Q, R, P0
    k.x = [0.5, 0.1, 0.0]
    np.testing.assert_array_equal(k.F, F)
    np.testing.assert_array_equal(k.H, H)
    np.testing.assert_array_equal(k.Q, Q)
    np.testing.assert_array_equal(k.R, R)
    np.testing.assert_allclose(k.F_ahead, np.linalg.matrix_power(F, 4), rtol=1e-12)
    for z, (x_ref, P_ref, y_ref) in zip(ZS, reference_run(ZS, [0.5, 0.1, 0.0], model=(F, H, Q, R), P0=P0)):
        k.predict()
        assert k.update(z) == pytest.approx(y_ref, rel=1e-12, abs=1e-12)
        np.testing.assert_allclose(k.x, x_ref, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(k.P, P_ref, rtol=1e-10, atol=1e-12)
    assert k.value == pytest.approx((H @ k.x)[0], rel=1e-12)
    # filterpy's other spellings: R as a number, H as 1-D, A for F.
    k.R = 5
    k.H = [1.0, 0.0, 0.0]
    k.A = np.eye(3)
    assert k.R.shape == (1, 1) and k.R[0, 0] == 5.0
    np.testing.assert_array_equal(k.H, [[1.0, 0.0, 0.0]])
    np.testing.assert_array_equal(k.F, np.eye(3))


def test_writing_into_a_copy_raises_instead_of_doing_nothing():
    k = ndr.Kalman3(T)
    k.x = [1.0, 2.0, 3.0]
    for name, index in [("x", 0), ("P", (0, 0)), ("Q", (2, 2)), ("R", (0, 0)), ("F", (0, 1)), ("H", (0, 0))]:
        with pytest.raises(ValueError, match="read-only"):
            getattr(k, name)[index] = 5.0
    np.testing.assert_array_equal(k.x, [1.0, 2.0, 3.0])
    # The copy-and-assign spelling works.
    x = k.x.copy()
    x[0] = 5.0
    k.x = x
    assert k.value == 5.0


@pytest.mark.parametrize(
    "name, value, message",
    [
        ("x", [1.0, 2.0], r"x: expected a 1-D array of shape \(3,\), got shape \(2,\)"),
        ("P", np.eye(2), r"P: expected a 2-D array of shape \(3, 3\), got shape \(2, 2\)"),
        ("Q", np.ones(3), r"Q: expected a 2-D array of shape \(3, 3\), got shape \(3,\)"),
        ("F", np.eye(4), r"F: expected a 2-D array of shape \(3, 3\), got shape \(4, 4\)"),
        ("H", [1.0, 0.0], r"H: expected a 2-D array of shape \(1, 3\) or a 1-D array of shape \(3,\), got shape \(2,\)"),
        ("R", np.ones((2, 2)), r"R: expected a number or a 2-D array of shape \(1, 1\), got shape \(2, 2\)"),
        ("R", 0.0, "R = 0 must be finite and positive"),
        ("Q", np.full((3, 3), np.nan), "finite"),
    ],
)
def test_assignments_check_the_shape(name, value, message):
    k = ndr.Kalman3(T)
    before = (k.x, k.P, k.F, k.H, k.Q, k.R)
    with pytest.raises(ValueError, match=message):
        setattr(k, name, value)
    for a, b in zip(before, (k.x, k.P, k.F, k.H, k.Q, k.R)):
        np.testing.assert_array_equal(a, b)
