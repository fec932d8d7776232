"""ndr: a regulated teleoperation link.

Periodic samples travel both ways over TCP; a Network Delay Regulator at each
input releases them at a constant period, so the controller sees a constant,
known delay. This package is the Python face of the Rust crates.

So far it exposes the paper's sizing laws; the link, the filters and the
simulator follow.
"""

from ._native import INIT_EXCHANGES, __version__, init_stats, nominal_size, period_law

__all__ = ["INIT_EXCHANGES", "__version__", "init_stats", "nominal_size", "period_law"]
