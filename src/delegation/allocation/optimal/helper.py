"""The helper process of ``parallel``, on the second core: run as a script by its path
(``python helper.py payload-file``), not as ``-m``.

One script for both portfolios, so that reading the payload, answering and exiting are written
once: the payload (a pickle file ``parallel`` wrote) names its ``search``:

- ``minmax`` (``parallel.HelperSearch``): plain data (arrays, lists); this loads only
  ``minmax.py`` (numpy and the standard library) by its path, since importing
  ``delegation.allocation`` would load OR-Tools, shapely and the rest (seconds on a loaded
  machine). Answer: the routes, their lengths and the round and restart counts.
- ``lns`` (``parallel.HelperLns``): the problem, the objective, the start schedule's assignment
  and orders; ``lns`` with another seed. Importing ``lns`` loads the allocation core without
  OR-Tools (about 0.3 s). Answer: the best assignment and orders found, the iteration and
  improvement counts.

Either gets its deadline as wall-clock time and answers a pickled tuple on stdout.
"""

from __future__ import annotations

import importlib.util
import os
import pickle
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

_HERE = Path(__file__).resolve().parent
#: ``src`` (or ``site-packages``): where the ``delegation`` package lives.
_ROOT = _HERE.parents[2]


def _deadline(data: dict[str, Any]) -> float:
    """The payload's wall-clock deadline on this process's ``perf_counter``."""
    return time.perf_counter() + (float(data.pop("wall_deadline")) - time.time())


def _load_minmax() -> ModuleType:
    spec = importlib.util.spec_from_file_location("_delegation_minmax", _HERE / "minmax.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def _minmax(data: dict[str, Any]) -> tuple[Any, ...]:
    deadline = _deadline(data)
    routes, seed = data.pop("routes"), data.pop("seed")
    sweep_first = data.pop("sweep_first", False)
    minmax = _load_minmax()
    best = minmax.minmax_search(minmax.MinMaxModel(**data), routes, deadline, seed,
                                sweep_first=sweep_first)
    return best.routes, best.lengths.tolist(), best.rounds, best.restarts


def _lns(data: dict[str, Any]) -> tuple[Any, ...]:
    deadline = _deadline(data)
    from delegation.allocation.optimal.lns import lns
    from delegation.allocation.schedule import evaluate

    problem = data["problem"]
    start = evaluate(problem, data["assign"], data["orders"])
    found = lns(problem, data["objective"], start, deadline, seed=data["seed"])
    return (found.schedule.assign.tolist(), [list(map(int, o)) for o in found.schedule.orders],
            found.iterations, found.improvements)


SEARCHES: dict[str, Callable[[dict[str, Any]], tuple[Any, ...]]] = {
    "minmax": _minmax,
    "lns": _lns,
}


def main(path: str) -> int:
    # A script run by path has its own folder first on sys.path: its siblings (``routing``,
    # ``shared`` ...) would shadow top-level modules of those names. ``_ROOT`` is there before
    # the payload is read: an ``lns`` payload holds the package's own types.
    sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
    if str(_ROOT) not in sys.path:
        sys.path.append(str(_ROOT))
    with open(path, "rb") as f:
        data = pickle.load(f)
    answer = SEARCHES[data.pop("search")](data)
    sys.stdout.buffer.write(pickle.dumps(answer))
    sys.stdout.buffer.flush()
    return 0


if __name__ == "__main__":
    code = main(sys.argv[1])
    # The answer is out and nothing else is open: skip the interpreter's teardown (tens of ms,
    # more on a loaded machine), which the waiting planner would pay for.
    os._exit(code)
