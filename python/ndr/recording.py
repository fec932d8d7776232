"""Reading a link's MCAP recording (``record=`` on :meth:`ndr.Link.connect`
and :meth:`ndr.Link.listen`, ``--record`` on ``ndr demo``, ``ndr base`` and
``ndr remote``) as numpy arrays, through the ``mcap`` package (an optional
extra: ``pip install 'ndr[record]'``).

::

    rec = ndr.read_recording("x.mcap")
    state = rec["/ndr/state"]
    fresh = state["status"] == "fresh"
    grtt = state["grtt_s"][fresh]           # NaN where no round trip closed
    positions = state["values"]["positions0"]

Each topic (``/ndr/command``, ``/ndr/state``, ``/ndr/event``,
``/ndr/stats``, ``/ndr/network``, ``/ndr/probe``) maps to a dict of equal-length arrays: one
per message field (numbers as float64, a missing or null one as NaN; text
as a numpy string array), ``log_time`` and ``publish_time`` (Unix seconds),
and for the releases ``values``: one array per value, by name. A file whose
writer was killed reads up to its last whole chunk; :attr:`Recording.truncated`
says so.
"""

from __future__ import annotations

import json
import math
from typing import Any, Dict, Iterator, List, Mapping, Tuple

import numpy as np

__all__ = ["TOPICS", "Recording", "read_recording"]

#: The topics of a recording.
TOPICS = (
    "/ndr/command",
    "/ndr/state",
    "/ndr/event",
    "/ndr/stats",
    "/ndr/network",
    "/ndr/probe",
)


class Recording(Dict[str, Dict[str, Any]]):
    """A recording, topic by topic (a dict), with what reading it found."""

    #: The file ended inside a record: its writer was killed; everything up
    #: to its last whole chunk is here.
    truncated: bool = False
    #: The topics' schema names, by topic.
    schemas: Dict[str, str]

    def __init__(self) -> None:
        super().__init__()
        self.schemas = {}


def _mcap() -> Tuple[Any, Any, Any]:
    try:
        from mcap.exceptions import McapError  # type: ignore[import-not-found,unused-ignore]
        from mcap.records import Channel, Message, Schema  # type: ignore[import-not-found,unused-ignore]
        from mcap.stream_reader import StreamReader  # type: ignore[import-not-found,unused-ignore]
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError(
            "reading a recording needs the mcap package: pip install 'ndr[record]' "
            "(or pip install mcap)"
        ) from e
    return StreamReader, McapError, (Schema, Channel, Message)


def _messages(path: str, rec: Recording) -> Iterator[Tuple[str, Any]]:
    StreamReader, McapError, (Schema, Channel, Message) = _mcap()
    schemas: Dict[int, str] = {}
    topics: Dict[int, str] = {}
    with open(path, "rb") as f:
        records = StreamReader(f, skip_magic=False).records
        while True:
            try:
                r = next(records)
            except StopIteration:
                return
            except (McapError, EOFError, ValueError) as e:
                # A killed writer leaves its last record cut short.
                if rec or topics:
                    rec.truncated = True
                    return
                raise ValueError(f"{path} is not an MCAP recording: {e}") from None
            if isinstance(r, Schema):
                schemas[r.id] = r.name
            elif isinstance(r, Channel):
                topics[r.id] = r.topic
                rec.schemas[r.topic] = schemas.get(r.schema_id, "")
                rec.setdefault(r.topic, {"log_time": np.zeros(0), "publish_time": np.zeros(0)})
            elif isinstance(r, Message):
                topic = topics.get(r.channel_id)
                if topic is not None:
                    yield topic, r


def _column(values: List[Any]) -> np.ndarray:
    if all(v is None or isinstance(v, (bool, int, float)) for v in values):
        return np.asarray([math.nan if v is None else float(v) for v in values], dtype=float)
    return np.asarray(["" if v is None else str(v) for v in values])


def read_recording(path: str) -> Recording:
    """The recording at ``path``, topic by topic, as numpy arrays (see the
    module's docs). Raises ``ValueError`` for a file that is not an MCAP
    recording, ``OSError`` for one that cannot be read, ``ImportError``
    without the ``mcap`` package."""
    rec = Recording()
    rows: Dict[str, List[Tuple[float, float, Mapping[str, Any]]]] = {}
    for topic, m in _messages(str(path), rec):
        try:
            body = json.loads(m.data)
        except ValueError:
            raise ValueError(f"{path}: a {topic} message is not JSON") from None
        rows.setdefault(topic, []).append((m.log_time * 1e-9, m.publish_time * 1e-9, body))
    for topic, msgs in rows.items():
        fields: List[str] = []
        names: List[str] = []
        for _, _, body in msgs:
            for k, v in body.items():
                if k == "values" and isinstance(v, Mapping):
                    names.extend(n for n in v if n not in names)
                elif k not in fields:
                    fields.append(k)
        out: Dict[str, Any] = {
            "log_time": np.asarray([m[0] for m in msgs], dtype=float),
            "publish_time": np.asarray([m[1] for m in msgs], dtype=float),
        }
        for k in fields:
            out[k] = _column([body.get(k) for _, _, body in msgs])
        if names:
            out["values"] = {
                n: np.asarray(
                    [float(body.get("values", {}).get(n, math.nan)) for _, _, body in msgs],
                    dtype=float,
                )
                for n in names
            }
        rec[topic] = out
    return rec
