"""The second core: a min-max search in its own process, beside the routing solver.

A portfolio: while this process runs the routing solver (then ``minmax`` from its routes), a helper
process runs ``minmax`` from the auction's routes with another seed; the caller keeps the better.
The helper is a fresh interpreter (``python -m`` this module), not ``multiprocessing``: a fork would
copy locks that the service's other threads hold, and ``spawn`` re-imports the caller's main
script (which breaks scripts without a ``__main__`` guard). The model goes in through a temporary
file, the routes come back on stdout; the helper gets its deadline as wall-clock time, is waited
for with a timeout and killed when late, so nothing waits forever.
"""

from __future__ import annotations

import logging
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from delegation.allocation.optimal.minmax import MinMaxModel, RouteSet, minmax_search

log = logging.getLogger(__name__)

#: The helper is not started for models larger than this (matrix entries): the copy would cost
#: more than the search gains.
HELPER_MAX_ENTRIES = 4_000_000


class HelperSearch:
    """``minmax_search`` in a helper process until ``seconds`` from now."""

    def __init__(self, model: MinMaxModel, routes: list[list[int]], seconds: float, seed: int):
        fd, name = tempfile.mkstemp(prefix="delegation-minmax-", suffix=".pickle")
        self._input = Path(name)
        with os.fdopen(fd, "wb") as f:
            pickle.dump((model, routes, time.time() + seconds, seed), f)
        src = str(Path(__file__).resolve().parents[3])  # the directory holding ``delegation``
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(
            p for p in (src, os.environ.get("PYTHONPATH", "")) if p
        )}
        self._process = subprocess.Popen(
            [sys.executable, "-m", __name__, str(self._input)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
        )

    def result(self, timeout: float) -> RouteSet | str:
        """The helper's routes, or why there are none (late, failed); the helper is gone after."""
        try:
            out, err = self._process.communicate(timeout=max(0.0, timeout))
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.communicate()
            return "no answer in time (stopped)"
        finally:
            self._input.unlink(missing_ok=True)
        if self._process.returncode != 0:
            lines = err.decode(errors="replace").strip().splitlines()
            return f"helper failed ({lines[-1] if lines else self._process.returncode})"
        routes, lengths, rounds = pickle.loads(out)
        return RouteSet(routes, np.asarray(lengths, dtype=float), rounds)


def _main(path: str) -> int:
    """The helper: read the model, search until the deadline, print the routes (pickled)."""
    with open(path, "rb") as f:
        model, routes, wall_deadline, seed = pickle.load(f)
    deadline = time.perf_counter() + (wall_deadline - time.time())
    best = minmax_search(model, routes, deadline, seed)
    sys.stdout.buffer.write(pickle.dumps((best.routes, best.lengths.tolist(), best.rounds)))
    sys.stdout.buffer.flush()
    return 0


if __name__ == "__main__":
    sys.exit(_main(sys.argv[1]))
