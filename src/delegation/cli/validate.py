"""``delegation validate FILE...``: check a TST or any WARA-PS command/message.

Prints ``OK`` and what the file holds, or one line per problem (file, node or message, field,
what is wrong); exit 0 when every file is valid, 1 otherwise.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "validate",
        help="check a TST or a command (start-tst, start-task, delegate, ...) from a file",
        description=(
            "Check a Task Specification Tree, or any WARA-PS command or message, read from FILE "
            "('-' for standard input). A command carrying a tree (start-tst, delegate, get-bids) "
            "has its tree checked against the task catalogue too. Exit 0 when valid, 1 otherwise."
        ),
    )
    parser.add_argument("files", nargs="+", metavar="FILE", help="JSON file, or - for stdin")
    parser.set_defaults(func=run)


def _read(name: str) -> bytes:
    if name == "-":
        return sys.stdin.buffer.read()
    with open(name, "rb") as handle:
        return handle.read()


def run(args: argparse.Namespace) -> int:
    from delegation.messages.check import check_bytes

    failed = False
    for name in args.files:
        label = "<stdin>" if name == "-" else name
        try:
            payload = _read(name)
        except OSError as exc:
            print(f"{label}: cannot read: {exc.strerror or exc}")
            failed = True
            continue
        result = check_bytes(payload, source="")
        if result.ok:
            print(f"{label}: OK: {result.summary}")
            continue
        failed = True
        for problem in result.problems:
            print(f"{label}: {problem}" if problem.where else f"{label}: {problem.message}")
    return 1 if failed else 0
