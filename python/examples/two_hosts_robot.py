"""The robot's side of a link between two hosts: it waits for the
operator (examples/two_hosts_operator.py), drives a simulated axis with the
commands the link releases and sends its position back, once a period.

On the robot (plain TCP on a network you trust; see the operator's
docstring for TLS and QUIC)::

    python two_hosts_robot.py --listen 0.0.0.0:7000 --insecure

It serves one operator, then exits 0 if the operator ended the link in
order. It prints ``listening on HOST:PORT`` once it listens, then one
JSON line when the link ends.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Optional

import ndr


def tls_from(args: argparse.Namespace) -> Optional[ndr.TlsConfig]:
    """Mutual TLS 1.3 from the command line: this side's pair, and the
    peer's certificate (pinned) or its fingerprint."""
    if args.cert is None:
        return None
    return ndr.TlsConfig(args.cert, args.key, peer_cert=args.peer_cert, pins=args.pin)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--listen", default="0.0.0.0:7000", help="HOST:PORT (port 0: any free one)")
    p.add_argument("--transport", default="tcp", help="tcp, udp or quic (quic needs TLS)")
    p.add_argument("--period", type=float, default=0.02, help="seconds; both sides alike")
    p.add_argument("--insecure", action="store_true", help="plain link off loopback")
    p.add_argument("--cert", help="this side's certificate (ndr keygen)")
    p.add_argument("--key", help="this side's key")
    p.add_argument("--peer-cert", help="the operator's certificate, pinned")
    p.add_argument("--pin", help="the operator's SHA-256 fingerprint, instead")
    args = p.parse_args()

    listener = ndr.Link.listen(
        args.listen,
        period=args.period,
        transport=args.transport,
        tls=tls_from(args),
        insecure=args.insecure,
    )
    host, port = listener.address
    print(f"listening on {host}:{port}", flush=True)

    position = 0.0
    released = 0
    with listener.accept() as link:
        # Until the operator ends the link in order; any other end raises.
        for tick in link.ticks(timeout=30.0):
            command = float(tick.sample[0])
            # A first-order axis: a tenth of the way to the command each
            # period. A lost link holds (the watchdog's "link_lost" event,
            # and held ticks repeat the last command).
            position += 0.1 * (command - position)
            link.send([position])
            released += 1
        stats = link.stats
    late = stats["late"] if stats is not None else 0
    print(json.dumps({"released": released, "late": late}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
