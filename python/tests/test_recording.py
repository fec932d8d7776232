"""MCAP recordings: ``record=`` on a link, read back with the ``mcap``
package (not ndr's reader) and with :func:`ndr.read_recording`; ``python -m
ndr plot`` draws one; ``ndr demo --record`` agrees with its report.

Real-time runs of a second or two; judged by counts, never by timings."""

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

import ndr

mcap_reader = pytest.importorskip("mcap.reader")
from mcap.stream_reader import StreamReader  # noqa: E402
from mcap.records import Message  # noqa: E402

LOOPBACK = ("127.0.0.1", 0)
TOPICS = {
    "/ndr/command",
    "/ndr/state",
    "/ndr/event",
    "/ndr/stats",
    "/ndr/network",
    "/ndr/probe",
}
ROOT = Path(__file__).resolve().parents[2]


def channels(path):
    """Topic → (schema name, schema encoding), through the mcap package."""
    with open(path, "rb") as f:
        summary = mcap_reader.make_reader(f).get_summary()
    return {
        c.topic: (summary.schemas[c.schema_id].name, summary.schemas[c.schema_id].encoding)
        for c in summary.channels.values()
    }


def messages(path):
    """(topic, log_time, body) of every message, through the mcap package."""
    with open(path, "rb") as f:
        return [
            (c.topic, m.log_time, json.loads(m.data))
            for _, c, m in mcap_reader.make_reader(f).iter_messages(log_time_order=False)
        ]


def record_pair(path, seconds=1.5):
    """A base and a remote over loopback, both recorded into ``path``
    (the remote through its listener's ``record=``, the base's into
    ``path``.base); the base's and the remote's final stats."""
    listener = ndr.Link.listen(LOOPBACK, period=0.01, record=path)
    got = {}

    def serve():
        remote = listener.accept(timeout=5)
        for tick in remote:
            remote.send(tick.sample)
        got["remote"] = remote.stats
        remote.close()

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    base_path = str(path) + ".base.mcap"
    with ndr.Link.connect(listener.address, period=0.01, record=base_path) as base:
        assert base.recording is not None
        end = base.now() + seconds
        for tick in base:
            base.send([np.sin(tick.released_at)])
            if tick.released_at > end:
                break
    # The counters once closed: the link releases until then.
    got["base"] = base.stats
    assert base.recording is None, "a closed link lets its recording go"
    t.join(5)
    assert "remote" in got, "the remote's link did not end"
    listener.close()
    return base_path, got


def test_a_recorded_link_reads_back_with_the_mcap_package(tmp_path):
    path = tmp_path / "remote.mcap"
    base_path, got = record_pair(path)
    # The listener's file, finished once it and its link are closed.
    for p, side, topic in [(path, "remote", "/ndr/command"), (base_path, "base", "/ndr/state")]:
        ch = channels(p)
        assert set(ch) == TOPICS
        assert all(enc == "jsonschema" for _, enc in ch.values())
        msgs = messages(p)
        releases = [b for t, _, b in msgs if t == topic]
        fresh = sum(b["status"] == "fresh" for b in releases)
        assert fresh == got[side]["released_fresh"], side
        # ndr's reader agrees with the mcap package.
        rec = ndr.read_recording(str(p))
        assert not rec.truncated
        assert int((rec[topic]["status"] == "fresh").sum()) == fresh
        assert rec[topic]["seq"].dtype == np.float64
        assert np.all(np.diff(rec[topic]["log_time"]) >= 0)
        assert len(rec[topic]["values"]["command0" if side == "remote" else "state0"]) == len(
            releases
        )


def test_a_recording_cut_short_reads_to_its_last_whole_record(tmp_path):
    path = tmp_path / "remote.mcap"
    base_path, _ = record_pair(path, seconds=3.0)
    data = Path(base_path).read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 3 // 4])
    whole = ndr.read_recording(base_path)
    part = ndr.read_recording(str(cut))
    assert part.truncated and not whole.truncated
    n = len(part["/ndr/state"]["seq"])
    assert 0 < n < len(whole["/ndr/state"]["seq"])
    assert np.array_equal(part["/ndr/state"]["seq"], whole["/ndr/state"]["seq"][:n])
    # The mcap package's stream reader reads the same messages before the cut.
    count = 0
    with open(cut, "rb") as f:
        try:
            for r in StreamReader(f).records:
                count += isinstance(r, Message)
        except Exception:
            pass
    assert count == sum(len(t["log_time"]) for t in part.values())
    with pytest.raises(ValueError, match="not an MCAP recording"):
        bad = tmp_path / "bad.mcap"
        bad.write_bytes(b"t_s,seq\n")
        ndr.read_recording(str(bad))


def test_the_plot_command_draws_a_recording(tmp_path):
    pytest.importorskip("matplotlib")
    path = tmp_path / "remote.mcap"
    base_path, _ = record_pair(path, seconds=1.0)
    out = tmp_path / "x.png"
    done = subprocess.run(
        [sys.executable, "-m", "ndr", "plot", base_path, "-o", str(out)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert out.stat().st_size > 10_000


def ndr_binary():
    exe = os.environ.get("NDR_BIN") or str(ROOT / "target" / "debug" / "ndr")
    if not os.path.exists(exe):
        pytest.skip(f"no ndr binary at {exe}: build it (cargo build) or set NDR_BIN")
    return exe


def test_a_recorded_demo_agrees_with_its_report(tmp_path):
    rec, csv = tmp_path / "x.mcap", tmp_path / "x.csv"
    done = subprocess.run(
        [ndr_binary(), "demo", "--duration-s", "10", "--record", str(rec),
         "--out", str(csv), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert set(channels(rec)) == TOPICS
    msgs = messages(rec)
    by = {t: [(lt, b) for tt, lt, b in msgs if tt == t] for t in TOPICS}
    fresh = {t: sum(b["status"] == "fresh" for _, b in by[t]) for t in ("/ndr/state", "/ndr/command")}
    # The demo's count is both sides'. Every fresh row of the base's CSV is
    # a fresh state of the recording (which also has the releases after the
    # operator stopped reading).
    assert fresh["/ndr/state"] + fresh["/ndr/command"] == report["samples_released"]
    recorded = {b["seq"] for _, b in by["/ndr/state"] if b["status"] == "fresh"}
    rows = [line.split(",") for line in csv.read_text().splitlines()[1:]]
    csv_fresh = [int(r[1]) for r in rows if r[2] == "fresh"]
    assert len(csv_fresh) > 100 and set(csv_fresh) <= recorded
    for t in ("/ndr/state", "/ndr/command"):
        times = [lt for lt, _ in by[t]]
        assert times == sorted(times)
    sent = {b["sent_ns"] for _, b in by["/ndr/command"]}
    grtts = []
    for _, b in by["/ndr/state"]:
        if b["answers_sent_ns"] is not None:
            assert b["answers_sent_ns"] in sent
            grtts.append((b["released_ns"] - b["answers_sent_ns"]) * 1e-9)
    assert len(grtts) == report["grtt_count"]
    assert abs(np.mean(grtts) - report["grtt_mean_s"]) < 1e-6
