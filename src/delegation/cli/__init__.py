"""The ``delegation`` command: a thin layer that parses arguments, calls the library, renders.

Each sub-command lives in its own module with a ``register(subparsers)`` function; modules keep
heavy imports inside their handlers so that ``delegation --help`` stays fast. Errors reach the
user as one clear line (exit 1 for bad input, 2 for usage), never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

from delegation import __version__
from delegation.cli.options import (
    EXIT_INPUT,
    EXIT_SIGINT,
    EXIT_USAGE,
    Parser,
    Stopped,
    UsageError,
    add_logging_args,
    install_signal_handlers,
    setup_logging,
)
from delegation.errors import DelegationError

log = logging.getLogger("delegation")

#: Sub-command modules under ``delegation.cli``; each defines ``register(subparsers)``.
_COMMAND_MODULES: tuple[str, ...] = (
    "validate",
    "plan",
    "bench",
    "demo",
    "serve",
    "submit",
    "agents",
    "units",
    "missions",
    "ui",
    "bridge",
)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="delegation",
        description="Delegation service for WARA-PS: allocate units to Task Specification Trees.",
        epilog="Exit codes: 0 done (also when stopped by SIGTERM), 1 bad input or the "
        "mission/plan failed, 2 bad usage (flag or WARAPS_* value), 130 stopped by SIGINT. No "
        "--broker and no WARAPS_BROKER: every command uses 127.0.0.1 (demo starts its own "
        "broker). Details: docs/deployment.md.",
    )
    parser.add_argument("--version", action="version", version=f"delegation {__version__}")
    add_logging_args(parser, top=True)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _COMMAND_MODULES:
        module = importlib.import_module(f"delegation.cli.{name}")
        module.register(sub)
    for command in sub.choices.values():
        add_logging_args(command, top=False)
    return parser


#: Commands that plan (and so may run ``optimal``).
PLANNING_COMMANDS = frozenset({"plan", "bench", "serve", "demo"})


@contextmanager
def both_cores(command: str | None) -> Iterator[None]:
    """While a planning command runs, ``optimal`` may run its helper search on a second core (a
    process of its own) where the machine has one: allocation only says what to run, a
    composition root says it may (``allocation.optimal.parallel``). Put back afterwards, so
    that ``main`` called in-process leaves nothing behind."""
    if command not in PLANNING_COMMANDS or (os.cpu_count() or 1) < 2:
        yield
        return
    from delegation.allocation.optimal.parallel import use_second_core
    from delegation.runtime.second_core import launch

    previous = use_second_core(launch)
    try:
        yield
    finally:
        use_second_core(previous)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    setup_logging(args)
    args.argv = list(sys.argv[1:] if argv is None else argv)  # for results' provenance
    handler = getattr(args, "func", None)
    if handler is None:
        parser.print_help()
        return EXIT_USAGE
    install_signal_handlers()
    try:
        with both_cores(args.command):
            return int(handler(args) or 0)
    except UsageError as exc:
        print(f"delegation {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except DelegationError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        log.warning("stopped by SIGINT")
        return EXIT_SIGINT
    except Stopped as exc:
        log.warning("stopped by %s", exc)
        return exc.exit_code


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
