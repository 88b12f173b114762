"""Helper processes for the planner's second core (``allocation.optimal.parallel``).

A fresh interpreter per helper, not ``multiprocessing``: a fork would copy locks that the
service's other threads hold, and ``spawn`` re-imports the caller's main script. The payload goes
in through a private temporary file, the answer comes back on stdout; a helper still running when
its answer is due is killed.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path


class HelperProcess:
    """``python script payload-file``, started at once."""

    def __init__(self, script: Path, payload: bytes) -> None:
        fd, name = tempfile.mkstemp(prefix="delegation-helper-", suffix=".pickle")
        self._input = Path(name)
        with os.fdopen(fd, "wb") as f:
            f.write(payload)
        self._process = subprocess.Popen(
            [sys.executable, str(script), name], stdout=subprocess.PIPE, stderr=subprocess.PIPE
        )

    def result(self, timeout: float) -> bytes | str:
        """Its stdout once it exits within ``timeout`` s, else why not (it is killed then)."""
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
        return out


def launch(script: Path, payload: bytes) -> HelperProcess:
    """A ``SecondCore`` for ``allocation.optimal.parallel.use_second_core``."""
    return HelperProcess(script, payload)
