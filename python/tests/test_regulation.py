"""One name for how the delay is regulated: ``regulation=``, the names of
``ndr demo --regulation`` and of the reports' ``"regulation"``, all from the
Rust core's playout registry. There is no other spelling."""

import pytest

import ndr
import ndr.sim
from ndr import _native

LOOPBACK = ("127.0.0.1", 0)


def test_regulation_is_the_only_word():
    with pytest.raises(TypeError, match="mode"):
        ndr.sim.run("lan-75km", mode="paper-dynamic", duration=5, series=False)
    with pytest.raises(TypeError, match="playout"):
        ndr.sim.run("lan-75km", playout="neteq", duration=5, series=False)
    with pytest.raises(TypeError, match="playout"):
        ndr.Link.listen(LOOPBACK, playout="fifo")
    with pytest.raises(TypeError, match="mode"):
        ndr.Link.connect(("127.0.0.1", 9), mode="paper-static")
    with ndr.Link.listen(LOOPBACK, regulation="paper-dynamic"):
        pass


def test_the_listed_names_come_from_the_registry():
    assert ndr.sim.REGULATIONS == (
        "paper-static", "paper-dynamic", "ramjee-1", "ramjee-4", "neteq", "fixed", "adaptive"
    )
    assert _native.REGULATION_NAMES.startswith("adaptive[:PERCENT[:QUANTUM_MS]] (the default), ")
    for name in ndr.sim.REGULATIONS:
        assert name in _native.REGULATION_NAMES


@pytest.mark.parametrize(
    "given, parts",
    [
        ("adaptive", ("adaptive", "paper-static", "adaptive")),
        ("paper-static", ("paper-static", "paper-static", "fifo")),
        ("paper-dynamic", ("paper-dynamic", "paper-dynamic", "fifo")),
        ("fixed", ("fixed:200", "paper-static", "fixed:200")),
        ("adaptive:1:10", ("adaptive:1:10", "paper-static", "adaptive:1:10")),
    ],
)
def test_each_regulation_is_a_mode_and_a_playout(given, parts):
    got = _native._regulation(regulation=given, default="adaptive")
    assert got == parts
    assert _native._regulation(regulation=None, default=given) == parts


def test_a_wrong_name_says_what_is_valid():
    with pytest.raises(ValueError, match="unknown regulation; valid: adaptive"):
        ndr.sim.run(regulation="lifo", duration=5)
    # `fifo` is the queue, not how it is sized: the message says both ways.
    with pytest.raises(ValueError, match="paper-static .* paper-dynamic"):
        ndr.Link.listen(LOOPBACK, regulation="fifo")
