"""``python -m ndr``: the package's commands (``demo``)."""

from __future__ import annotations

import sys
from typing import Optional, Sequence

USAGE = """usage: python -m ndr <command> [options]

commands:
  demo    the whole link in one process: remote with the simulated plant,
          a delaying relay, and a base whose operator follows a signal
          (python -m ndr demo --help for its options)
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
    print(f"unknown command {command!r}\n\n{USAGE}", end="", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
