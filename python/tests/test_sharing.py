"""A robot shared from Python: one controller, observers, control that
changes hands (``Link.listen(observers=N)``, ``Link.connect(observe=True)``,
``wait_for_control=``, ``Link.yield_control``). The real-time test runs
once and checks order, fencing and the hand-over's events with wide
margins; the floor's decisions themselves are tested in simulated time in
ndr-core."""

import threading
import time

import numpy as np
import pytest

import ndr

LOOPBACK = ("127.0.0.1", 0)
PERIOD = 0.01


def robot(listener, stop):
    """Accepts every link; each on a thread applies what its link releases
    (the links have fenced it: only the controller's commands come) and
    sends the state, the last command applied, back on every link. Returns
    what it applied: (value, term), in order."""
    applied = []
    state = [0.0]
    lock = threading.Lock()

    def serve(link):
        try:
            while not stop.is_set():
                with lock:
                    link.send(state[0])
                try:
                    tick = link.recv(timeout=PERIOD / 2)
                except TimeoutError:
                    continue
                if tick.status == "fresh":
                    with lock:
                        applied.append((float(tick.sample[0]), tick.term))
                        state[0] = float(tick.sample[0])
        except ndr.LinkError:
            pass

    def accept():
        while not stop.is_set():
            try:
                link = listener.accept(timeout=0.1)
            except TimeoutError:
                continue
            except ndr.LinkError:
                return
            threading.Thread(target=serve, args=(link,), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    return applied


class Base:
    """A base on a thread: sends ``tag·1000 + k`` at its k-th release, and
    keeps what it saw: the states (seq, term), its events (kind, term,
    when), the applied commands (term, values)."""

    def __init__(self, address, run, tag, yield_at=None, **seat):
        self.states = []
        self.events = []
        self.applied = []
        self.error = None
        self.stats = None
        self.observer_at_end = None
        self.yielded_at = None
        self._args = (address, run, tag, yield_at, seat)
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        address, run, tag, yield_at, seat = self._args
        try:
            link = ndr.Link.connect(address, axes=1, period=PERIOD, **seat)
            self.peer_seat = link.peer_seat
            start = time.monotonic()
            k = 0
            with link:
                while time.monotonic() - start < run:
                    if yield_at is not None and self.yielded_at is None \
                            and time.monotonic() - start >= yield_at:
                        # (Stamped first: the grant may reach the other
                        # base before this thread runs again.)
                        self.yielded_at = time.monotonic()
                        link.yield_control()
                    try:
                        tick = link.recv(timeout=0.1)
                    except TimeoutError:
                        continue
                    if tick.status == "fresh":
                        self.states.append((tick.seq, tick.term))
                    k += 1
                    link.send(tag * 1000.0 + k)
                    for e in link.events():
                        self.events.append((e.kind, e.term, time.monotonic()))
                        if e.kind == "applied":
                            assert isinstance(e.values, np.ndarray)
                            self.applied.append((e.term, float(e.values[0])))
                self.stats = link.stats
                self.observer_at_end = link.is_observer
        except Exception as e:  # noqa: BLE001 - judged by the test
            self.error = e

    def first(self, kind):
        return next(((t, at) for k, t, at in self.events if k == kind), None)


def test_control_passes_to_the_waiting_base_when_the_controller_yields():
    stop = threading.Event()
    with ndr.Link.listen(LOOPBACK, axes=1, period=PERIOD, observers=2) as listener:
        applied = robot(listener, stop)
        a = Base(listener.address, run=4.0, tag=1, yield_at=2.0)
        time.sleep(0.5)
        o = Base(listener.address, run=4.5, tag=9, observe=True)
        b = Base(listener.address, run=4.0, tag=2, wait_for_control=10.0)
        for base in (a, o, b):
            base.thread.join(timeout=20)
        sharing = listener.sharing
        stop.set()
    for base in (a, o, b):
        assert base.error is None, base.error
    # A held term 1, was told B waits, yielded and lost control.
    assert a.first("control_granted")[0] == 1
    assert a.first("control_requested") is not None
    assert a.first("control_lost")[0] == 1
    assert a.observer_at_end and a.stats["role"] == "observer"
    # B observed first, then was granted term 2 soon after A yielded.
    assert b.peer_seat == "observe"
    term, granted = b.first("control_granted")
    assert term == 2
    assert 0 <= granted - a.yielded_at < 1.5, granted - a.yielded_at
    assert not b.observer_at_end and b.stats["role"] == "controller"
    assert b.stats["grants"] == 1
    # The robot applied A's commands, then B's, none of A's after B's
    # first, none of the observer's; each under its own term.
    values = [v for v, _ in applied if v != 0.0]
    first_b = next(i for i, v in enumerate(values) if v >= 2000.0)
    assert first_b > 50, "A commanded first"
    assert all(1000.0 <= v < 2000.0 for v in values[:first_b]), values[:first_b]
    assert all(2000.0 <= v < 3000.0 for v in values[first_b:]), values[first_b:]
    assert len(values) - first_b > 50, "B commanded"
    assert {t for v, t in applied if 1000.0 <= v < 2000.0} == {1}
    assert {t for v, t in applied if v >= 2000.0} == {2}
    # The observer: states in order, under both terms; the commands applied
    # under both, with their values; it never controlled.
    seqs = [s for s, _ in o.states]
    assert all(y > x for x, y in zip(seqs, seqs[1:]))
    assert {t for _, t in o.states} >= {1, 2}
    assert {t for t, _ in o.applied} >= {1, 2}
    # (A base's sample is zeros until its application sets one: a
    # controller's first commands may be, and be applied.)
    odd = [v for _, v in o.applied if v != 0.0 and not 1000.0 <= v < 3000.0]
    assert not odd, odd
    assert o.first("control_granted") is None
    assert o.stats["role"] == "observer" and o.stats["applied_received"] > 50
    # The listener counted one hand-over and both observers at once.
    assert sharing["floor"]["handovers"] == 1
    assert sharing["floor"]["observers_max"] >= 2
    assert sharing["applied_forwarded"] > 50


def test_a_base_that_waits_too_long_for_control_is_closed_and_told_why():
    stop = threading.Event()
    with ndr.Link.listen(LOOPBACK, axes=1, period=PERIOD, observers=1) as listener:
        robot(listener, stop)
        with ndr.Link.connect(listener.address, axes=1, period=PERIOD) as holder:
            holder.recv(timeout=5)
            waiter = ndr.Link.connect(
                listener.address, axes=1, period=PERIOD, wait_for_control=0.5
            )
            assert waiter.is_observer
            start = time.monotonic()
            with pytest.raises(ndr.LinkError, match="wait_for_control=0.5") as caught:
                while time.monotonic() - start < 5:
                    waiter.recv(timeout=1)
            assert not isinstance(caught.value, ndr.LinkClosedError)
            assert 0.4 < time.monotonic() - start < 3
            # The controller kept control all along.
            assert not holder.is_observer
        stop.set()


def test_a_second_controller_without_wait_is_refused_as_busy():
    stop = threading.Event()
    with ndr.Link.listen(LOOPBACK, axes=1, period=PERIOD, observers=1) as listener:
        robot(listener, stop)
        with ndr.Link.connect(listener.address, axes=1, period=PERIOD) as holder:
            holder.recv(timeout=5)
            with pytest.raises(ndr.PeerClosedError, match="busy|control"):
                with ndr.Link.connect(listener.address, axes=1, period=PERIOD) as late:
                    late.recv(timeout=5)
        stop.set()
        assert listener.stats["refused_busy"] >= 1


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"observe": True, "wait_for_control": 5.0}, "two seats"),
        ({"wait_for_control": 0.0}, "wait_for_control must be a positive"),
        ({"wait_for_control": -1.0}, "wait_for_control"),
        ({"role": "remote", "observe": True}, "a base's"),
    ],
)
def test_seat_arguments_that_do_not_fit_are_refused_before_connecting(kwargs, message):
    # Nothing listens there: the settings are refused first.
    with pytest.raises(ValueError, match=message):
        ndr.Link.connect(("127.0.0.1", 9), axes=1, connect_timeout=1, **kwargs)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"observers": 65}, "observers must be an integer from 0 to 64"),
        ({"observers": -1}, "observers"),
        ({"observers": 2, "role": "base"}, "observers= is a remote's"),
    ],
)
def test_observer_counts_that_do_not_fit_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ndr.Link.listen(LOOPBACK, **kwargs)


def test_an_unshared_listener_has_no_sharing_stats_and_its_link_controls():
    stop = threading.Event()
    with ndr.Link.listen(LOOPBACK, axes=1, period=PERIOD) as listener:
        robot(listener, stop)
        assert listener.sharing is None
        with ndr.Link.connect(listener.address, axes=1, period=PERIOD) as link:
            link.recv(timeout=5)
            assert not link.is_observer and link.stats["role"] == "controller"
        stop.set()


def test_tls_observer_allow_list_arguments_are_checked(tmp_path):
    cert, key, _ = ndr.keygen(str(tmp_path), "robot")
    peer, _, fingerprint = ndr.keygen(str(tmp_path), "base")
    ndr.TlsConfig(cert, key, peer_cert=peer, observer_pins=[fingerprint])
    ndr.TlsConfig(cert, key, peer_cert=peer, observer_certs=peer)
    with pytest.raises(ValueError, match="observer_pins"):
        ndr.TlsConfig(cert, key, peer_cert=peer, observer_pins=["nothex"])
    with pytest.raises(ValueError, match="name no observer"):
        ndr.TlsConfig(cert, key, peer_cert=peer, observer_pins=[])
    with pytest.raises(ValueError, match="observer_certs"):
        ndr.TlsConfig(cert, key, peer_cert=peer, observer_certs=str(tmp_path / "none.crt"))
