"""The ``delegation`` command: a thin layer that parses arguments, calls the library, renders.

Each sub-command lives in its own module with a ``register(subparsers)`` function; modules keep
heavy imports inside their handlers so that ``delegation --help`` stays fast. Errors reach the
user as one clear line (exit 1 for bad input, 2 for usage), never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from delegation import __version__
from delegation.errors import DelegationError

#: Sub-command modules under ``delegation.cli``; each defines ``register(subparsers)``.
_COMMAND_MODULES: tuple[str, ...] = (
    "validate",
    "plan",
    "bench",
    "runtime",
    "units",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="delegation",
        description="Delegation service for WARA-PS: allocate units to Task Specification Trees.",
    )
    parser.add_argument("--version", action="version", version=f"delegation {__version__}")
    parser.add_argument(
        "-v", "--verbose", action="count", default=0, help="more logging (-v info, -vv debug)"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMAND_MODULES:
        module = importlib.import_module(f"delegation.cli.{name}")
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # for results' provenance
    level = {0: logging.WARNING, 1: logging.INFO}.get(args.verbose, logging.DEBUG)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    handler = getattr(args, "func", None)
    if handler is None:
        parser.print_help()
        return 2
    try:
        return int(handler(args) or 0)
    except DelegationError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
