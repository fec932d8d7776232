"""The stats dicts are what their TypedDicts declare, key for key, nested
ones too: a key the Rust stats have and the TypedDict lacks fails, and so
does one the TypedDict declares and the dict lacks. The dicts come from
live objects (a loopback link, a listener, a relay)."""

import threading
import typing
from typing import Any, List, Union

import ndr

LOOPBACK = ("127.0.0.1", 0)


def _is_typeddict(t: Any) -> bool:
    return isinstance(t, type) and issubclass(t, dict) and hasattr(t, "__total__")


def mismatches(value: Any, annotation: Any, path: str = "") -> List[str]:
    """Where ``value`` differs from ``annotation``: missing or extra keys of
    a TypedDict (recursively), or a value of another type."""
    where = path.rstrip(".") or "<root>"
    if _is_typeddict(annotation):
        if not isinstance(value, dict):
            return [f"{where}: {value!r}, not a dict"]
        hints = typing.get_type_hints(annotation)
        name = annotation.__name__
        out = [f"{path}{k}: in the dict, not in {name}" for k in value.keys() - hints.keys()]
        out += [f"{path}{k}: in {name}, not in the dict" for k in hints.keys() - value.keys()]
        for k in sorted(hints.keys() & value.keys()):
            out += mismatches(value[k], hints[k], f"{path}{k}.")
        return out
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is Union:
        if value is None and type(None) in args:
            return []
        inner = [a for a in args if a is not type(None)]
        if len(inner) == 1:
            return mismatches(value, inner[0], path)
        if any(not mismatches(value, a, path) for a in inner):
            return []
        return [f"{where}: {value!r} is none of {args}"]
    if origin is tuple:
        if not isinstance(value, tuple) or len(value) != len(args):
            return [f"{where}: {value!r}, not a tuple of {len(args)}"]
        pairs = enumerate(zip(value, args))
        return [m for i, (v, a) in pairs for m in mismatches(v, a, f"{path}{i}.")]
    if annotation is float:
        return [] if isinstance(value, float) else [f"{where}: {value!r}, not a float"]
    if annotation is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
        return [] if ok else [f"{where}: {value!r}, not an int"]
    if annotation in (str, bool):
        ok = isinstance(value, annotation)
        return [] if ok else [f"{where}: {value!r}, not a {annotation.__name__}"]
    return [f"{where}: annotation {annotation!r} is not one the test knows"]


def test_the_checker_sees_a_key_missing_either_way_and_a_wrong_type():
    whole = {"count": 1, "mean": 0.0, "std": 0.0, "min": 0.0, "max": 0.0}
    assert mismatches(whole, ndr.RunningStats) == []
    short = {k: v for k, v in whole.items() if k != "max"}
    assert mismatches(short, ndr.RunningStats) == ["max: in RunningStats, not in the dict"]
    extra = {**whole, "p50": 0.0}
    assert mismatches(extra, ndr.RunningStats) == ["p50: in the dict, not in RunningStats"]
    assert mismatches({**whole, "count": 1.0, "mean": 0}, ndr.RunningStats) == [
        "count: 1.0, not an int",
        "mean: 0, not a float",
    ]
    # Nested: a TypedDict inside a TypedDict, and an optional tuple.
    lateness = {"count": 1, "missed": 0, "min": 0.0, "p50": 0.0, "p99": 0.0,
                "p999": 0.0, "max": 0.0, "mean": 0.0}
    assert mismatches(lateness, ndr.LatenessStats) == []
    link = {k: None for k in ndr.LinkStats.__annotations__}
    assert "queue_range: None, not an int" not in mismatches(link, ndr.LinkStats)
    assert "lateness: None, not a dict" in mismatches(link, ndr.LinkStats)


def test_a_live_links_stats_are_its_typeddict():
    listener = ndr.Link.listen(LOOPBACK, axes=2, period=0.02)
    accepted = []
    t = threading.Thread(target=lambda: accepted.append(listener.accept(timeout=5)), daemon=True)
    t.start()
    try:
        with ndr.Link.connect(listener.address, axes=2, period=0.02) as base:
            base.send([0.0, 0.0])
            base.recv(timeout=3)
            stats = base.stats
            assert stats is not None
            assert mismatches(stats, ndr.LinkStats) == []
            t.join(5)
            assert mismatches(listener.stats, ndr.ListenerStats) == []
            assert listener.stats["accepted"] == 1
    finally:
        for link in accepted:
            link.close()
        listener.close()


def test_a_listeners_and_a_relays_stats_are_their_typeddicts():
    with ndr.Link.listen(LOOPBACK, period=0.02) as listener:
        assert mismatches(listener.stats, ndr.ListenerStats) == []
        with ndr.Relay(LOOPBACK, listener.address, profile="constant:1") as relay:
            assert mismatches(relay.stats, ndr.RelayStats) == []
        assert mismatches(relay.stats, ndr.RelayStats) == []
