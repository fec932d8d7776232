"""Python's link events are the Rust link's, no others: no event Rust does
not emit ("underflow" is a held tick, "resized" a second "started"), each
one to the log and ``on_event`` once, then to ``events()``."""

import pathlib
import re
import threading
from types import SimpleNamespace

import ndr
from ndr.link import Link
from realtime import echo

EVENT_RS = pathlib.Path(__file__).parents[2] / "crates/ndr-core/src/endpoint/event.rs"


def rust_kinds():
    """The kinds of ``Event::kind`` in ndr-core, less ``released`` (which
    reaches Python as ticks)."""
    source = EVENT_RS.read_text(encoding="utf-8")
    body = source.split("pub const fn kind(&self)", 1)[1].split("\n    }\n", 1)[0]
    return set(re.findall(r'=> "(\w+)"', body)) - {"released"}


def documented_kinds():
    """The kinds ``ndr.Event``'s docstring lists, one bullet each."""
    return set(re.findall(r'^\s*- ``"(\w+)"``', ndr.Event.__doc__ or "", re.M))


def test_the_documented_kinds_are_the_rust_ones():
    assert "connected" in rust_kinds() and "link_restored" in rust_kinds()
    assert documented_kinds() == rust_kinds()


class FakeNative:
    """The native link's event calls, for the Python layer alone."""

    role = "base"

    def __init__(self):
        self.kept = []
        self.seen = 0
        self.ticks = []

    @property
    def unseen_events(self):
        return len(self.kept) - self.seen

    def new_events(self):
        new = self.kept[self.seen:]
        self.seen = len(self.kept)
        return new

    def events(self):
        seen = self.kept[: self.seen]
        del self.kept[: self.seen]
        self.seen = 0
        return seen

    def recv(self, timeout=None):
        return self.ticks.pop(0)


def test_a_pause_is_followed_by_started_and_a_held_tick_is_no_event():
    native = FakeNative()
    native.kept = [("paused", {"period": 0.02, "ns": 3}), ("started", {"period": 0.02, "ns": 3})]
    seen = []
    link = Link(native, on_event=seen.append)
    assert [e.kind for e in seen] == ["paused", "started"]
    native.ticks.append(SimpleNamespace(status="held", seq=7))
    assert link.recv().status == "held"
    assert [e.kind for e in seen] == ["paused", "started"]
    assert [(e.kind, e.ns) for e in link.events()] == [("paused", 3), ("started", 3)]
    assert link.events() == []


def test_an_event_that_comes_after_the_callbacks_waits_for_them():
    native = FakeNative()
    seen = []
    link = Link(native, on_event=seen.append)
    native.kept.append(("link_lost", {"silent_for": 1.0}))
    link._pump()
    # It came between the callbacks and the read: it stays for the next.
    native.kept.append(("link_restored", {}))
    original = native.new_events
    native.new_events = lambda: []
    assert [e.kind for e in link.events()] == ["link_lost"]
    native.new_events = original
    assert [e.kind for e in link.events()] == ["link_restored"]
    assert [e.kind for e in seen] == ["link_lost", "link_restored"]


def test_a_live_links_events_are_rust_kinds_and_none_were_dropped():
    listener = ndr.Link.listen(("127.0.0.1", 0), period=0.02)
    accepted = []
    t = threading.Thread(target=lambda: accepted.append(listener.accept(timeout=5)), daemon=True)
    t.start()
    try:
        seen = []
        with ndr.Link.connect(listener.address, period=0.02, on_event=seen.append) as base:
            base.recv(timeout=3)
            events = base.events()
            # A base the robot gives control at once is told so before
            # the samples flow.
            assert [e.kind for e in events][:3] == ["connected", "control_granted", "started"]
            assert events[1].term == 1 and events[0].details["seat"] == "control"
            assert events == seen
            assert {e.kind for e in events} <= rust_kinds()
            assert base.events_dropped == 0 == base.stats["events_dropped"]
            assert base.events() == []
        t.join(5)
    finally:
        for link in accepted:
            link.close()
        listener.close()


def test_the_round_trip_is_announced_in_periods_with_its_grtt():
    period = 0.02
    listener = ndr.Link.listen(("127.0.0.1", 0), period=period)
    accepted, stop = [], threading.Event()

    def robot():
        accepted.append(listener.accept(timeout=5))
        echo(accepted[0], stop)

    t = threading.Thread(target=robot, daemon=True)
    t.start()
    try:
        with ndr.Link.connect(listener.address, period=period) as base:
            grtts = []
            for i in range(30):
                base.send([float(i)])
                tick = base.recv(timeout=3)
                if tick.grtt is not None:
                    grtts.append(tick.grtt)
            trips = [e for e in base.events() if e.kind == "round_trip_changed"]
            stats = base.stats
        assert grtts and trips, (grtts, trips)
        for e in trips:
            assert e.ticks - 1 < e.grtt / period <= e.ticks + 1e-9, e
        assert trips[0].grtt == grtts[0]
        assert stats["round_trip_changes"] >= len(trips)
        assert stats["round_trip_ticks"] >= 1
    finally:
        stop.set()
        t.join(5)
        for link in accepted:
            link.close()
        listener.close()
