"""A strategy that kills its process (as OR-Tools does on an internal check failure), for the
isolation tests of the bench executors; importable on Dask workers through PYTHONPATH."""

from __future__ import annotations

import os
from typing import Any


def abort(problem: Any, objective: Any, time_limit: float, /) -> Any:
    os.abort()


def sleepy(problem: Any, objective: Any, time_limit: float, /) -> Any:
    """Say "started" on ``$BENCH_TEST_MARKER`` (a FIFO the test reads) and sleep: a run still
    going when the test presses Ctrl-C."""
    import time

    with open(os.environ["BENCH_TEST_MARKER"], "w") as marker:
        marker.write("started\n")
    time.sleep(120)


def stuck(problem: Any, objective: Any, time_limit: float, /) -> Any:
    """Never answers (within any test's patience): a run that always outlives its timeout,
    however briefly the machine lets its parent wait."""
    import time

    time.sleep(120)
