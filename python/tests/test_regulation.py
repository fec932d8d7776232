"""One name for how the delay is regulated: ``regulation=``, the names of
``ndr demo --regulation`` and of the reports' ``"regulation"``. The old
``mode=`` and ``playout=`` still work for one release, with a
``DeprecationWarning`` at the caller's line that names the regulation to
give instead."""

import warnings

import pytest

import ndr
import ndr.sim
from ndr import _native

LOOPBACK = ("127.0.0.1", 0)


def test_the_old_spellings_give_the_same_run_and_name_the_regulation():
    new = ndr.sim.run("lan-75km", regulation="paper-dynamic", duration=60, series=False)
    with pytest.warns(DeprecationWarning, match='use regulation="paper-dynamic"') as record:
        old = ndr.sim.run("lan-75km", mode="paper-dynamic", duration=60, series=False)
    assert old.summary == new.summary
    assert new["regulation"] == "paper-dynamic"
    # At the caller's line, not inside the package.
    assert record[0].filename == __file__
    with pytest.warns(DeprecationWarning, match='use regulation="neteq"'):
        ndr.sim.run("lan-75km", playout="neteq", duration=5, series=False)


def test_a_link_takes_the_old_spellings_with_a_warning_at_the_callers_line():
    with pytest.warns(DeprecationWarning, match='use regulation="paper-static"') as record:
        with ndr.Link.listen(LOOPBACK, mode="paper-static", playout="fifo"):
            pass
    assert record[0].filename == __file__
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        with ndr.Link.listen(LOOPBACK, regulation="paper-dynamic"):
            pass
    assert not [w for w in seen if issubclass(w.category, DeprecationWarning)]


def test_the_pairing_no_regulation_names_still_runs_by_its_parts():
    with pytest.warns(DeprecationWarning, match="has no name"):
        r = ndr.sim.run(
            "lan-75km", mode="paper-dynamic", playout="adaptive", duration=30, series=False
        )
    assert r["regulation"] == "paper-dynamic with adaptive"
    assert (r["mode"], r["playout"]) == ("paper-dynamic", "adaptive")


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
    got = _native._regulation(
        regulation=given, mode=None, playout=None, default="adaptive", stacklevel=1
    )
    assert got == parts


def test_a_wrong_name_says_what_is_valid():
    with pytest.raises(ValueError, match="unknown regulation; valid: adaptive"):
        ndr.sim.run(regulation="lifo", duration=5)
    # `fifo` is the queue, not how it is sized: the message says both ways.
    with pytest.raises(ValueError, match="paper-static .* paper-dynamic"):
        ndr.Link.listen(LOOPBACK, regulation="fifo")
    with pytest.raises(ValueError, match="give regulation alone"):
        ndr.Link.listen(LOOPBACK, regulation="adaptive", playout="fifo")
