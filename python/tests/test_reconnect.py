"""A base that waits for its remote (``connect_timeout``) and comes back
after losing it (``reconnect=True``), with real processes on loopback: a
remote started two seconds after the base connects; a remote killed
(SIGKILL) and started again two seconds later. Margins are seconds wide:
a loaded host delays the processes' starts, not what is checked."""

import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

import ndr

PERIOD = 0.02

# A remote in a process of its own, so that it can be killed: serves one
# base after another, echoing each command as its state.
REMOTE = """
import sys, ndr
lst = ndr.Link.listen(("127.0.0.1", int(sys.argv[1])), period={period})
print("listening", flush=True)
while True:
    link = lst.accept()
    try:
        while True:
            tick = link.recv()
            link.send(tick.sample)
    except ndr.LinkError:
        pass
"""


def _free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def _remote(port: int) -> subprocess.Popen:
    proc = subprocess.Popen(
        [sys.executable, "-c", REMOTE.format(period=PERIOD), str(port)],
        stdout=subprocess.PIPE,
        text=True,
    )
    return proc


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait(timeout=10)


def test_connect_waits_for_a_remote_started_two_seconds_later():
    port = _free_port()
    served = threading.Event()

    def remote() -> None:
        time.sleep(2.0)
        with ndr.Link.listen(("127.0.0.1", port), period=PERIOD) as lst:
            with lst.accept(timeout=20):
                served.wait(20)

    t = threading.Thread(target=remote)
    t.start()
    try:
        with ndr.Link.connect(("127.0.0.1", port), period=PERIOD, connect_timeout=10) as link:
            for _ in range(5):
                link.recv(timeout=10)
            waited = link.stats["waited"]
            served.set()
    finally:
        served.set()
        t.join(30)
    # The remote came two seconds after the first attempt.
    assert 1.0 <= waited < 10.0, waited


def test_connect_timeout_zero_makes_one_attempt():
    port = _free_port()
    start = time.monotonic()
    with pytest.raises(ConnectionRefusedError):
        ndr.Link.connect(("127.0.0.1", port), connect_timeout=0)
    assert time.monotonic() - start < 1.0


def test_reconnect_is_a_bases():
    with pytest.raises(ValueError, match="reconnect=True is a base's"):
        ndr.Link.connect(("127.0.0.1", 9), role="remote", reconnect=True, connect_timeout=0)


def test_a_base_comes_back_after_its_remote_is_killed_and_restarted():
    port = _free_port()
    first = _remote(port)
    second = None
    try:
        link = ndr.Link.connect(
            ("127.0.0.1", port), period=PERIOD, reconnect=True, connect_timeout=20
        )
        seqs = []  # (seq, held)
        events = []
        killed_at = restarted_at = None
        # Fresh states released before the kill, and after the restore.
        before = after = 0
        start = time.monotonic()
        with link:
            # Long enough for a restarted remote whose start a loaded host
            # delays by seconds.
            while time.monotonic() - start < 14.0:
                now = time.monotonic() - start
                if killed_at is None and now > 1.5:
                    first.send_signal(signal.SIGKILL)
                    first.wait(timeout=10)
                    killed_at = now
                if restarted_at is None and killed_at is not None and now > killed_at + 2.0:
                    second = _remote(port)
                    restarted_at = now
                try:
                    tick = link.recv(timeout=0.2)
                except TimeoutError:
                    pass
                else:
                    seqs.append((tick.seq, tick.status == "held"))
                    link.send(tick.sample)
                    fresh = tick.status == "fresh"
                    if killed_at is None:
                        before += fresh
                    elif any(e.kind == "link_restored" for e in events):
                        after += fresh
                events.extend(link.events())
            stats = link.stats
        kinds = [e.kind for e in events]
        assert "link_lost" in kinds and "link_restored" in kinds, kinds
        restored = [e for e in events if e.kind == "link_restored"]
        assert len(restored) == 1, restored
        # Two seconds away, then the new session's start.
        outage = restored[0].outage
        assert 1.9 <= outage < 12.0, outage
        assert stats["reconnects"] == 1, stats
        assert stats["outage_total"] == pytest.approx(outage), stats
        assert stats["stale"] == 0, stats
        # The new session ran its initialization pattern and announced its
        # round trip after the restore.
        since_restore = kinds[kinds.index("link_restored") :]
        assert "round_trip_changed" in since_restore, kinds
        # One rising sequence across the sessions: nothing twice, nothing
        # out of order; states on both sides of the outage.
        last = None
        for seq, held in seqs:
            if last is not None:
                assert seq == last if held else seq > last, (seq, held, last)
            if not held:
                last = seq
        assert before >= 10 and after >= 10, (before, after)
    finally:
        _stop(first)
        if second is not None:
            _stop(second)
