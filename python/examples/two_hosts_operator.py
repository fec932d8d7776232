"""The operator's side of a link between two hosts: it connects to the
robot (examples/two_hosts_robot.py), sends a sine command once a period and reads
the robot's position back, at the constant round trip the link holds.

Plain TCP on a network you trust (``insecure=True`` allows a plain link
off loopback)::

    python two_hosts_robot.py    --listen 0.0.0.0:7000 --insecure
    python two_hosts_operator.py --connect robot.local:7000 --insecure

Mutual TLS 1.3 over TCP, each side pinning the other's fingerprint
(``ndr keygen --out keys --name robot`` on the robot, ``--name operator``
here; each prints its fingerprint)::

    python two_hosts_robot.py    --listen 0.0.0.0:7000 --cert keys/robot.crt \\
        --key keys/robot.key --pin OPERATORS_SHA256
    python two_hosts_operator.py --connect robot.local:7000 --cert keys/operator.crt \\
        --key keys/operator.key --pin ROBOTS_SHA256

QUIC (datagrams under the same mutual TLS; one UDP port, no TCP): add
``--transport quic`` on both sides. It prints one JSON line: the states
released, the round trip's mean, and how the link ended.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from typing import List, Optional

import ndr


def tls_from(args: argparse.Namespace) -> Optional[ndr.TlsConfig]:
    """Mutual TLS 1.3 from the command line: this side's pair, and the
    peer's certificate (pinned) or its fingerprint."""
    if args.cert is None:
        return None
    return ndr.TlsConfig(args.cert, args.key, peer_cert=args.peer_cert, pins=args.pin)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--connect", required=True, help="the robot's HOST:PORT")
    p.add_argument("--transport", default="tcp", help="tcp, udp or quic (quic needs TLS)")
    p.add_argument("--period", type=float, default=0.02, help="seconds; both sides alike")
    p.add_argument("--duration", type=float, default=10.0, help="seconds of samples")
    p.add_argument("--insecure", action="store_true", help="plain link off loopback")
    p.add_argument("--cert", help="this side's certificate (ndr keygen)")
    p.add_argument("--key", help="this side's key")
    p.add_argument("--peer-cert", help="the robot's certificate, pinned")
    p.add_argument("--pin", help="the robot's SHA-256 fingerprint, instead")
    args = p.parse_args()

    grtts: List[float] = []
    released = 0
    with ndr.Link.connect(
        args.connect,
        period=args.period,
        transport=args.transport,
        tls=tls_from(args),
        insecure=args.insecure,
    ) as link:
        start = time.monotonic()
        link.send([0.0])
        for tick in link.ticks(timeout=10.0):
            t = time.monotonic() - start
            if t >= args.duration:
                break
            released += 1
            if tick.grtt is not None:
                grtts.append(tick.grtt)
            link.send([math.sin(2 * math.pi * 0.5 * t)])
    # Leaving the block closed the link in order: the robot's loop ends.
    report = {
        "released": released,
        "grtt_mean_s": sum(grtts) / len(grtts) if grtts else None,
        "end": "completed",
    }
    print(json.dumps(report), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
