"""The second core: a search in its own process, beside this one's.

Portfolios: while this process runs the routing solver (then ``minmax`` from its routes), a helper
process runs ``minmax`` from sweeps with another seed (``HelperSearch``); on trees
that are not plain, while this process runs the large neighbourhood search, a helper runs another
one with another seed from the same start (``HelperLns``). The caller keeps the better.

Allocation is pure (no processes, no threads: the import contracts), so it only says what to run:
the script (``helper.py``, for either search) and a pickled payload that names the search.
Starting the process is the job of a ``SecondCore`` that a composition root hands to
``use_second_core`` (the runtime's ``runtime.second_core.launch``); without one, ``optimal``
searches on one core. The helper gets its deadline as wall-clock time (it is a script run by path,
not ``-m``: importing the whole package would take seconds on a loaded machine); its answer is
waited for with a timeout.
"""

from __future__ import annotations

import dataclasses
import pickle
import time
from pathlib import Path
from typing import Any, Generic, Protocol, TypeVar

import numpy as np

from delegation.allocation.optimal.minmax import MinMaxModel, RouteSet
from delegation.allocation.problem import Problem
from delegation.allocation.schedule import Schedule
from delegation.allocation.strategies import Objective

#: The helper is not started for models larger than this (matrix entries): the copy would cost
#: more than the search gains.
HELPER_MAX_ENTRIES = 4_000_000
#: What a helper process runs, either search: ``python HELPER_SCRIPT payload-file``.
HELPER_SCRIPT = Path(__file__).with_name("helper.py")


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


def _launch(search: str, data: dict[str, Any]) -> Pending | None:
    """Start ``search`` (a name in ``helper.SEARCHES``) on the second core (None: no
    ``SecondCore`` was given)."""
    if _second_core is None:
        return None
    return _second_core(HELPER_SCRIPT, pickle.dumps({**data, "search": search}))


Answer = TypeVar("Answer")


class _Helper(Generic[Answer]):
    """A search running in a helper process; its answer tuple becomes an ``Answer``."""

    def __init__(self, pending: Pending) -> None:
        self._pending = pending

    def result(self, timeout: float) -> Answer | str:
        """The helper's answer, or why there is none (late, failed)."""
        out = _answer(self._pending, timeout, 4)
        return out if isinstance(out, str) else self._convert(out)

    @staticmethod
    def _convert(out: tuple[Any, ...]) -> Answer:
        raise NotImplementedError


class HelperSearch(_Helper[RouteSet]):
    """``minmax_search`` in a helper process until ``seconds`` from now."""

    @staticmethod
    def start(
        model: MinMaxModel, routes: list[list[int]], seconds: float, seed: int
    ) -> HelperSearch | None:
        """Start the helper (None: no ``SecondCore`` was given)."""
        pending = _launch("minmax", {
            "matrices": model.matrices, "starts": model.starts, "ends": model.ends,
            "capacity": model.capacity, "allowed": model.allowed, "pinned": model.pinned,
            "angle": model.angle, "total": model.total, "every_unit": model.every_unit,
            "routes": routes, "wall_deadline": time.time() + seconds, "seed": seed,
            "sweep_first": True,  # this process explores the basin of its own start
        })
        return None if pending is None else HelperSearch(pending)

    @staticmethod
    def _convert(out: tuple[Any, ...]) -> RouteSet:
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


class HelperLns(_Helper[LnsAnswer]):
    """``lns`` in a helper process, with another seed, until ``seconds`` from now."""

    @staticmethod
    def start(
        problem: Problem, objective: Objective, start: Schedule, seconds: float, seed: int
    ) -> HelperLns | None:
        """Start the helper (None: no ``SecondCore`` was given)."""
        pending = _launch("lns", {
            "problem": dataclasses.replace(problem, cache={}),  # derived data: rebuilt there
            "objective": objective.value,
            "assign": np.asarray(start.assign).tolist(),
            "orders": [list(map(int, o)) for o in start.orders],
            "wall_deadline": time.time() + seconds, "seed": seed,
        })
        return None if pending is None else HelperLns(pending)

    @staticmethod
    def _convert(out: tuple[Any, ...]) -> LnsAnswer:
        assign, orders, iterations, improvements = out
        return LnsAnswer(assign, orders, iterations, improvements)
