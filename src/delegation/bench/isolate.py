"""Run one plan in a child process: a native crash or a run past its deadline costs one run.

OR-Tools aborts the whole process on an internal check failure (``Check failed: ...``), and a
solve cannot be interrupted from Python. A forked child that is killed at its deadline keeps a
benchmark going in both cases, and lets the scale sweep stop a strategy *at* its budget instead
of after it. The child is always joined (or killed and joined) before this returns.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

from delegation.errors import DelegationError


@dataclass(frozen=True, slots=True)
class Outcome:
    """What happened in the child: its value, an input error, a crash, or a timeout."""

    value: Any = None
    input_error: str | None = None
    crashed: str | None = None
    timed_out: bool = False

    @property
    def ok(self) -> bool:
        return self.input_error is None and self.crashed is None and not self.timed_out


def _child(conn: Connection, fn: Callable[..., Any], kwargs: dict[str, Any]) -> None:
    try:
        message: tuple[str, Any] = ("ok", fn(**kwargs))
    except DelegationError as exc:
        message = ("input", str(exc))
    except BaseException as exc:  # reported to the parent as this run's crash
        message = ("error", f"{type(exc).__name__}: {exc}")
    conn.send(message)
    conn.close()
    # Leave at once: a normal exit flushes stdio, whose locks another parent thread (the progress
    # bar's refresher) may have held at fork time, and the child would hang there.
    os._exit(0)


def _exit_text(code: int | None) -> str:
    if code is not None and code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        return f"planner process died ({name}; OR-Tools aborts like this on an internal error)"
    return f"planner process exited with code {code} without a result"


def call_isolated(
    fn: Callable[..., Any], kwargs: dict[str, Any], timeout: float | None = None
) -> Outcome:
    """``fn(**kwargs)`` in a forked child; killed after ``timeout`` seconds (None: no limit)."""
    ctx = multiprocessing.get_context("fork")
    receiver, sender = ctx.Pipe(duplex=False)
    process = ctx.Process(target=_child, args=(sender, fn, kwargs), daemon=True)
    process.start()
    sender.close()
    try:
        if not receiver.poll(timeout):
            process.kill()
            return Outcome(timed_out=True)
        try:
            kind, payload = receiver.recv()
        except EOFError:  # the child died before sending anything
            process.join()
            return Outcome(crashed=_exit_text(process.exitcode))
    except BaseException:  # Ctrl-C: the run is abandoned, its child must not outlive it
        process.kill()
        raise
    finally:
        receiver.close()
        process.join()
    if kind == "ok":
        return Outcome(value=payload)
    if kind == "input":
        return Outcome(input_error=payload)
    return Outcome(crashed=str(payload))
