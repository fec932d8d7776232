"""ndr: a regulated teleoperation link.

Periodic samples travel both ways over TCP; a Network Delay Regulator at each
input releases them at a constant period, so the controller sees a constant,
known delay. This package is the Python face of the Rust crates.

The building blocks, with the names Python users already know:

- sizing: :func:`init_stats`, :func:`nominal_size`, :func:`period_law`;
- the queue: :class:`Regulator` (raises :class:`RegulatorFull` when full);
- the paper's network predictor: :class:`Kalman3` (filterpy's ``x, P, Q, R,
  F, H``, ``predict()``, ``update(z)``), :class:`NetworkPredictor`,
  :class:`LowPass`, :class:`Envelope`;
- the remote's model: :class:`Rls` (padasip's ``adapt(d, x)``,
  ``predict(x)``, ``w``), :class:`Tf2`, :class:`Tf2State`, :class:`Arx2`,
  :class:`Estimator` (``to_tf()`` gives scipy.signal's ``(num, den, dt)``);
- batch functions on numpy arrays, run without the GIL:
  :func:`kalman3_filter`, :func:`rls_filter`, :func:`lowpass`,
  :func:`envelope`.

Times are seconds (float); arrays are float64. Bad input raises ValueError
(or TypeError for a wrong kind of object) naming what was expected. The link
and the simulator follow.
"""

from ._native import (
    ESTIMATOR_HISTORY,
    INIT_EXCHANGES,
    MAX_CAPACITY,
    Arx2,
    Envelope,
    Estimator,
    Kalman3,
    LowPass,
    NetworkPredictor,
    Prediction,
    Regulator,
    RegulatorFull,
    Rls,
    Tf2,
    Tf2State,
    __version__,
    envelope,
    init_stats,
    kalman3_filter,
    lowpass,
    nominal_size,
    period_law,
    rls_filter,
)

__all__ = [
    "ESTIMATOR_HISTORY",
    "INIT_EXCHANGES",
    "MAX_CAPACITY",
    "Arx2",
    "Envelope",
    "Estimator",
    "Kalman3",
    "LowPass",
    "NetworkPredictor",
    "Prediction",
    "Regulator",
    "RegulatorFull",
    "Rls",
    "Tf2",
    "Tf2State",
    "__version__",
    "envelope",
    "init_stats",
    "kalman3_filter",
    "lowpass",
    "nominal_size",
    "period_law",
    "rls_filter",
]
