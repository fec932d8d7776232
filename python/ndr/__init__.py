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
- control across the link: :class:`SmithPredictor` (a position loop on the
  remote's delayed state, ``round_trip`` ticks from :func:`round_trip_ticks`),
  :class:`Pid`, :class:`WaveTransform` and :class:`WaveEnergy` (wave
  variables and the channel's energy account); ``python/examples/`` has a
  controller closing the loop over a real link;
- batch functions on numpy arrays, run without the GIL:
  :func:`kalman3_filter`, :func:`rls_filter`, :func:`lowpass`,
  :func:`envelope`.

The link (:mod:`ndr.link`): :class:`Link` (``Link.connect``,
``Link.listen``), :class:`Listener`, :class:`Tick`, :class:`Event`,
:class:`LinkStats` (what ``Link.stats`` holds, typed), the
delaying :class:`Relay`, :class:`TlsConfig` (mutual TLS 1.3; plain links
off loopback need ``insecure=True``), and the exceptions, all ``ConnectionError``
subclasses: :class:`LinkError`, :class:`HandshakeError`,
:class:`ProtocolError`, :class:`PeerClosedError`,
:class:`DisconnectedError`, :class:`LinkClosedError`.

The simulator is :func:`ndr.sim.run`; :mod:`ndr.plot` draws the paper's
figures (``pip install 'ndr[plot]'`` for matplotlib); ``python -m ndr demo``
runs the main job.

Times are seconds (float); arrays are float64. Bad input raises ValueError
(or TypeError for a wrong kind of object) naming what was expected. Rust's
log records reach :mod:`logging` under the ``ndr`` logger
(:func:`set_log_level` chooses how verbose Rust is, default ``"info"``).
"""

from ._native import (
    ESTIMATOR_HISTORY,
    INIT_EXCHANGES,
    MAX_AXES,
    MAX_WIDTH,
    MAX_CAPACITY,
    SMITH_HISTORY,
    Arx2,
    DisconnectedError,
    Envelope,
    Estimator,
    HandshakeError,
    Kalman3,
    LinkClosedError,
    LinkError,
    LowPass,
    NetworkPredictor,
    PeerClosedError,
    Pid,
    Prediction,
    ProtocolError,
    Regulator,
    RegulatorFull,
    Relay,
    Rls,
    Signal,
    SmithPredictor,
    Tf2,
    Tf2State,
    Tick,
    TlsConfig,
    WaveEnergy,
    WaveTransform,
    __version__,
    envelope,
    flush_logs,
    init_stats,
    kalman3_filter,
    keygen,
    lowpass,
    nominal_size,
    period_law,
    rls_filter,
    round_trip_ticks,
    set_log_level,
)
from . import sim
from .link import (
    Event,
    FloorStats,
    LatenessStats,
    Link,
    LinkStats,
    Listener,
    ListenerStats,
    RelayDatagramDirectionStats,
    RelayDatagramStats,
    RelayDirectionStats,
    RelayStats,
    RunningStats,
    SharingStats,
)
from .recording import Recording, read_recording

__all__ = [
    "ESTIMATOR_HISTORY",
    "INIT_EXCHANGES",
    "MAX_AXES",
    "MAX_WIDTH",
    "MAX_CAPACITY",
    "SMITH_HISTORY",
    "Arx2",
    "DisconnectedError",
    "Envelope",
    "Estimator",
    "Event",
    "FloorStats",
    "HandshakeError",
    "Kalman3",
    "LatenessStats",
    "Link",
    "LinkClosedError",
    "LinkError",
    "LinkStats",
    "Listener",
    "ListenerStats",
    "LowPass",
    "NetworkPredictor",
    "PeerClosedError",
    "Pid",
    "Prediction",
    "ProtocolError",
    "Recording",
    "Regulator",
    "RegulatorFull",
    "Relay",
    "RelayDatagramDirectionStats",
    "RelayDatagramStats",
    "RelayDirectionStats",
    "RelayStats",
    "Rls",
    "RunningStats",
    "SharingStats",
    "Signal",
    "SmithPredictor",
    "Tf2",
    "Tf2State",
    "Tick",
    "TlsConfig",
    "WaveEnergy",
    "WaveTransform",
    "__version__",
    "envelope",
    "flush_logs",
    "init_stats",
    "kalman3_filter",
    "keygen",
    "lowpass",
    "nominal_size",
    "period_law",
    "read_recording",
    "rls_filter",
    "round_trip_ticks",
    "set_log_level",
    "sim",
]
