"""Type stubs of the extension module ``ndr._native``.

Times are seconds (float). Arrays come out as float64 numpy arrays; anything
numpy can read as real numbers goes in (lists, tuples, integer arrays).
A wrong shape, dtype or number of axes, a NaN or an infinity raises
``ValueError`` naming what was expected; an object of the wrong kind for a
number raises ``TypeError``.
"""

import os
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union, final, overload

import numpy as np
import numpy.typing as npt

from .link import LinkStats, ListenerStats, RelayStats, SharingStats

_Floats = npt.NDArray[np.float64]
_ArrayLike = npt.ArrayLike
_Tf = Tuple[_Floats, _Floats, float]

__all__ = [
    "ESTIMATOR_HISTORY",
    "INIT_EXCHANGES",
    "MAX_AXES",
    "MAX_WIDTH",
    "MAX_CAPACITY",
    "REGULATIONS",
    "REGULATION_NAMES",
    "DisconnectedError",
    "HandshakeError",
    "LinkClosedError",
    "LinkError",
    "PeerClosedError",
    "ProtocolError",
    "Relay",
    "Signal",
    "Tick",
    "TlsConfig",
    "connect",
    "keygen",
    "flush_logs",
    "listen",
    "set_log_level",
    "sim_run",
    "__version__",
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
    "SMITH_HISTORY",
    "Pid",
    "SmithPredictor",
    "WaveEnergy",
    "WaveTransform",
    "round_trip_ticks",
    "envelope",
    "init_stats",
    "kalman3_filter",
    "lowpass",
    "nominal_size",
    "period_law",
    "rls_filter",
]

__version__: str
INIT_EXCHANGES: int
MAX_CAPACITY: int
"""The largest ``capacity`` of a :class:`Regulator` (4096)."""
ESTIMATOR_HISTORY: int
"""An :class:`Estimator` needs ``delay_fwd + delay_bwd + 3 <= ESTIMATOR_HISTORY`` (4096)."""

# ---------------------------------------------------------------- sizing

def nominal_size(mt: float, period: float, *, eta: float = 1.3) -> int:
    """Nominal NDR queue size ``2 + floor(eta * mt / period)`` (never below 2).

    ``mt`` and ``period`` are in seconds. Raises ``ValueError`` for negative or
    non-finite values, a zero period or a non-positive ``eta``.
    """

def period_law(nrtt: float, *, min_period: float = 0.05) -> float:
    """The paper's period law ``max(min_period, nrtt / 3)``, in seconds."""

def init_stats(
    nrtt: Union[Sequence[float], npt.NDArray[np.floating[Any]], npt.NDArray[np.integer[Any]]],
) -> tuple[float, float, float, float]:
    """``(nrtt_min, nrtt_max, nrtt_mean, mt)`` of an initialization pattern.

    Takes 1 to ``INIT_EXCHANGES`` round-trip times in seconds (a list, a
    tuple or a 1-D numpy array); ``mt`` is the largest lag of a reception
    behind its schedule, ``max - min``.
    """

# ---------------------------------------------------------------- regulator

class RegulatorFull(OverflowError):
    """Raised by :meth:`Regulator.push` when the queue is full.

    Nothing is lost: the refused sample is in :attr:`sample`, and the
    rejection is counted in :attr:`Regulator.rejected`.
    """

    sample: _Floats

@final
class Regulator:
    """The Network Delay Regulator: a FIFO of float64 vectors of a fixed
    ``width``, released one per :meth:`tick` at a constant period.

    The queue is pre-filled: releases start at the first tick that finds more
    than ``ns`` samples queued, so ``ns`` samples of stock stay behind each
    release. Nothing is dropped silently; at every moment
    ``arrived == released + len + rejected + discarded``.

    ``Regulator(ns, width=1, *, capacity=64)``: ``0 <= ns < capacity <=
    MAX_CAPACITY``.
    """

    def __new__(cls, ns: int, width: int = 1, *, capacity: int = 64) -> "Regulator": ...
    def __copy__(self) -> "Regulator":
        """An independent copy: queue, samples, phase and counters."""
    def __deepcopy__(self, memo: object) -> "Regulator": ...
    def push(self, sample: Union[float, _ArrayLike]) -> None:
        """Queues a sample that has just arrived: a float when ``width`` is 1,
        else ``width`` floats. Raises :class:`RegulatorFull` when full."""
    def tick(self) -> Optional[_Floats]:
        """One tick of the release clock: the released sample, shape
        ``(width,)``, or None while pre-filling or on an underflow (see
        :attr:`last_tick`)."""
    @property
    def last_tick(self) -> Optional[str]:
        """What the last tick did: ``"released"``, ``"prefilling"``,
        ``"underflow"``, or None before the first tick."""
    @property
    def phase(self) -> str:
        """``"prefilling"`` until a tick finds more than ``ns`` queued, then ``"running"``."""
    def front(self) -> Optional[_Floats]:
        """The oldest queued sample (the next released), not removed."""
    def samples(self) -> _Floats:
        """The queued samples, oldest first, shape ``(len, width)``."""
    def discard_front(self) -> Optional[_Floats]:
        """Removes the oldest sample without releasing it (counted as discarded)."""
    def clear(self) -> int:
        """Empties the queue (counted as discarded); returns how many were removed."""
    def restart_prefill(self) -> None:
        """Goes back to pre-filling, as after the paper's pause; queued samples stay."""
    def reset_occupancy(self) -> None:
        """Forgets the occupancy statistics; the counters stay."""
    @property
    def ns(self) -> int:
        """The nominal size (assignable; must stay below ``capacity``)."""
    @ns.setter
    def ns(self, value: int) -> None: ...
    @property
    def capacity(self) -> int: ...
    @property
    def width(self) -> int: ...
    def __len__(self) -> int: ...
    @property
    def arrived(self) -> int:
        """Samples offered to :meth:`push`."""
    @property
    def released(self) -> int:
        """Samples released by a tick."""
    @property
    def rejected(self) -> int:
        """Samples refused because the queue was full."""
    @property
    def discarded(self) -> int:
        """Samples removed other than by a release."""
    @property
    def underflows(self) -> int:
        """Running ticks that released nothing."""
    @property
    def ticks(self) -> int:
        """Running ticks (pre-fill ticks excluded)."""
    @property
    def counters(self) -> dict[str, int]:
        """``arrived, released, rejected, discarded, underflows, ticks`` as a dict."""
    @property
    def occupancy(self) -> Optional[dict[str, float]]:
        """``{min, max, mean, ticks}`` of the occupancy just before each
        running tick (the paper's ``s(t)``), or None before the first one."""

# ---------------------------------------------------------------- Kalman, predictor

@final
class Kalman3:
    """The paper's triple-integrator Kalman filter, with filterpy's names.

    State ``x = [value, rate, acceleration]``; ``F = [[1, T, T²/2], [0, 1, T],
    [0, 0, 1]]``, ``H = [[1, 0, 0]]``, ``Q = diag(0, 0, sigma_q²)``,
    ``R = [[sigma_q²]]``, ``P0 = sigma_q²·I``. ``predict()`` and ``update(z)``
    are filterpy's equations; the estimates do not depend on ``sigma_q``.
    ``x`` is 1-D (filterpy also accepts that). ``x``, ``P``, ``F`` (``A``),
    ``H``, ``Q`` and ``R`` can be assigned, as in filterpy, with their shapes
    checked (``ValueError`` naming the shape). Reading one gives a read-only
    copy: ``kf.x[0] = 5`` raises ``ValueError`` instead of changing a copy
    silently; write ``x = kf.x.copy(); x[0] = 5; kf.x = x``.
    """

    def __new__(cls, period: float, *, sigma_q: float = 1.0, horizon: int = 50) -> "Kalman3": ...
    def predict(self) -> None:
        """Time update: ``x ← F·x``, ``P ← F·P·Fᵀ + Q``."""
    def update(self, z: float) -> float:
        """Measurement update; returns the innovation ``z − H·x`` (also ``y``).
        A NaN or infinite ``z`` raises ValueError and changes nothing."""
    def step(self, z: float) -> float:
        """``predict()`` then ``update(z)``; returns the filtered value ``x[0]``."""
    def run(self, z: _ArrayLike) -> Tuple[_Floats, _Floats]:
        """A :meth:`step` per sample of ``z`` (shape ``(n,)``), without the GIL.
        Returns ``(x, ahead)``: states ``(n, 3)`` and horizon predictions ``(n,)``."""
    def predict_ahead(self) -> float:
        """The value predicted ``horizon`` periods ahead, ``H·F^l·x``."""
    def predict_ahead_state(self) -> _Floats:
        """The state predicted ``horizon`` periods ahead, ``F^l·x``."""
    def reset(self) -> None:
        """Back to ``x = 0``, ``P = sigma_q²·I``."""
    @property
    def x(self) -> _Floats:
        """The state, shape ``(3,)``; assign 3 finite floats to set it."""
    @x.setter
    def x(self, value: _ArrayLike) -> None: ...
    @property
    def value(self) -> float:
        """The filtered value ``x[0]``."""
    @property
    def y(self) -> float:
        """The last innovation (filterpy's ``y``); 0 before the first update."""
    @property
    def P(self) -> _Floats:
        """The state covariance, shape ``(3, 3)``."""
    @P.setter
    def P(self, value: _ArrayLike) -> None: ...
    @property
    def F(self) -> _Floats:
        """The transition matrix, shape ``(3, 3)``; ``F_ahead`` follows an assignment."""
    @F.setter
    def F(self, value: _ArrayLike) -> None: ...
    @property
    def A(self) -> _Floats:
        """The paper's name for ``F``."""
    @A.setter
    def A(self, value: _ArrayLike) -> None: ...
    @property
    def F_ahead(self) -> _Floats:
        """``F`` to the power ``horizon``."""
    @property
    def H(self) -> _Floats:
        """``[[1, 0, 0]]`` unless assigned (shape ``(1, 3)`` or ``(3,)``), shape ``(1, 3)``."""
    @H.setter
    def H(self, value: _ArrayLike) -> None: ...
    @property
    def Q(self) -> _Floats:
        """``diag(0, 0, sigma_q²)`` unless assigned, shape ``(3, 3)``."""
    @Q.setter
    def Q(self, value: _ArrayLike) -> None: ...
    @property
    def R(self) -> _Floats:
        """``[[sigma_q²]]`` unless assigned (a number or shape ``(1, 1)``, > 0), shape ``(1, 1)``."""
    @R.setter
    def R(self, value: Union[float, _ArrayLike]) -> None: ...
    @property
    def sigma_q(self) -> float: ...
    @property
    def period(self) -> float:
        """``T`` in seconds; assigning keeps the estimate (it is per second) and
        sets ``F`` back to the triple integrator's."""
    @period.setter
    def period(self, value: float) -> None: ...
    @property
    def horizon(self) -> int:
        """The prediction horizon ``l``, in periods."""
    def __copy__(self) -> "Kalman3": ...
    def __deepcopy__(self, memo: object) -> "Kalman3": ...

def kalman3_filter(
    z: _ArrayLike,
    *,
    period: float,
    sigma_q: float = 1.0,
    horizon: int = 50,
    x0: Optional[_ArrayLike] = None,
) -> Tuple[_Floats, _Floats]:
    """Filters ``z`` (shape ``(n,)``) with a fresh :class:`Kalman3` (state
    ``x0``, default zero), without the GIL. Returns ``(x, ahead)``: the states
    after each step ``(n, 3)`` and the value predicted ``horizon`` periods
    ahead after each step ``(n,)``."""

@final
class Prediction:
    """One step of :class:`NetworkPredictor`; times in seconds."""

    @property
    def nrtt_mean(self) -> float:
        """Measured mean NRTT (the low-passed samples)."""
    @property
    def mt(self) -> float:
        """Measured ``mt`` (the low-passed envelope of the gaps)."""
    @property
    def nrtt_ahead(self) -> float:
        """Mean NRTT predicted ``horizon`` periods ahead, smoothed, never negative."""
    @property
    def mt_ahead(self) -> float:
        """``mt`` predicted ``horizon`` periods ahead, smoothed, never negative."""
    @property
    def period(self) -> float:
        """The period the paper's law would choose: ``max(min_period, nrtt_ahead / 3)``."""
    @property
    def ns(self) -> int:
        """The nominal size the paper's law would choose at that period."""

@final
class NetworkPredictor:
    """The paper's network predictor: low-pass and envelope filters, two
    :class:`Kalman3`, an ``horizon``-period forecast of the mean NRTT and
    ``mt``, and the ``(period, ns)`` the laws would choose. Time constants are
    in periods; the defaults are the paper's."""

    def __new__(
        cls,
        period: float,
        *,
        horizon: int = 50,
        nrtt_tau: float = 250.0,
        mt_tau: float = 25.0,
        ahead_tau: float = 50.0,
        decay: float = 1.00005,
        sigma_q: float = 1.0,
        eta: float = 1.3,
        min_period: float = 0.05,
    ) -> "NetworkPredictor": ...
    def observe_nrtt(self, nrtt: float) -> None:
        """A round trip was measured (seconds)."""
    def observe_gap(self, gap: float) -> None:
        """A frame arrived ``gap`` seconds later than its schedule, relative to the previous one."""
    def step(self) -> Optional[Prediction]:
        """Runs the filters one period; None until one NRTT and one gap were observed."""
    def update(
        self, nrtt: Optional[float] = None, gap: Optional[float] = None
    ) -> Optional[Prediction]:
        """Observes what is given, then :meth:`step`."""
    @property
    def last(self) -> Optional[Prediction]: ...
    @property
    def steps(self) -> int: ...
    @property
    def period(self) -> float:
        """The period in seconds; assigning keeps what was learnt."""
    @period.setter
    def period(self, value: float) -> None: ...
    @property
    def horizon(self) -> int: ...
    @property
    def nrtt_filter(self) -> Kalman3:
        """A copy of the Kalman filter of the mean NRTT."""
    @property
    def mt_filter(self) -> Kalman3:
        """A copy of the Kalman filter of ``mt``."""

# ---------------------------------------------------------------- filters

@final
class LowPass:
    """First-order low-pass ``y ← y + α·(x − y)``, ``α = 1 − exp(−period/tau)``,
    starting at the first sample. ``tau`` and ``period`` in seconds."""

    def __new__(cls, tau: float, period: float) -> "LowPass": ...
    @staticmethod
    def from_alpha(alpha: float) -> "LowPass":
        """A low-pass with ``α`` in (0, 1] given directly."""
    def update(self, x: float) -> float: ...
    def run(self, x: _ArrayLike) -> _Floats:
        """An :meth:`update` per sample, shape ``(n,)``, without the GIL."""
    @property
    def value(self) -> Optional[float]: ...
    @property
    def alpha(self) -> float: ...
    def set_period(self, period: float) -> None:
        """Changes the period, keeping the time constant in seconds."""
    def reset(self) -> None: ...

@final
class Envelope:
    """The paper's envelope: ``e ← x`` if ``x > e``, else ``e ← e / decay``."""

    def __new__(cls, decay: float = 1.00005) -> "Envelope": ...
    def update(self, x: float) -> float: ...
    def run(self, x: _ArrayLike) -> _Floats:
        """An :meth:`update` per sample, shape ``(n,)``, without the GIL."""
    @property
    def value(self) -> Optional[float]: ...
    @property
    def decay(self) -> float: ...
    def reset(self) -> None: ...

def lowpass(x: _ArrayLike, tau: float, period: float) -> _Floats:
    """Low-passes ``x`` (shape ``(n,)``) with time constant ``tau`` at period ``period``."""

def envelope(x: _ArrayLike, *, decay: float = 1.00005) -> _Floats:
    """The envelope of ``x`` (shape ``(n,)``)."""

# ---------------------------------------------------------------- identification

@final
class Rls:
    """Recursive least squares with forgetting factor ``lam`` and initial
    covariance ``delta·I``, ``n`` from 1 to 8 weights; padasip's names.

    ``P`` is reset to ``delta·I`` when its trace exceeds ``trace_bound``
    (default ``1e6·n·delta``): the guard against covariance wind-up.
    """

    def __new__(
        cls,
        n: int,
        *,
        lam: float = 0.99,
        delta: float = 1000.0,
        trace_bound: Optional[float] = None,
    ) -> "Rls": ...
    def adapt(self, d: float, x: Union[float, _ArrayLike]) -> float:
        """Adapts to desired value ``d`` and regressor ``x`` (shape ``(n,)``);
        returns the a-priori error ``d − w·x``. A failed update changes nothing."""
    def predict(self, x: Union[float, _ArrayLike]) -> float:
        """The output ``w·x``."""
    def run(self, d: _ArrayLike, x: _ArrayLike) -> Tuple[_Floats, _Floats, _Floats]:
        """padasip's ``run``, without the GIL: ``d`` shape ``(N,)``, ``x``
        shape ``(N, n)``; returns ``(y, e, w)``, the outputs before each
        adaptation, the errors, and the weights used ``(N, n)``."""
    @property
    def w(self) -> _Floats:
        """The weights, shape ``(n,)``; assignable."""
    @w.setter
    def w(self, value: _ArrayLike) -> None: ...
    @property
    def P(self) -> _Floats:
        """The covariance, shape ``(n, n)``."""
    @property
    def n(self) -> int: ...
    @property
    def lam(self) -> float:
        """The forgetting factor, in (0, 1]; assignable."""
    @lam.setter
    def lam(self, value: float) -> None: ...
    @property
    def delta(self) -> float: ...
    @property
    def trace_bound(self) -> float: ...
    @trace_bound.setter
    def trace_bound(self, value: float) -> None: ...
    @property
    def updates(self) -> int: ...
    @property
    def covariance_resets(self) -> int:
        """Automatic resets of ``P`` (wind-up guard or lost definiteness)."""
    def reset_covariance(self) -> None:
        """``P ← delta·I``, keeping the weights."""
    def reset(self) -> None:
        """Zero weights, ``P = delta·I``, counters at zero."""
    def __copy__(self) -> "Rls": ...
    def __deepcopy__(self, memo: object) -> "Rls": ...

def rls_filter(
    d: _ArrayLike, x: _ArrayLike, *, lam: float = 0.99, delta: float = 1000.0
) -> Tuple[_Floats, _Floats, _Floats]:
    """:meth:`Rls.run` with a fresh ``Rls(x.shape[1], lam=lam, delta=delta)``."""

@final
class Tf2:
    """``H(z) = (b0 + b1 z⁻¹ + b2 z⁻²) / (1 + a1 z⁻¹ + a2 z⁻²)`` sampled every
    ``dt`` seconds; ``num = [b0, b1, b2]``, ``den = [a0, a1, a2]`` as in
    scipy.signal (``den`` is normalized so that ``a0 = 1``). Both are
    polynomials in ``z``, highest power first: a shorter ``num`` (python-control's
    ``[b1, b2]``) is padded on the left, and a ``(1, 3)`` one (what
    ``scipy.signal.cont2discrete`` returns) is taken as its row."""

    def __new__(cls, num: _ArrayLike, den: _ArrayLike, dt: float) -> "Tf2": ...
    @staticmethod
    def low_pass(wn: float, zeta: float, gain: float, dt: float) -> "Tf2":
        """Bilinear discretization of ``gain·wn² / (s² + 2·zeta·wn·s + wn²)``, ``wn`` in rad/s."""
    def to_tf(self) -> _Tf:
        """``(num, den, dt)``: ``scipy.signal.dlti(num, den, dt=dt)`` (``dt`` by
        name: three positional arguments are zeros, poles and gain there), or
        ``control.tf(*tf.to_tf())``."""
    @property
    def num(self) -> _Floats: ...
    @property
    def den(self) -> _Floats: ...
    @property
    def dt(self) -> float: ...
    @property
    def dc_gain(self) -> float: ...
    def is_stable(self) -> bool: ...
    def simulate(
        self,
        u: _ArrayLike,
        *,
        u_past: Optional[_ArrayLike] = None,
        y_past: Optional[_ArrayLike] = None,
    ) -> _Floats:
        """The response to ``u`` (shape ``(n,)``), from rest unless
        ``u_past = [u[-1], u[-2]]``, ``y_past = [y[-1], y[-2]]``; equals
        ``scipy.signal.lfilter(num, den, u)`` from rest."""

@final
class Tf2State:
    """A :class:`Tf2` being simulated, one input at a time."""

    def __new__(
        cls,
        model: Tf2,
        *,
        u_past: Optional[_ArrayLike] = None,
        y_past: Optional[_ArrayLike] = None,
    ) -> "Tf2State": ...
    def step(self, u: float) -> float: ...
    def run(self, u: _ArrayLike) -> _Floats: ...
    @property
    def output(self) -> float: ...
    @property
    def model(self) -> Tf2: ...
    @model.setter
    def model(self, value: Tf2) -> None: ...
    def reset(self) -> None: ...

@final
class Arx2:
    """Online identification of a :class:`Tf2` by RLS on
    ``[u[k], u[k-1], u[k-2], -y[k-1], -y[k-2]]``; weights ``[b0, b1, b2, a1, a2]``.

    An input that does not excite the model (a constant, say) leaves some of
    its coefficients undetermined: ``fit``, ``model`` and ``to_tf`` then warn
    (``RuntimeWarning``), and ``unexcited`` counts those directions."""

    def __new__(cls, dt: float, *, lam: float = 1.0, delta: float = 1e6) -> "Arx2": ...
    def update(self, u: float, y: float) -> Optional[float]:
        """Records ``u[k]``, ``y[k]``; adapts once two earlier samples are
        known and returns the a-priori error, else None."""
    def fit(self, u: _ArrayLike, y: _ArrayLike) -> _Floats:
        """An :meth:`update` per pair, without the GIL; errors ``(n,)``, NaN
        where no adaptation happened. Warns if the input left the model unexcited."""
    def record_substitute(self, u: float, y: float) -> None:
        """Records a stand-in pair without adapting on it."""
    def clear_history(self) -> None: ...
    def predict(self, u: float) -> Optional[float]:
        """The model's output for ``u``, or None until two samples are known."""
    @property
    def model(self) -> Tf2:
        """The identified model (``RuntimeWarning`` if the input did not excite it)."""
    def to_tf(self) -> _Tf:
        """``(num, den, dt)`` of the identified model, scipy.signal's convention
        (``RuntimeWarning`` if the input did not excite it)."""
    @property
    def unexcited(self) -> int:
        """How many of the model's 5 directions the data has not determined:
        0 once the input excites them all, 2 or more under a constant input."""
    @property
    def dt(self) -> float: ...
    @property
    def rls(self) -> Rls:
        """A copy of the underlying 5-weight :class:`Rls`."""
    @property
    def updates(self) -> int: ...
    def reset(self) -> None: ...

@final
class Estimator:
    """The remote's state now (``x3e``) and when the command sent now takes
    effect (``x3p``), from the commands in flight and the delayed feedback.

    ``delay_fwd``, ``delay_bwd``: the regulated one-way delays, in ticks.
    With ``model`` (a :class:`Tf2`) the model is fixed; otherwise it is
    identified with an :class:`Arx2` (``lam``, ``delta``). ``dt`` is the
    period in seconds (taken from ``model`` if not given).
    """

    def __new__(
        cls,
        delay_fwd: int,
        delay_bwd: int,
        *,
        dt: Optional[float] = None,
        model: Optional[Tf2] = None,
        lam: float = 1.0,
        delta: float = 1e6,
    ) -> "Estimator": ...
    def step(self, u: float, y: Optional[float] = None) -> Tuple[float, float, bool]:
        """One tick: the command ``u`` sent now, the state sample ``y``
        released now (None on an underflow). Returns ``(x3e, x3p, from_model)``;
        before the model is usable both hold the last state received."""
    def run(
        self, u: _ArrayLike, y: _ArrayLike, received: Optional[_ArrayLike] = None
    ) -> Tuple[_Floats, _Floats, npt.NDArray[np.bool_]]:
        """A :meth:`step` per tick, without the GIL; ``received`` (bool,
        default all True) marks the ticks with a sample, ``y`` is ignored where
        it is False."""
    @property
    def model(self) -> Tf2: ...
    def to_tf(self) -> _Tf:
        """``(num, den, dt)`` of the model in use, scipy.signal's convention."""
    @property
    def arx(self) -> Optional[Arx2]:
        """A copy of the identifier, or None with a fixed model."""
    @property
    def is_identifying(self) -> bool: ...
    @property
    def delays(self) -> Tuple[int, int]:
        """``(delay_fwd, delay_bwd)`` in ticks; assignable."""
    @delays.setter
    def delays(self, value: Tuple[int, int]) -> None: ...
    @property
    def dt(self) -> float: ...
    @property
    def ticks(self) -> int: ...
    @property
    def last_received(self) -> Optional[float]: ...
    def reset(self) -> None:
        """Forgets the command history and anchors, keeping the model."""
    def reset_identification(self) -> None:
        """Restarts identification from a zero model."""


# ---------------------------------------------------------------- control

SMITH_HISTORY: int
"""The longest round trip a :class:`SmithPredictor` follows, in ticks (8192)."""

def round_trip_ticks(grtt: float, period: float) -> int:
    """The round trip in whole ticks that a release's GRTT is at ``period``
    (both in seconds), for an application that takes each release at its
    next tick: ``ceil(grtt / period)``. What a :class:`SmithPredictor` is
    given from ``tick.grtt``."""

@final
class SmithPredictor:
    """A Smith predictor for a position loop closed at the base on the
    remote's state, released ``round_trip`` ticks after the command it
    answers (1 to :data:`SMITH_HISTORY`).

    ``model`` is the plant's :class:`Tf2` (used as given), or an
    :class:`Arx2` that identifies it online from the commands and the
    measured states (until it has adapted enough on states that answer a
    command, the controller is given the measured state itself; on a long
    round trip, drive the plant open loop until :attr:`correction` stays
    small, then close the loop). A local copy of the model runs undelayed
    on the commands; the controller sees its newest output corrected by
    how far the plant was from it one round trip ago. With the true model
    and a constant round trip the loop is the delay-free loop, delayed.

    Each tick: ``seen = sp.feedback(y or None)``, then the controller's
    ``u`` from ``seen``, then ``sp.command(u)``. When the link announces a
    new round trip (``"round_trip_changed"``, a new ``tick.grtt``), call
    :meth:`set_round_trip` (see :func:`round_trip_ticks`).
    """

    def __new__(cls, model: Union[Tf2, Arx2], *, round_trip: int) -> "SmithPredictor": ...
    def feedback(self, measured: Optional[float]) -> float:
        """Tick ``k``, first half: the state released now (None for a held
        repeat or no release); returns what the controller should take as
        the plant's state."""
    def command(self, u: float) -> None:
        """Tick ``k``, second half: the command sent now."""
    def run(self, measured: _ArrayLike, commands: _ArrayLike) -> _Floats:
        """Replays recorded ticks without the GIL: for each ``k``,
        ``feedback(measured[k])`` (NaN: no state) then
        ``command(commands[k])``; returns the feedbacks, shape ``(n,)``.
        Nothing changes if a tick is refused."""
    def set_round_trip(self, round_trip: int) -> None:
        """The link announced a new round trip, in ticks; the history is
        kept by tick, so nothing jumps."""
    def set_delays(self, delay_fwd: int, delay_bwd: int) -> None:
        """The same from the one-way delays in ticks (their sum)."""
    @property
    def round_trip(self) -> int: ...
    @property
    def model(self) -> Tf2:
        """The local model in use; assignable (a new period), keeping the history."""
    @model.setter
    def model(self, value: Tf2) -> None: ...
    @property
    def model_ready(self) -> bool:
        """Whether the model is used (an identified one: after enough adaptations)."""
    @property
    def is_identifying(self) -> bool: ...
    @property
    def ticks(self) -> int:
        """Commands given so far."""
    @property
    def correction(self) -> float:
        """The last measured state less the model's output one round trip before."""
    @property
    def dt(self) -> float: ...

@final
class Pid:
    """A discrete PID: ``u = kp*e + ki*integral(e) + kd*d(-y)/dt`` with
    ``e = r - y`` (the derivative on the measurement: a reference step does
    not kick), output held in ``[out_min, out_max]`` with anti-windup, the
    derivative low-passed with time constant ``derivative_filter`` seconds
    (0: none). ``dt`` is the period in seconds."""

    def __new__(
        cls,
        kp: float,
        ki: float = 0.0,
        kd: float = 0.0,
        *,
        dt: float,
        out_min: float = ...,
        out_max: float = ...,
        derivative_filter: float = 0.0,
    ) -> "Pid": ...
    def step(self, r: float, y: float) -> float:
        """One step: the output for reference ``r`` and measurement ``y``."""
    def run(self, r: _ArrayLike, y: _ArrayLike) -> _Floats:
        """A :meth:`step` per pair of the series ``r``, ``y`` (an open loop:
        the measurements are given), without the GIL; nothing changes if a
        step is refused."""
    def reset(self) -> None: ...
    @property
    def kp(self) -> float: ...
    @property
    def ki(self) -> float: ...
    @property
    def kd(self) -> float: ...
    @property
    def derivative_filter(self) -> float: ...
    @property
    def limits(self) -> Tuple[float, float]:
        """``(out_min, out_max)``."""
    @property
    def dt(self) -> float:
        """The period, seconds; assignable (the link resized), keeping the state."""
    @dt.setter
    def dt(self, value: float) -> None: ...

@final
class WaveTransform:
    """Niemeyer and Slotine's wave variables at impedance ``b > 0`` (force
    per velocity): ``u = (b*v + F)/sqrt(2b)``, ``w = (b*v - F)/sqrt(2b)``,
    and ``v*F = (u**2 - w**2)/2``. The master sends ``u`` and decodes the
    backward wave; the slave decodes ``u`` and sends the backward wave.
    Over a link, decode a held repeat as a zero wave: a wave delivered
    twice is energy the channel creates (see :class:`WaveEnergy`)."""

    def __new__(cls, b: float) -> "WaveTransform": ...
    @property
    def b(self) -> float: ...
    @overload
    def forward_wave(self, velocity: float, force: float) -> float: ...
    @overload
    def forward_wave(self, velocity: _ArrayLike, force: _ArrayLike) -> _Floats: ...
    @overload
    def backward_wave(self, velocity: float, force: float) -> float: ...
    @overload
    def backward_wave(self, velocity: _ArrayLike, force: _ArrayLike) -> _Floats: ...
    def master(self, velocity: float, v: float) -> Tuple[float, float]:
        """The master at ``velocity`` receives the backward wave ``v``:
        ``(force, u)``, the force reflected and the wave to send."""
    def slave(self, u: float, force: float) -> Tuple[float, float]:
        """The slave receives ``u`` and meets ``force`` (its local
        controller's): ``(velocity, v)``, the velocity to command and the
        wave to send."""

@final
class WaveEnergy:
    """The energy account of a wave channel, both directions: what entered
    (``0.5*wave**2*dt`` per wave sent), what left (per wave decoded), and
    the most it ever gave beyond what it received (``generated``: zero for
    a passive channel)."""

    def __new__(cls) -> "WaveEnergy": ...
    def sent(self, wave: Union[float, _ArrayLike], *, dt: float) -> None:
        """A wave (or successive waves) entered the channel, ``dt`` seconds each."""
    def delivered(self, wave: Union[float, _ArrayLike], *, dt: float) -> None:
        """A wave (or successive waves) left the channel, ``dt`` seconds each."""
    @property
    def entered(self) -> float: ...
    @property
    def left(self) -> float: ...
    @property
    def stored(self) -> float:
        """Entered less left (negative once the channel generated energy)."""
    @property
    def generated(self) -> float: ...


# -- the link ---------------------------------------------------------------

MAX_WIDTH: int
MAX_AXES: int
_Address = Union[str, Tuple[str, int]]

class LinkError(ConnectionError):
    """The link failed or ended; every link failure is a subclass."""

class HandshakeError(LinkError):
    """The peers disagree (version, role, widths, layout, transport, period,
    mode) or the handshake did not finish in time."""

class ProtocolError(LinkError):
    """The peer sent bytes that are not a valid ndr frame."""

class PeerClosedError(LinkError):
    """The peer ended the link; ``reason`` 0 is a normal end. A remote that
    refused the link for now says why: 9 busy (it serves another base), 14
    (too many handshakes pending from this side's address: something else
    behind the same NAT or relay keeps connecting), 15 (every handshake
    slot taken); trying again may succeed."""

    reason: int
    reason_name: str

class DisconnectedError(LinkError):
    """The connection dropped without a Close frame."""

class LinkClosedError(LinkError):
    """This side closed the link."""

@final
class Tick:
    """A sample released by the link's regulator at one of its ticks."""

    @property
    def sample(self) -> _Floats:
        """The values, a new float64 array of shape ``(axes,)``."""
    @property
    def seq(self) -> int: ...
    @property
    def sent_at(self) -> float:
        """When the peer sent it, on the peer's clock (s)."""
    @property
    def arrived_at(self) -> float:
        """When it arrived, on this side's link clock (s)."""
    @property
    def released_at(self) -> float:
        """The tick that released it, on this side's link clock (s)."""
    @property
    def status(self) -> str:
        """``"fresh"``, or ``"held"`` on an underflow (the last sample repeated)."""
    @property
    def grtt(self) -> Optional[float]:
        """The round trip as the application sees it, when this release closes one."""
    @property
    def added_delay(self) -> float:
        """``released_at - arrived_at``."""
    @property
    def term(self) -> int:
        """The control term its frame carried (0 outside a shared robot's
        terms)."""

@final
class _Link:
    def recv(self, timeout: Optional[float] = None) -> Tick: ...
    def try_recv(self) -> Optional[Tick]: ...
    def unrecv(self, tick: Tick) -> None: ...
    def send(self, sample: Union[_ArrayLike, float]) -> None: ...
    def yield_control(self) -> None:
        """Base: gives control up; a ``control_lost`` event follows."""
    @property
    def is_observer(self) -> bool:
        """Whether this link observes now."""
    @property
    def peer_seat(self) -> Optional[str]:
        """The seat the peer's Hello named: ``"control"``, ``"observe"``
        or ``"wait_for_control"``."""
    def abort(self) -> None: ...
    def events(self) -> List[Tuple[str, Dict[str, Any]]]:
        """The events ``new_events`` has returned, oldest first, as
        ``(kind, fields)``; they leave the link."""
    def new_events(self) -> List[Tuple[str, Dict[str, Any]]]:
        """The events since the last call; they stay for ``events``."""
    @property
    def unseen_events(self) -> int:
        """Events waiting for ``new_events``."""
    @property
    def events_dropped(self) -> int:
        """``stats()["events_dropped"]``, also before the first tick."""
    def stats(self) -> Optional[LinkStats]: ...
    def metrics(self) -> str: ...
    def recording(self) -> Optional[Dict[str, int]]: ...
    def now(self) -> float: ...
    def close(self) -> None: ...
    @property
    def axes(self) -> int: ...
    @property
    def command_width(self) -> int: ...
    @property
    def state_width(self) -> int: ...
    @property
    def period(self) -> float: ...
    @property
    def role(self) -> str: ...
    @property
    def peer(self) -> Tuple[str, int]: ...

@final
class _Listener:
    def accept(self, timeout: Optional[float] = None) -> Optional[_Link]: ...
    def close(self) -> None: ...
    @property
    def address(self) -> Tuple[str, int]: ...
    @property
    def refused(self) -> int: ...
    @property
    def stats(self) -> ListenerStats: ...
    @property
    def sharing(self) -> Optional[SharingStats]: ...

@final
class _LinkSettings:
    """One side's link settings, checked once (see :meth:`ndr.Link.connect`)."""

    def __new__(
        cls,
        *,
        role: str,
        axes: Optional[int],
        command_width: Optional[int],
        state_width: Optional[int],
        period: float,
        regulation: Optional[str],
        underflow: str,
        watchdog: Optional[float],
        liveness: Optional[float],
        handshake_timeout: float,
        app_queue: int,
        insecure: bool,
        transport: str,
        realtime: str,
        rt_priority: int,
        rt_cpu: Optional[int],
        observers: Optional[int] = None,
        observe: bool = False,
        wait_for_control: Optional[float] = None,
    ) -> "_LinkSettings": ...

@final
class TlsConfig:
    """Mutual TLS 1.3 for a link: this side's certificate and key (PEM
    files), and whom it trusts: exactly one of ``peer_cert`` (the peer's
    certificate, pinned by fingerprint), ``pins`` (SHA-256 fingerprints, a
    list, or one as a str) or ``ca`` (a CA certificate; the server's
    certificate must name ``server_name``). A robot that shares itself
    (``Link.listen(observers=N)``) may also trust peers who may only
    observe: ``observer_pins`` (fingerprints) and ``observer_certs``
    (certificate files, each pinned); one of them that asks for control is
    refused. ``ValueError`` names a file or value it cannot use."""

    def __new__(
        cls,
        cert: Union[str, "os.PathLike[str]"],
        key: Union[str, "os.PathLike[str]"],
        *,
        peer_cert: Optional[Union[str, "os.PathLike[str]"]] = None,
        pins: Union[str, Sequence[str], None] = None,
        ca: Optional[Union[str, "os.PathLike[str]"]] = None,
        server_name: Optional[str] = None,
        handshake_timeout: Optional[float] = None,
        observer_pins: Union[str, Sequence[str], None] = None,
        observer_certs: Union[
            str, "os.PathLike[str]", Sequence[Union[str, "os.PathLike[str]"]], None
        ] = None,
    ) -> "TlsConfig": ...
    @property
    def fingerprint(self) -> str:
        """This side's certificate fingerprint (SHA-256), to pin on the peer."""

def keygen(dir: Union[str, "os.PathLike[str]"], name: str = "ndr") -> Tuple[str, str, str]:
    """A self-signed certificate pair for a lab setup (as ``ndr keygen``):
    ``(cert_path, key_path, fingerprint)``; never overwrites a key."""

def connect(
    address: _Address,
    settings: _LinkSettings,
    *,
    connect_timeout: Optional[float],
    reconnect: bool = False,
    tls: Optional[TlsConfig] = None,
    record: Optional[str] = None,
) -> _Link: ...
def listen(
    address: _Address,
    settings: _LinkSettings,
    *,
    tls: Optional[TlsConfig] = None,
    record: Optional[str] = None,
) -> _Listener: ...

@final
class Relay:
    """A delay-injecting TCP and UDP proxy (``ndr relay``) running in this process:
    listens on ``listen`` and forwards each connection to ``upstream``,
    delaying every frame by a delay model (one of ``profile``, ``trace``,
    ``dist`` with ``mean`` and ``std``; with none of them, the
    ``"lan-75km"`` profile), keeping order. It also listens on the same port
    over UDP and relays datagrams to ``upstream``'s port over UDP, delayed
    the same way and lost by ``loss`` (``"none"``, a percent such as ``"1"``,
    or ``"ge:PERCENT:BURST"`` for bursts; ``stats["datagrams"]``). ``seed``
    (0 to 2**64 - 1) seeds the delays and losses. A context manager.

    Raises ``OSError`` (with ``errno``, e.g. ``errno.EADDRINUSE``) when it
    cannot listen on ``listen``, and ``ValueError`` for an address that is
    not loopback without ``insecure=True`` (the relay passes plain links
    through to the network)."""

    def __new__(
        cls,
        listen: _Address,
        upstream: _Address,
        *,
        profile: Optional[str] = None,
        trace: Optional[str] = None,
        dist: Optional[str] = None,
        mean: Optional[float] = None,
        std: Optional[float] = None,
        seed: int = 1,
        insecure: bool = False,
        loss: str = "none",
    ) -> "Relay": ...
    @property
    def address(self) -> Tuple[str, int]: ...
    @property
    def model(self) -> str: ...
    @property
    def stats(self) -> RelayStats: ...
    def close(self) -> None: ...
    def __enter__(self) -> "Relay": ...
    def __exit__(self, *exc: object) -> bool: ...

# -- the simulator ------------------------------------------------------------

@final
class Signal:
    """An operator's command: ``"sine[:amp=A,freq=F,offset=O]"``,
    ``"steps[:low=L,high=H,period=P]"`` or ``"constant:V"``."""

    def __new__(cls, spec: str = "sine") -> "Signal": ...
    def __call__(self, t: float, axis: int = 0) -> float:
        """The value at time ``t`` (s) for ``axis`` (≥ 0; axes are phase-shifted)."""
    @property
    def kind(self) -> str: ...

def sim_run(
    *,
    profile: Optional[str] = None,
    trace: Optional[str] = None,
    dist: Optional[str] = None,
    mean: Optional[float] = None,
    std: Optional[float] = None,
    regulation: Optional[str] = None,
    underflow: str = "hold",
    period: float = 0.2,
    duration: float = 600.0,
    seed: int = 1,
    axes: int = 1,
    signal: str = "sine",
    series: bool = True,
    loss: str = "none",
    transport: str = "stream",
) -> Tuple[str, Dict[str, _Floats]]:
    """One simulation: ``(summary JSON, series)``, ``null`` in the JSON where
    nothing was measured; use :func:`ndr.sim.run`."""

def _regulation(
    *,
    regulation: Optional[str],
    default: str,
) -> Tuple[str, str, str]:
    """``(name, mode, playout)`` of ``regulation=`` (``default`` when None)
    as reports write them; ``ValueError`` as ``ndr.Link.connect``."""

REGULATIONS: Tuple[str, ...]
"""The regulations named without a value, in the order of the Rust core's
playout registry (:data:`ndr.sim.REGULATIONS`)."""

REGULATION_NAMES: str
"""Every name ``regulation=`` takes, with the values of those that take
one (``adaptive[:PERCENT[:QUANTUM_MS]] (the default), paper-static, …``),
from the playout registry."""

# -- logging ------------------------------------------------------------------

def set_log_level(level: Union[str, int, None]) -> None:
    """How verbose Rust is: ``"error"``, ``"warning"``, ``"info"`` (the
    default), ``"debug"``, ``"trace"``; a :mod:`logging` level such as
    ``logging.DEBUG`` (the Rust records at or above it are kept); or
    ``"off"`` or None (no Rust records)."""

def flush_logs() -> None:
    """Hands the waiting Rust log records to :mod:`logging` now."""
