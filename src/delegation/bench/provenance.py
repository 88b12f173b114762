"""Where a result came from: versions, commit, machine, date and the exact command.

Stored under ``meta.provenance`` in every results.json, so that two result files can be compared
honestly (``delegation bench compare`` prints both).
"""

from __future__ import annotations

import datetime as dt
import os
import platform
import shlex
import subprocess
import sys
from collections.abc import Sequence
from importlib import metadata
from pathlib import Path
from typing import Any


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def git_commit(where: Path | None = None) -> str | None:
    """The commit of the checkout holding this package (``+dirty`` with local changes); None
    when it is not in a git checkout or git is missing."""
    folder = where or Path(__file__).resolve().parent
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=folder, capture_output=True,
                                text=True, timeout=5, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=folder, capture_output=True, text=True, timeout=5,
                               check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return commit + ("+dirty" if dirty else "") if commit else None


def provenance(argv: Sequence[str] | None = None, **extra: Any) -> dict[str, Any]:
    """The facts a reader needs to trust or reproduce a result."""
    from delegation import __version__

    words = list(argv) if argv is not None else sys.argv[1:]
    return {
        "delegation": __version__,
        "commit": git_commit(),
        "python": platform.python_version(),
        "ortools": _version("ortools"),
        "numpy": _version("numpy"),
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "date": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "command": shlex.join(["delegation", *words]),
        "cwd": os.getcwd(),
        **extra,
    }
