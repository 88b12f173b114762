"""The helper process of ``parallel``: run as a script by its path, not as ``-m``.

So that it starts fast: importing ``delegation.allocation`` would load OR-Tools, shapely and the
rest (seconds on a loaded machine); this file loads only ``minmax.py`` (numpy and the standard
library) by its path. Input: a pickle file of plain data (arrays, lists) that ``parallel`` wrote;
output: the routes, their lengths and the perturbation count, pickled on stdout.
"""

from __future__ import annotations

import importlib.util
import os
import pickle
import sys
import time
from pathlib import Path
from types import ModuleType


def _load_minmax() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "_delegation_minmax", Path(__file__).with_name("minmax.py")
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def main(path: str) -> int:
    with open(path, "rb") as f:
        data = pickle.load(f)
    deadline = time.perf_counter() + (data.pop("wall_deadline") - time.time())
    routes, seed = data.pop("routes"), data.pop("seed")
    sweep_first = data.pop("sweep_first", False)
    minmax = _load_minmax()
    best = minmax.minmax_search(minmax.MinMaxModel(**data), routes, deadline, seed,
                                sweep_first=sweep_first)
    answer = (best.routes, best.lengths.tolist(), best.rounds, best.restarts)
    sys.stdout.buffer.write(pickle.dumps(answer))
    sys.stdout.buffer.flush()
    return 0


if __name__ == "__main__":
    code = main(sys.argv[1])
    # The answer is out and nothing else is open: skip the interpreter's teardown (tens of ms,
    # more on a loaded machine), which the waiting planner would pay for.
    os._exit(code)
