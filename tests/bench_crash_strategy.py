"""A strategy that kills its process (as OR-Tools does on an internal check failure), for the
isolation tests of the bench executors; importable on Dask workers through PYTHONPATH."""

from __future__ import annotations

import os
from typing import Any


def abort(problem: Any, objective: Any, time_limit: float, /) -> Any:
    os.abort()
