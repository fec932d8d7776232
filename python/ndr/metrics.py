"""Links' figures for a ``prometheus_client`` registry.

:class:`LinkCollector` is a custom collector: register it once and each
scrape of the registry reads every link it holds, with the names and labels
of ``ndr remote --metrics`` (``docs/guide/metrics.md``)::

    from prometheus_client import REGISTRY, start_http_server
    import ndr
    from ndr.metrics import LinkCollector

    links = LinkCollector()
    REGISTRY.register(links)
    start_http_server(9464)
    with ndr.Link.connect(("robot", 7000), axes=2) as link:
        links.add(link)
        ...

It needs the ``prometheus-client`` package (``pip install "ndr[metrics]"``);
:meth:`ndr.Link.metrics` alone does not.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING, Dict, Iterator, List

if TYPE_CHECKING:
    from prometheus_client.metrics_core import Metric

    from .link import Link

__all__ = ["LinkCollector"]


class LinkCollector:
    """A ``prometheus_client`` collector of links' figures.

    Each scrape parses :meth:`ndr.Link.metrics` of every link added (the
    text the Rust library encodes: one source for the CLI, Rust and
    Python) and merges the links' samples into one family per name. A link
    that ended keeps showing its last figures until :meth:`remove`."""

    def __init__(self) -> None:
        try:
            from prometheus_client import parser
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError(
                "ndr.metrics.LinkCollector needs the prometheus-client package: "
                'pip install "ndr[metrics]" (or prometheus-client)'
            ) from e
        self._parse = parser.text_string_to_metric_families
        self._links: List["Link"] = []
        self._lock = threading.Lock()

    def add(self, link: "Link") -> None:
        """Shows ``link``'s figures from the next scrape on."""
        with self._lock:
            if all(link is not other for other in self._links):
                self._links.append(link)

    def remove(self, link: "Link") -> None:
        """Stops showing ``link`` (its series end); a link not added is ignored."""
        with self._lock:
            self._links = [other for other in self._links if other is not link]

    def collect(self) -> Iterator["Metric"]:
        """The families of every link added (called by the registry)."""
        with self._lock:
            links = list(self._links)
        families: Dict[str, "Metric"] = {}
        for link in links:
            for family in self._parse(link.metrics()):
                merged = families.get(family.name)
                if merged is None:
                    families[family.name] = family
                else:
                    merged.samples.extend(family.samples)
        return iter(families.values())
