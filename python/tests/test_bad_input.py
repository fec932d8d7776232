"""Every bad input raises ValueError or TypeError naming what was expected."""

import math

import numpy as np
import pytest

import ndr

NAN = math.nan


def regulator_full_of(ns=1, width=3):
    r = ndr.Regulator(ns, width)
    return r


def kalman():
    return ndr.Kalman3(0.2)


CASES = [
    # (call, exception, words the message must contain)
    # Regulator
    (lambda: ndr.Regulator(-1), ValueError, "ns must be an integer"),
    (lambda: ndr.Regulator(2**80), ValueError, "ns must be an integer"),
    (lambda: ndr.Regulator(1.5), TypeError, "ns must be an integer"),  # type: ignore[arg-type]
    (lambda: ndr.Regulator("2"), TypeError, "ns must be an integer"),  # type: ignore[arg-type]
    (lambda: ndr.Regulator(1, 0), ValueError, "width must be an integer"),
    (lambda: ndr.Regulator(1, capacity=0), ValueError, "capacity must be an integer"),
    (lambda: ndr.Regulator(1, capacity=10**6), ValueError, "capacity must be an integer"),
    (lambda: ndr.Regulator(8, capacity=8), ValueError, "capacity 8"),
    (lambda: regulator_full_of().push([1.0, 2.0]), ValueError, "shape (3,)"),
    (lambda: regulator_full_of().push([[1.0, 2.0, 3.0]]), ValueError, "1-D array"),
    (lambda: regulator_full_of().push(1.0), ValueError, "shape (3,)"),
    (lambda: regulator_full_of().push(["a", "b", "c"]), ValueError, "float64"),
    (lambda: regulator_full_of().push("abc"), ValueError, "float64"),
    (lambda: regulator_full_of().push([1.0, NAN, 2.0]), ValueError, "sample[1] is nan"),
    (lambda: regulator_full_of().push([1, [2, 3], 4]), ValueError, "1-D array"),
    (lambda: regulator_full_of().push([1j, 2, 3]), ValueError, "float64"),
    (lambda: regulator_full_of().push(None), ValueError, "float64"),
    (lambda: regulator_full_of(width=1).push(NAN), ValueError, "finite"),
    (lambda: regulator_full_of(width=1).push("x"), ValueError, "float64"),
    # Kalman3
    (lambda: ndr.Kalman3(0.0), ValueError, "period"),
    (lambda: ndr.Kalman3(-0.2), ValueError, "period"),
    (lambda: ndr.Kalman3(NAN), ValueError, "period"),
    (lambda: ndr.Kalman3("0.2"), TypeError, "real number"),  # type: ignore[arg-type]
    (lambda: ndr.Kalman3(0.2, sigma_q=0.0), ValueError, "sigma_q"),
    (lambda: ndr.Kalman3(0.2, sigma_q=NAN), ValueError, "sigma_q"),
    (lambda: ndr.Kalman3(0.2, horizon=-1), ValueError, "horizon"),
    (lambda: ndr.Kalman3(0.2, horizon=2.5), TypeError, "horizon"),  # type: ignore[arg-type]
    (lambda: kalman().update(NAN), ValueError, "not finite"),
    (lambda: kalman().update("1.0"), TypeError, "real number"),
    (lambda: kalman().step(math.inf), ValueError, "not finite"),
    (lambda: setattr(kalman(), "x", [1.0, 2.0]), ValueError, "shape (3,)"),
    (lambda: setattr(kalman(), "x", np.zeros((3, 1))), ValueError, "1-D array"),
    (lambda: setattr(kalman(), "x", [0.0, NAN, 0.0]), ValueError, "x[1] is nan"),
    (lambda: setattr(kalman(), "period", 0.0), ValueError, "period"),
    (lambda: setattr(kalman(), "P", np.eye(2)), ValueError, "P: expected a 2-D array of shape (3, 3)"),
    # NetworkPredictor
    (lambda: ndr.NetworkPredictor(0.0), ValueError, "period"),
    (lambda: ndr.NetworkPredictor(0.2, decay=0.5), ValueError, "decay"),
    (lambda: ndr.NetworkPredictor(0.2, nrtt_tau=-1.0), ValueError, "nrtt_tau"),
    (lambda: ndr.NetworkPredictor(0.2, eta=0.0), ValueError, "eta"),
    (lambda: ndr.NetworkPredictor(0.2).observe_nrtt(-0.1), ValueError, "nrtt"),
    (lambda: ndr.NetworkPredictor(0.2).observe_gap(NAN), ValueError, "gap"),
    (lambda: ndr.NetworkPredictor(0.2).update(nrtt=math.inf), ValueError, "nrtt"),
    # Rls
    (lambda: ndr.Rls(0), ValueError, "n must be an integer from 1 to 8"),
    (lambda: ndr.Rls(9), ValueError, "n must be an integer from 1 to 8"),
    (lambda: ndr.Rls(3, lam=1.5), ValueError, "(0, 1]"),
    (lambda: ndr.Rls(3, delta=-1.0), ValueError, "> 0"),
    (lambda: ndr.Rls(3, trace_bound=1.0), ValueError, "trace bound"),
    (lambda: ndr.Rls(3).adapt(1.0, [1.0, 2.0]), ValueError, "shape (3,)"),
    (lambda: ndr.Rls(3).adapt(NAN, [1.0, 2.0, 3.0]), ValueError, "d must be a finite"),
    (lambda: ndr.Rls(3).adapt(1.0, [1.0, NAN, 3.0]), ValueError, "x[1] is nan"),
    (lambda: ndr.Rls(3).adapt(1.0, "abc"), ValueError, "float64"),
    (lambda: ndr.Rls(3).predict(np.ones((3, 1))), ValueError, "1-D array"),
    (lambda: ndr.Rls(3).adapt(1.0, [1e200, 1e200, 0.0]), ValueError, "overflow"),
    (lambda: setattr(ndr.Rls(2), "w", [1.0]), ValueError, "shape (2,)"),
    (lambda: setattr(ndr.Rls(2), "lam", 0.0), ValueError, "(0, 1]"),
    (lambda: ndr.Rls(2).run(np.ones(3), np.ones((3, 3))), ValueError, "shape (n, 2)"),
    (lambda: ndr.Rls(2).run(np.ones(4), np.ones((3, 2))), ValueError, "same number"),
    (lambda: ndr.Rls(2).run(np.ones((3, 1)), np.ones((3, 2))), ValueError, "1-D array"),
    (lambda: ndr.rls_filter(np.ones(3), np.ones(3)), ValueError, "2-D array"),
    (lambda: ndr.rls_filter(np.ones(3), np.ones((3, 9))), ValueError, "1 <= n <= 8"),
    (lambda: ndr.rls_filter(np.ones(3), np.ones((3, 0))), ValueError, "1 <= n <= 8"),
    (lambda: ndr.rls_filter(np.ones(3), np.ones((3, 2, 1))), ValueError, "3 dimensions"),
    (lambda: ndr.rls_filter([1, NAN, 2], np.ones((3, 2))), ValueError, "d[1] is nan"),
    (lambda: ndr.rls_filter(np.ones(3), np.full((3, 2), NAN)), ValueError, "x[0, 0] is nan"),
    # Tf2, Tf2State, Arx2, Estimator
    (lambda: ndr.Tf2([1.0, 2.0, 3.0, 4.0], [1.0, 0.5, 0.1], 0.1), ValueError, "num: expected"),
    (lambda: ndr.Tf2([1.0, 2.0, 3.0], [0.0, 0.5, 0.1], 0.1), ValueError, "den[0]"),
    (lambda: ndr.Tf2([1.0, 2.0, 3.0], [1.0, 0.5, 0.1], 0.0), ValueError, "dt"),
    (lambda: ndr.Tf2([1.0, 2.0, 3.0], [1.0, NAN, 0.1], 0.1), ValueError, "den[1] is nan"),
    (lambda: ndr.Tf2.low_pass(0.0, 0.7, 1.0, 0.1), ValueError, "natural frequency"),
    (lambda: ndr.Tf2.low_pass(1.0, 0.7, 1.0, 1e-300), ValueError, "degenerate"),
    (lambda: ndr.Tf2([1, 0, 0], [1, 0, 0], 0.1).simulate(np.ones((2, 2))), ValueError, "1-D"),
    (lambda: ndr.Tf2([1, 0, 0], [1, 0, 0], 0.1).simulate([1, NAN]), ValueError, "u[1] is nan"),
    (lambda: ndr.Tf2State(ndr.Tf2([1, 0, 0], [1, 0, 0], 0.1), y_past=[1.0]), ValueError, "y_past"),
    (lambda: ndr.Tf2State(ndr.Tf2([1, 0, 0], [1, 0, 0], 0.1)).step(NAN), ValueError, "u must"),
    (lambda: ndr.Arx2(0.1, lam=0.0), ValueError, "forgetting factor"),
    (lambda: ndr.Arx2(-0.1), ValueError, "dt"),
    (lambda: ndr.Arx2(0.1).update(1.0, NAN), ValueError, "NaN or infinite"),
    (lambda: ndr.Arx2(0.1).fit([1.0, 2.0], [1.0]), ValueError, "same number"),
    (lambda: ndr.Estimator(1, 1), ValueError, "needs dt"),
    (lambda: ndr.Estimator(-1, 1, dt=0.1), ValueError, "delay_fwd must be"),
    (lambda: ndr.Estimator(3000, 2000, dt=0.1), ValueError, "at most 4096"),
    (
        lambda: ndr.Estimator(1, 1, dt=0.2, model=ndr.Tf2([1, 0, 0], [1, 0, 0], 0.1)),
        ValueError,
        "differs",
    ),
    (lambda: ndr.Estimator(1, 1, dt=0.1).step(NAN), ValueError, "u must"),
    (lambda: ndr.Estimator(1, 1, dt=0.1).step(1.0, math.inf), ValueError, "y must"),
    (lambda: ndr.Estimator(1, 1, dt=0.1).run([1.0], [NAN]), ValueError, "received"),
    (lambda: ndr.Estimator(1, 1, dt=0.1).run([1.0], [1.0], [1]), ValueError, "bool"),
    (lambda: ndr.Estimator(1, 1, dt=0.1).run([1.0], [1.0], [True, False]), ValueError, "same"),
    (lambda: setattr(ndr.Estimator(1, 1, dt=0.1), "delays", (5000, 0)), ValueError, "delay"),
    # Filters and batch functions
    (lambda: ndr.LowPass(-1.0, 0.2), ValueError, "tau"),
    (lambda: ndr.LowPass(1.0, 0.0), ValueError, "period"),
    (lambda: ndr.LowPass.from_alpha(1.5), ValueError, "(0, 1]"),
    (lambda: ndr.LowPass(1.0, 0.2).update(NAN), ValueError, "not finite"),
    (lambda: ndr.Envelope(0.5), ValueError, ">= 1"),
    (lambda: ndr.Envelope().update(math.inf), ValueError, "not finite"),
    (lambda: ndr.lowpass([[1.0]], 1.0, 0.2), ValueError, "1-D array"),
    (lambda: ndr.lowpass([1.0, NAN], 1.0, 0.2), ValueError, "x[1] is nan"),
    (lambda: ndr.lowpass(["a"], 1.0, 0.2), ValueError, "float64"),
    (lambda: ndr.envelope(np.zeros(3), decay=NAN), ValueError, "decay"),
    (lambda: ndr.kalman3_filter(np.zeros((2, 2)), period=0.2), ValueError, "(2 dimensions)"),
    (lambda: ndr.kalman3_filter(np.float64(1.0), period=0.2), ValueError, "(0 dimensions)"),
    (lambda: ndr.kalman3_filter(np.array(["1"]), period=0.2), ValueError, "float64"),
    (lambda: ndr.kalman3_filter(np.array([1, None]), period=0.2), ValueError, "object"),
    (lambda: ndr.kalman3_filter([0.0, math.inf], period=0.2), ValueError, "z[1] is inf"),
    (lambda: ndr.kalman3_filter([0.0], period=-1.0), ValueError, "period"),
    (lambda: ndr.kalman3_filter([0.0], period=0.2, x0=[1.0]), ValueError, "x: expected"),
    (lambda: ndr.kalman3_filter([0.0], 0.2), TypeError, "positional"),  # type: ignore[call-arg]
    # Sizing: the shape named, a period under a nanosecond called that, a huge
    # value written in scientific notation.
    (lambda: ndr.init_stats(np.ones((2, 2))), ValueError, "got shape (2, 2) (2 dimensions)"),
    (lambda: ndr.nominal_size(0.1, 1e-10), ValueError, "at least 1 ns), got 1e-10"),
    (lambda: ndr.nominal_size(0.1, 1e300), ValueError, "period = 1e300 s is too long"),
    # A link's settings are refused before it dials.
    (lambda: ndr.Link.connect(("127.0.0.1", 9), regulation="adaptive:0.1:0.5"), ValueError, "QUANTUM_MS"),
    (lambda: ndr.Link.connect(("127.0.0.1", 9), regulation="lifo"), ValueError, "regulation"),
    (lambda: ndr.Link.connect(("127.0.0.1", 9), regulation="fifo"), ValueError, "paper-dynamic"),
    (lambda: ndr.Link.connect(("127.0.0.1", 9), regulation="neteq", mode="paper-static"),
     TypeError, "mode"),
    (lambda: ndr.Link.connect(("127.0.0.1", 9), realtime="fifo"), ValueError, "enforce, try or off"),
    (lambda: ndr.Link.connect(("127.0.0.1", 9), rt_priority=0), ValueError, "rt_priority"),
    (lambda: ndr.Link.connect(("127.0.0.1", 9), rt_priority=100), ValueError, "rt_priority"),
    (lambda: ndr.Link.listen(("127.0.0.1", 0), rt_cpu=-1), ValueError, "rt_cpu"),
]


@pytest.mark.parametrize(("call", "exc", "words"), CASES)
def test_bad_input_is_refused_with_a_message(call, exc, words):
    with pytest.raises(exc) as info:
        call()
    assert words.lower() in str(info.value).lower()


def test_a_refused_push_changes_nothing():
    r = ndr.Regulator(0, 2)
    with pytest.raises(ValueError):
        r.push([1.0, NAN])
    assert len(r) == 0 and r.arrived == 0


def test_a_failed_batch_changes_nothing():
    rls = ndr.Rls(2, lam=0.5, delta=1.0)
    rls.adapt(1.0, [1.0, 0.5])
    w, P = rls.w, rls.P
    X = np.array([[1.0, 0.0], [1e200, 1e200]])
    with pytest.raises(ValueError, match="sample 1"):
        rls.run([1.0, 0.0], X)
    np.testing.assert_array_equal(rls.w, w)
    np.testing.assert_array_equal(rls.P, P)
    assert rls.updates == 1
