"""Type stubs of the extension module ``ndr._native``."""

__version__: str
INIT_EXCHANGES: int

def nominal_size(mt: float, period: float, *, eta: float = 1.3) -> int:
    """Nominal NDR queue size ``2 + floor(eta * mt / period)`` (never below 2).

    ``mt`` and ``period`` are in seconds. Raises ``ValueError`` for negative or
    non-finite values, a zero period or a non-positive ``eta``.
    """

def period_law(nrtt: float, *, min_period: float = 0.05) -> float:
    """The paper's period law ``max(min_period, nrtt / 3)``, in seconds."""

def init_stats(nrtt: list[float]) -> tuple[float, float, float, float]:
    """``(nrtt_min, nrtt_max, nrtt_mean, mt)`` of an initialization pattern.

    Takes 1 to ``INIT_EXCHANGES`` round-trip times in seconds; ``mt`` is the
    largest lag of a reception behind its schedule, ``max - min``.
    """
