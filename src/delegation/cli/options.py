"""What every ``delegation`` command shares: logging flags, one-line errors, signals, values.

* ``-v``/``-q``/``--log-level``/``--log-json`` are accepted before and after the sub-command.
* A bad flag or environment value is one line naming it and exit 2 (`UsageError`); bad input
  (a file, a mission) is exit 1. Never a traceback.
* SIGINT (``KeyboardInterrupt``) and SIGTERM (`Stopped`) both stop a command through its
  ``finally`` blocks, with a log line; exit 130 after SIGINT (the shell's convention for
  Ctrl-C) and 0 after SIGTERM (a requested stop, as systemd and docker expect of a service).
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import time
from collections.abc import Mapping
from typing import Any, NoReturn

from delegation.errors import DelegationError

#: Exit codes (docs/deployment.md, "Exit codes").
EXIT_OK = 0
EXIT_INPUT = 1
EXIT_USAGE = 2
EXIT_SIGINT = 130
EXIT_SIGTERM = 0

#: Commands that run until stopped: they log at INFO unless told otherwise.
DAEMONS: frozenset[str] = frozenset({"serve", "engine", "sim", "ui", "bridge"})

LOG_LEVELS: tuple[str, ...] = ("debug", "info", "warning", "error")


class UsageError(DelegationError):
    """A bad flag or environment value (exit 2)."""


class Stopped(BaseException):
    """SIGINT or SIGTERM arrived: unwinds the command like ``KeyboardInterrupt`` does."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return EXIT_SIGINT if self.signum == signal.SIGINT else EXIT_SIGTERM


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (``delegation serve: error: ...``) instead of the usage."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def add_logging_args(parser: argparse.ArgumentParser, *, top: bool) -> None:
    """The logging flags; on sub-commands they default to SUPPRESS so as not to undo the
    top-level ones (``delegation -v serve`` and ``delegation serve -v`` are the same)."""
    d = {} if top else {"default": argparse.SUPPRESS}
    g = parser.add_argument_group("logging (accepted anywhere on the line)")
    g.add_argument("-v", "--verbose", action="count", help="more logging (-v info, -vv debug)",
                   **({"default": 0} if top else d))
    g.add_argument("-q", "--quiet", action="store_true", help="errors only",
                   **({"default": False} if top else d))
    g.add_argument("--log-level", choices=LOG_LEVELS, type=str.lower,
                   help="log level (default: info for serve/engine/sim/ui, else warning)",
                   **({"default": None} if top else d))
    g.add_argument("--log-json", action="store_true", help="log one JSON object per line",
                   **({"default": False} if top else d))


def log_level(args: argparse.Namespace) -> int:
    """The level the flags ask for; INFO by default for the long-running commands."""
    if args.log_level:
        return int(getattr(logging, args.log_level.upper()))
    if args.quiet:
        return logging.ERROR
    if args.verbose:
        return logging.INFO if args.verbose == 1 else logging.DEBUG
    return logging.INFO if getattr(args, "command", None) in DAEMONS else logging.WARNING


class JsonFormatter(logging.Formatter):
    """One JSON object per line: time, level, logger, message (and the exception, if any)."""

    def format(self, record: logging.LogRecord) -> str:
        out: dict[str, Any] = {
            "time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
            + f".{int(record.msecs):03d}Z",
            "level": record.levelname.lower(),
            "logger": record.name,
            "message": record.getMessage(),
        }
        if record.exc_info:
            out["exception"] = self.formatException(record.exc_info)
        return json.dumps(out)


def setup_logging(args: argparse.Namespace) -> None:
    handler = logging.StreamHandler(sys.stderr)
    if args.log_json:
        handler.setFormatter(JsonFormatter())
    else:
        handler.setFormatter(
            logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s")
        )
    root = logging.getLogger()
    for old in list(root.handlers):
        root.removeHandler(old)
    root.addHandler(handler)
    root.setLevel(log_level(args))


def install_signal_handlers() -> None:
    """SIGTERM (docker stop, systemd) raises `Stopped` in the main thread, as SIGINT (Ctrl-C)
    raises ``KeyboardInterrupt``: both unwind through the command's ``finally`` blocks. SIGINT
    keeps Python's handler, so code that keeps partial results on ``KeyboardInterrupt`` works."""

    def handler(signum: int, _frame: object) -> None:
        raise Stopped(signum)

    try:
        signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread (tests calling main()): leave the default
        return


# --------------------------------------------------------------------------- values


def port_number(value: str) -> int:
    """An argparse ``type`` for ``--port``: 1..65535."""
    try:
        port = int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{value!r} is not a port number (1-65535)") from None
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{port} is not a port number (1-65535)")
    return port


def _number(value: str) -> float:
    try:
        return float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{value!r} is not a number") from None


def positive_float(value: str) -> float:
    """An argparse ``type`` for durations and factors that must be > 0."""
    number = _number(value)
    if not number > 0 or number == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, not {value}")
    return number


def add_duration_arg(parser: argparse.ArgumentParser) -> None:
    """``--duration``, for the commands that otherwise run until stopped (engine, sim, bridge)."""
    parser.add_argument("--duration", type=positive_float, default=None,
                        help="stop after this many seconds (default: run)")


def add_format_args(parser: argparse.ArgumentParser) -> None:
    """``--format table|json`` and its short form ``--json``, for the commands that print either
    a table for people or JSON for programs (plan, agents)."""
    parser.add_argument("--format", default="table", choices=("table", "json"),
                        help="output format (default: table)")
    parser.add_argument("--json", dest="format", action="store_const", const="json",
                        help="same as --format json")


def fraction(value: str) -> float:
    """An argparse ``type`` for a number in 0..1."""
    number = _number(value)
    if not 0.0 <= number <= 1.0:
        raise argparse.ArgumentTypeError(f"{value} is not in 0..1")
    return number


_TRUE = ("1", "true", "yes", "on")
_FALSE = ("", "0", "false", "no", "off")


def env_port(environ: Mapping[str, str]) -> int | None:
    """``WARAPS_PORT``, checked; None when unset or empty."""
    raw = (environ.get("WARAPS_PORT") or "").strip()
    if not raw:
        return None
    try:
        return port_number(raw)
    except argparse.ArgumentTypeError as exc:
        raise UsageError(f"WARAPS_PORT: {exc}") from None


def env_flag(environ: Mapping[str, str], name: str) -> bool | None:
    """A yes/no environment variable, checked; None when unset."""
    raw = environ.get(name)
    if raw is None:
        return None
    value = raw.strip().lower()
    if value in _TRUE:
        return True
    if value in _FALSE:
        return False
    raise UsageError(f"{name}: {raw!r} is not a yes/no value (1/0, true/false, yes/no, on/off)")
