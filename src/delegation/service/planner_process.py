"""Planning in a process of its own, so that a plan never competes with the service for the GIL.

The service's thread reads commands, answers re-sends, stores and publishes; the planner thread
runs `run_job`. In one process both need the GIL, so a burst of plans slows every answer and a
second core stays idle. `PlannerProcess` is a drop-in ``planner`` for `DelegationService`: the
planner thread sends each job down a pipe to one child process and waits for its result.

The child ends when the pipe closes, so it never outlives the service (even one killed with
``kill -9``). A child that dies (killed, out of memory) answers its job ``failed`` with the reason
and is replaced; a plan still running at `close` ends with its process instead of being
abandoned on a thread.

The child is forked while the service runs one thread (`serve` makes it before anything else:
9 ms, the planner already imported), else spawned (forking a process with threads copies locks
another thread may hold): a spawned child imports the planner, 1.2 s and 0.6 s of CPU on this
machine before the first plan. Moving a job there and its result back costs ~0.13 ms of pickling
(a small mission: ~1.3 kB each way), against a plan's ~2 ms.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import signal
import sys
import threading
from multiprocessing.connection import Connection
from multiprocessing.context import ForkContext, SpawnContext
from multiprocessing.process import BaseProcess

from delegation.errors import InputError, InputProblem
from delegation.service.jobs import Job, JobFailed, JobResult, run_job

log = logging.getLogger(__name__)

#: Seconds a new child may take to import the planner and say it is ready.
START_TIMEOUT = 60.0


def _serve(conn: Connection, parent: Connection | None = None) -> None:
    """The child: plan each job received until the pipe closes (the service stopped or died).
    A forked child first closes its copy of the service's end (``parent``: while it is open,
    the pipe never closes), and leaves signals to the service: Ctrl-C or SIGTERM to the group
    stops the service, which ends its child (no traceback from it)."""
    if parent is not None:
        parent.close()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    conn.send("ready")
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        conn.send(run_job(job))


def _context() -> ForkContext | SpawnContext:
    """``fork`` while this process runs one thread (nothing another thread holds is copied),
    else ``spawn``."""
    if threading.active_count() == 1 and "fork" in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("spawn")


def _failed(reason: str) -> JobFailed:
    return JobFailed(InputError(InputProblem("planner", "", reason)).fail_reason)


class PlannerProcess:
    """``planner(job) -> JobResult`` run in one child process (jobs one at a time, in order, as
    on the planner thread). Called from one thread; `close` may come from another."""

    def __init__(self) -> None:
        self._closed = False
        self._conn, self._process = self._start()

    def _start(self) -> tuple[Connection, BaseProcess]:
        context = _context()
        parent, child = context.Pipe()
        forked = context.get_start_method() == "fork"
        process = context.Process(target=_serve, args=(child, parent if forked else None),
                                  name="planner", daemon=True)
        if forked:  # the child flushes its copy of what is buffered when it ends: once is enough
            for stream in (sys.stdout, sys.stderr):
                with contextlib.suppress(Exception):
                    stream.flush()
        process.start()
        child.close()
        if not parent.poll(START_TIMEOUT) or parent.recv() != "ready":
            process.kill()
            raise RuntimeError(f"the planner process did not start within {START_TIMEOUT:.0f} s")
        log.debug("planner process %s ready (%s)", process.pid, context.get_start_method())
        return parent, process

    @property
    def pid(self) -> int | None:
        """The child's process id (tests kill it)."""
        return self._process.pid

    def __call__(self, job: Job) -> JobResult:
        try:
            self._conn.send(job)
            result: JobResult = self._conn.recv()
            return result
        except (EOFError, OSError):
            if self._closed:
                return _failed("the service stopped while planning this tree")
            log.error("the planner process died while planning job %s (exit code %s); "
                      "starting a new one", job.id, self._process.exitcode)
            self._process.join(1.0)
            self._conn, self._process = self._start()
            return _failed("the planner process died while planning this tree (killed or out "
                           "of memory)")

    def close(self) -> None:
        """End the child, and with it a plan still running (its command is never answered, as
        a plan abandoned at stop)."""
        self._closed = True
        self._conn.close()
        self._process.join(2.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join(5.0)
