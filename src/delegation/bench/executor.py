"""Where bench runs happen: here (in this process or a forked child per run) or on Dask.

An executor takes the runs as keyword dicts for one function and yields ``(index, Outcome)`` as
runs finish, in any order; the runner puts the records back in run order, so every executor
gives the same records. Isolation is the same everywhere: with ``isolate`` each run is a forked
child (``bench.isolate``), on a Dask worker too, so a crash or a run past its timeout costs that
run only (docs/bench.md).
"""

from __future__ import annotations

import logging
import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack
from typing import Any, Protocol

from delegation.bench.isolate import Outcome, call_isolated
from delegation.errors import DelegationError, InputError, InputProblem

log = logging.getLogger(__name__)

#: What Dask workers need so that a task may fork its run's child (see ``_run_on_worker``).
WORKER_DAEMON_HINT = (
    "Dask workers run as daemonic processes, which may not fork a child per run: start them with "
    "DASK_DISTRIBUTED__WORKER__DAEMON=False (docs/bench.md)"
)


class Executor(Protocol):
    """Runs ``fn(**kwargs)`` for every kwargs; yields (index, outcome) as runs finish."""

    def run(
        self, fn: Callable[..., Any], runs: Sequence[dict[str, Any]], timeout: float | None
    ) -> Iterator[tuple[int, Outcome]]: ...

    def prepare(self, fn: Callable[..., None], *args: Any) -> None:
        """Call ``fn(*args)`` wherever runs will happen (a warm-up), before any run."""


def run_here(fn: Callable[..., Any], kwargs: dict[str, Any], isolate: bool,
             timeout: float | None) -> Outcome:
    """One run in this process (input errors caught) or in a forked child."""
    if isolate:
        return call_isolated(fn, kwargs, timeout=timeout)
    try:
        return Outcome(value=fn(**kwargs))
    except DelegationError as exc:
        return Outcome(input_error=str(exc))


class LocalExecutor:
    """Runs one after another on this machine, each in a forked child unless ``isolate`` is off."""

    def __init__(self, isolate: bool = True) -> None:
        self.isolate = isolate

    def prepare(self, fn: Callable[..., None], *args: Any) -> None:
        fn(*args)  # forked children inherit the warm state

    def run(
        self, fn: Callable[..., Any], runs: Sequence[dict[str, Any]], timeout: float | None
    ) -> Iterator[tuple[int, Outcome]]:
        for index, kwargs in enumerate(runs):
            yield index, run_here(fn, kwargs, self.isolate, timeout)


def _run_on_worker(fn: Callable[..., Any], kwargs: dict[str, Any], isolate: bool,
                   timeout: float | None) -> Outcome:
    """The Dask task: one run, isolated in a child of the worker exactly as locally."""
    if isolate and multiprocessing.current_process().daemon:
        return Outcome(crashed=WORKER_DAEMON_HINT)
    return run_here(fn, kwargs, isolate, timeout)


def _warm_worker(fn: Callable[..., None], *args: Any) -> None:
    fn(*args)


class DaskExecutor:
    """Every run is a task on a Dask distributed cluster: ``scheduler`` (``tcp://host:port``), or a
    ``LocalCluster`` on 127.0.0.1 with ``workers`` processes when no address is given.

    Use as a context manager (it connects, and closes what it started). Tasks are submitted all
    at once and gathered as they finish; Ctrl-C cancels the ones not finished.
    """

    def __init__(self, scheduler: str | None = None, *, workers: int | None = None,
                 isolate: bool = True, connect_timeout: float = 30.0) -> None:
        self.scheduler = scheduler
        self.workers = workers
        self.isolate = isolate
        self.connect_timeout = connect_timeout
        self._stack = ExitStack()
        self.client: Any = None

    def __enter__(self) -> DaskExecutor:
        # Dask logs every worker's start at INFO on stderr; the CLI's -v decides what is shown.
        os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")
        logging.getLogger("distributed").setLevel(
            max(logging.WARNING, logging.getLogger().getEffectiveLevel()))
        try:
            import dask
            from distributed import Client, LocalCluster
        except ImportError:
            raise InputError(InputProblem("bench", "--executor", "dask needs the optional extra: "
                                     "pip install 'delegation[dask]'")) from None
        try:
            if self.scheduler:
                self.client = self._stack.enter_context(
                    Client(self.scheduler, timeout=self.connect_timeout)
                )
            else:
                # Non-daemonic workers so that each task may fork its run's child.
                self._stack.enter_context(dask.config.set({"distributed.worker.daemon": False}))
                cluster = self._stack.enter_context(LocalCluster(
                    n_workers=self.workers or multiprocessing.cpu_count(), threads_per_worker=1,
                    host="127.0.0.1", processes=True, scheduler_kwargs={"dashboard": False},
                ))
                self.client = self._stack.enter_context(Client(cluster))
        except OSError as exc:
            self._stack.close()
            raise InputError(InputProblem("bench", "--scheduler",
                                     f"cannot reach {self.scheduler}: {exc}")) from None
        return self

    def __exit__(self, *exc: object) -> None:
        self._stack.close()

    def prepare(self, fn: Callable[..., None], *args: Any) -> None:
        self.client.run(_warm_worker, fn, *args)

    def run(
        self, fn: Callable[..., Any], runs: Sequence[dict[str, Any]], timeout: float | None
    ) -> Iterator[tuple[int, Outcome]]:
        from distributed import as_completed

        futures = [
            self.client.submit(_run_on_worker, fn, kwargs, self.isolate, timeout, pure=False)
            for kwargs in runs
        ]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for future in as_completed(futures):
                try:
                    outcome = future.result()
                except Exception as exc:  # the worker died under the task, or it was lost
                    outcome = Outcome(crashed=f"dask task failed: {type(exc).__name__}: {exc}")
                yield index[future.key], outcome
        finally:
            self.client.cancel([f for f in futures if not f.done()])
