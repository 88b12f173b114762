"""The second core: a search in its own process, beside this one's.

Portfolios: while this process runs the routing solver (then ``minmax`` from its routes), a helper
process runs ``minmax`` from sweeps with another seed (``HelperSearch``); on trees
that are not plain, while this process runs the large neighbourhood search, a helper runs another
one with another seed from the same start (``HelperLns``). The caller keeps the better.

Allocation is pure (no processes, no threads: the import contracts), so it only says what to run:
the script (``minmax_helper.py``, ``lns_helper.py``) and a pickled payload. Starting the process
is the job of a ``SecondCore`` that a composition root hands to ``use_second_core`` (the runtime's
``runtime.second_core.launch``); without one, ``optimal`` searches on one core. The helper gets its
deadline as wall-clock time (it is a script run by path, not ``-m``: importing the whole package
would take seconds on a loaded machine); its answer is waited for with a timeout.
"""

from __future__ import annotations

import dataclasses
import pickle
import time
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from delegation.allocation.optimal.minmax import MinMaxModel, RouteSet
from delegation.allocation.problem import Problem
from delegation.allocation.schedule import Schedule
from delegation.allocation.strategies import Objective

#: The helper is not started for models larger than this (matrix entries): the copy would cost
#: more than the search gains.
HELPER_MAX_ENTRIES = 4_000_000
#: What the helper process runs: ``python HELPER_SCRIPT payload-file``.
HELPER_SCRIPT = Path(__file__).with_name("minmax_helper.py")
#: The large neighbourhood search's helper: ``python LNS_HELPER_SCRIPT payload-file``.
LNS_HELPER_SCRIPT = Path(__file__).with_name("lns_helper.py")


class Pending(Protocol):
    """A started helper: its stdout when it is done, or why there is none (the helper is gone
    after this returns)."""

    def result(self, timeout: float) -> bytes | str: ...


class SecondCore(Protocol):
    """Starts ``python script <file holding payload>`` in its own process."""

    def __call__(self, script: Path, payload: bytes) -> Pending: ...


_second_core: SecondCore | None = None


def use_second_core(launcher: SecondCore | None) -> SecondCore | None:
    """Let ``optimal`` run a helper search through ``launcher`` (None: one core only); returns
    the launcher it replaces, for the caller to put back."""
    global _second_core
    previous, _second_core = _second_core, launcher
    return previous


def second_core() -> bool:
    """Whether a ``SecondCore`` was given (helpers can be started)."""
    return _second_core is not None


def _answer(pending: Pending, timeout: float, size: int) -> tuple[Any, ...] | str:
    """A helper's pickled answer tuple of ``size`` items, or why there is none (late, failed,
    or unreadable)."""
    out = pending.result(timeout)
    if isinstance(out, str):
        return out
    try:
        answer = pickle.loads(out)
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError) as exc:
        return f"helper answered nothing usable ({type(exc).__name__})"
    if not isinstance(answer, tuple) or len(answer) != size:
        return "helper answered nothing usable (not the expected tuple)"
    return answer


class HelperSearch:
    """``minmax_search`` in a helper process until ``seconds`` from now."""

    def __init__(self, pending: Pending) -> None:
        self._pending = pending

    @staticmethod
    def start(
        model: MinMaxModel, routes: list[list[int]], seconds: float, seed: int
    ) -> HelperSearch | None:
        """Start the helper (None: no ``SecondCore`` was given)."""
        if _second_core is None:
            return None
        data = {
            "matrices": model.matrices, "starts": model.starts, "ends": model.ends,
            "capacity": model.capacity, "allowed": model.allowed, "pinned": model.pinned,
            "angle": model.angle, "total": model.total, "every_unit": model.every_unit,
            "routes": routes, "wall_deadline": time.time() + seconds, "seed": seed,
            "sweep_first": True,  # this process explores the basin of its own start
        }
        return HelperSearch(_second_core(HELPER_SCRIPT, pickle.dumps(data)))

    def result(self, timeout: float) -> RouteSet | str:
        """The helper's routes, or why there are none (late, failed)."""
        out = _answer(self._pending, timeout, 4)
        if isinstance(out, str):
            return out
        routes, lengths, rounds, restarts = out
        return RouteSet(routes, np.asarray(lengths, dtype=float), rounds, restarts)


@dataclasses.dataclass(frozen=True)
class LnsAnswer:
    """What the helper's search found: an assignment and orders (to evaluate here), and its
    iteration and improvement counts (for notes)."""

    assign: list[int]
    orders: list[list[int]]
    iterations: int
    improvements: int


class HelperLns:
    """``lns`` in a helper process, with another seed, until ``seconds`` from now."""

    def __init__(self, pending: Pending) -> None:
        self._pending = pending

    @staticmethod
    def start(
        problem: Problem, objective: Objective, start: Schedule, seconds: float, seed: int
    ) -> HelperLns | None:
        """Start the helper (None: no ``SecondCore`` was given)."""
        if _second_core is None:
            return None
        data = {
            "problem": dataclasses.replace(problem, cache={}),  # derived data: rebuilt there
            "objective": objective.value,
            "assign": np.asarray(start.assign).tolist(),
            "orders": [list(map(int, o)) for o in start.orders],
            "wall_deadline": time.time() + seconds, "seed": seed,
        }
        return HelperLns(_second_core(LNS_HELPER_SCRIPT, pickle.dumps(data)))

    def result(self, timeout: float) -> LnsAnswer | str:
        """The helper's answer, or why there is none (late, failed)."""
        out = _answer(self._pending, timeout, 4)
        if isinstance(out, str):
            return out
        assign, orders, iterations, improvements = out
        return LnsAnswer(assign, orders, iterations, improvements)
