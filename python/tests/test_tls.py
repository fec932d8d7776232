"""Mutual TLS and the insecure switch, from Python."""

import threading

import numpy as np
import pytest

import ndr
from realtime import assert_constant, assert_round_trips, counted_gaps, echo, no_gap, regulated

LOOPBACK = ("127.0.0.1", 0)


@pytest.fixture(scope="module")
def certs(tmp_path_factory):
    d = tmp_path_factory.mktemp("certs")
    pairs = {name: ndr.keygen(d, name) for name in ("base", "robot", "stranger")}
    return pairs


def tls(certs, me, peer):
    cert, key, _ = certs[me]
    return ndr.TlsConfig(cert, key, peer_cert=certs[peer][0])


def test_keygen_writes_a_pair_and_never_overwrites_a_key(tmp_path):
    cert, key, fingerprint = ndr.keygen(tmp_path, "lab")
    assert cert.endswith("lab.crt") and key.endswith("lab.key")
    assert len(fingerprint.replace(":", "")) == 64
    assert ndr.TlsConfig(cert, key, pins=[fingerprint]).fingerprint == fingerprint
    with pytest.raises(ValueError, match="lab"):
        ndr.keygen(tmp_path, "lab")
    with pytest.raises(ValueError, match="name"):
        ndr.keygen(tmp_path, "../evil")


def test_a_link_over_mutual_tls_runs_with_a_constant_delay(certs):
    # The paper's FIFO, whose delay is set once (the adaptive default's
    # follows the jitter, which a busy host brings).
    def run():
        with ndr.Link.listen(
            LOOPBACK, period=0.01, regulation="paper-static", tls=tls(certs, "robot", "base")
        ) as lst:
            got = []
            t = threading.Thread(target=lambda: got.append(lst.accept(timeout=5)), daemon=True)
            t.start()
            with ndr.Link.connect(
                lst.address, period=0.01, regulation="paper-static", tls=tls(certs, "base", "robot")
            ) as base:
                t.join(5)
                remote = got[0]
                stop = threading.Event()
                robot = threading.Thread(target=echo, args=(remote, stop), daemon=True)
                robot.start()
                grtt, at, ticks = [], [], []
                # 150 round trips, however many ticks a held host leaves
                # without one (bounded).
                for i in range(1000):
                    base.send(float(i))
                    tick = base.recv(timeout=2)
                    ticks.append(tick)
                    if tick.grtt is not None:
                        grtt.append(tick.grtt)
                        at.append(tick.released_at)
                    if len(grtt) >= 150:
                        break
                stop.set()
                robot.join(5)
                stats = [base.stats, remote.stats]
                remote.close()
            assert lst.stats["accepted"] == 1
        counted = counted_gaps(stats[0], stats[1])
        assert no_gap(ticks, counted), ([(t.seq, t.status) for t in ticks], stats)
        return (grtt, at, ticks, stats), stats

    (grtt, at, ticks, stats), stalls = regulated(run)
    if not stalls:
        assert all(t.status == "fresh" for t in ticks)
    # The ticks the loop ran past 150 round trips: those without one, each
    # accounted for by a counter (see `assert_round_trips`).
    accounted = (sum(s["underflows"] for s in stats) + stats[1]["samples_repeated"]
                 + counted_gaps(stats[0], stats[1]) + counted_gaps(stats[1], stats[0]))
    assert_round_trips([t.grtt for t in ticks], accounted)
    assert_constant(grtt, stalls, "GRTT", released_at=at, period=0.01,
                    underflows=sum(s["underflows"] for s in stats))


def test_a_stranger_is_refused_and_never_reaches_the_application(certs):
    with ndr.Link.listen(LOOPBACK, period=0.02, tls=tls(certs, "robot", "base")) as lst:
        # The listener handshakes with whoever connects while it accepts.
        accepted = []

        def serve():
            try:
                accepted.append(lst.accept(timeout=6))
            except TimeoutError:
                pass

        t = threading.Thread(target=serve, daemon=True)
        t.start()
        # TLS 1.3 lets the client finish before the server checks the
        # client's certificate: the refusal then ends the link at once.
        with pytest.raises((ndr.HandshakeError, ndr.DisconnectedError)):
            ndr.Link.connect(lst.address, period=0.02, tls=tls(certs, "stranger", "robot"))
        # Without TLS at all: the listener sees no TLS handshake.
        with pytest.raises(ConnectionError):
            ndr.Link.connect(lst.address, period=0.02, connect_timeout=3, handshake_timeout=1)
        # The right peer is served after them.
        with ndr.Link.connect(lst.address, period=0.02, tls=tls(certs, "base", "robot")):
            t.join(6)
        assert len(accepted) == 1, "only the right peer reaches the application"
        accepted[0].close()
        assert lst.stats["refused_certificate"] >= 1
        assert lst.refused >= 2


def test_a_plain_link_off_loopback_needs_insecure():
    with pytest.raises(ValueError, match="insecure"):
        ndr.Link.listen(("0.0.0.0", 0))
    lst = ndr.Link.listen(("0.0.0.0", 0), insecure=True)
    lst.close()
    with pytest.raises(ValueError, match="insecure"):
        ndr.Link.connect(("192.0.2.1", 9), connect_timeout=1)


def test_bad_tls_settings_are_value_errors(certs, tmp_path):
    cert, key, _ = certs["base"]
    with pytest.raises(ValueError, match="exactly one"):
        ndr.TlsConfig(cert, key)
    with pytest.raises(ValueError, match="pins"):
        ndr.TlsConfig(cert, key, pins=["not-hex"])
    with pytest.raises(ValueError, match="TLS"):
        ndr.TlsConfig(tmp_path / "missing.crt", key, peer_cert=cert)
