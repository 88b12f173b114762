"""The helper process of ``parallel.HelperLns``: ``lns`` with another seed on the second core.

Run as a script by its path (``python lns_helper.py payload-file``). Input: a pickle of the
problem, the objective, the start schedule's assignment and orders, a wall-clock deadline and a
seed (``parallel`` wrote it); output: the best assignment and orders found, the iteration and
improvement counts, pickled on stdout. Importing ``lns`` loads the allocation core without
OR-Tools (about 0.3 s).
"""

from __future__ import annotations

import os
import pickle
import sys
import time
from pathlib import Path

_HERE = Path(__file__).resolve().parent
#: ``src`` (or ``site-packages``): where the ``delegation`` package lives.
_ROOT = _HERE.parents[2]


def main(path: str) -> int:
    # A script run by path has its own folder first on sys.path: its siblings (``routing``,
    # ``shared`` ...) would shadow top-level modules of those names.
    sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _HERE]
    if str(_ROOT) not in sys.path:
        sys.path.append(str(_ROOT))
    with open(path, "rb") as f:
        data = pickle.load(f)
    deadline = time.perf_counter() + (data["wall_deadline"] - time.time())
    from delegation.allocation.optimal.lns import lns
    from delegation.allocation.schedule import evaluate

    problem = data["problem"]
    start = evaluate(problem, data["assign"], data["orders"])
    found = lns(problem, data["objective"], start, deadline, seed=data["seed"])
    answer = (found.schedule.assign.tolist(), [list(map(int, o)) for o in found.schedule.orders],
              found.iterations, found.improvements)
    sys.stdout.buffer.write(pickle.dumps(answer))
    sys.stdout.buffer.flush()
    return 0


if __name__ == "__main__":
    code = main(sys.argv[1])
    # The answer is out and nothing else is open: skip the interpreter's teardown (tens of ms,
    # more on a loaded machine), which the waiting planner would pay for.
    os._exit(code)
