"""A robot's states over zenoh, read without ndr: only the `eclipse-zenoh`
package and the wire format (docs/wire.md, §2, §3.5 and §4.1).

    python zenoh_states.py --robot arm1 --connect tcp/HOST:7447 [--count N]

Subscribes to `ndr/ROBOT/state/*`, where a remote publishes each link's
states as Bundles, and prints one line per Bundle: the link's session,
the newest sample's `seq` and its values, each state once. No playout: the states arrive as
the network brings them, not at the link's regulated delay.
"""

import argparse
import struct
import threading

import zenoh

HEADER = struct.Struct("<IBBHQQQQQ")  # length, version, kind, term, seq, sent_at, echo, echo_hold, released
BUNDLE = struct.Struct("<QBBHI")  # session, count, repeat, width, missed
KIND_BUNDLE = 5


def decode(payload: bytes):
    """(seq, sent_at_ns, values) of a Bundle's newest sample, or None."""
    if len(payload) < HEADER.size + BUNDLE.size:
        return None
    length, version, kind, _term, seq, sent_at, _echo, _hold, _released = HEADER.unpack_from(payload)
    if kind != KIND_BUNDLE or length != len(payload):
        return None
    _session, count, _repeat, width, _missed = BUNDLE.unpack_from(payload, HEADER.size)
    start = HEADER.size + BUNDLE.size
    # Width 0: a probe of the initialization pattern, no state yet.
    if count < 1 or width == 0 or len(payload) < start + 8 * width:
        return None
    values = struct.unpack_from(f"<{width}d", payload, start)
    return seq, sent_at, values


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", required=True)
    parser.add_argument("--connect", action="append", default=[])
    parser.add_argument("--count", type=int, default=0, help="stop after N states (0: never)")
    args = parser.parse_args()
    config = zenoh.Config()
    if args.connect:
        config.insert_json5("mode", '"client"')
        config.insert_json5("connect/endpoints", str(args.connect).replace("'", '"'))
    done = threading.Event()
    seen = [0]
    # The newest seq printed per link: a Bundle repeated on a lossy path,
    # or one that came late, is not printed again.
    newest = {}

    def on_sample(sample):
        decoded = decode(bytes(sample.payload.to_bytes()))
        if decoded is None or done.is_set():
            return
        seq, sent_at, values = decoded
        session = str(sample.key_expr).rsplit("/", 1)[-1]
        if newest.get(session, -1) >= seq:
            return
        newest[session] = seq
        print(f"{session} seq {seq} sent_at {sent_at} values {list(values)}", flush=True)
        seen[0] += 1
        if args.count and seen[0] >= args.count:
            done.set()

    with zenoh.open(config) as session:
        subscriber = session.declare_subscriber(f"ndr/{args.robot}/state/*", on_sample)
        done.wait(None if not args.count else 60)
        subscriber.undeclare()


if __name__ == "__main__":
    main()
