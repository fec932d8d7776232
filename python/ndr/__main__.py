"""``python -m ndr``: the package's commands (``demo``)."""

from __future__ import annotations

import sys
from typing import Optional, Sequence

USAGE = """usage: python -m ndr <command> [options]

commands:
  demo    the whole link in one process: remote with the simulated plant,
          a delaying relay, and a base whose operator follows a signal
          (python -m ndr demo --help for its options)
  plot    draw a run's CSV (ndr demo's ndr-demo.csv) or MCAP recording
          (--record) as the paper's figure: NRTT against GRTT, command
          against state (needs matplotlib, and mcap for a recording;
          python -m ndr plot --help)
"""


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Runs the command named by ``argv`` (default ``sys.argv[1:]``); returns
    the exit status (2, with the usage on standard error, for a usage error)."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args:
        print(f"no command given\n\n{USAGE}", end="", file=sys.stderr)
        return 2
    if args[0] in ("-h", "--help"):
        print(USAGE, end="")
        return 0
    command, rest = args[0], args[1:]
    if command == "demo":
        from .demo import main as demo

        return demo(rest)
    if command == "plot":
        return _plot(rest)
    print(f"unknown command {command!r}\n\n{USAGE}", end="", file=sys.stderr)
    return 2


def _plot(argv: Sequence[str]) -> int:
    import argparse
    import os

    parser = argparse.ArgumentParser(
        prog="python -m ndr plot",
        description="Draw a run's CSV series (ndr demo --out, ndr base --out) or its "
        "MCAP recording (--record) as the paper's figure: NRTT against GRTT, and "
        "command against state.",
    )
    parser.add_argument("csv", help="the series, e.g. ndr-demo.csv, or a recording, x.mcap")
    parser.add_argument(
        "-o", "--out", help="the image to write (its suffix picks the format; "
        "default: the input's name with .png)"
    )
    args = parser.parse_args(argv)
    out = args.out or os.path.splitext(args.csv)[0] + ".png"
    try:
        from .plot import demo

        fig = demo(args.csv)
    except (OSError, ValueError, ImportError) as e:
        print(f"python -m ndr plot: {e}", file=sys.stderr)
        return 1
    fig.savefig(out, dpi=120)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
