"""Prometheus metrics: `ndr remote --metrics` scraped during a run, and
`Link.metrics()` / `ndr.metrics.LinkCollector`, each page read with
prometheus_client's own text parser."""

import json
import os
import pathlib
import queue
import re
import signal
import subprocess
import threading
import time
import urllib.request

import pytest
from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.parser import text_string_to_metric_families

import ndr
from ndr.metrics import LinkCollector

LOOPBACK = ("127.0.0.1", 0)
ROOT = pathlib.Path(__file__).resolve().parents[2]


def ndr_cli() -> str:
    """The `ndr` command the Rust tests built (scripts/test runs
    `cargo test` first), or the one NDR_CLI names."""
    path = os.environ.get("NDR_CLI") or str(ROOT / "target" / "debug" / "ndr")
    if not os.access(path, os.X_OK):
        pytest.fail(f"no ndr command at {path}: run `cargo build` first, or set NDR_CLI")
    return path


def samples(text):
    """{(sample name, frozen labels): value} of a page, parsed by prometheus_client."""
    out = {}
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            out[(s.name, frozenset(s.labels.items()))] = s.value
    return out


def value(page, name, **labels):
    """The one sample of `name` whose labels include `labels`."""
    found = [v for (n, ls), v in page.items() if n == name and set(labels.items()) <= ls]
    assert len(found) == 1, (name, labels, found)
    return found[0]


class Lines:
    """A process's stderr, line by line, read on a thread."""

    def __init__(self, stream):
        self.lines = queue.Queue()
        self.seen = []
        threading.Thread(target=self._read, args=(stream,), daemon=True).start()

    def _read(self, stream):
        for line in stream:
            self.lines.put(line)
        self.lines.put(None)

    def wait_for(self, pattern, timeout):
        end = time.monotonic() + timeout
        while True:
            for line in self.seen:
                m = re.search(pattern, line)
                if m:
                    return m
            left = end - time.monotonic()
            if left <= 0:
                raise AssertionError(f"no line matching {pattern!r} in {self.seen}")
            try:
                line = self.lines.get(timeout=left)
            except queue.Empty:
                continue
            if line is None:
                raise AssertionError(f"the process ended with no line matching {pattern!r}: "
                                     f"{self.seen}")
            self.seen.append(line)


def scrape(url):
    with urllib.request.urlopen(url, timeout=5) as r:
        assert r.headers["Content-Type"].startswith("text/plain; version=0.0.4")
        return r.read().decode()


def test_ndr_remote_serves_metrics_during_a_run_and_its_count_matches_the_report(tmp_path):
    cli = ndr_cli()
    remote = subprocess.Popen(
        [cli, "remote", "--listen", "127.0.0.1:0", "--metrics", "127.0.0.1:0",
         "--period-ms", "20"],
        stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
    )
    try:
        err = Lines(remote.stderr)
        url = err.wait_for(r"metrics at (http://\S+/metrics)", 20).group(1)
        listen = err.wait_for(r"waiting for a base on (\S+) ", 20).group(1)
        # Before any base: the listener's series, no link's.
        first = samples(scrape(url))
        assert value(first, "ndr_links_accepted_total", peer=listen) == 0
        assert not [k for k in first if k[0] == "ndr_samples_released_total"]

        base = subprocess.Popen(
            [cli, "base", "--connect", listen, "--duration-s", "3", "--period-ms", "20",
             "--json", "--out", str(tmp_path / "base.csv")],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        peer = err.wait_for(r"base (\S+): handshake done", 20).group(1)
        released = []
        running = 0
        while base.poll() is None:
            page = samples(scrape(url))
            if any(k[0] == "ndr_samples_released_total" for k in page):
                labels = dict(peer=peer, role="remote", transport="tcp")
                released.append(value(page, "ndr_samples_released_total", **labels))
                running += value(page, "ndr_link_running", **labels) == 1
                assert value(page, "ndr_period_seconds", **labels) == pytest.approx(0.02)
                count = value(page, "ndr_release_lateness_seconds_count", **labels)
                inf = value(page, "ndr_release_lateness_seconds_bucket", le="+Inf", **labels)
                assert inf == count
            time.sleep(0.05)
        out, base_err = base.communicate(timeout=30)
        assert base.returncode == 0, base_err
        assert json.loads(out)["ok"] is True
        # Scraped while the link ran, the count never going back.
        assert running >= 3, (running, released)
        assert released == sorted(released) and released[-1] > 0

        ended = err.wait_for(rf"base {re.escape(peer)}: .* after (\d+) samples released", 20)
        final = samples(scrape(url))
        labels = dict(peer=peer, role="remote", transport="tcp")
        assert value(final, "ndr_samples_released_total", **labels) == int(ended.group(1))
        assert value(final, "ndr_link_running", **labels) == 0
        assert value(final, "ndr_links_accepted_total", peer=listen) == 1
    finally:
        remote.send_signal(signal.SIGTERM)
        try:
            remote.wait(timeout=10)
        except subprocess.TimeoutExpired:
            remote.kill()
            remote.wait()


def test_a_link_metrics_page_parses_and_holds_its_stats():
    listener = ndr.Link.listen(LOOPBACK, period=0.01, transport="udp")
    accepted = []
    t = threading.Thread(target=lambda: accepted.append(listener.accept(timeout=5)), daemon=True)
    t.start()
    base = ndr.Link.connect(listener.address, period=0.01, transport="udp")
    t.join(5)
    (remote,) = accepted
    try:
        got = 0
        for _ in base.ticks(timeout=3):
            got += 1
            if got == 30:
                break
        collector = LinkCollector()
        collector.add(base)
        collector.add(remote)
        registry = CollectorRegistry()
        registry.register(collector)
        both = samples(generate_latest(registry).decode())
        for role in ("base", "remote"):
            assert value(both, "ndr_samples_released_total", role=role, transport="udp") > 0
        collector.remove(remote)
        only = samples(generate_latest(registry).decode())
        assert not [k for k in only if ("role", "remote") in k[1]]
    finally:
        base.close()
        remote.close()
        listener.close()
    # Closed: the last snapshot, the same in both forms.
    page = samples(base.metrics())
    stats = base.stats
    host, port = remote_peer = base.peer
    labels = dict(peer=f"{host}:{port}", role="base", transport="udp")
    assert remote_peer
    assert value(page, "ndr_samples_released_total", **labels) == stats["released_fresh"]
    assert value(page, "ndr_samples_sent_total", **labels) == stats["samples_sent"]
    assert value(page, "ndr_underflows_total", **labels) == stats["underflows"]
    assert value(page, "ndr_grtt_seconds", **labels) == pytest.approx(stats["grtt"]["mean"])
    assert value(page, "ndr_queue_nominal_samples", **labels) == stats["ns"]
    assert value(page, "ndr_release_lateness_seconds_count", **labels) == (
        stats["release_lateness"]["count"]
    )
    assert value(page, "ndr_playout_delay_seconds", direction="states", **labels) == (
        pytest.approx(stats["playout_delay"])
    )
